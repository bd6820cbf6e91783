"""A positioner's node set under its namespace (issue 27, item 1), without ROS: the remaps
cover every wire name of a set, the parameter files are rewritten for it (node sections
under the namespace, every seed moved on by the set's index, the set's nodes bound to each
other), and a new wire name must say whether a set remaps it."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from positioning_cell import names
from positioning_cell.config import config_path, load_parameter_file
from positioning_cell.errors import ConfigError
from positioning_cell.ros.node_sets import ALL_NODES, remap_arguments, set_parameter_files

#: Wire names no set remaps: ROS's own, the coordinator's and the coordinated run's (the
#: root's), the live view's Foxglove channels (not ROS topics).
NOT_REMAPPED = {names.PARAMETER_EVENTS, names.COORDINATED_MOVE_ACTION, names.COORDINATED_STOP,
                names.COORDINATED_RELAX, names.COORDINATED_RELAX_FORCES, names.PANEL_FORCES,
                names.PANEL_MEASURED_POSE, names.PANEL_TRUE_POSE, names.PANEL_PROGRAM,
                names.LIVE_SCENE, names.LIVE_TRANSFORMS, names.LIVE_DEVIATION,
                names.LIVE_STATUS}


def test_every_wire_name_is_remapped_by_a_set_or_said_not_to_be() -> None:
    wire = {v for k, v in vars(names).items()
            if k.isupper() and isinstance(v, str) and v.startswith('/') and v != '/**'}
    remapped = {*names.SET_TOPICS, *names.SET_SERVICES, *names.SET_ACTIONS}
    assert wire - remapped - NOT_REMAPPED == set()


def test_the_remaps_put_every_name_of_the_set_under_its_namespace() -> None:
    args = remap_arguments('p2')
    rules = dict(r.split(':=') for r in args[1::2])
    assert args[::2] == ['-r'] * (len(args) // 2)
    assert rules.pop('__ns') == '/p2'
    for name in (*names.SET_TOPICS, *names.SET_SERVICES):
        assert rules.pop(name) == f'/p2{name}'
    for action in names.SET_ACTIONS:
        for part in names.ACTION_ENDPOINTS:
            assert rules.pop(f'{action}/{part}') == f'/p2{action}/{part}'
    assert rules == {}


@pytest.mark.parametrize('namespace', ['', 'p 1', '1p', 'p/1', 'ä'])
def test_a_namespace_that_is_not_a_name_is_refused(namespace: str) -> None:
    with pytest.raises(ConfigError, match='namespace'):
        remap_arguments(namespace)


def test_the_parameter_files_are_the_cells_rewritten_for_the_set(tmp_path: Path) -> None:
    shipped = config_path('cell.yaml')
    files = set_parameter_files([shipped], 'p3', 2, tmp_path,
                                {names.NODE_POSITIONER: {'motion': {'linear_speed': 0.02}}})
    assert [f.name for f in files] == ['p3.0.yaml', 'p3.bindings.yaml']
    original = load_parameter_file(shipped)
    rewritten = load_parameter_file(files[0])
    assert rewritten[ALL_NODES] == original[ALL_NODES]
    assert set(rewritten) == {ALL_NODES} | {f'/p3/{n}' for n in original if n != ALL_NODES}
    truth = rewritten['/p3/pose_measurement']['ros__parameters']['truth']
    before = original['pose_measurement']['ros__parameters']['truth']
    assert truth['geometry_seed'] == before['geometry_seed'] + 2
    assert truth['clearance']['seed'] == before['clearance']['seed'] + 2
    assert truth['drives']['seed'] == before['drives']['seed'] + 2
    assert (rewritten['/p3/leg_driver']['ros__parameters']['encoder']['seed']
            == original['leg_driver']['ros__parameters']['encoder']['seed'] + 2)
    # Everything but the seeds as shipped.
    assert (rewritten['/p3/positioner']['ros__parameters']
            == original['positioner']['ros__parameters'])
    bound = yaml.safe_load(files[1].read_text())
    positioner = bound['/p3/positioner']['ros__parameters']
    assert positioner['sources'] == {'leg_driver': '/p3/leg_driver',
                                     'tracker': '/p3/pose_measurement'}
    assert positioner['motion'] == {'linear_speed': 0.02}
    assert 'sets/p3/' in positioner['operator']['coordinate_systems_file']
    assert bound['/p3/leg_driver']['ros__parameters']['command'] == {
        'commander': '/p3/positioner'}


def test_a_seed_that_draws_nothing_stays_and_a_namespaced_section_is_refused(
        tmp_path: Path) -> None:
    given = tmp_path / 'given.yaml'
    given.write_text(yaml.safe_dump({'pose_measurement': {'ros__parameters': {
        'truth': {'geometry_seed': -1}, 'seed': 4, 'seeded': True}}}))
    (first, _) = set_parameter_files([given], 'p2', 1, tmp_path / 'out')
    params = load_parameter_file(first)['/p2/pose_measurement']['ros__parameters']
    assert params == {'truth': {'geometry_seed': -1}, 'seed': 5, 'seeded': True}
    given.write_text(yaml.safe_dump({'/p1/positioner': {'ros__parameters': {}}}))
    with pytest.raises(ConfigError, match="section '/p1/positioner'"):
        set_parameter_files([given], 'p2', 1, tmp_path / 'out')
