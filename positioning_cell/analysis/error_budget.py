"""An error budget of the live cell: what the true position error of the settled visits of one
compensation mode is made of. Pure numpy, positions in m in the ``base`` frame, joints in the
order of :data:`positioning_cell.core.mechanism.JOINT_NAMES` (m on the length axes, rad on the
θ axes).

Per visit n (N of them; W_n its settle window, :class:`positioning_cell.accuracy.Visit`):

* **truth error** e_n = t̄_n − p_cmd,n: the mean true position over W_n (the simulation truth,
  used only to judge) minus the commanded one. E = √(mean_n |e_n|²) is what the budget splits.
* **servo steady state**: δq_n = q̄_enc,n − q_cmd,n, the mean encoder reading over W_n minus
  the final commanded joint values (the last point of the last trajectory sent before the
  end of W_n); in position δp_n = J_n δq_n with J_n = ∂p/∂q (3 × 6) at the commanded pose
  (the position rows of :func:`positioning_cell.core.kinematics.jacobian`).
  c_servo = √(mean_n |J_n δq_n|²).
* **encoder quantisation**: a reading is within ±r/2 of the axis (r the resolution), uniformly:
  variance r²/12 per joint, constant while the axis stands (averaging does not reduce it);
  in position Σ_n = J_n diag(r²/12) J_nᵀ and c_quant = √(mean_n tr Σ_n).
* **tracker noise**: the variance of the mean of the k_n measured positions over W_n, from
  their scatter s²_n (unbiased, per axis): c_noise = √(mean_n Σ_axes s²_n / k_n).
* **tracker systematics** (needs the truth): d_n = m̄_n − t̄_n, the measured minus the true
  mean over the same window, holds the systematic error and the noise of the mean:
  c_sys = √(max(0, mean_n |d_n|² − c_noise²)).
* **unmodelled residual**: what is left of the truth error once the contributions that reach
  the platform in this mode are taken out, root-sum-square:
  c_res = √(max(0, E² − Σ_i c_i²)).

A contribution reaches the platform (``in_chain``) when the positioner's loop runs through
it: the servo and the encoders in every mode; the tracker only in ``measured`` mode, where the
positioner corrects on its measurements (in ``none`` and ``model`` the tracker only watches).
The *share* of an in-chain contribution is c_i² / E² (root-sum-square shares: with the
residual they add up to 1 when Σ_i c_i² <= E²; when they exceed E² the contributions are
not independent or partly cancel, and the budget says so). Without the truth, E, the
systematics, the residual and the shares are unknown: the budget says so and guesses nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

SERVO = 'servo steady state'
QUANTISATION = 'encoder quantisation'
TRACKER_NOISE = 'tracker noise'
TRACKER_SYSTEMATICS = 'tracker systematics'
RESIDUAL = 'unmodelled residual'
#: The lines of a budget, in order.
CONTRIBUTIONS = (SERVO, QUANTISATION, TRACKER_NOISE, TRACKER_SYSTEMATICS, RESIDUAL)
#: The mode whose positioner closes its loop on the tracker.
CLOSED_ON_TRACKER = 'measured'
NO_TRUTH = ('the bag holds no simulation truth (/sim/platform/true_pose): the truth error, '
            'the tracker systematics, the residual and the shares are not known')


@dataclass(frozen=True)
class Contribution:
    """One line of the budget: its ``name``, RMS size over the visits (m; None: not known),
    share of the squared truth error (None: not known or not in the chain), whether it
    reaches the platform in this mode, and a note (how it was found or why not)."""

    name: str
    rms: float | None
    share: float | None
    in_chain: bool
    note: str = ''

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI)."""
        return dict(self.__dict__)


@dataclass(frozen=True)
class ErrorBudget:
    """The budget of one mode: ``visits`` judged, the truth error E (m RMS, None without the
    truth), the contributions (the residual last) and notes."""

    mode: str
    visits: int
    truth_rms: float | None
    contributions: tuple[Contribution, ...]
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI)."""
        return {'mode': self.mode, 'visits': self.visits, 'truth_rms': self.truth_rms,
                'contributions': [c.to_dict() for c in self.contributions],
                'notes': list(self.notes)}

    def contribution(self, name: str) -> Contribution:
        """The contribution called ``name``."""
        return next(c for c in self.contributions if c.name == name)


def _rows(value: ArrayLike | None, n: int, width: int, name: str) -> FloatArray | None:
    if value is None:
        return None
    a = np.asarray(value, dtype=float)
    if a.shape != (n, width):
        raise InputError(f'{name}: expected shape ({n}, {width}), got {a.shape}')
    return a


def _rms(squares: FloatArray) -> float:
    """√ of the mean of per-visit squared sizes (N,), NaN ones left out (not measured)."""
    known = squares[np.isfinite(squares)]
    return float(math.sqrt(known.mean())) if known.size else math.nan


def error_budget(mode: str, truth_error: ArrayLike | None,
                 servo_joint_error: ArrayLike | None, joint_to_position: ArrayLike | None,
                 resolution: ArrayLike | None, tracker_mean_variance: ArrayLike | None,
                 tracker_minus_truth: ArrayLike | None, visits: int) -> ErrorBudget:
    """The budget of ``visits`` settled visits of ``mode`` (module docstring): per visit the
    truth error e_n (N, 3) m, the servo's joint error δq_n (N, 6), the sensitivities J_n
    (N, 3, 6) m per joint unit, the encoder resolution r (6,), the variance of the tracker's
    window mean per axis (N, 3) m², and the tracker minus the truth d_n (N, 3) m. None: not
    recorded (the line says so); a visit's NaN row: not measured in that visit."""
    n = int(visits)
    e = _rows(truth_error, n, 3, 'truth_error')
    dq = _rows(servo_joint_error, n, 6, 'servo_joint_error')
    var = _rows(tracker_mean_variance, n, 3, 'tracker_mean_variance')
    d = _rows(tracker_minus_truth, n, 3, 'tracker_minus_truth')
    jac = None if joint_to_position is None else np.asarray(joint_to_position, dtype=float)
    if jac is not None and jac.shape != (n, 3, 6):
        raise InputError(f'joint_to_position: expected shape ({n}, 3, 6), got {jac.shape}')
    closed = mode == CLOSED_ON_TRACKER
    notes: list[str] = []
    truth_rms = _rms((e * e).sum(axis=1)) if e is not None and n else None
    if truth_rms is None or math.isnan(truth_rms):
        truth_rms = None
        notes.append(NO_TRUTH)

    servo = quant = None
    if jac is not None and dq is not None:
        dp = np.einsum('nij,nj->ni', jac, dq)
        servo = _rms((dp * dp).sum(axis=1))
    if jac is not None and resolution is not None:
        r = np.asarray(resolution, dtype=float).reshape(6)
        quant = _rms(np.einsum('nij,j,nij->n', jac, r * r / 12.0, jac))
    noise = _rms(var.sum(axis=1)) if var is not None else None
    systematics = None
    if d is not None and noise is not None and truth_rms is not None:
        systematics = math.sqrt(max(0.0, _rms((d * d).sum(axis=1)) ** 2 - noise ** 2))

    def line(name: str, rms: float | None, in_chain: bool, note: str) -> Contribution:
        known = rms is not None and not math.isnan(rms)
        share = ((rms or 0.0) ** 2 / truth_rms ** 2
                 if known and in_chain and truth_rms is not None and truth_rms > 0.0 else None)
        return Contribution(name, rms if known else None, share, in_chain,
                            note if known else f'not recorded: {note}')

    lines = [
        line(SERVO, servo, True, 'encoders against the last commanded joints, through J'),
        line(QUANTISATION, quant, True, 'resolution²/12 per joint, through J'),
        line(TRACKER_NOISE, noise, closed,
             'scatter of the measurements in the settle window, of their mean (the positioner '
             'averages its own readings and corrects only outside its goal tolerance: an '
             'upper bound of what reaches the platform)' if closed else
             'scatter of the measurements in the settle window, of their mean'),
        line(TRACKER_SYSTEMATICS, systematics, closed,
             'measured minus true window mean, less the noise'
             if truth_rms is not None else 'needs the truth'),
    ]
    chain = sum((c.rms or 0.0) ** 2 for c in lines if c.in_chain)
    residual: float | None = None
    if truth_rms is not None:
        residual = math.sqrt(max(0.0, truth_rms ** 2 - chain))
        if chain > truth_rms ** 2:
            notes.append('the contributions that reach the platform exceed the truth error: '
                         'they are not independent or partly cancel')
    lines.append(line(RESIDUAL, residual, True, 'truth error less the contributions, RSS'
                      if truth_rms is not None else 'needs the truth'))
    if not closed:
        notes.append(f'in mode {mode!r} the positioner does not correct on the tracker: its '
                     'noise and systematics do not reach the platform (listed, no share)')
    return ErrorBudget(mode, n, truth_rms, tuple(lines), tuple(notes))


class WindowStats:
    """Streaming count, mean and scatter of a sampled signal (d,) inside V disjoint windows
    [start_v, stop_v] (s, ascending), relative to a reference per window (V, d) so that the
    sums keep the digits of µm scatter around 0.2 m: :meth:`add` batches in time order,
    vectorised (np.bincount), any grouping giving the same sums up to rounding."""

    def __init__(self, starts: ArrayLike, stops: ArrayLike, reference: ArrayLike) -> None:
        self.starts = np.asarray(starts, dtype=float).reshape(-1)
        self.stops = np.asarray(stops, dtype=float).reshape(-1)
        self.reference = np.asarray(reference, dtype=float)
        v, dim = self.reference.shape
        if self.starts.size != v or self.stops.size != v:
            raise InputError(f'{self.starts.size} starts, {self.stops.size} stops and {v} '
                             'references')
        self.count = np.zeros(v)
        self._sum = np.zeros((v, dim))
        self._squares = np.zeros((v, dim))

    def add(self, time: ArrayLike, values: ArrayLike) -> None:
        """Samples at ``time`` (N,) s of ``values`` (N, d); those outside every window are
        left out."""
        t = np.asarray(time, dtype=float).reshape(-1)
        x = np.asarray(values, dtype=float).reshape(t.size, -1)
        v = self.starts.size
        index = np.searchsorted(self.starts, t, side='right') - 1
        inside = (index >= 0) & np.isfinite(x).all(axis=1)
        inside[inside] &= t[inside] <= self.stops[index[inside]]
        k = index[inside]
        rel = x[inside] - self.reference[k]
        self.count += np.bincount(k, minlength=v)
        for j in range(rel.shape[1]):  # over the d components, not samples
            self._sum[:, j] += np.bincount(k, rel[:, j], minlength=v)
            self._squares[:, j] += np.bincount(k, rel[:, j] ** 2, minlength=v)

    def mean(self) -> FloatArray:
        """Mean per window (V, d), absolute; NaN where no sample fell."""
        with np.errstate(invalid='ignore', divide='ignore'):
            mean: FloatArray = self.reference + self._sum / self.count[:, np.newaxis]
        return mean

    def variance_of_mean(self) -> FloatArray:
        """Unbiased sample variance over k, per component, divided by k: the variance of the
        window mean (V, d); NaN below two samples."""
        k = self.count[:, np.newaxis]
        with np.errstate(invalid='ignore', divide='ignore'):
            var = (self._squares - self._sum ** 2 / k) / (k - 1.0)
            out: FloatArray = np.where(k >= 2, np.maximum(var, 0.0) / k, math.nan)
        return out


def last_before(times: ArrayLike, values: ArrayLike, at: ArrayLike) -> FloatArray:
    """The value (d,) of the last of ``times`` (M,) s (ascending) at or before each of ``at``
    (V,): (V, d), NaN where none is."""
    t = np.asarray(times, dtype=float).reshape(-1)
    x = np.asarray(values, dtype=float)
    x = x.reshape(t.size, x.shape[-1] if x.ndim > 1 else -1)
    index = np.searchsorted(t, np.asarray(at, dtype=float), side='right') - 1
    out = np.full((index.size, x.shape[1]), math.nan)
    out[index >= 0] = x[index[index >= 0]]
    return out
