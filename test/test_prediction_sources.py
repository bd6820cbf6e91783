"""Error sources and the tolerance spec (seed 004 §1-2): parsing, refusals, sampling."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError
from positioning_cell.prediction.sources import (
    catalogue,
    draw_sources,
    load_tolerance_spec,
    parse_tolerance_spec,
)
from positioning_cell.tools.predict_accuracy import shipped_config

MECH = Mechanism.default()
BASE: dict[str, object] = {'tolerances': {'u_centre': 20e-6}, 'requirement': {'position': 1e-4,
                                                           'orientation': 1e-3}}


def spec_with(**changes: object) -> dict[str, object]:
    data: dict[str, object] = dict(BASE)
    data.update(changes)
    return data


def test_shipped_spec_names_every_source_in_si() -> None:
    spec = load_tolerance_spec(shipped_config('tolerances.yaml'), MECH)
    assert spec.names == tuple(name for name, *_ in catalogue())
    assert spec.gap.mode == 'any'  # the default: every clearance direction
    assert len(spec.sources) == 45  # 27 scalars + 6 clearance offset vectors (x, y, z)
    assert len(spec.balls) == 6
    assert all(spec.sources[a].in_ball and spec.sources[a].axis == 'x' for a, _ in spec.balls)
    assert all(0.0 < b < 1e-3 for b in spec.bounds)
    enc = next(s for s in spec.sources if s.kind == 'encoder_theta')
    assert enc.bound == pytest.approx(enc.tolerance / 2)  # quantisation: ±q/2


def test_specific_names_override_groups_and_clearance_defaults_to_the_mechanism() -> None:
    spec = parse_tolerance_spec(spec_with(tolerances={
        'u_centre': 20e-6, 'u_centre_2': 5e-6, 'u_centre_2_x': 1e-6}), MECH)
    value = dict(zip(spec.names, (s.tolerance for s in spec.sources), strict=True))
    assert value['u_centre_1_y'] == 20e-6
    assert value['u_centre_2_y'] == 5e-6
    assert value['u_centre_2_x'] == 1e-6
    assert value['leg_length_1'] == 0.0
    assert value['u_clearance_3_x'] == MECH.joint_clearance_u  # one offset vector per joint
    assert value['s_clearance_1_z'] == MECH.joint_clearance_s


@pytest.mark.parametrize(('changes', 'words'), [
    ({'tolerances': {'u_center': 1e-5}}, ["'u_center'", 'unknown source']),
    ({'tolerances': {'leg_length_4': 1e-5}}, ["'leg_length_4'", 'unknown source']),
    ({'tolerances': {'s_centre': -1e-6}}, ['tolerances.s_centre', '-1e-06']),
    ({'tolerances': {'leg_length': math.nan}}, ['tolerances.leg_length', 'nan']),
    ({'tolerances': {'leg_length': 'big'}}, ['tolerances.leg_length', "'big'"]),
    ({'tolerances': {'u_centre': 0.02}}, ['tolerances.u_centre', 'SI units']),
    ({'tolerances': {}}, ['tolerances']),
    ({'requirement': {'position': 1e-4}}, ['requirement', 'orientation']),
    ({'requirement': {'position': 0.0, 'orientation': 1e-3}}, ['requirement.position']),
    ({'distributions': {'u_centre': 'gauss'}}, ['distributions.u_centre', "'gauss'"]),
    ({'clearance_direction': 'load'}, ['clearance_direction', "'load'"]),
    ({'tolerances': {'u_clearance_2_x': 1e-4}}, ["'u_clearance_2_x'", 'name the joint']),
    ({'tolerances': {'s_clearance_1_z': 1e-4}, 'clearance_direction': 'leg'},
     ["'s_clearance_1_z'", 'unknown source']),
    ({'motion': [0, 0, 1]}, ['motion']),
    ({'tolerance': {}}, ["'tolerance'", 'unknown key']),
])
def test_bad_specs_are_refused_naming_key_and_value(changes: dict[str, object],
                                                    words: list[str]) -> None:
    with pytest.raises(ConfigError) as info:
        parse_tolerance_spec(spec_with(**changes), MECH)
    for word in words:
        assert word in str(info.value)


def test_draws_respect_bounds_laws_and_seed() -> None:
    spec = parse_tolerance_spec(spec_with(
        tolerances={'u_centre': 30e-6, 'leg_length': 10e-6, 'encoder_theta': 1e-4},
        distributions={'leg_length': 'uniform'}), MECH)
    x = draw_sources(spec, 40_000, np.random.default_rng(3))
    again = draw_sources(spec, 40_000, np.random.default_rng(3))
    np.testing.assert_array_equal(x, again)
    assert np.all(np.abs(x) <= spec.bounds)
    # each column against its law (truncated normal at 3σ, or uniform), independent of the code
    for j, src in enumerate(spec.sources):
        if src.in_ball:  # a component of a clearance offset vector: test_clearance_balls_...
            continue
        if src.bound == 0.0:
            assert np.all(x[:, j] == 0.0)
            continue
        law = (stats.truncnorm(-3, 3, scale=src.bound / 3) if src.distribution == 'normal'
               else stats.uniform(-src.bound, 2 * src.bound))
        assert stats.kstest(x[:, j], law.cdf).pvalue > 1e-4, src.name
        assert x[:, j].std() == pytest.approx(src.std, rel=0.03)


def test_clearance_balls_are_drawn_in_every_direction_within_their_radius() -> None:
    spec = parse_tolerance_spec(spec_with(tolerances={'u_clearance': 1.6e-4,
                                                      's_clearance_2': 1e-4}), MECH)
    assert spec.names[spec.balls[0][0]:spec.balls[0][1]] == (
        'u_clearance_1_x', 'u_clearance_1_y', 'u_clearance_1_z')
    x = draw_sources(spec, 40_000, np.random.default_rng(8))
    for a, b in spec.balls:
        src = spec.sources[a]
        e = x[:, a:b]
        length = np.linalg.norm(e, axis=1)
        assert np.all(length <= src.bound * (1 + 1e-12))
        # the length follows the source's law (uniform on ±r: |x| uniform on [0, r]) ...
        assert stats.kstest(length, stats.uniform(0, src.bound).cdf).pvalue > 1e-4, src.name
        # ... the direction is uniform on the sphere: each coordinate of e/|e| is U[-1, 1]
        for k in range(3):
            assert stats.kstest(e[:, k] / length, stats.uniform(-1, 2).cdf).pvalue > 1e-4
        # uncorrelated components, each with the std the linear model uses (σ_x / √3)
        np.testing.assert_allclose(np.cov(e.T), np.eye(3) * src.std**2, rtol=0,
                                   atol=0.03 * src.std**2)
        assert all(s.std == src.std for s in spec.sources[a:b])
