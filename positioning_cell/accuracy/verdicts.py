"""Tolerance verdicts of settled poses: the tolerances, the verdict of one pose error, and of a
settled visit, each error with the expanded uncertainty U (k = 2) of its measurement and the
decision the rule in force draws from it (ISO 14253-1 by default: conforms, indeterminate or
does not conform; :mod:`positioning_cell.accuracy.decisions`). SI: m and rad; a value equal
to its tolerance passes."""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from positioning_cell.accuracy.decisions import (
    Decision,
    DecisionRule,
    decision,
    norm_expanded_uncertainty,
)
from positioning_cell.accuracy.settle import Visit
from positioning_cell.core.poses import matrix_from_quaternion, pose_error, row_norms
from positioning_cell.errors import InputError
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]

#: Default position tolerance of a settled pose, m (0.05 mm).
POSITION_TOLERANCE = 0.05e-3

#: Default orientation tolerance of a settled pose, rad (0.01°).
ORIENTATION_TOLERANCE = math.radians(0.01)


@dataclass(frozen=True)
class Tolerances:
    """Tolerances of a settled pose: ``position`` (m) on |p − p_cmd| and ``orientation``
    (rad) on the rotation angle of R_cmdᵀ·R (the monitor's ``tolerance:`` block, dynamic).
    Defaults 0.05 mm and 0.01°."""

    position: float = setting(POSITION_TOLERANCE, 'settled-pose tolerance on |p - p_cmd|', 'm',
                              low=0.0, low_open=True, high=0.01, dynamic=True)
    orientation: float = setting(ORIENTATION_TOLERANCE, 'settled-pose tolerance on the '
                                 'rotation angle of R_cmd^T R', 'rad', low=0.0, low_open=True,
                                 high=0.1, dynamic=True)
    decision_rule: str = setting(DecisionRule.ISO_14253_1.value, 'how a verdict accounts for '
                                 "the measurement's expanded uncertainty U: iso_14253_1 (guard "
                                 'bands of U at the tolerance: conforms, indeterminate, does '
                                 'not conform) or simple_acceptance (U ignored)',
                                 choices=tuple(r.value for r in DecisionRule), dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)

    @property
    def rule(self) -> DecisionRule:
        """:attr:`decision_rule` as the enum."""
        return DecisionRule(self.decision_rule)


# -- verdicts --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Verdict:
    """A settled pose against the tolerances: errors, their expanded uncertainties U (k = 2;
    NaN: the measurement stated none) and tolerances in m and rad. ``ok``: the measured
    errors within tolerance as they stand (a value equal to its tolerance passes);
    ``decision``: what the measurement shows by the rule in force (the tolerances'
    ``decision_rule``)."""

    position_error: float
    orientation_error: float
    tolerances: Tolerances
    position_uncertainty: float = math.nan
    orientation_uncertainty: float = math.nan

    @property
    def position_ok(self) -> bool:
        """|Δp| <= position tolerance."""
        return self.position_error <= self.tolerances.position

    @property
    def orientation_ok(self) -> bool:
        """Rotation angle <= orientation tolerance."""
        return self.orientation_error <= self.tolerances.orientation

    @property
    def ok(self) -> bool:
        """Both within tolerance."""
        return self.position_ok and self.orientation_ok

    @property
    def position_decision(self) -> Decision:
        """|Δp| against its tolerance by the rule in force (:func:`decide`)."""
        return decide(self.position_error, self.position_uncertainty,
                      self.tolerances.position, self.tolerances.rule)

    @property
    def orientation_decision(self) -> Decision:
        """The rotation angle against its tolerance by the rule in force."""
        return decide(self.orientation_error, self.orientation_uncertainty,
                      self.tolerances.orientation, self.tolerances.rule)

    @functools.cached_property
    def decision(self) -> Decision:
        """The pose's: it conforms when both do, does not when either does not, else
        indeterminate (computed once: a replay's summaries ask each verdict many times)."""
        both = {self.position_decision, self.orientation_decision}
        if Decision.DOES_NOT_CONFORM in both:
            return Decision.DOES_NOT_CONFORM
        return Decision.CONFORMS if both == {Decision.CONFORMS} else Decision.INDETERMINATE

    def message(self) -> str:
        """For people: µm and degrees, each error ± its U, the decision and its rule."""
        return (f'position error {self.position_error * 1e6:.1f} µm '
                f'{_plus_minus(self.position_uncertainty * 1e6, ".1f")} µm (tolerance '
                f'{self.tolerances.position * 1e6:.1f} µm), orientation error '
                f'{math.degrees(self.orientation_error):.4f}° '
                f'{_plus_minus(math.degrees(self.orientation_uncertainty), ".4f")}° (tolerance '
                f'{math.degrees(self.tolerances.orientation):.4f}°): '
                f'{self.decision.value.upper()} ({RULE_NAMES[self.tolerances.rule]})')

    def short(self) -> str:
        """In a few words, as a run prints it: ``|Δp| 3.2 ± 4.1 µm, 0.0004°: conforms``
        (:func:`summary_of_values` of :func:`verdict_values`)."""
        return summary_of_values(verdict_values(self))


#: How each rule is named in a verdict's message.
RULE_NAMES = {DecisionRule.ISO_14253_1: 'ISO 14253-1, U at k = 2',
               DecisionRule.SIMPLE_ACCEPTANCE: 'simple acceptance, U not used'}

#: The level of the monitor's ``settled pose`` status for each decision.
DECISION_LEVELS = {Decision.CONFORMS: 'ok', Decision.INDETERMINATE: 'warn',
                   Decision.DOES_NOT_CONFORM: 'error'}


def _plus_minus(u: float, spec: str) -> str:
    """``± U`` of a value, or ``± ?`` when the measurement stated no uncertainty."""
    return f'± {u:{spec}}' if math.isfinite(u) else '± ?'


def verdict_values(verdict: Verdict) -> dict[str, str]:
    """A verdict's figures as the monitor's ``settled pose`` status gives them (µm and
    degrees as text; an unstated U is ``nan``), with its decision and the rule it was drawn
    by."""
    return {'position_error_um': f'{verdict.position_error * 1e6:.1f}',
            'position_uncertainty_um': f'{verdict.position_uncertainty * 1e6:.1f}',
            'orientation_error_deg': f'{math.degrees(verdict.orientation_error):.4f}',
            'orientation_uncertainty_deg':
                f'{math.degrees(verdict.orientation_uncertainty):.4f}',
            'decision': verdict.decision.value,
            'decision_rule': verdict.tolerances.decision_rule}


def summary_of_values(values: Mapping[str, str]) -> str:
    """A verdict in a few words from :func:`verdict_values` (its own, or a status's values as
    received): ``|Δp| 3.2 ± 4.1 µm, 0.0004°: conforms``; what is missing shown as ``?``."""
    u = values.get('position_uncertainty_um', 'nan')
    return (f'|Δp| {values.get("position_error_um", "?")} ± '
            f'{"?" if u.strip().lower() == "nan" else u} µm, '
            f'{values.get("orientation_error_deg", "?")}°: {values.get("decision", "?")}')


def decide(value: float, uncertainty: float, tolerance: float, rule: DecisionRule) -> Decision:
    """An error ``value`` (≥ 0) measured with expanded uncertainty ``uncertainty`` against an
    upper ``tolerance`` by ``rule`` (:func:`positioning_cell.accuracy.decisions.decision`).
    An unknown U (NaN) decides nothing under ISO 14253-1: indeterminate; simple acceptance
    does not use U."""
    if rule is DecisionRule.SIMPLE_ACCEPTANCE:
        return decision(value, 0.0, tolerance, rule=rule)
    if not math.isfinite(uncertainty):
        return Decision.INDETERMINATE
    return decision(value, uncertainty, tolerance, rule=rule)


def judge(position_error: float, orientation_error: float,
          tolerances: Tolerances | None = None, position_uncertainty: float = math.nan,
          orientation_uncertainty: float = math.nan) -> Verdict:
    """Verdict of a pose error: ``position_error`` |Δp| (m), ``orientation_error`` the
    rotation angle (rad), both finite and >= 0, with their expanded uncertainties U (m, rad;
    >= 0, or NaN: not stated)."""
    for name, value in (('position_error', position_error),
                        ('orientation_error', orientation_error)):
        if not (math.isfinite(value) and value >= 0.0):
            raise InputError(f'{name} = {value!r}: must be a finite number >= 0')
    for name, value in (('position_uncertainty', position_uncertainty),
                        ('orientation_uncertainty', orientation_uncertainty)):
        if not (math.isnan(value) or (math.isfinite(value) and value >= 0.0)):
            raise InputError(f'{name} = {value!r}: must be a finite number >= 0 or NaN '
                             '(not stated)')
    return Verdict(float(position_error), float(orientation_error), tolerances or Tolerances(),
                   float(position_uncertainty), float(orientation_uncertainty))

def judge_visit(visit: Visit, tolerances: Tolerances | None = None,
                covariance: FloatArray | None = None) -> Verdict:
    """Verdict of a settled visit: its attained pose against its commanded pose
    (:func:`judge_visits`)."""
    return judge_visits([visit], tolerances,
                        None if covariance is None else np.asarray(covariance)[None])[0]


def judge_visits(visits: Sequence[Visit], tolerances: Tolerances | None = None,
                 covariances: FloatArray | None = None) -> list[Verdict]:
    """Verdicts of settled visits (:func:`judge_poses` of their attained and commanded
    poses; ``covariances`` (N, 6, 6) of their attained poses, the mean of each one's
    readings: :meth:`positioning_cell.accuracy.monitor.Readings.covariance_of`)."""
    if not visits:
        return []
    return judge_poses(np.array([v.position for v in visits]),
                       np.array([v.quaternion for v in visits]),
                       np.array([v.commanded_position for v in visits]),
                       np.array([v.commanded_quaternion for v in visits]), tolerances,
                       covariances)


def judge_poses(position: FloatArray, quaternion: FloatArray, commanded_position: FloatArray,
                commanded_quaternion: FloatArray, tolerances: Tolerances | None = None,
                covariances: FloatArray | None = None) -> list[Verdict]:
    """Verdicts of N attained poses (positions (N, 3) m, unit quaternions (N, 4)) against
    their commanded poses, computed together (row by row the same as one at a time).
    ``covariances`` (N, 6, 6): of each attained pose as measured (e.g. the mean of its
    readings: :func:`positioning_cell.moves.correction.mean_reading`), order x, y, z, rot-x,
    rot-y, rot-z in ``base`` (m², m·rad, rad²; rotations small angles about the base axes);
    a row with a NaN, or None for all: not stated (U NaN). The commanded pose is exact, so U
    of |Δp| is that of the attained position's norm about the commanded one
    (:func:`~positioning_cell.accuracy.decisions.norm_expanded_uncertainty`), and U of the
    rotation angle that of the rotation vector of R_cmdᵀ·R, whose covariance is the base one
    turned into the attained frame (R = exp([δθ]×)·R̄ gives R_cmdᵀR = R_cmdᵀR̄·exp([R̄ᵀδθ]×):
    δθ enters as R̄ᵀδθ, to first order in the small error)."""
    dp, rv = pose_error(position, quaternion, commanded_position, commanded_quaternion)
    n = dp.shape[0]
    u_position, u_angle = np.full(n, math.nan), np.full(n, math.nan)
    if covariances is not None:
        cov = np.asarray(covariances, dtype=float)
        if cov.shape != (n, 6, 6):
            raise InputError(f'covariances: expected shape ({n}, 6, 6) for the {n} poses, '
                             f'got {cov.shape}')
        stated = np.all(np.isfinite(cov), axis=(1, 2))
        if np.any(stated):
            r = matrix_from_quaternion(np.asarray(quaternion, dtype=float)[stated])
            turned = np.swapaxes(r, 1, 2) @ cov[stated, 3:, 3:] @ r
            u_position[stated] = norm_expanded_uncertainty(dp[stated], cov[stated, :3, :3])
            u_angle[stated] = norm_expanded_uncertainty(rv[stated], turned)
    return [judge(float(d), float(a), tolerances, float(up), float(ua))
            for d, a, up, ua in zip(row_norms(dp).tolist(), row_norms(rv).tolist(),
                                    u_position.tolist(), u_angle.tolist(), strict=True)]


def decision_key(decision: Decision) -> str:
    """A decision as a key of counts: its value with underscores (``conforms``,
    ``indeterminate``, ``does_not_conform``)."""
    return decision.value.replace(' ', '_')


def decision_counts(verdicts: Sequence[Verdict]) -> dict[str, int]:
    """How many of ``verdicts`` drew each decision, keyed by :func:`decision_key` (every
    decision, in :class:`Decision`'s order)."""
    counts = {decision_key(d): 0 for d in Decision}
    for v in verdicts:
        counts[decision_key(v.decision)] += 1
    return counts
