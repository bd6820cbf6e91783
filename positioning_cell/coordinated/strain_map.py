"""The panel's strain as its pose changes, learnt from the legs' load cells (issue 27, item 4).

The relax from the load cells (:meth:`~.coordinator.Coordinator.relax_forces`) finds, at one
panel pose, each positioner's load correction: one translation of its platform goal that
takes the strain away there. Away from that pose the strain comes back: on the shipped cell
from 30 N at home to 113 N at a pose 6 mm and 5 mrad away, the same at every visit (the
positioners' and the cell file's errors grow with the motion; no model of the cell holds
them). This module learns how it grows.

A sample: at rest at some pose, each positioner's attachment point where the load cells say it
would leave the panel unstrained, in its own base frame: where its platform goal puts it
(:func:`~.panel_motion.attachment_points`) plus its relaxing step
(:func:`~.load_cells.relaxing_steps`). That is a fact of the machine, not of a cell file: a
calibrated file that comes later reads the same samples. Under a cell file each sample's points
(cell frame) have a nearest rigid panel: the weighted Kabsch fit (Arun et al. 1987,
:func:`~positioning_cell.metrology.fit.weighted_kabsch`) of the file's panel points to them,
``T = (R, p)``; what is left, ``r_i = a_i − (R·b_i + p)``, is the strain-free misfit the file
leaves at that pose. Its model, per attachment, is affine in the panel's pose
``v = (p m, rotation vector of R rad)``:

    r_i(v) = c_i + G_i·v          (G_i: 3×6, least squares over the samples)

each sample weighted by ``1 / (floor² + (share·|step|)²)``: the step comes through the cell
file's stiffness, and a real panel's differs (a relaxing move leaves about a quarter of the
force on the shipped cell), so a sample is good to that share of its step. The coordinator
keeps the relax's load corrections where they were found (pose ``v₀``) and adds each
positioner's ``R_base_iᵀ·G_i·(v − v₀)`` to its goal at ``v``: the constant stays measured, the
map supplies only how the strain changes with the pose.

The map is used once the samples span the pose's six coordinates (the weighted design's
smallest singular value at least :data:`MIN_CONDITION` of its largest, columns in mm and
mrad); before, the load corrections are one for every pose, as without it. Its fit says when
the affine model falls short: its residuals' weighted RMS over what their weights expect
(:attr:`StrainFit.factor`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.panel_motion import bases
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import scipy_rotation
from positioning_cell.errors import InputError
from positioning_cell.frames.transforms import Transform
from positioning_cell.metrology.fit import weighted_kabsch

FloatArray = NDArray[np.float64]

#: The pose's columns in the fit: position in mm, rotation in mrad (comparable sizes on the
#: cell's few-mm, few-mrad moves, so that the conditioning below means something).
POSE_SCALE = 1e3
#: The weighted design's smallest singular value over its largest below which the samples do
#: not span the pose (the map is not used).
MIN_CONDITION = 1e-3
#: Most samples kept (the oldest go first): a run's calibration and program poses.
MAX_SAMPLES = 400


@dataclass(frozen=True)
class StrainSample:
    """One rest's reading: each positioner's unstrained attachment point ``balls_base``
    (N, 3) m, each in its own base frame, and its uncertainty ``sigma`` m."""

    balls_base: FloatArray
    sigma: float


def pose_coordinates(panel: Transform) -> FloatArray:
    """(6,) the panel pose T_cell_panel as the map's coordinates: position m, rotation vector
    rad (home: zeros)."""
    out: FloatArray = np.concatenate([panel.p,
                                         scipy_rotation().from_matrix(panel.R).as_rotvec()])
    return out


def balls_in_base(cell: CellFile, platforms: Sequence[tuple[ArrayLike, ArrayLike]],
                  steps: ArrayLike) -> FloatArray:
    """(N, 3) m: each positioner's attachment point in its base frame with its platform at
    ``platforms`` (position m, quaternion; its base frame) moved by its relaxing step
    ``steps`` (N, 3) m (its base frame)."""
    d = np.asarray(steps, dtype=float)
    if len(platforms) != len(cell.positioners) or d.shape != (len(cell.positioners), 3):
        raise InputError(f'{len(platforms)} platforms and steps {d.shape} for '
                         f'{len(cell.positioners)} positioners')
    out: FloatArray = np.array([Transform.from_pq(*pose).apply(np.asarray(e.offset, dtype=float))
                                for pose, e in zip(platforms, cell.positioners, strict=True)]) + d
    return out


@dataclass(frozen=True)
class StrainFit:
    """The affine map under one cell file (module docstring): ``gradient`` (N, 3, 6) per
    attachment, cell frame (m per m and per rad), ``constant`` (N, 3) m, the ``samples``
    fitted, a ball's residual ``rms`` m (weighted as they are) and its ``factor`` over what
    their sigmas expect (about 1: the affine model holds their scatter; well above: it falls
    short)."""

    gradient: FloatArray
    constant: FloatArray
    samples: int
    rms: float
    factor: float
    r_bases: FloatArray

    def changes(self, panel: Transform, since: Transform) -> FloatArray:
        """(N, 3) m: each positioner's correction change, in its base frame, from the panel at
        ``since`` to the panel at ``panel`` (both T_cell_panel)."""
        dv = pose_coordinates(panel) - pose_coordinates(since)
        in_cell = self.gradient @ dv
        out: FloatArray = np.einsum('nji,nj->ni', self.r_bases, in_cell)
        return out

    def words(self) -> str:
        """The map in a few words, for a reason or a log line."""
        falls = '' if self.factor <= 3.0 else ': the affine model falls short of them'
        return (f'strain map from {self.samples} rests, residual {self.rms * 1e6:.1f} um '
                f'RMS ({self.factor:.1f} x their uncertainty{falls})')


class StrainMap:
    """The samples (module docstring), taken from any thread; ``floor`` m and ``share`` set
    each sample's sigma from its largest step."""

    def __init__(self, floor: float = 1e-6, share: float = 0.25) -> None:
        if not (floor > 0.0 and 0.0 <= share <= 1.0):
            raise InputError(f'strain map: floor {floor} m must be > 0 and share {share} in '
                             '[0, 1]')
        self.floor, self.share = floor, share
        self._samples: list[StrainSample] = []
        self._lock = threading.Lock()
        self._cache: tuple[int, int, StrainFit | None] | None = None

    def __len__(self) -> int:
        with self._lock:
            return len(self._samples)

    def add(self, balls_base: ArrayLike, steps: ArrayLike) -> None:
        """One rest's unstrained attachment points (N, 3) m (:func:`balls_in_base`) and the
        relaxing steps (N, 3) m they came from (their size sets the sample's sigma)."""
        balls = np.array(balls_base, dtype=float)
        d = np.asarray(steps, dtype=float)
        if balls.ndim != 2 or balls.shape[1] != 3 or d.shape != balls.shape \
                or not (np.isfinite(balls).all() and np.isfinite(d).all()):
            raise InputError(f'strain sample: expected finite (N, 3) points and steps, got '
                             f'{balls.shape} and {d.shape}')
        step = float(np.linalg.norm(d, axis=1).max())
        sigma = float(np.hypot(self.floor, self.share * step))
        with self._lock:
            self._samples.append(StrainSample(balls, sigma))
            del self._samples[:-MAX_SAMPLES]
            self._cache = None

    def fit(self, cell: CellFile, mech: Mechanism) -> StrainFit | None:
        """The map under ``cell`` (module docstring); None while the samples do not span the
        pose's six coordinates. Fitted once per cell file and set of samples."""
        with self._lock:
            samples = list(self._samples)
            cached = self._cache
        key = (id(cell), len(samples))
        if cached is not None and cached[:2] == key:
            return cached[2]
        found = fit_strain(cell, mech, samples)
        with self._lock:
            if len(self._samples) == len(samples):
                self._cache = (*key, found)
        return found


def fit_strain(cell: CellFile, mech: Mechanism, samples: Sequence[StrainSample]
               ) -> StrainFit | None:
    """The affine strain map of ``samples`` under ``cell`` (module docstring), or None when
    they do not span the pose."""
    n = len(cell.positioners)
    usable = [s for s in samples if s.balls_base.shape == (n, 3)]
    if len(usable) < 7:
        return None
    base = bases(cell)
    r_bases = np.array([b.R for b in base])
    balls_cell = np.array([[b.apply(point) for b, point in zip(base, s.balls_base, strict=True)]
                           for s in usable])  # (K, N, 3)
    body = cell.panel_points(mech)
    rot, pos = weighted_kabsch(body, balls_cell, np.ones(balls_cell.shape[:2]))
    misfit = balls_cell - pos[:, None] - body @ np.swapaxes(rot, 1, 2)  # (K, N, 3)
    v = np.hstack([pos, scipy_rotation().from_matrix(rot).as_rotvec()])
    design = np.hstack([np.ones((len(usable), 1)), v * POSE_SCALE])
    weight = 1.0 / np.array([s.sigma for s in usable])
    scaled = design * weight[:, None]
    singular = np.linalg.svd(scaled, compute_uv=False)
    if singular[-1] < MIN_CONDITION * singular[0]:
        return None
    target = misfit.reshape(len(usable), 3 * n) * weight[:, None]
    coef, *_ = np.linalg.lstsq(scaled, target, rcond=None)  # (7, 3N)
    left = (target - scaled @ coef).reshape(len(usable), n, 3)
    dof = max(1, (len(usable) - 7) * 3 * n)
    factor = float(np.sqrt(np.sum(left**2) / dof))
    # the residual of a ball, weighted as the samples are (the sure ones count)
    rms = float(np.sqrt(np.sum(left**2) / (n * np.sum(weight**2))))
    gradient: FloatArray = np.asarray(coef[1:].T * POSE_SCALE, dtype=float).reshape(n, 3, 6)
    return StrainFit(gradient, coef[0].reshape(n, 3), len(usable), rms, factor, r_bases)
