"""Mechanism parameters: seed 000 Table 1 defaults, construction from config, validation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from positioning_cell.config import config_path, flatten, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError


def test_defaults_are_seed_000_table_1() -> None:
    m = Mechanism.default()
    assert (m.base_radius, m.platform_radius) == (0.100, 0.060)
    assert (m.length_min, m.length_max) == (0.180, 0.220)
    assert (m.phi_min, m.phi_max, m.theta_min, m.theta_max) == (
        -math.pi / 4, math.pi / 4, -math.pi / 4, math.pi / 4)
    assert m.tilt_max == pytest.approx(math.pi / 3)
    assert m.joint_clearance_u == m.joint_clearance_s == 0.16e-3
    assert m.home_height == pytest.approx(math.sqrt(0.2**2 - 0.04**2))
    # Legs at 90°, 210°, 330°; S-joint triangle of side √3·R_B.
    np.testing.assert_allclose(m.base_joints[0], [0.0, 0.1, 0.0], atol=1e-15)
    side = np.linalg.norm(m.platform_joints[0] - m.platform_joints[1])
    assert side == pytest.approx(math.sqrt(3) * 0.06)


def test_shipped_config_holds_the_default_mechanism() -> None:
    params = node_parameters(load_parameter_file(config_path()), 'positioner')
    assert Mechanism.from_params(params['mechanism']) == Mechanism.default()


def test_from_params_accepts_nested_and_dotted_keys() -> None:
    nested = Mechanism.from_params({'mechanism': {'base_radius': 0.12}})
    dotted = Mechanism.from_params(flatten({'mechanism': {'base_radius': 0.12}}))
    assert nested == dotted and nested.base_radius == 0.12
    assert Mechanism.from_params(Mechanism.default().to_params()) == Mechanism.default()


@pytest.mark.parametrize(('params', 'words'), [
    ({'base_radius': -1.0}, r'mechanism.base_radius = -1.0: must be > 0'),
    ({'base_radus': 0.1}, r'mechanism.base_radus: unknown parameter'),
    ({'length_max': 0.1}, r'length_max = 0.1: must exceed length_min'),
    ({'platform_radius': 'big'}, r"mechanism.platform_radius = 'big': expected a number"),
    ({'tilt_max': 2.0}, r'tilt_max = 2.0'),
    ({'phi_min': float('nan')}, r'must be finite'),
    ({'base_offsets': [1, 2]}, r'mechanism.base_offsets = \[1, 2\]: expected 9 numbers'),
])
def test_bad_parameters_name_key_and_value(params: dict[str, object], words: str) -> None:
    with pytest.raises(ConfigError, match=words):
        Mechanism.from_params(params)


def test_offsets_displace_joint_centres() -> None:
    offsets = np.arange(9.0).reshape(3, 3) * 1e-4
    m = Mechanism.default().with_offsets(base_offsets=offsets)
    np.testing.assert_allclose(m.base_joints - Mechanism.default().base_joints, offsets)
    with pytest.raises(ValueError, match='read-only'):
        m.base_joints[0, 0] = 1.0


def test_node_parameters_merge_global_and_node_sections(tmp_path: object) -> None:
    data = {'/**': {'ros__parameters': {'a': 1, 'm': {'x': 1, 'y': 2}}},
            'node': {'ros__parameters': {'a': 2, 'm': {'y': 3}}}}
    assert node_parameters(data, 'node') == {'a': 2, 'm': {'x': 1, 'y': 3}}
    assert node_parameters(data, 'other') == {'a': 1, 'm': {'x': 1, 'y': 2}}


def test_bad_parameter_file(tmp_path: pytest.TempPathFactory) -> None:
    path = tmp_path / 'bad.yaml'  # type: ignore[operator]
    path.write_text('a: [1, 2')
    with pytest.raises(ConfigError, match='not valid YAML'):
        load_parameter_file(path)
    with pytest.raises(ConfigError, match='cannot be read'):
        load_parameter_file(tmp_path / 'missing.yaml')  # type: ignore[operator]
