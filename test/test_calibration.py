"""Calibration of an unknown machine (positioning_cell.calibration): the identification model
against a second path (the machine model's own IK), its analytic Jacobian against finite
differences, recovery of a simulated machine from simulated tracker data (the truth only
judges), refusals of data that cannot identify, and the calibration file."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from positioning_cell.calibration import file as calfile
from positioning_cell.calibration import identify as idf
from positioning_cell.calibration import parameters as cp
from positioning_cell.calibration import program as prog
from positioning_cell.calibration.calibrated import calibrated_machine
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.kinematics import inverse
from positioning_cell.motion.settings import PositionerSettings
from positioning_cell.parameters import parse
from positioning_cell.sim.campaign import measure_program
from positioning_cell.sim.encoders import EncoderSettings
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings, PoseMeasurementSimulator
from positioning_cell.sim.truth import TruthParameters

PARAMS = node_parameters(load_parameter_file(config_path()), 'pose_measurement')
SETTINGS = parse(PoseMeasurementSettings, PARAMS)
MECH, PAYLOAD, STRUCTURE = SETTINGS.mechanism, SETTINGS.payload, SETTINGS.structure
ENCODERS = EncoderSettings()
PROGRAM = prog.ProgramSettings(poses=60, hold_out=20, candidates=2000)
POSE_COV = np.diag([3e-6**2] * 3 + [2e-5**2] * 3)
JOINT_SIGMA = np.r_[[4e-7] * 3, [3e-6] * 3]


def simulator(geometry_seed: int, **payload: Any) -> PoseMeasurementSimulator:
    """The simulated machine of ``geometry_seed``, exactly of the identified model (its
    effects outside the model off: these tests claim recovery of that model)."""
    truth = replace(SETTINGS.truth.without_effects(), geometry_seed=geometry_seed)
    return PoseMeasurementSimulator(replace(SETTINGS, truth=truth,
                                            payload=replace(PAYLOAD, **payload)))


def campaign(sim: PoseMeasurementSimulator, p: Any, q: Any, seed: int = 1) -> idf.CalibrationData:
    """What the cell records commanding poses by nominal IK and measuring them."""
    cmd = inverse(MECH, p, q)
    assert sim.location is not None
    return measure_program(sim.truth, sim.instrument, sim.location.tracker, SETTINGS.targets,
                           ENCODERS, np.c_[cmd.lengths, cmd.thetas], np.random.default_rng(seed))


@pytest.fixture(scope='module')
def program() -> prog.Program:
    return prog.choose(MECH, PAYLOAD, STRUCTURE, PROGRAM, POSE_COV, JOINT_SIGMA)


@pytest.fixture(scope='module')
def calibrated(program: prog.Program) -> tuple[PoseMeasurementSimulator, idf.Identification]:
    sim = simulator(0)
    data = campaign(sim, program.position, program.quaternion)
    return sim, idf.identify(MECH, PAYLOAD, STRUCTURE, data)


def truth_vector(sim: PoseMeasurementSimulator) -> Any:
    return cp.vector_of(sim.truth, MECH)


def test_identification_model_matches_the_machine_model_ik(program: prog.Program) -> None:
    """Second path: the identification's closed-form leg model at the truth's vector gives
    the encoder values MachineModel.commands computes through the clearance model's IK."""
    sim = simulator(3)
    x = truth_vector(sim)
    model = cp.machine_model(x, MECH, PAYLOAD, STRUCTURE)
    pred, _ = idf.predicted_joints(x, MECH, PAYLOAD, STRUCTURE, program.position,
                                   program.quaternion)
    cmd = model.commands(program.position, program.quaternion)
    assert np.allclose(pred, np.c_[cmd.lengths, cmd.thetas], atol=1e-12, rtol=0.0)
    back = model.poses(cmd.lengths, cmd.thetas, cmd.phis)  # FK round trip of the same model
    assert np.allclose(back.position, program.position, atol=1e-9)


def test_analytic_jacobian_matches_finite_differences(program: prog.Program) -> None:
    x = truth_vector(simulator(2))
    p, q = program.position[:10], program.quaternion[:10]
    _, jac = idf.predicted_joints(x, MECH, PAYLOAD, STRUCTURE, p, q, with_jacobian=True)
    assert jac is not None
    scale = cp.scales(MECH)
    frozen = idf.force_directions(x, MECH, PAYLOAD, STRUCTURE, p, q)
    for k in range(cp.COUNT):
        dx = np.zeros(cp.COUNT)
        dx[k] = h = 1e-3 * scale[k]
        numeric = {}
        for label, directions in (('frozen', frozen), ('full', None)):
            plus, _ = idf.predicted_joints(x + dx, MECH, PAYLOAD, STRUCTURE, p, q,
                                           directions=directions)
            minus, _ = idf.predicted_joints(x - dx, MECH, PAYLOAD, STRUCTURE, p, q,
                                            directions=directions)
            numeric[label] = (plus - minus) / (2 * h)
        column = np.abs(numeric['full']).max()
        # exact with the force directions held (as the analytic Jacobian holds them) ...
        assert np.abs(jac[:, :, k] - numeric['frozen']).max() <= 1e-6 * column, \
            cp.PARAMETER_NAMES[k]
        # ... and what turning them adds is a few per cent of a joint-centre column
        assert np.abs(jac[:, :, k] - numeric['full']).max() <= 0.05 * column, \
            cp.PARAMETER_NAMES[k]


def test_program_is_within_limits_and_better_conditioned_than_random(
        program: prog.Program) -> None:
    from positioning_cell.core.limits import within_limits
    assert within_limits(MECH, program.position, program.quaternion).all()
    assert within_limits(MECH, program.hold_out_position, program.hold_out_quaternion).all()
    rows = idf.information_rows(MECH, PAYLOAD, STRUCTURE, program.position, program.quaternion,
                                POSE_COV, JOINT_SIGMA)
    p, q = prog.candidates(MECH, PROGRAM)
    rnd = idf.information_rows(MECH, PAYLOAD, STRUCTURE, p[:60], q[:60], POSE_COV, JOINT_SIGMA)

    # poses alone excite every class but the thermal and reversal ones (conditions do)
    excited = np.r_[0:cp.THERMAL.start, cp.LEAD]
    assert not rows[:, :, cp.THERMAL].any() and not rows[:, :, cp.REVERSAL].any()

    def singular_values(r: Any) -> Any:
        return np.linalg.svd(r.reshape(-1, cp.COUNT)[:, excited], compute_uv=False)

    chosen, drawn = singular_values(rows), singular_values(rnd)
    # D-optimal: the volume of the information ellipsoid, and its thinnest axis, both grow
    assert np.sum(np.log(chosen)) > np.sum(np.log(drawn)) + 5.0
    assert chosen[-1] > drawn[-1]


def test_calibration_recovers_the_machine_and_removes_its_error(
        program: prog.Program, calibrated: Any) -> None:
    sim, result = calibrated
    truth = truth_vector(sim)
    ident = result.identifiability.identified
    z = (result.x - truth)[ident] / result.sigma[ident]
    assert np.mean(np.abs(z) <= 3.0) >= 0.95, dict(zip(np.array(cp.PARAMETER_NAMES)[ident],
                                                        np.round(z, 2), strict=True))
    assert result.chi2 / result.dof < 2.0
    hp, hq = program.hold_out_position, program.hold_out_quaternion
    errors = {}
    for name, cmd in (('none', inverse(MECH, hp, hq)),
                      ('calibrated', result.model(MECH, PAYLOAD, STRUCTURE).commands(hp, hq))):
        att = sim.truth.poses(cmd.lengths, cmd.thetas)
        errors[name] = np.linalg.norm(att.position - hp, axis=1)
    rms = {k: float(np.sqrt(np.mean(v**2))) for k, v in errors.items()}
    assert rms['none'] > 50e-6
    assert rms['calibrated'] <= 0.05 * rms['none'] and errors['calibrated'].max() <= 25e-6


@pytest.mark.parametrize('mass', [30.0, 70.0])
def test_a_new_payload_needs_its_mass_not_a_new_calibration(program: prog.Program,
                                                            calibrated: Any,
                                                            mass: float) -> None:
    _, result = calibrated
    heavier = simulator(0, mass=mass)
    payload = replace(PAYLOAD, mass=mass)
    hp, hq = program.hold_out_position, program.hold_out_quaternion
    none = inverse(MECH, hp, hq)
    told = result.model(MECH, payload, STRUCTURE).commands(hp, hq)
    e_none = heavier.truth.poses(none.lengths, none.thetas).position - hp
    e_told = heavier.truth.poses(told.lengths, told.thetas).position - hp
    assert np.sqrt(np.mean(e_told**2)) <= 0.10 * np.sqrt(np.mean(e_none**2))


def test_too_few_poses_are_refused(program: prog.Program) -> None:
    data = campaign(simulator(0), program.position[:5], program.quaternion[:5])
    with pytest.raises(idf.IdentificationError, match='5 poses: a calibration needs at least'):
        idf.identify(MECH, PAYLOAD, STRUCTURE, data)


def test_degenerate_poses_are_refused_with_rank_and_names(program: prog.Program) -> None:
    """Twelve measurements of one pose: 6 independent equations, not 26."""
    p = np.repeat(program.position[:1], 12, axis=0)
    q = np.repeat(program.quaternion[:1], 12, axis=0)
    data = campaign(simulator(0), p, q)
    with pytest.raises(idf.IdentificationError,
                       match=rf'12 poses identify \d+ of {cp.COUNT} parameters '
                             '.*not identifiable: '):
        idf.identify(MECH, PAYLOAD, STRUCTURE, data)


def test_parameters_that_cannot_be_separated_are_fixed_and_named(
        program: prog.Program) -> None:
    """Without rotations the U and S centres of a leg move the leg alike: merged, named."""
    p = program.position
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(p), 1))
    data = campaign(simulator(0), p, q)
    result = idf.identify(MECH, PAYLOAD, STRUCTURE, data,
                          idf.IdentificationSettings(min_identified=6))
    merged = result.identifiability.merged
    assert merged and result.identifiability.rank < cp.COUNT
    # each names who absorbs it, or why it was left out (no temperature, no approach), or
    # has hardly an effect at all (a leg's compliance without rotations: no partner >= 0.1)
    info = dict(zip(cp.PARAMETER_NAMES, result.identifiability.information, strict=True))
    assert all(partners or name in result.excluded or info[name] < 1.0
               for name, partners in merged.items())
    assert all(merged[f'leg{i}.platform_offset.z'] for i in (1, 2, 3))
    # the exact machine's campaign holds the air at 20 degC: no range to excite expansion
    assert data.temperature is not None and np.ptp(data.temperature) < 1.0
    assert result.excluded['thermal.leg_expansion'].startswith('temperature range 0.')
    no_approach = idf.identify(MECH, PAYLOAD, STRUCTURE, data._replace(approach=None),
                               idf.IdentificationSettings(min_identified=6))
    assert no_approach.excluded['leg1.theta_reversal'] == 'no approach directions recorded'
    assert np.all(np.isnan(result.sigma[~result.identifiability.identified]))
    # fixed at nominal: 0, but a compliance the nominal structure's (a leg is not rigid)
    fixed = ~result.identifiability.identified
    nominal = np.zeros(cp.COUNT)
    nominal[cp.COMPLIANCE] = cp.nominal_compliance(STRUCTURE)
    np.testing.assert_array_equal(result.x[fixed], nominal[fixed])
    assert np.any(fixed[cp.COMPLIANCE])  # and this case shows it


def test_bad_data_is_refused() -> None:
    n = 10
    good = idf.CalibrationData(np.zeros((n, 6)), np.ones((n, 6)), np.zeros((n, 3)),
                               np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
                               np.tile(np.eye(6), (n, 1, 1)))
    with pytest.raises(idf.InputError, match='joints has shape'):
        idf.check_data(good._replace(joints=np.zeros((n, 5))))
    with pytest.raises(idf.InputError, match='non-finite'):
        idf.check_data(good._replace(covariance=np.full((n, 6, 6), np.nan)))
    with pytest.raises(idf.InputError, match='joint_sigma must be > 0'):
        idf.check_data(good._replace(joint_sigma=np.zeros((n, 6))))
    with pytest.raises(idf.InputError, match='temperature has shape'):
        idf.check_data(good._replace(temperature=np.zeros(n - 1)))
    for bad in (np.nan, 80.0):
        with pytest.raises(idf.InputError, match='temperature must be finite and within'):
            idf.check_data(good._replace(temperature=np.full(n, bad)))
    with pytest.raises(idf.InputError, match='approach holds values other than'):
        idf.check_data(good._replace(approach=np.full((n, 6), 0.5)))
    located = good._replace(registration_origin=np.zeros((n, 3)),
                            registration_covariance=np.tile(np.eye(6), (n, 1, 1)))
    with pytest.raises(idf.InputError, match='come together'):
        idf.check_data(located._replace(registration_covariance=None))
    with pytest.raises(idf.InputError, match=r'expected \(10, 3\) and \(10, 6, 6\)'):
        idf.check_data(located._replace(registration_origin=np.zeros((n - 1, 3))))
    skewed = np.tile(np.eye(6), (n, 1, 1))
    skewed[:, 0, 1] = 1e-3
    with pytest.raises(idf.InputError, match='symmetric covariances'):
        idf.check_data(located._replace(registration_covariance=skewed))


def test_the_conditions_of_each_pose_follow_a_subset() -> None:
    n = 4
    data = idf.check_data(idf.CalibrationData(
        np.zeros((n, 6)), np.ones((n, 6)), np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
        np.tile(np.eye(6), (n, 1, 1)), np.array([20.0, 21.0, 22.0, 23.0]),
        np.tile([1.0, -1.0, 0.0, 1.0, 1.0, -1.0], (n, 1))))
    part = data.subset([1, 3])
    assert part.temperature is not None and part.approach is not None
    np.testing.assert_allclose(part.temperature, [21.0, 23.0])
    assert part.approach.shape == (2, 6)
    assert idf.check_data(data._replace(temperature=None, approach=None)).subset([0]).temperature \
        is None


def test_the_registrations_share_is_how_a_registration_error_moves_the_fit(
        program: prog.Program) -> None:
    """The registration's consider term (identify.registration_consider) against the fit
    itself: the same data re-measured through a registration off by one standard deviation
    along each of its six axes (every measured pose moved rigidly, exactly), re-identified;
    the parameters' responses A (COUNT, 6) give A·Σ_r·Aᵀ, which must match the stated share
    at the hold-out poses. Without registrations in the data the share is zero."""
    sim = simulator(0)
    data = campaign(sim, program.position, program.quaternion)
    assert data.registration_origin is not None and data.registration_covariance is not None
    base = idf.identify(MECH, PAYLOAD, STRUCTURE, data)
    assert base.registration_share is not None
    origin, sigma_r = data.registration_origin[0], data.registration_covariance[0]
    step = np.sqrt(np.diag(sigma_r))
    response = np.empty((cp.COUNT, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = step[i]
        turn = Rotation.from_rotvec(d[3:])
        moved = data._replace(position=origin + d[:3] + turn.apply(data.position - origin),
                              quaternion=(turn * Rotation.from_quat(data.quaternion)).as_quat())
        response[:, i] = (idf.identify(MECH, PAYLOAD, STRUCTURE, moved).x - base.x) / step[i]
    refit = response @ sigma_r @ response.T
    hp, hq = program.hold_out_position, program.hold_out_quaternion
    stated = idf.pose_uncertainty(base.x, base.registration_share, MECH, PAYLOAD, STRUCTURE,
                                  hp, hq)
    seen = idf.pose_uncertainty(base.x, refit, MECH, PAYLOAD, STRUCTURE, hp, hq)
    np.testing.assert_allclose(np.sqrt(np.diagonal(stated, axis1=1, axis2=2)),
                               np.sqrt(np.diagonal(seen, axis1=1, axis2=2)), rtol=0.05,
                               atol=1e-8)
    # the share is a micrometre-size part of the pose uncertainty, not a rounding error
    assert np.sqrt(stated[:, 0, 0]).max() > 1e-6
    bare = idf.identify(MECH, PAYLOAD, STRUCTURE,
                        data._replace(registration_origin=None, registration_covariance=None))
    assert bare.registration_share is not None and not bare.registration_share.any()


# -- the calibration file ----------------------------------------------------------------------
def test_file_round_trip_and_the_positioner_loads_it(tmp_path: Path, calibrated: Any) -> None:
    _, result = calibrated
    path = calfile.write(tmp_path / 'calibration.yaml',
                         calfile.document(result, MECH, 1.0, {'poses': 60}))
    loaded = calfile.load(path, MECH)
    assert np.array_equal(loaded.x, result.x)
    assert np.allclose(loaded.sigma, result.sigma, equal_nan=True)
    assert np.array_equal(loaded.covariance, result.covariance)
    settings = parse(PositionerSettings, {'compensation.calibration_file': str(path)})
    calibrated = calibrated_machine(settings)
    assert calibrated is not None
    assert calibrated.lacks == ('adequacy', 'envelope')  # document() was given neither
    p, q = MECH.home_position, MECH.home_quaternion
    assert np.allclose(calibrated.model.commands(p, q).lengths,
                       result.model(MECH, PAYLOAD, STRUCTURE).commands(p, q).lengths)
    text = path.read_text()
    assert 'truth' not in text  # the file holds what was identified, nothing of the simulator


def test_the_load_bound_is_on_the_read_not_on_a_busy_processor(
        tmp_path: Path, calibrated: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """A parse stretched past the bound (a loaded machine: CI refused a good file so) still
    loads; a read that takes longer than the bound (a stalled file system) is refused."""
    import time

    from positioning_cell.calibration import calibrated as calibrated_module
    _, result = calibrated
    path = calfile.write(tmp_path / 'calibration.yaml',
                         calfile.document(result, MECH, 1.0, {'poses': 60}))
    settings = parse(PositionerSettings, {'compensation.calibration_file': str(path)})
    bound = 0.05
    real_parse, real_read = calfile.parse, calfile.read

    def slow_parse(*args: Any) -> Any:
        time.sleep(3 * bound)
        return real_parse(*args)

    monkeypatch.setattr(calibrated_module, 'parse', slow_parse)
    assert calibrated_machine(settings, timeout=bound) is not None

    def slow_read(*args: Any) -> Any:
        time.sleep(3 * bound)
        return real_read(*args)

    monkeypatch.setattr(calibrated_module, 'read', slow_read)
    with pytest.raises(calfile.CalibrationFileError, match=f'not loaded within {bound:g} s'):
        calibrated_machine(settings, timeout=bound)


@pytest.mark.parametrize(('edit', 'words'), [
    (lambda d: d['calibration'].update(mechanism_fingerprint='0123456789abcdef'),
     'belongs to mechanism'),
    (lambda d: d['calibration']['parameters'].pop('leg2.theta_offset'),
     'lacks parameters leg2.theta_offset'),
    (lambda d: d['calibration']['parameters']['clearance.r_a'].update(value='x'),
     'clearance.r_a.value'),
    (lambda d: d['calibration'].update(format=7), 'format 7'),
    (lambda d: d['calibration'].update(covariance=[[0.0]]),
     f'covariance must be {cp.COUNT} x {cp.COUNT}'),
    (lambda d: d.clear(), 'no "calibration:" mapping'),
])
def test_bad_files_are_refused_with_the_reason(tmp_path: Path, calibrated: Any, edit: Any,
                                               words: str) -> None:
    _, result = calibrated
    doc = calfile.document(result, MECH, 1.0, {'poses': 60})
    edit(doc)
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(calfile.CalibrationFileError, match=words):
        calfile.load(path, MECH)


def test_unreadable_and_non_yaml_files_are_refused(tmp_path: Path) -> None:
    with pytest.raises(calfile.CalibrationFileError, match='cannot be read'):
        calfile.load(tmp_path / 'missing.yaml', MECH)
    (tmp_path / 'junk.yaml').write_text('calibration: [unclosed')
    with pytest.raises(calfile.CalibrationFileError, match='not valid YAML'):
        calfile.load(tmp_path / 'junk.yaml', MECH)


def test_truth_geometry_seed_draws_one_machine_per_seed() -> None:
    a = TruthParameters(geometry_seed=4).geometric_errors()
    b = TruthParameters(geometry_seed=4).geometric_errors()
    c = TruthParameters(geometry_seed=5).geometric_errors()
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], c[0])
    assert all(not np.any(x) for x in TruthParameters().geometric_errors())


@pytest.mark.nodes  # imports the nodes (rclpy) to read their declarations
def test_no_node_but_the_simulators_declares_a_truth_parameter() -> None:
    """The oracle rule, checked on the declarations: the positioner, the monitor, the recorder
    and the player declare no truth.* parameter (the simulators do: the tracker simulator
    holds the machine's truth). The calibration file is checked in the round-trip test."""
    from positioning_cell.nodes.accuracy_monitor_node import AccuracyMonitorNode
    from positioning_cell.nodes.bag_player_node import BagPlayerNode
    from positioning_cell.nodes.kinematics_node import PositionerNode
    from positioning_cell.nodes.pose_measurement_node import PoseMeasurementNode
    from positioning_cell.nodes.recorder_node import RecorderNode
    from positioning_cell.parameters import declarations
    for node in (PositionerNode, AccuracyMonitorNode, RecorderNode, BagPlayerNode):
        found = [d.name for d in declarations(node.SETTINGS) if 'truth' in d.name.split('.')]
        assert not found, (node.NAME, found)
    assert any(d.name.startswith('truth.') for d in declarations(PoseMeasurementNode.SETTINGS))


def test_pose_uncertainty_matches_machines_drawn_from_the_parameter_covariance(
        program: prog.Program, calibrated: Any) -> None:
    """Second path: machines drawn from N(x, Cov) of the identification, each commanded with
    the calibrated model; the scatter of where they put the platform against the first-order
    covariance pose_uncertainty promises. The fixed parameters' prior is left out here (its
    consider covariance holds r_a about its bound 0, which a draw would cross; it has its own
    Monte Carlo test below)."""
    sim, _ = calibrated
    data = campaign(sim, program.position, program.quaternion)
    result = idf.identify(MECH, PAYLOAD, STRUCTURE, data, idf.IdentificationSettings(
        fixed_prior=0.0, compliance_prior=0.0))
    p, q = program.hold_out_position[:3], program.hold_out_quaternion[:3]
    promised = idf.pose_uncertainty(result.x, result.covariance, MECH, PAYLOAD, STRUCTURE,
                                    p, q)
    cmd = result.model(MECH, PAYLOAD, STRUCTURE).commands(p, q)
    rng = np.random.default_rng(11)
    free = result.identifiability.identified
    cov = result.covariance[np.ix_(free, free)]
    reached = []
    # Draws of a third of the covariance: r_a - r_b is poorly determined, and full draws
    # would cross the physical bound r >= 0 (a clearance cannot be negative).
    shrink = 1.0 / 3.0
    for draw in rng.multivariate_normal(np.zeros(free.sum()), cov * shrink**2, 300):
        x = result.x.copy()
        x[free] += draw
        assert np.all(x[cp.CLEARANCE] >= 0.0)
        reached.append(cp.machine_model(x, MECH, PAYLOAD, STRUCTURE)
                       .poses(cmd.lengths, cmd.thetas, cmd.phis).position)
    scatter = np.std(np.array(reached), axis=0) / shrink  # (poses, 3)
    sigma = np.sqrt(np.diagonal(promised[:, :3, :3], axis1=1, axis2=2))
    assert np.allclose(scatter, sigma, rtol=0.15), (scatter * 1e6, sigma * 1e6)


def test_predict_accuracy_gives_the_calibrated_machines_uncertainty(
        tmp_path: Path, calibrated: Any) -> None:
    """predict_accuracy --calibration: the promise of the identified parameters at a pose, as
    pose_uncertainty computes it from the file's covariance."""
    from positioning_cell.tools.predict_accuracy import calibrated_prediction
    _, result = calibrated
    path = calfile.write(tmp_path / 'calibration.yaml',
                         calfile.document(result, MECH, 1.0, {'poses': 60}))
    position = MECH.home_position + [0.004, -0.002, 0.003]
    text = calibrated_prediction(path, position=position, rotvec=(0.02, 0.0, -0.01))
    q = Rotation.from_rotvec([0.02, 0.0, -0.01]).as_quat()
    cov = idf.pose_uncertainty(result.x, result.covariance, MECH, PAYLOAD, STRUCTURE,
                               position, q)[0]
    assert f'|dp| {np.linalg.norm(np.sqrt(np.diag(cov)[:3])) * 1e6:.3f} um' in text, text
    other = yaml.safe_load(path.read_text())
    other['calibration']['mechanism_fingerprint'] = '1' * 16
    path.write_text(yaml.safe_dump(other))
    with pytest.raises(calfile.CalibrationFileError, match='belongs to mechanism'):
        calibrated_prediction(path)


def test_the_consider_covariance_is_that_of_a_fit_with_parameters_held() -> None:
    """Monte Carlo of the linear model y = J x + noise fitted with the columns outside
    ``free`` held at 0 while their true values scatter with ``prior``: the sample covariance
    of (fitted error, held values) matches consider_covariance."""
    rng = np.random.default_rng(5)
    jac = rng.normal(size=(60, cp.COUNT))
    jac[:, 30] = jac[:, 3] + 0.3 * rng.normal(size=60)  # held, partly absorbed by column 3
    free = np.setdiff1d(np.arange(cp.COUNT), [30, 31, 40])
    prior = np.zeros(cp.COUNT)
    prior[[30, 31]] = [0.5, 2.0]  # column 40 held without uncertainty
    j_free = jac[:, free]
    fit = np.linalg.pinv(j_free.T @ j_free) @ j_free.T
    draws = 20000
    x_true = rng.normal(size=(draws, cp.COUNT)) * np.where(np.isin(np.arange(cp.COUNT), free),
                                                           1.0, prior)
    y = x_true @ jac.T + rng.normal(size=(draws, 60))
    error = np.zeros((draws, cp.COUNT))
    error[:, free] = y @ fit.T - x_true[:, free]
    error[:, [30, 31, 40]] = -x_true[:, [30, 31, 40]]  # held at 0: off by the true value
    expected = idf.consider_covariance(jac, free, np.linalg.pinv(j_free.T @ j_free), prior)
    sample = np.cov(error.T)
    scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected))) + 1e-12
    np.testing.assert_allclose(sample / scale, expected / scale, atol=0.05)
    assert expected[30, 30] == pytest.approx(0.25) and expected[40, 40] == 0.0
    # without prior the held columns add nothing
    bare = idf.consider_covariance(jac, free, np.linalg.pinv(j_free.T @ j_free),
                                   np.zeros(cp.COUNT))
    np.testing.assert_allclose(bare[np.ix_(free, free)], np.linalg.pinv(j_free.T @ j_free))
    assert not bare[[30, 31, 40]].any()
