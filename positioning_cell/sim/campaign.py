"""A calibration run simulated offline, without ROS: what the cell would record when it
commands each pose of a program and measures it stationary. The machine (the truth) goes
where its commanded encoder values put it; the encoders read those values with their noise
and resolution, averaged over ``samples`` readings; the tracker measures the true pose
``samples`` times and the cell averages the fits. The result holds only what the cell would
see (:class:`~positioning_cell.calibration.identify.CalibrationData`); the truth stays here.

The machine's effects outside the identified model follow the run (:class:`Timing`): pose k
is measured ``start + k·seconds_per_pose`` s after the start, so the air drifts over the run;
the legs warm with the travel between poses; each axis's reversal error follows the
direction the commanded sequence last moved it in. The cell records the air-temperature
sensor's reading (with its error) and that approach direction with each pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.calibration import parameters as cp
from positioning_cell.calibration.file import Calibration
from positioning_cell.calibration.identify import CalibrationData
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import pose_error
from positioning_cell.errors import ConvergenceError
from positioning_cell.metrology.instrument import Tracker, averaged_covariance
from positioning_cell.metrology.targets import TargetLayout
from positioning_cell.moves.correction import mean_pose
from positioning_cell.sim.effects.history import sequence_conditions
from positioning_cell.sim.effects.thermal import REFERENCE_TEMPERATURE
from positioning_cell.sim.encoders import EncoderSettings, quantise
from positioning_cell.sim.tracker import SimulatedTracker, observe
from positioning_cell.sim.truth import Truth

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Timing:
    """When the poses of an offline run are measured: the first ``start`` s after the start
    of the machine's day, then one every ``seconds_per_pose`` s (the move, settling and the
    readings; a real calibration run takes 20-60 s per pose). ``feeds_tracker``: the
    tracker's weather correction takes the cell's sensor reading (else 20 °C)."""

    seconds_per_pose: float = 30.0
    start: float = 0.0
    feeds_tracker: bool = True

    def times(self, n: int) -> FloatArray:
        """The measurement times (n,) s."""
        out: FloatArray = self.start + self.seconds_per_pose * np.arange(n, dtype=float)
        return out


def measure_program(truth: Truth, instrument: SimulatedTracker, located: Tracker,
                    targets: TargetLayout, encoders: EncoderSettings, commands: ArrayLike,
                    rng: np.random.Generator, samples: int = 10,
                    timing: Timing | None = None) -> CalibrationData:
    """The data of measuring the machine ``truth`` at encoder commands (N, 6) (lengths m, then
    θ rad): the drives hold the commanded counts (the axes dither by the encoder noise), the
    encoder means and their uncertainty, and the mean of ``samples`` fits of the real
    ``instrument``'s readings through the cell's ``located`` registration, with the fits' mean
    covariance divided by ``samples`` (the registration's own error is common to every pose:
    it is not divided); with each pose the sensor's air temperature and the approach
    direction of each axis and the registration (module docstring, ``timing`` default
    :class:`Timing`)."""
    timing = timing or Timing()
    cmd = np.atleast_2d(np.asarray(commands, dtype=float))
    n = cmd.shape[0]
    noise = encoders.noise
    axis = cmd + rng.standard_normal(cmd.shape) * noise
    readings = quantise(axis[:, None, :] + rng.standard_normal((n, samples, 6)) * noise,
                        encoders.resolution)
    joints = readings.mean(axis=1)
    joint_sigma = np.sqrt(noise**2 / samples + encoders.resolution**2 / 12.0
                          + noise**2) * np.ones((n, 1))
    times = timing.times(n)
    thermal = truth.effects.thermal
    conditions = sequence_conditions(thermal, cmd, times)
    true = truth.poses(axis[:, :3], axis[:, 3:], conditions=conditions)
    if not np.all(true.converged):
        raise ConvergenceError('the simulated machine has no pose for a commanded pose')
    if thermal is None:
        temperature, refraction = np.full(n, REFERENCE_TEMPERATURE), np.zeros(n)
    else:
        temperature = thermal.sensor(times, rng)
        used = temperature if timing.feeds_tracker else REFERENCE_TEMPERATURE
        refraction = thermal.range_scale_ppm(conditions.air, used)
    reps = np.repeat(true.position, samples, axis=0), np.repeat(true.quaternion, samples, axis=0)
    _, fit = observe(instrument, located, targets, reps[0], reps[1], rng,
                     refraction_ppm=np.repeat(refraction, samples))
    position = np.empty((n, 3))
    quaternion = np.empty((n, 4))
    for k in range(n):  # one mean per pose (rotation mean: scipy, per set)
        rows = slice(k * samples, (k + 1) * samples)
        position[k], quaternion[k] = mean_pose(fit.position[rows], fit.quaternion[rows])
    covariance = averaged_covariance(fit.covariance.reshape(n, samples, 6, 6).mean(axis=1),
                                     located.registration_covariance(position), samples)
    registration = located.registration
    return CalibrationData(joints, joint_sigma, position, quaternion, covariance,
                           temperature=temperature, approach=conditions.approach,
                           registration_origin=None if registration is None
                           else np.tile(registration.position, (n, 1)),
                           registration_covariance=None if registration is None
                           else np.tile(registration.covariance, (n, 1, 1)))


def true_errors(truth: Truth, lengths: ArrayLike, thetas: ArrayLike, position: ArrayLike,
                quaternion: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Judging only: where the machine ``truth`` really goes for encoder commands (N, 3) m,
    (N, 3) rad, against the desired poses (N, 3) m, (N, 4): position error (N, 3) m and
    rotation-vector error (N, 3) rad, base frame."""
    attained = truth.poses(lengths, thetas)
    if not np.all(attained.converged):
        raise ConvergenceError('the simulated machine has no pose for a command')
    return pose_error(attained.position, attained.quaternion, np.asarray(position, dtype=float),
                      np.asarray(quaternion, dtype=float))


def truth_table(calibration: Calibration, truth: Truth, nominal: Mechanism) -> list[str]:
    """Judging only: a Markdown table of each identified parameter against the machine's
    truth (µm, µrad) with the difference in standard uncertainties, and a summary line. The
    terms beyond geometry (compliance, thermal, lead, reversal) the truth holds in another
    form (:mod:`positioning_cell.sim.effects`): listed, not compared. The summary is the last
    line."""
    true_x = cp.vector_of(truth, nominal)
    lines = ['| parameter | identified | sigma | truth | difference / sigma |',
             '|---|---|---|---|---|']
    within = []
    for k, name in enumerate(cp.PARAMETER_NAMES):
        if not calibration.identified[k]:
            lines.append(f'| {name} | fixed | | {true_x[k] * 1e6:.2f} | |')
            continue
        if k >= cp.FORMAT1_COUNT:
            lines.append(f'| {name} | {calibration.x[k]:.4g} | {calibration.sigma[k]:.2g} | '
                         'another form (sim/effects) | |')
            continue
        z = (calibration.x[k] - true_x[k]) / calibration.sigma[k]
        within.append(abs(z) <= 3.0)
        lines.append(f'| {name} | {calibration.x[k] * 1e6:.2f} | {calibration.sigma[k] * 1e6:.2f} '
                     f'| {true_x[k] * 1e6:.2f} | {z:+.2f} |')
    lines.append('')
    if truth.effects.active:
        lines.append('The machine also has effects the model holds in another form or not at '
                     'all (sim/effects: drive errors, heating, joint compliance, refraction); the '
                     'geometric parameters absorb part of them (e.g. the theta drives\' constant '
                     'sag under the payload in the theta offsets), so a difference here is not a '
                     'calibration error alone.')
    lines.append(f'{sum(within)} of {len(within)} identified geometric parameters within 3 sigma '
                 'of the truth (µm; µrad for the theta offsets). The base frame is the located '
                 'one: what is identified is the machine as the tracker sees it.')
    return lines
