"""Identification of a machine model from a calibration run: weighted nonlinear least squares
of the geometric and clearance parameters (:mod:`positioning_cell.calibration.parameters`)
from measured platform poses and the encoder readings at them.

The residual of pose k is in joint space (the inverse-kinematic formulation of parallel-robot
calibration, e.g. Zhuang 1997; seed 000 eq. 9 in its exact vector form): the encoder values the
model predicts at the measured pose, minus the encoder values read,

    r_k = IK_x(p_k, q_k) − δ − e_k   (6: three lengths m, three θ rad),

closed form per leg with the load model's joint-centre shifts
d_i = p + R (b_i + r_b s_B,i) − (A_i + r_a s_A,i), l_i = |d_i|, θ_i = asin(u_i · e_t,i)
(s_A, s_B the seated force directions of :class:`~positioning_cell.clearance.load
.LoadAwareClearance` at the measured pose), and the terms beyond geometry of
:mod:`positioning_cell.calibration.machine` (compliance times the statics' joint efforts,
thermal expansion about the reference temperature, lead, reversal times the approach sign)
under each pose's recorded conditions. Its Jacobian is analytic: ∂l/∂d = uᵀ,
∂θ/∂d = wᵀ with w = (e_t − (u·e_t) u) / (l cos θ) (the rows of
:func:`positioning_cell.core.kinematics.inverse_jacobian`); the force directions s_A, s_B are
those of the current geometry, held constant in the Jacobian (turning them adds at most a few
per cent to a joint-centre column: 0.1 mm of geometry turns them by ~2 mrad). The residuals
are exact, so the fit reaches the same minimum; only its covariance is that approximate.
Each residual is whitened by its
covariance J⁻¹ Σ_pose J⁻ᵀ + Σ_encoder (Σ_pose the tracker fit's, mapped through the inverse
Jacobian J⁻¹), so the weighted sum of squares is χ² with 6N − n degrees of freedom.

Identifiability: the whitened Jacobian in units of each parameter's expected size is
decomposed by QR with column pivoting (the base-parameter method of Khalil & Dombre). A
parameter whose new information |R_jj| is below ``min_information`` (its standard uncertainty
would exceed 1/min_information of its expected size) cannot be separated from those already
chosen: it is fixed at its nominal value (0; a compliance the nominal structure's 1/k, since
a leg is not rigid) and the parameters that absorb it are named.
Before that, the classes the settings switch off and those the data cannot excite (no
temperature recorded or too narrow a range, an axis approached from one side only) are left
out, each with why (:func:`excluded_parameters`). After the fit, the residuals' χ² test
(:mod:`positioning_cell.calibration.adequacy`) says whether the model is adequate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.calibration import adequacy as adq
from positioning_cell.calibration import parameters as cp
from positioning_cell.calibration.conditions import (
    STANDARD_TEMPERATURE,
    Conditions,
    checked_approach,
    checked_temperature,
)
from positioning_cell.calibration.machine import (
    MachineModel,
    leg_vectors,
    mid_length,
    terms_offsets,
)
from positioning_cell.clearance import LoadAwareClearance
from positioning_cell.core.kinematics import inverse_jacobian, jacobian
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch, matrix_from_quaternion
from positioning_cell.errors import InputError
from positioning_cell.mechanics.statics import Payload, Structure, actuator_efforts
from positioning_cell.metrology.instrument import registration_jacobian
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


#: The compliance columns: fixed, they keep the nominal value (not 0).
_COMPLIANCE_COLUMNS = np.arange(cp.COUNT)[cp.COMPLIANCE]

class IdentificationError(InputError):
    """The data cannot identify the model (too few or degenerate poses); the message gives the
    rank and the parameters left unidentifiable."""


@dataclass(frozen=True)
class IdentificationSettings:
    """How identification treats its data (the ``identification:`` block)."""

    min_information: float = setting(
        3.0, 'a parameter is identified when its standard uncertainty is at most its expected '
        'size divided by this', low=0.0, low_open=True, high=1e6)
    min_identified: int = setting(
        12, 'refuse data that identify fewer parameters than this', low=1, high=cp.COUNT)
    min_poses: int = setting(8, 'refuse fewer measured poses than this', low=2, high=10000)
    seating_force: float = setting(1.0, 'F_0 of the load model', 'N', low=0.0, low_open=True)
    fit_clearance: bool = setting(True, 'identify the clearances r_a, r_b (false: a '
                                  'geometry-only fit, the clearance fixed at 0)')
    fit_compliance: bool = setting(True, "identify the legs' axial and the theta drives' "
                                   'torsional compliance (false: rigid)')
    fit_thermal: bool = setting(True, "identify the legs' and the structure's thermal "
                                'expansion (false: none)')
    fit_lead: bool = setting(True, "identify each leg's lead scale (false: none)")
    fit_reversal: bool = setting(True, "identify each axis' reversal half-band (false: "
                                 'none)')
    allowance_length: float = setting(
        1e-6, 'model allowance of the adequacy test: what the model may miss per leg', 'm',
        low=0.0, high=1e-3)
    allowance_theta: float = setting(
        5e-6, 'model allowance of the adequacy test per theta axis', 'rad', low=0.0,
        high=1e-2)
    adequacy_p: float = setting(
        0.01, 'the model is adequate when the p-value of its residuals\' chi2 is at least '
        'this', low=0.0, low_open=True, high=0.5)
    compliance_prior: float = setting(
        0.3, "relative standard uncertainty of the nominal structure's compliances (its "
        'stiffnesses by design or FEA), which a compliance the data cannot separate keeps: '
        'carried into the stated uncertainty (consider covariance)', low=0.0, high=10.0)
    fixed_prior: float = setting(
        1.0, 'standard uncertainty of any other parameter the data cannot separate, held at '
        'its nominal value, in units of its expected size (calibration.parameters.scales): '
        'carried into the stated uncertainty', low=0.0, high=100.0)
    screw_pitch: float = setting(
        0.005, "lead of the legs' screws (what a periodic error of the residuals is sought "
        'at)', 'm', low=0.0, low_open=True, high=0.1)
    min_temperature_range: float = setting(
        1.0, 'thermal terms are fitted only over a wider range of measured temperatures', 'K',
        low=0.0, high=50.0)

    def __post_init__(self) -> None:
        check_fields(self)


class CalibrationData(NamedTuple):
    """A calibration run, N stationary poses: the encoder means ``joints`` (N, 6) (lengths m,
    then θ rad, JOINT_NAMES order) and their standard uncertainties ``joint_sigma`` (N, 6);
    the measured pose ``position`` (N, 3) m, ``quaternion`` (N, 4) x, y, z, w in ``base`` and
    its ``covariance`` (N, 6, 6) (x, y, z, rot-x, rot-y, rot-z; m², rad²).

    Conditions of each pose, as the cell knows them (None: not recorded): ``temperature``
    (N,) the measured cell air temperature, °C (the temperature sensor's reading, not the
    machine's own), and ``approach`` (N, 6) the direction each axis last moved in before
    the pose was reached, in JOINT_NAMES order: +1 increasing, −1 decreasing, 0 not known
    (what a reversal error depends on).

    The tracker registration each pose was measured through (None: not known):
    ``registration_origin`` (N, 3) m, the located tracker origin in ``base``, and
    ``registration_covariance`` (N, 6, 6), that registration's covariance (δp m, δθ rad at
    the origin; :class:`~positioning_cell.metrology.instrument.Registration`). Its error is
    common to every pose measured through it, so the fit cannot average it away: poses with
    the same registration share one error (:func:`registration_consider`)."""

    joints: FloatArray
    joint_sigma: FloatArray
    position: FloatArray
    quaternion: FloatArray
    covariance: FloatArray
    temperature: FloatArray | None = None
    approach: FloatArray | None = None
    registration_origin: FloatArray | None = None
    registration_covariance: FloatArray | None = None

    def subset(self, rows: ArrayLike) -> CalibrationData:
        """The poses ``rows`` (indices or a mask)."""
        idx = np.asarray(rows)

        def pick(a: FloatArray | None) -> FloatArray | None:
            return None if a is None else take(a)

        def take(a: ArrayLike) -> FloatArray:
            out: FloatArray = np.asarray(a, dtype=float)[idx]
            return out

        return CalibrationData(take(self.joints), take(self.joint_sigma), take(self.position),
                               take(self.quaternion), take(self.covariance),
                               pick(self.temperature), pick(self.approach),
                               pick(self.registration_origin),
                               pick(self.registration_covariance))


def check_data(data: CalibrationData) -> CalibrationData:
    """The data as float arrays with consistent shapes and finite values (InputError naming
    the field otherwise); quaternions normalised."""
    p, q = as_pose_batch(data.position, data.quaternion)
    n = p.shape[0]
    shapes = {'joints': (n, 6), 'joint_sigma': (n, 6), 'covariance': (n, 6, 6)}
    arrays = {}
    for name, shape in shapes.items():
        arr = np.asarray(getattr(data, name), dtype=float)
        if arr.shape != shape:
            raise InputError(f'calibration data {name} has shape {arr.shape}, expected {shape}')
        if not np.all(np.isfinite(arr)):
            raise InputError(f'calibration data {name} holds non-finite values')
        arrays[name] = arr
    if np.any(arrays['joint_sigma'] <= 0.0):
        raise InputError('calibration data joint_sigma must be > 0')
    return CalibrationData(arrays['joints'], arrays['joint_sigma'], p, q, arrays['covariance'],
                           checked_temperature(data.temperature, n),
                           checked_approach(data.approach, n),
                           *checked_registrations(data.registration_origin,
                                                  data.registration_covariance, n))


def checked_registrations(origin: ArrayLike | None, covariance: ArrayLike | None, n: int
                          ) -> tuple[FloatArray | None, FloatArray | None]:
    """The registrations of n poses (:class:`CalibrationData`) as float arrays: both None, or
    a finite origin (n, 3) and a finite, symmetric covariance (n, 6, 6) with a non-negative
    diagonal; InputError naming what is wrong otherwise."""
    if origin is None and covariance is None:
        return None, None
    if origin is None or covariance is None:
        raise InputError('calibration data: registration_origin and registration_covariance '
                         'come together (one is missing)')
    o = np.asarray(origin, dtype=float)
    c = np.asarray(covariance, dtype=float)
    if o.shape != (n, 3) or c.shape != (n, 6, 6):
        raise InputError(f'calibration data registrations: expected ({n}, 3) and ({n}, 6, 6), '
                         f'got {o.shape} and {c.shape}')
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(c))
            and np.all(np.diagonal(c, axis1=1, axis2=2) >= 0.0)
            and np.allclose(c, np.swapaxes(c, 1, 2), rtol=1e-9, atol=0.0)):
        raise InputError('calibration data registrations: expected finite origins and finite, '
                         'symmetric covariances with a non-negative diagonal')
    return o, c


def predicted_joints(x: FloatArray, nominal: Mechanism, payload: Payload, structure: Structure,
                     position: FloatArray, quaternion: FloatArray, seating_force: float = 1.0,
                     *, with_jacobian: bool = False,
                     directions: tuple[FloatArray, FloatArray] | None = None,
                     conditions: Conditions | None = None,
                     reference_temperature: float = STANDARD_TEMPERATURE,
                     efforts: FloatArray | None = None,
                     ) -> tuple[FloatArray, FloatArray | None]:
    """Encoder values (N, 6) the machine of vector ``x`` reads at validated poses (N, 3),
    (N, 4) under ``conditions`` (None: not known; the thermal terms about
    ``reference_temperature`` °C), and (``with_jacobian``) their analytic Jacobian
    (N, 6, COUNT) in the vector's units (module docstring; the terms beyond geometry:
    :mod:`positioning_cell.calibration.machine`). ``directions``: the seated force directions
    (s_A base frame, s_B platform frame, (N, 3, 3) each) to use instead of those of this
    geometry (:func:`force_directions`). The joint efforts of the compliance are those of the
    nominal machine at the pose (geometry errors of 0.1 mm change them by ~0.05 %), so the
    Jacobian is exact with the force directions held."""
    n = position.shape[0]
    cond = conditions or Conditions()
    change = cond.temperature_change(n, reference_temperature)
    approach = cond.approach_signs(n)
    mech = _geometry(x, nominal)
    s_a, s_b = directions or force_directions(x, nominal, payload, structure, position,
                                              quaternion, seating_force)
    rot = matrix_from_quaternion(quaternion)
    s_b_base = np.einsum('nij,nkj->nki', rot, s_b)
    r_a, r_b = x[cp.R_A], x[cp.R_B]
    eps = x[cp.STRUCTURE_EXPANSION] * change
    b_base = np.einsum('nij,kj->nki', rot, mech.platform_joints)
    d = position[:, None, :] + b_base + r_b * s_b_base - (mech.base_joints + r_a * s_a)
    # the structure's expansion scales the seated joint centres by 1 + ε (machine.py)
    lever = d - position[:, None, :]
    d = d + eps[:, None, None] * lever
    legs = leg_vectors(d, mech.tangential)
    theta = np.arcsin(np.clip(legs.ut, -1.0, 1.0))
    if efforts is None and (with_jacobian or x[cp.COMPLIANCE].any()):
        efforts = actuator_efforts(mech, position, quaternion, payload, structure)
    mid = mid_length(nominal)
    gain, offset = terms_offsets(cp.terms_of(x, reference_temperature), legs.length, efforts,
                                 change, approach, mid)
    pred = np.concatenate([legs.length * gain + offset[:, :3] - x[cp.LENGTH],
                           theta + offset[:, 3:] - x[cp.THETA]], axis=1)
    if not with_jacobian:
        return pred, None
    assert efforts is not None
    grow = 1.0 + eps
    jac = np.zeros((n, 6, cp.COUNT))
    for i in range(3):  # three legs, each block vectorised over the poses
        base_cols = slice(cp.BASE.start + 3 * i, cp.BASE.start + 3 * i + 3)
        plat_cols = slice(cp.PLATFORM.start + 3 * i, cp.PLATFORM.start + 3 * i + 3)
        for row, grad in ((i, legs.u[:, i] * gain[:, i, None]), (3 + i, legs.w[:, i])):
            jac[:, row, cp.STRUCTURE_EXPANSION] = np.einsum('nj,nj->n', grad,
                                                            lever[:, i]) * change
            g = grad * grow[:, None]  # ∂d/∂(joint centres, clearances) scale with the structure
            jac[:, row, base_cols] = -g
            jac[:, row, plat_cols] = np.einsum('nj,njk->nk', g, rot)
            jac[:, row, cp.R_A] = -np.einsum('nj,nj->n', g, s_a[:, i])
            jac[:, row, cp.R_B] = np.einsum('nj,nj->n', g, s_b_base[:, i])
            jac[:, row, cp.REVERSAL.start + row] = approach[:, row]
        jac[:, i, cp.LENGTH.start + i] = -1.0
        jac[:, 3 + i, cp.THETA.start + i] = -1.0
        jac[:, i, cp.LEG_COMPLIANCE.start + i] = efforts[:, i]
        jac[:, 3 + i, cp.THETA_COMPLIANCE.start + i] = efforts[:, 3 + i]
        jac[:, i, cp.LEG_EXPANSION] = -change * legs.length[:, i]
        jac[:, i, cp.LEAD.start + i] = mid - legs.length[:, i]
    return pred, jac


def _geometry(x: FloatArray, nominal: Mechanism) -> Mechanism:
    """The mechanism with the joint-centre errors of ``x``."""
    return nominal.with_offsets(np.asarray(nominal.base_offsets) + x[cp.BASE].reshape(3, 3),
                                np.asarray(nominal.platform_offsets)
                                + x[cp.PLATFORM].reshape(3, 3))


def force_directions(x: FloatArray, nominal: Mechanism, payload: Payload,
                     structure: Structure, position: FloatArray, quaternion: FloatArray,
                     seating_force: float = 1.0) -> tuple[FloatArray, FloatArray]:
    """The seated joint-force directions of the geometry of ``x`` at poses: s_A (N, 3, 3) base
    frame, s_B (N, 3, 3) platform frame (:meth:`LoadAwareClearance.offsets` with r = 1)."""
    unit = LoadAwareClearance(1.0, 1.0, payload, structure, seating_force)
    return unit.offsets(_geometry(x, nominal), position, quaternion)


def joint_covariance(nominal: Mechanism, data: CalibrationData) -> FloatArray:
    """C_k (N, 6, 6) = J⁻¹ Σ_k J⁻ᵀ + diag(σ_joint²): the joint-space covariance of pose k's
    residual (m², rad²)."""
    jinv = inverse_jacobian(nominal, data.position, data.quaternion)
    cov = jinv @ data.covariance @ np.swapaxes(jinv, 1, 2)
    out: FloatArray = cov + np.einsum('ni,ij->nij', data.joint_sigma**2, np.eye(6))
    return out


def whitening(nominal: Mechanism, data: CalibrationData) -> FloatArray:
    """W_k (N, 6, 6) with W_k C_k W_kᵀ = I, C_k of :func:`joint_covariance`."""
    chol = np.linalg.cholesky(joint_covariance(nominal, data))
    eye = np.broadcast_to(np.eye(6), chol.shape)
    white: FloatArray = np.asarray(np.linalg.solve(chol, eye), dtype=float)
    return white


class Identifiability(NamedTuple):
    """Which parameters the data can separate: ``identified`` (COUNT,) mask; ``information``
    (COUNT,) |R_jj| of the pivoted QR in units of each parameter's expected size (the inverse of
    its standard uncertainty in those units, had it been added last); ``merged``, per fixed
    parameter, the identified ones that absorb it (name, coefficient); ``singular_values``
    (COUNT,) of the scaled whitened Jacobian, largest first."""

    identified: BoolArray
    information: FloatArray
    merged: dict[str, tuple[tuple[str, float], ...]]
    singular_values: FloatArray

    @property
    def rank(self) -> int:
        """How many parameters are identified."""
        return int(self.identified.sum())


def identifiability(scaled_jacobian: FloatArray, min_information: float) -> Identifiability:
    """Identifiable parameters of a whitened Jacobian (M, COUNT) in units of the parameters'
    expected sizes (module docstring)."""
    import scipy.linalg  # here: only calibrations ask, the positioner's start does not

    _, r, piv = scipy.linalg.qr(scaled_jacobian, mode='economic', pivoting=True)
    diag = np.abs(np.diag(r))
    top = diag[0] if diag.size else 0.0
    info = np.zeros(cp.COUNT)
    info[piv[:diag.size]] = diag
    keep = np.zeros(cp.COUNT, dtype=bool)
    for j, col in enumerate(piv[:diag.size]):
        if diag[j] < min_information or diag[j] <= 1e-10 * top:
            break
        keep[col] = True
    merged: dict[str, tuple[tuple[str, float], ...]] = {}
    kept_cols = np.flatnonzero(keep)
    if kept_cols.size and (~keep).any():
        coef, *_ = np.linalg.lstsq(scaled_jacobian[:, kept_cols],
                                   scaled_jacobian[:, ~keep], rcond=None)
        for k, col in enumerate(np.flatnonzero(~keep)):
            order = np.argsort(-np.abs(coef[:, k]))
            partners = tuple((cp.PARAMETER_NAMES[kept_cols[o]], round(float(coef[o, k]), 3))
                             for o in order[:3] if abs(coef[o, k]) >= 0.1)
            merged[cp.PARAMETER_NAMES[col]] = partners
    elif not kept_cols.size:
        merged = {name: () for name in cp.PARAMETER_NAMES}
    sv = np.asarray(np.linalg.svd(scaled_jacobian, compute_uv=False), dtype=float)
    return Identifiability(keep, info, merged, sv)


@dataclass(frozen=True)
class Identification:
    """An identified machine: the vector ``x`` (COUNT,) (fixed parameters at their nominal values),
    its covariance (COUNT, COUNT) (the fitted parameters' scaled by the a-posteriori variance
    factor when χ²/dof > 1; with the fixed ones' prior uncertainty considered:
    :func:`consider_covariance`; zero rows and columns for classes left out), the
    :class:`Identifiability`, the raw joint residuals (N, 6) and their whitened sum of squares
    ``chi2`` with ``dof`` degrees of freedom, and the pose-space residual position per pose
    (N,) m (the joint residual through the velocity Jacobian), ``nfev`` function evaluations,
    the ``reference_temperature`` °C of the thermal terms (the data's mean temperature; 20
    without one) and ``excluded``: the parameters left out before the fit (not to be fitted, or
    not excited by the data: no temperature, one approach direction), each with why, and the
    ``model_error`` (6,) per joint (m, rad): what the model misses by the ``adequacy`` test (0:
    adequate; else the allowance and the widening together;
    :mod:`positioning_cell.calibration.adequacy`). ``registration_share`` (COUNT, COUNT):
    the part of the covariance the tracker registrations' errors give
    (:func:`registration_consider`; None: not known), the accuracy the machine has in the
    true base frame rather than in the located one."""

    x: FloatArray
    covariance: FloatArray
    identifiability: Identifiability
    residuals: FloatArray
    pose_residual_position: FloatArray
    chi2: float
    dof: int
    nfev: int
    reference_temperature: float = STANDARD_TEMPERATURE
    excluded: dict[str, str] = field(default_factory=dict)
    model_error: FloatArray = field(default_factory=lambda: np.zeros(6))
    adequacy: adq.Adequacy | None = None
    registration_share: FloatArray | None = None

    @property
    def sigma(self) -> FloatArray:
        """Standard uncertainty per parameter (COUNT,), NaN for fixed ones."""
        out = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return np.where(self.identifiability.identified, out, np.nan)

    def model(self, nominal: Mechanism, payload: Payload, structure: Structure,
              seating_force: float = 1.0) -> MachineModel:
        """The identified machine carrying ``payload`` (any payload: the clearance is a load
        model, so a new panel needs its mass and centre of gravity, not a new calibration)."""
        return cp.machine_model(self.x, nominal, payload, structure, seating_force,
                                self.reference_temperature)


def switched_off(settings: IdentificationSettings) -> tuple[str, ...]:
    """The parameter classes (:data:`~positioning_cell.calibration.parameters.CLASSES`) the
    ``settings`` leave out of the model (``fit_<class>: false``)."""
    switches = (('clearance', settings.fit_clearance), ('compliance', settings.fit_compliance),
                ('thermal', settings.fit_thermal), ('lead', settings.fit_lead),
                ('reversal', settings.fit_reversal))
    return tuple(kind for kind, on in switches if not on)


def prior_sigma(settings: IdentificationSettings) -> FloatArray:
    """The standard uncertainty (COUNT,) a parameter the data cannot identify keeps, in units
    of its expected size (:func:`~positioning_cell.calibration.parameters.scales`): a
    compliance ``compliance_prior`` (its expected size is the nominal structure's 1/k, which
    it keeps), the others ``fixed_prior`` (their expected size is that of their error); 0 for
    the classes the settings leave out (the model has no such term: what they miss is the
    adequacy test's to find, not a stated uncertainty)."""
    out = np.full(cp.COUNT, settings.fixed_prior)
    out[cp.COMPLIANCE] = settings.compliance_prior
    for kind in switched_off(settings):
        out[cp.CLASSES[kind]] = 0.0
    return out


def consider_covariance(scaled_jacobian: FloatArray, free: NDArray[np.intp],
                        free_covariance: FloatArray, prior: FloatArray) -> FloatArray:
    """The covariance (COUNT, COUNT) of the whole vector, in units of the expected sizes, when
    the parameters outside ``free`` are not fitted but held at their nominal values with the
    standard uncertainty ``prior`` (COUNT,): the consider covariance of Schmidt's consider
    analysis (e.g. Tapley, Schutz & Born, *Statistical Orbit Determination*, 2004, §6.3).
    The fitted parameters absorb the held ones' errors δc by δz = A δc with
    A = −(J_Fᵀ J_F)⁺ J_Fᵀ J_C (``scaled_jacobian`` (M, COUNT) whitened), so

        P_FF = ``free_covariance`` + A Σ_c Aᵀ,  P_FC = A Σ_c,  P_CC = Σ_c = diag(prior²).

    A prediction's covariance S P Sᵀ through this then holds what the held parameters do
    where the fit could not absorb them: at the calibration's poses and load little, at
    another payload or temperature what the unidentified compliance or expansion does
    there."""
    held = np.setdiff1d(np.arange(cp.COUNT), free)
    held = held[prior[held] > 0.0]
    out = np.zeros((cp.COUNT, cp.COUNT))
    out[np.ix_(free, free)] = free_covariance
    if not held.size:
        return out
    j_free, j_held = scaled_jacobian[:, free], scaled_jacobian[:, held]
    absorb = -np.linalg.pinv(j_free.T @ j_free) @ (j_free.T @ j_held)
    sigma_held = np.diag(prior[held]**2)
    cross = absorb @ sigma_held
    out[np.ix_(free, free)] += cross @ absorb.T
    out[np.ix_(free, held)] = cross
    out[np.ix_(held, free)] = cross.T
    out[np.ix_(held, held)] = sigma_held
    return out


def registration_consider(nominal: Mechanism, data: CalibrationData, white: FloatArray,
                          scaled_jacobian: FloatArray, free: NDArray[np.intp]) -> FloatArray:
    """The covariance (COUNT, COUNT), in units of the expected sizes, that the tracker
    registrations' errors give the fitted parameters (zero without registrations in the
    validated ``data``): a consider term like :func:`consider_covariance`'s. A registration
    error δr (δp, δθ at its origin; covariance Σ_r) moves every pose measured through it by
    J_r,k·δr (:func:`~positioning_cell.metrology.instrument.registration_jacobian`), so the
    whitened residuals by G·δr, G_k = W_k·J⁻¹_k·J_r,k (``white`` W (N, 6, 6), J⁻¹ the inverse
    Jacobian); the fit absorbs it by δz = A·δr, A = −(J_Fᵀ J_F)⁺ J_Fᵀ G (``scaled_jacobian``
    J (6N, COUNT), ``free`` its fitted columns), so P_FF gains Σ_g A_g·Σ_r,g·A_gᵀ, one term
    per registration g (poses with equal origin and covariance share one; registrations are
    independent of each other). The per-pose covariances already hold J_r,k·Σ_r·J_r,kᵀ, but
    as if independent between poses, which a fit of N poses averages down by ~N."""
    out = np.zeros((cp.COUNT, cp.COUNT))
    if data.registration_origin is None or data.registration_covariance is None:
        return out
    n = data.position.shape[0]
    keys = np.concatenate([data.registration_origin,
                           data.registration_covariance.reshape(n, 36)], axis=1)
    _, first, group = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    moved = white @ inverse_jacobian(nominal, data.position, data.quaternion) \
        @ registration_jacobian(data.registration_origin, data.position)
    j_free = scaled_jacobian[:, free]
    solve = np.linalg.pinv(j_free.T @ j_free) @ j_free.T
    for g, row in enumerate(first):  # one pass per registration (a run has one or a few)
        absorb = -solve @ np.where((group.ravel() == g)[:, None, None], moved, 0.0
                                   ).reshape(6 * n, 6)
        out[np.ix_(free, free)] += absorb @ data.registration_covariance[row] @ absorb.T
    return out


def excluded_parameters(data: CalibrationData,
                        settings: IdentificationSettings) -> dict[str, str]:
    """The parameters identification leaves out before fitting (fixed at 0), with why: a
    class switched off in ``settings``, the thermal terms without temperatures or over a
    range narrower than ``min_temperature_range``, the reversal of an axis without approach
    directions or approached from one side only (validated ``data``)."""
    out: dict[str, str] = {}

    def leave(index: slice | int, why: str) -> None:
        names = cp.PARAMETER_NAMES[index]
        for name in (names,) if isinstance(names, str) else names:
            out.setdefault(name, why)

    for kind in switched_off(settings):
        leave(cp.CLASSES[kind], f'not fitted (identification.fit_{kind}: false)')
    if data.temperature is None:
        leave(cp.THERMAL, 'no temperature recorded')
    elif np.ptp(data.temperature) < settings.min_temperature_range:
        leave(cp.THERMAL, f'temperature range {np.ptp(data.temperature):.2f} K below '
              f'{settings.min_temperature_range:g} K')
    if data.approach is None:
        leave(cp.REVERSAL, 'no approach directions recorded')
    else:
        for j in range(6):
            if not (np.any(data.approach[:, j] > 0) and np.any(data.approach[:, j] < 0)):
                leave(cp.REVERSAL.start + j, 'approached from one side only')
    return out


def reference_temperature(data: CalibrationData) -> float:
    """The reference of the thermal terms: the data's mean temperature (°C; 20 without)."""
    return STANDARD_TEMPERATURE if data.temperature is None else float(np.mean(data.temperature))


def identify(nominal: Mechanism, payload: Payload, structure: Structure,
             data: CalibrationData,
             settings: IdentificationSettings | None = None) -> Identification:
    """Identify the machine model from ``data`` (module docstring). IdentificationError when
    there are too few poses or they identify fewer than ``settings.min_identified``
    parameters (the message names the rank and the unidentifiable parameters)."""
    s = settings or IdentificationSettings()
    data = check_data(data)
    n = data.position.shape[0]
    if n < s.min_poses:
        raise IdentificationError(f'{n} poses: a calibration needs at least {s.min_poses}')
    scale = cp.scales(nominal, structure=structure)
    white = whitening(nominal, data)
    conditions = Conditions(data.temperature, data.approach)
    reference = reference_temperature(data)
    excluded = excluded_parameters(data, s)
    out_cols = [cp.PARAMETER_NAMES.index(name) for name in excluded]

    def evaluate(x: FloatArray, jac: bool) -> tuple[FloatArray, FloatArray | None]:
        pred, j = predicted_joints(x, nominal, payload, structure, data.position,
                                   data.quaternion, s.seating_force, with_jacobian=jac,
                                   conditions=conditions, reference_temperature=reference)
        res = np.einsum('nij,nj->ni', white, pred - data.joints).ravel()
        if j is None:
            return res, None
        return res, (white @ j).reshape(6 * n, cp.COUNT) * scale

    x0 = np.zeros(cp.COUNT)
    x0[cp.R_A], x0[cp.R_B] = scale[cp.R_A], scale[cp.R_B]
    # A leg is not rigid: a compliance the data cannot separate keeps the nominal structure's
    # (at another payload 0 would be a rigid leg, the whole deflection change unexplained).
    x0[cp.COMPLIANCE] = cp.nominal_compliance(structure)
    x0[out_cols] = 0.0
    _, j0 = evaluate(x0, True)
    assert j0 is not None
    j0[:, out_cols] = 0.0
    ident = identifiability(j0, s.min_information)
    if ident.rank < s.min_identified or 6 * n <= ident.rank:
        unknown = ', '.join(name for name, ok in zip(cp.PARAMETER_NAMES, ident.identified,
                                                      strict=True) if not ok)
        raise IdentificationError(
            f'{n} poses identify {ident.rank} of {cp.COUNT} parameters (at least '
            f'{s.min_identified} needed); not identifiable: {unknown}')
    free = np.flatnonzero(ident.identified)
    start = np.where(ident.identified | np.isin(np.arange(cp.COUNT), _COMPLIANCE_COLUMNS),
                     x0, 0.0)

    def full(z: FloatArray) -> FloatArray:
        x = start.copy()
        x[free] = z * scale[free]
        return x

    def fun(z: FloatArray) -> FloatArray:
        return evaluate(full(z), False)[0]

    def jac(z: FloatArray) -> FloatArray:
        j = evaluate(full(z), True)[1]
        assert j is not None
        return j[:, free]

    lower = np.where(np.isin(free, (cp.R_A, cp.R_B)), 0.0, -np.inf)
    # imported here: the positioner loads this module (a calibration file's uncertainty) but
    # never fits, and scipy.optimize cost its start ~0.1 s
    from scipy.optimize import least_squares

    fit = least_squares(fun, start[free] / scale[free], jac=jac, method='trf',
                        bounds=(lower, np.full(free.size, np.inf)), x_scale=1.0,
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=100)
    x = full(fit.x)
    res_white, j_final = evaluate(x, True)
    assert j_final is not None
    chi2 = float(res_white @ res_white)
    dof = 6 * n - free.size
    jf = j_final[:, free]
    factor = max(chi2 / dof, 1.0) if dof > 0 else 1.0
    registration = registration_consider(nominal, data, white, j_final, free) \
        * np.outer(scale, scale)
    cov = consider_covariance(j_final, free, np.linalg.pinv(jf.T @ jf) * factor,
                              prior_sigma(s)) * np.outer(scale, scale) + registration
    pred, _ = predicted_joints(x, nominal, payload, structure, data.position, data.quaternion,
                               s.seating_force, conditions=conditions,
                               reference_temperature=reference)
    residuals = pred - data.joints
    pose_res = np.einsum('nij,nj->ni', jacobian(nominal, data.position, data.quaternion).matrix,
                         residuals)
    allowance = adq.allowance_covariance(s.allowance_length, s.allowance_theta)
    verdict = adq.assess('fit', residuals, joint_covariance(nominal, data) + allowance, dof,
                         s.adequacy_p, _signatures(x, nominal, payload, structure, data, s))
    model_error = np.zeros(6) if verdict.adequate else \
        np.sqrt(np.diag(allowance) + verdict.model_error**2)
    return Identification(x, cov, ident, residuals, np.linalg.norm(pose_res[:, :3], axis=1),
                          chi2, dof, int(fit.nfev), reference, excluded, model_error, verdict,
                          registration)


def _signatures(x: FloatArray, nominal: Mechanism, payload: Payload, structure: Structure,
                data: CalibrationData, settings: IdentificationSettings
                ) -> dict[str, FloatArray]:
    """The effects' signatures at the poses of ``data`` (:func:`adequacy.signatures`)."""
    efforts = actuator_efforts(_geometry(x, nominal), data.position, data.quaternion, payload,
                               structure)
    return adq.signatures(efforts, data.temperature, data.approach, data.joints[:, :3],
                          settings.screw_pitch)


def hold_out_adequacy(result: Identification, nominal: Mechanism, payload: Payload,
                      structure: Structure, data: CalibrationData,
                      settings: IdentificationSettings | None = None) -> adq.Adequacy:
    """The χ² test of the identified model at hold-out poses ``data`` it was not fitted to
    (6N degrees of freedom; their covariance: the measurement's, the allowance and the
    identified parameters' own uncertainty; not the model error, which is what is tested).
    The parameters' share from the registrations is left out: a hold-out pose's own
    covariance already holds its registration's error, which is the fit's too when both
    were measured through one registration (they then cancel in the residual)."""
    s = settings or IdentificationSettings()
    data = check_data(data)
    fitted = result.covariance if result.registration_share is None \
        else result.covariance - result.registration_share
    pred, sens = predicted_joints(result.x, nominal, payload, structure, data.position,
                                  data.quaternion, s.seating_force, with_jacobian=True,
                                  conditions=Conditions(data.temperature, data.approach),
                                  reference_temperature=result.reference_temperature)
    assert sens is not None
    cov = (joint_covariance(nominal, data)
           + adq.allowance_covariance(s.allowance_length, s.allowance_theta)
           + sens @ fitted @ np.swapaxes(sens, 1, 2))
    residuals = pred - data.joints
    return adq.assess('hold-out', residuals, cov, 6 * residuals.shape[0], s.adequacy_p,
                      _signatures(result.x, nominal, payload, structure, data, s))


def information_rows(nominal: Mechanism, payload: Payload, structure: Structure,
                     position: ArrayLike, quaternion: ArrayLike, covariance: FloatArray,
                     joint_sigma: ArrayLike, seating_force: float = 1.0,
                     conditions: Conditions | None = None,
                     reference: float = STANDARD_TEMPERATURE) -> FloatArray:
    """The scaled whitened identification Jacobian of candidate poses (N, 6, COUNT): what each
    pose would add to the calibration (for choosing the measurement program; without
    ``conditions`` the thermal and reversal columns are 0, a pose alone does not excite
    them; with the measured ones, about the ``reference`` temperature °C, what the measured
    poses did add). ``covariance`` (6, 6) or (N, 6, 6) the expected pose measurement
    covariance, ``joint_sigma`` (6,) the encoders'."""
    p, q = as_pose_batch(position, quaternion)
    n = p.shape[0]
    data = CalibrationData(np.zeros((n, 6)), np.broadcast_to(np.asarray(joint_sigma,
                                                                          dtype=float), (n, 6)),
                           p, q, np.broadcast_to(covariance, (n, 6, 6)))
    scale = cp.scales(nominal, structure=structure)
    x0 = np.zeros(cp.COUNT)
    x0[cp.R_A], x0[cp.R_B] = scale[cp.R_A], scale[cp.R_B]
    _, j = predicted_joints(x0, nominal, payload, structure, p, q, seating_force,
                            with_jacobian=True, conditions=conditions,
                            reference_temperature=reference)
    assert j is not None
    rows: FloatArray = whitening(nominal, data) @ j * scale
    return rows


def pose_uncertainty(x: FloatArray, covariance: FloatArray, nominal: Mechanism,
                     payload: Payload, structure: Structure, position: ArrayLike,
                     quaternion: ArrayLike, seating_force: float = 1.0,
                     model_error: ArrayLike | None = None, *,
                     conditions: Conditions | None = None,
                     reference_temperature: float = STANDARD_TEMPERATURE,
                     temperature_sigma: float = 0.0) -> FloatArray:
    """Covariance (N, 6, 6) (x, y, z, rot-x, rot-y, rot-z; m², rad²) of where the calibrated
    machine puts the platform when commanded to poses (N, 3), (N, 4) under ``conditions``
    (None: not known; the thermal terms about ``reference_temperature`` °C), from the
    identified parameters' covariance (first order: the encoder commands move by ∂e/∂x·δx, the
    pose by the velocity Jacobian of that): the accuracy the calibration itself promises
    there. ``x`` (COUNT,) and ``covariance`` (COUNT, COUNT): an :class:`Identification`'s, or
    a calibration file's. ``model_error`` (6,): the standard uncertainty of what the model
    misses, per joint (m, rad; :mod:`positioning_cell.calibration.adequacy`), added as an
    independent joint error (None: none). ``temperature_sigma`` K: the standard uncertainty
    of the temperature the thermal terms are given, added through the model's own
    sensitivity to it (a central difference of ±1 K; the terms are linear in it)."""
    p, q = as_pose_batch(position, quaternion)
    _, sens = predicted_joints(x, nominal, payload, structure, p, q, seating_force,
                               with_jacobian=True, conditions=conditions,
                               reference_temperature=reference_temperature)
    assert sens is not None
    vel = jacobian(nominal, p, q).matrix
    pose_sens = vel @ sens
    cov: FloatArray = pose_sens @ covariance @ np.swapaxes(pose_sens, 1, 2)
    if model_error is not None:
        joint_var = np.asarray(model_error, dtype=float)**2
        cov = cov + np.einsum('nij,j,nkj->nik', vel, joint_var, vel)
    if temperature_sigma > 0.0:
        per_kelvin = vel @ (_at_temperature(x, nominal, payload, structure, p, q, seating_force,
                                            conditions, reference_temperature, 1.0)
                            - _at_temperature(x, nominal, payload, structure, p, q,
                                              seating_force, conditions,
                                              reference_temperature, -1.0))[..., None] / 2.0
        cov = cov + temperature_sigma**2 * per_kelvin @ np.swapaxes(per_kelvin, 1, 2)
    return cov


def _at_temperature(x: FloatArray, nominal: Mechanism, payload: Payload, structure: Structure,
                    p: FloatArray, q: FloatArray, seating_force: float,
                    conditions: Conditions | None, reference: float, change: float
                    ) -> FloatArray:
    """The encoder values (N, 6) the machine of ``x`` reads at poses when the temperature is
    ``change`` K from that of ``conditions`` (the reference's when it has none)."""
    n = p.shape[0]
    cond = conditions or Conditions()
    shifted = Conditions(reference + cond.temperature_change(n, reference) + change,
                         cond.approach)
    return predicted_joints(x, nominal, payload, structure, p, q, seating_force,
                            conditions=shifted, reference_temperature=reference)[0]
