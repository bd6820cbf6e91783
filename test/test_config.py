"""config/cell.yaml and the nodes' declarations agree: every key of the file is declared by a
node that reads it (a typo or a dead block fails here, not silently at run time), every node's
section parses into its settings, and the declarations carry what ROS shows a user."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from positioning_cell import names
from positioning_cell.config import (
    config_path,
    flatten,
    load_parameter_file,
    merged,
    node_parameters,
    share_directory,
)
from positioning_cell.motion.settings import COMPENSATION_MODE, PositionerSettings
from positioning_cell.node_settings import NODE_SETTINGS
from positioning_cell.parameters import declarations, parse, to_params

#: Each node's settings type (the library's table; test_ros_parameters checks the nodes).
NODES = NODE_SETTINGS
CELL = load_parameter_file(config_path('cell.yaml'))


def declared(node: str) -> set[str]:
    return {d.name for d in declarations(NODES[node])}


def test_every_node_executable_has_a_settings_type() -> None:
    assert set(NODES) == {n.name for n in names.NODE_EXECUTABLES}


@pytest.mark.parametrize('section', [k for k in CELL if k != '/**'])
def test_every_key_of_a_node_section_is_declared_by_that_node(section: str) -> None:
    assert section in NODES, f'{section}: no node of that name'
    keys = flatten(CELL[section]['ros__parameters'])
    undeclared = sorted(set(keys) - declared(section))
    assert not undeclared, f'{section}: {undeclared} are read by no node'


def test_every_shared_key_is_declared_by_a_node() -> None:
    keys = flatten(CELL['/**']['ros__parameters'])
    everyone = set().union(*(declared(n) for n in NODES))
    assert not sorted(set(keys) - everyone)
    # The machine's load is shared by every node that models it (no silent defaults).
    for node in (names.NODE_POSITIONER, names.NODE_DRIVER, names.NODE_MEASUREMENT):
        assert {'payload.mass', 'structure.leg_stiffness', 'mechanism.base_radius'} <= \
            declared(node)


@pytest.mark.parametrize('node', sorted(NODES))
def test_each_section_parses_into_the_node_settings(node: str) -> None:
    params = flatten(node_parameters(CELL, node))
    mine = {k: v for k, v in params.items() if k in declared(node)}
    settings = parse(NODES[node], mine)
    # Every value of the file is the one the node gets (a key read into the wrong field, or
    # dropped for its default, would differ here).
    got = flatten(to_params(settings))
    for key, value in mine.items():
        assert key in got, f'{node}: {key} is not in the parsed settings'
        if isinstance(value, str | bool) or value is None or (
                isinstance(value, list) and all(isinstance(v, str) for v in value)):
            assert got[key] == value, f'{node}: {key}: file {value!r}, settings {got[key]!r}'
            continue
        want = np.asarray(value, dtype=float)
        if want.shape != np.shape(got[key]):  # a short form the settings expand (a diagonal)
            want = np.asarray(flatten(to_params(parse(NODES[node], {key: value})))[key],
                              dtype=float)
        np.testing.assert_allclose(np.asarray(got[key], dtype=float), want, rtol=1e-12,
                                   atol=0, err_msg=f'{node}: {key}')


def test_a_misspelt_key_would_be_found() -> None:
    bad = {'positioner': {'ros__parameters': {'goal_tolerance': {'positon': 1e-5}}}}
    keys = flatten(bad['positioner']['ros__parameters'])
    assert set(keys) - declared('positioner') == {'goal_tolerance.positon'}


def test_declarations_say_what_a_user_needs() -> None:
    for node, cls in NODES.items():
        for d in declarations(cls):
            assert d.rule.description, f'{node}: {d.name} has no description'
    by_name = {d.name: d for d in declarations(PositionerSettings)}
    speed = by_name['motion.linear_speed']
    assert speed.rule.unit == 'm/s' and not speed.read_only
    assert 'unit: m/s' in speed.constraints() and 'in [1e-05, 1]' in speed.constraints()
    iterations = by_name['compensation.max_iterations']
    assert (iterations.rule.low, iterations.rule.high) == (0, 50)
    assert by_name[COMPENSATION_MODE].rule.choices == ('none', 'model', 'measured')
    assert by_name['pose_rate_hz'].read_only


def test_a_pip_install_finds_its_config_under_the_prefix_without_ros(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`pip install .` puts config/ in <prefix>/share/positioning_cell (data_files); without
    a ROS environment (no ament index) that is where the shipped files are found."""
    share = tmp_path / 'share' / 'positioning_cell'
    (share / 'config').mkdir(parents=True)
    monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    monkeypatch.setattr(sys, 'prefix', str(tmp_path))
    assert share_directory() == share
    monkeypatch.setattr(sys, 'prefix', str(tmp_path / 'elsewhere'))
    assert (share_directory() / 'config' / 'cell.yaml').is_file()  # the source tree


def test_the_coordinated_cells_overlay_is_declared_and_parses_after_cell_yaml() -> None:
    """config/coordinated.yaml (run_cell --cell's nodes after config/cell.yaml): every key
    declared by its node, and the merged file parses into each node's settings with the
    overlay's values."""
    overlay = load_parameter_file(config_path('coordinated.yaml'))
    both = merged(CELL, overlay)
    for section, body in overlay.items():
        keys = flatten(body['ros__parameters'])
        assert not sorted(set(keys) - declared(section)), section
        settings = flatten(to_params(parse(NODES[section], {
            k: v for k, v in flatten(node_parameters(both, section)).items()
            if k in declared(section)})))
        for key, value in keys.items():
            assert settings[key] == pytest.approx(value), f'{section}: {key}'
