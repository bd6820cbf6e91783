"""Static compliance (ISO 9283 §10): the slope and its U by hand (positioning_cell.accuracy
.compliance), the load rig of the simulated machine (positioning_cell.sim.load_rig), the test's
program block and markers (positioning_cell.analysis.compliance_test), the procedure on the
in-process cell (positioning_cell.procedures.compliance_test), its place in the acceptance
record, and seeded runs whose measured compliance lies within U of the truth's."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from positioning_cell import names
from positioning_cell.accuracy.compliance import DIRECTIONS, static_compliance
from positioning_cell.analysis.acceptance import (
    MACHINE,
    AcceptanceLimits,
    characteristics,
    not_measured,
    program_gaps,
)
from positioning_cell.analysis.compliance_test import (
    ComplianceMarker,
    ComplianceTest,
    compliance_results,
    parse_markers,
)
from positioning_cell.analysis.program import program_from
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.kinematics import inverse
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.moves.correction import mean_reading
from positioning_cell.parameters import parse
from positioning_cell.procedures.compliance_test import run_compliance_test
from positioning_cell.procedures.port import ProcedureError
from positioning_cell.sim.pose_measurement import (
    PoseMeasurementSettings,
    PoseMeasurementSimulator,
)
from positioning_cell.sim.tracker import observe
from positioning_cell.testing.instant_port import InstantPort

P1 = np.array([0.0, 0.0, 0.196])
Q = np.array([0.0, 0.0, 0.0, 1.0])
X = np.array(DIRECTIONS['+x'])


def _settings() -> PoseMeasurementSettings:
    return parse(PoseMeasurementSettings,
                 node_parameters(load_parameter_file(config_path()), names.NODE_MEASUREMENT))


# -- the figure --------------------------------------------------------------------------------
def test_a_hand_worked_example() -> None:
    """Loads 0, 10, 20 N along +x, x at 0, 10, 22 µm: F̄ 10 N, S_FF 200 N², slope
    (−10·(0 − x̄) + 10·(22 − x̄)) µm/200 N² = 1.1 µm/N; the line through (10 N, x̄ 32/3 µm)
    misses the steps by 1/3, 2/3, 1/3 µm. Each position σ 1 µm per axis, the rig exact:
    u = σ/√S_FF, U = 2·1e-6/√200 m/N. With a 3 % rig (a bound): u_rel 3 %/√3 joins it."""
    p = np.array([[0.0, 0, 0], [10e-6, 0, 0], [22e-6, 0, 0]]) + P1
    cov = np.tile(np.eye(3) * 1e-12, (3, 1, 1))
    c = static_compliance(X, [0.0, 10.0, 20.0], p, cov, 0.0)
    assert c.compliance == pytest.approx(1.1e-6, rel=1e-9)
    assert c.along == pytest.approx(1.1e-6, rel=1e-9)
    np.testing.assert_allclose(c.slope, [1.1e-6, 0.0, 0.0], atol=1e-15)
    assert c.nonlinearity == pytest.approx(2e-6 / 3, rel=1e-6)
    assert c.u_compliance == pytest.approx(2 * 1e-6 / math.sqrt(200), rel=1e-9)
    assert c.largest_load == 20.0 and c.steps == 3
    rig = static_compliance(X, [0.0, 10.0, 20.0], p, cov, 0.03)
    assert rig.u_compliance == pytest.approx(
        2 * math.hypot(1e-6 / math.sqrt(200), 1.1e-6 * 0.03 / math.sqrt(3)), rel=1e-9)


def test_a_yield_across_the_load_counts_and_the_intercept_is_free() -> None:
    """A load along −y that moves the platform 3 µm/N along −y and 4 µm/N along +z from an
    offset start: |c| 5 µm/N, 3 along the load, on the line."""
    loads = np.linspace(0.0, 50.0, 6)
    p = P1 + [1e-4, 2e-4, -3e-4] + np.outer(loads, [0.0, -3e-6, 4e-6])
    c = static_compliance(DIRECTIONS['-y'], loads, p, np.zeros((6, 3, 3)), 0.0)
    assert c.compliance == pytest.approx(5e-6, rel=1e-9)
    assert c.along == pytest.approx(3e-6, rel=1e-9)
    assert c.nonlinearity == pytest.approx(0.0, abs=1e-12) and c.u_compliance == 0.0


@pytest.mark.parametrize(('direction', 'loads', 'why'), [
    (X, [10.0, 10.0], 'two different loads'),
    (X, [0.0, math.nan], 'finite'),
    ([1.0, 1.0, 0.0], [0.0, 10.0], 'unit vector'),
])
def test_bad_input_is_refused(direction: object, loads: list[float], why: str) -> None:
    with pytest.raises(InputError, match=why):
        static_compliance(direction, loads, np.tile(P1, (2, 1)), np.zeros((2, 3, 3)), 0.0)  # type: ignore[arg-type]


# -- the simulated load rig ---------------------------------------------------------------------
def test_the_rig_loads_the_simulated_machine_and_refuses_bad_commands() -> None:
    """A force joins the truth's payload (times 1 + the rig's error): the true pose moves
    under it; a force beyond the rig or not finite is refused and changes nothing; zero
    unloads."""
    sim = PoseMeasurementSimulator(_settings())
    mech = sim.settings.mechanism
    joints = inverse(mech, P1, Q)
    free = sim.truth.poses(joints.lengths, joints.thetas).position[0]
    assert sim.apply_load([50.0, 0.0, 0.0]).tolist() == [50.0, 0.0, 0.0]
    wrench = sim.truth.effects.payload.external_wrench
    assert wrench[0] == pytest.approx(50.0 * (1 + sim.settings.truth.load_rig.force_error))
    loaded = sim.truth.poses(joints.lengths, joints.thetas).position[0]
    assert 20e-6 < loaded[0] - free[0] < 100e-6  # this machine yields ~1 µm/N along x
    for bad, why in (([math.nan, 0.0, 0.0], 'finite'), ([2000.0, 0.0, 0.0], 'largest force'),
                     ([1.0, 2.0], 'three')):
        with pytest.raises(InputError, match=why):
            sim.apply_load(bad)
        assert sim.load.tolist() == [50.0, 0.0, 0.0]
    assert sim.diagnostics()[2]['load_rig_force_n'] == [50.0, 0.0, 0.0]
    sim.apply_load(np.zeros(3))
    np.testing.assert_allclose(sim.truth.poses(joints.lengths, joints.thetas).position[0],
                               free, atol=1e-12)


def test_a_new_load_makes_the_next_true_pose_anew() -> None:
    """The machine at rest (the same joints again) is computed anew after a load."""
    sim = PoseMeasurementSimulator(_settings())
    joints = inverse(sim.settings.mechanism, P1, Q)
    values = np.r_[joints.lengths[0], joints.thetas[0]]
    sim.joints(values, 1, 0.0)
    before = sim.update_truth()
    sim.apply_load([0.0, 40.0, 0.0])
    sim.joints(values, 2, 0.05)
    after = sim.update_truth()
    assert before is not None and after is not None and after.stamp == 2
    assert after.position[1] - before.position[1] > 20e-6


# -- the program block and the markers -----------------------------------------------------------
def _program(block: object) -> object:
    data = yaml.safe_load(config_path('acceptance.yaml').read_text())
    data['program']['compliance'] = block
    return program_from(data, Mechanism())


def test_the_shipped_acceptance_program_has_a_compliance_test() -> None:
    data = yaml.safe_load(config_path('acceptance.yaml').read_text())
    test = program_from(data, Mechanism()).compliance
    assert test is not None and test.pose == 'P1' and test.directions == tuple(DIRECTIONS)
    assert test.loads() == pytest.approx([6.0 * k for k in range(11)])
    assert test.measured_steps == 66


@pytest.mark.parametrize(('block', 'key'), [
    ({'pose': 'P9'}, 'compliance.pose'), ({'load': 0.0}, 'compliance.load'),
    ({'steps': 1}, 'compliance.steps'), ({'directions': ['+x', '+x']}, 'compliance.directions'),
    ({'directions': ['+w']}, 'compliance.directions'), ({'force_accuracy': -0.1},
                                                       'compliance.force_accuracy'),
    ({'loads': 3}, 'compliance.loads'), ([1, 2], 'compliance'),
])
def test_a_bad_compliance_block_is_refused_naming_its_key(block: object, key: str) -> None:
    with pytest.raises(ConfigError, match=f'program.{key}'):
        _program(block)


def _marker(step: int, load: float, x: float, direction: str = '+x',
            run: str = 'r1') -> ComplianceMarker:
    return ComplianceMarker(run, 'P1', direction, step, load, (x, 0.0, 0.196),
                            ((1e-12, 0.0, 0.0), (0.0, 1e-12, 0.0), (0.0, 0.0, 1e-12)),
                            float(step), step + 0.5, 10, 0.0)


def test_markers_round_trip_and_bad_ones_are_named() -> None:
    marker = _marker(1, 10.0, 1e-5)
    assert ComplianceMarker.from_json(marker.to_json()) == marker
    doc = json.loads(marker.to_json())
    bad = [json.dumps({**doc, 'direction': '+w'}), json.dumps({**doc, 'position': [1, 2]}),
           json.dumps({**doc, 'load': -1.0}), '{"run": 1}', 'not json']
    found, problems = parse_markers([marker.to_json(), *bad])
    assert found == [marker] and len(problems) == len(bad)
    assert all('compliance-test marker' in p for p in problems)


def test_results_per_run_and_direction_and_a_direction_without_two_loads() -> None:
    markers = [_marker(k, 10.0 * k, 1e-6 * k) for k in range(3)]
    markers += [_marker(0, 0.0, 0.0, '-z')]
    results, problems = compliance_results(markers)
    assert [(r.run, r.direction) for r in results] == [('r1', '+x')]
    assert results[0].figures.compliance == pytest.approx(1e-7, rel=1e-9)
    assert len(problems) == 1 and '-z' in problems[0]


# -- the acceptance record --------------------------------------------------------------------
def test_a_program_judging_compliance_without_load_steps_is_refused() -> None:
    data = yaml.safe_load(config_path('acceptance.yaml').read_text())
    del data['program']['compliance']
    program = program_from(data, Mechanism())
    gaps = program_gaps(program, ['compliance'])
    assert len(gaps) == 1 and 'ISO 9283 10' in gaps[0] and 'no load' in gaps[0]
    assert program_gaps(program_from(yaml.safe_load(config_path('acceptance.yaml').read_text()),
                                     Mechanism()), ['compliance']) == []


def test_compliance_decides_every_mode_and_leaves_the_not_measured_list() -> None:
    class Analysis:
        modes = ()
        compliance, _ = compliance_results([_marker(k, 10.0 * k, 1e-6 * k) for k in range(3)])

    found = characteristics(Analysis(), AcceptanceLimits())  # type: ignore[arg-type]
    assert [(c.mode, c.subject, c.clause, c.unit) for c in found] == [
        (MACHINE, 'P1 +x', '10', 'm/N')]
    assert found[0].decision.value == 'conforms'  # 0.1 ± 0.014 µm/N against 1.5 µm/N
    assert '10' not in {clause for clause, _ in not_measured(found)}
    assert '10' in {clause for clause, _ in not_measured(())}


# -- the procedure on the in-process cell --------------------------------------------------------
def test_the_procedure_measures_each_direction_within_u_of_the_truth(tmp_path: Path) -> None:
    """On the in-process cell: a marker per step on /cell/compliance_test, the mode put back,
    the rig unloaded; each direction's compliance within its U of the truth's (judging: the
    truth machine under the same real loads at the joints the drives held)."""
    port = InstantPort.from_config(tmp_path)
    port.home()
    port.set_mode('model')
    test = ComplianceTest(load=60.0, steps=4, directions=('+x', '-y', '+z'), samples=10)
    lines: list[str] = []
    markers = run_compliance_test(port, test, P1, Q, lines.append)
    assert len(markers) == len(port.marks) == test.measured_steps == 15
    assert {t for t, _ in port.marks} == {names.COMPLIANCE_TEST}
    assert port.mode() == 'model' and port.sim.load.tolist() == [0.0, 0.0, 0.0]
    assert sum('µm/N' in line for line in lines) == 3
    results, problems = compliance_results(markers)
    assert not problems
    held = port.cell.position
    sim = port.sim
    error = sim.settings.truth.load_rig.force_error
    for r in results:
        e = np.array(DIRECTIONS[r.direction])
        true = [sim.settings.true_machine(load * e).poses(held[None, :3], held[None, 3:])
                .position[0] for load in test.loads()]
        truth = static_compliance(e, np.array(test.loads()) * (1 + error), true,
                                  np.zeros((len(true), 3, 3)), 0.0)
        assert abs(r.figures.compliance - truth.compliance) <= r.figures.u_compliance
        assert 0.05e-6 < truth.compliance < 2e-6


def test_a_load_the_rig_refuses_ends_the_test_unloaded(tmp_path: Path) -> None:
    port = InstantPort.from_config(tmp_path)
    port.home()
    mode = port.mode()
    with pytest.raises(ProcedureError, match='largest force'):
        run_compliance_test(port, ComplianceTest(load=5000.0, directions=('+x',)), P1, Q,
                            lambda _: None)
    assert port.sim.load.tolist() == [0.0, 0.0, 0.0] and port.mode() == mode


# -- the truth within U, seeded -----------------------------------------------------------------
def test_the_measured_compliance_lies_within_u_of_the_truth_in_seeded_runs() -> None:
    """200 seeded tests of the six directions (10 steps to 60 N, 10 readings a step, a new
    registration every 20): the compliance from the simulated tracker's readings within its
    U of the one from the true poses under the rig's real loads in ≥ 95 % of them."""
    settings = _settings()
    sim = PoseMeasurementSimulator(settings)
    joints = inverse(settings.mechanism, P1, Q)
    loads = np.linspace(0.0, 60.0, 11)
    real = loads * (1 + settings.truth.load_rig.force_error)
    true = {d: np.array([settings.true_machine(f * np.array(e)).poses(
        joints.lengths, joints.thetas).position[0] for f in loads])
        for d, e in DIRECTIONS.items()}
    truth = {d: static_compliance(DIRECTIONS[d], real, p, np.zeros((11, 3, 3)), 0.0).compliance
             for d, p in true.items()}
    samples, covered, total = 10, 0, 0
    for seed in range(200):
        rng = np.random.default_rng(seed)
        if seed % 20 == 0:
            sim.locate()
        assert sim.location is not None
        located = sim.location.tracker
        for d, p in true.items():
            _, fit = observe(sim.instrument, located, settings.targets,
                             np.repeat(p, samples, axis=0), np.tile(Q, (11 * samples, 1)), rng)
            common = located.registration.covariance_at(p.mean(axis=0)[None])[0]
            means, covs = [], []
            for k in range(11):
                rows = slice(k * samples, (k + 1) * samples)
                m, _, cov = mean_reading(fit.position[rows], fit.quaternion[rows],
                                         fit.covariance[rows], common)
                means.append(m)
                covs.append(cov[:3, :3] - common[:3, :3])
            c = static_compliance(DIRECTIONS[d], loads, means, covs, 0.005)
            covered += abs(c.compliance - truth[d]) <= c.u_compliance
            total += 1
    assert covered / total >= 0.95, f'{covered}/{total}'
