"""The operator's coordinate systems (Symétrie hexapod controller semantics).

Frames, all right-handed, SI (m, rad, quaternions x, y, z, w):

- ``base``: the machine's fixed frame; the platform's pose in it is (p_base_platform,
  q_base_platform), the pose the kinematics and the wire use.
- ``machine``: origin at the platform frame's origin at the home pose, axes parallel to
  ``base`` (also when a mechanism's home orientation is not the identity):
  T_base_machine = (p_home, I). The machine pose is the platform pose in it,
  T_machine = (p − p_home, R_base_platform): zero at home.
- ``user``: a frame given in the machine CS, T_machine_user.
- ``object``: a frame given in the platform frame, T_platform_object; its origin is the pivot
  point, about which rotations of the object turn.

The user position G is the object frame in the user CS: G = T_user⁻¹ · T_machine · T_object.
An absolute move to G commands T_machine = T_user · G · T_object⁻¹. A move relative to the
object by Δ goes to G · Δ (translation along the object's axes, rotation about the pivot);
relative to the user by Δ it goes to (t_G + t_Δ, R_G · R_Δ): the translation is added along the
user axes, the rotation composed on the object side (about the pivot, in the object's axes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import FloatArray, as_pose_batch
from positioning_cell.errors import InputError
from positioning_cell.frames.transforms import Transform, compose_poses
from positioning_cell.names import (  # the frames' names, declared there
    ABSOLUTE_FRAMES,
    BASE_FRAME,
    MACHINE_FRAME,
    OBJECT_FRAME,
    USER_FRAME,
)

#: Move kinds of :meth:`CoordinateSystems.resolve_goal`.
ABSOLUTE = 'absolute'
RELATIVE_USER = 'relative_user'
RELATIVE_OBJECT = 'relative_object'
MOVE_KINDS = (ABSOLUTE, RELATIVE_USER, RELATIVE_OBJECT)

#: A pose argument: a Transform, or (position (3,) m, unit quaternion (4,) x, y, z, w).
PoseLike = Transform | tuple[ArrayLike, ArrayLike]

__all__ = [
    'ABSOLUTE',
    'ABSOLUTE_FRAMES',
    'MACHINE_FRAME',
    'MOVE_KINDS',
    'OBJECT_FRAME',
    'RELATIVE_OBJECT',
    'RELATIVE_USER',
    'USER_FRAME',
    'CoordinateSystems',
    'PoseLike',
    'machine_origin',
]


def machine_origin(mech: Mechanism) -> Transform:
    """T_base_machine = (p_home (3,) m, I): the machine CS in ``base``."""
    return Transform(mech.home_position, np.eye(3))


def _pq(pose: PoseLike, name: str) -> tuple[FloatArray, FloatArray]:
    """``pose`` as one validated position (3,) m and unit quaternion (4,) x, y, z, w: a (p, q)
    pair as given (normalised), a Transform's with w ≥ 0; InputError names ``name``."""
    if isinstance(pose, Transform):
        return pose.to_pq()
    try:
        position, quaternion = pose
    except (TypeError, ValueError) as err:
        raise InputError(f'{name}: expected a Transform or (position, quaternion), '
                         f'got {pose!r}') from err
    try:
        p, q = as_pose_batch(position, quaternion)
    except InputError as err:
        raise InputError(f'{name}: {err}') from None
    if p.shape[0] != 1:
        raise InputError(f'{name}: expected one pose, got {p.shape[0]}')
    return p[0], q[0]


def _transform(pose: PoseLike, name: str) -> Transform:
    """``pose`` as a Transform (a (p, q) pair is validated; InputError names ``name``)."""
    return pose if isinstance(pose, Transform) else Transform.from_pq(*_pq(pose, name))


@dataclass(frozen=True)
class CoordinateSystems:
    """The user CS ``user`` = T_machine_user and the object CS ``object`` = T_platform_object
    (module docstring); both the identity by default, where the user position is the machine
    pose. Every pose argument and result is one pose: (3,) m, (4,) x, y, z, w, or Transform."""

    user: Transform = field(default_factory=Transform.identity)
    object: Transform = field(default_factory=Transform.identity)

    def __post_init__(self) -> None:
        for name in ('user', 'object'):
            if not isinstance(getattr(self, name), Transform):
                raise InputError(f'coordinate systems: {name} must be a Transform, '
                                 f'got {getattr(self, name)!r}')

    # -- base <-> machine ------------------------------------------------------------------
    @staticmethod
    def machine_from_base(position: ArrayLike, quaternion: ArrayLike,
                          mech: Mechanism) -> Transform:
        """The machine pose T_machine = (p − p_home, R) of the platform pose in ``base``
        (``position`` (3,) m, unit ``quaternion`` (4,) x, y, z, w)."""
        return machine_origin(mech).inverse() @ Transform.from_pq(position, quaternion)

    @staticmethod
    def base_from_machine(machine: Transform,
                          mech: Mechanism) -> tuple[FloatArray, FloatArray]:
        """The platform pose in ``base`` (p (3,) m, q (4,) x, y, z, w, w ≥ 0) of the machine
        pose T_machine."""
        return (machine_origin(mech) @ machine).to_pq()

    def user_in_base(self, mech: Mechanism) -> Transform:
        """T_base_user = T_base_machine · T_machine_user: the user CS in ``base``."""
        return machine_origin(mech) @ self.user

    # -- user position ---------------------------------------------------------------------
    def user_position(self, position: ArrayLike, quaternion: ArrayLike,
                      mech: Mechanism) -> Transform:
        """G = T_user⁻¹ · T_machine · T_object: the object frame in the user CS, of the
        platform pose in ``base`` (``position`` (3,) m, ``quaternion`` (4,) x, y, z, w)."""
        return self.user.inverse() @ self.machine_from_base(position, quaternion, mech) \
            @ self.object

    def user_positions(self, position: ArrayLike, quaternion: ArrayLike,
                       mech: Mechanism) -> tuple[FloatArray, FloatArray]:
        """:meth:`user_position` of a batch of platform poses in ``base`` ((N, 3) m,
        (N, 4) x, y, z, w): G as positions (N, 3) m and quaternions (N, 4), w ≥ 0."""
        left = self.user.inverse() @ machine_origin(mech).inverse()
        return compose_poses(left, position, quaternion, self.object)

    def base_goal_absolute(self, goal: PoseLike,
                           mech: Mechanism) -> tuple[FloatArray, FloatArray]:
        """The platform goal in ``base`` (p (3,) m, q (4,), w ≥ 0) that puts the object frame
        at the user position ``goal`` = G: T_machine = T_user · G · T_object⁻¹."""
        g = _transform(goal, 'user goal')
        return self.base_from_machine(self.user @ g @ self.object.inverse(), mech)

    # -- relative moves --------------------------------------------------------------------
    @staticmethod
    def relative_object(goal: PoseLike, delta: PoseLike) -> Transform:
        """G · Δ: the user position ``goal`` moved by ``delta`` given in the object CS
        (translation along the object's axes, rotation about the pivot)."""
        return _transform(goal, 'user position') @ _transform(delta, 'relative move')

    @staticmethod
    def relative_user(goal: PoseLike, delta: PoseLike) -> Transform:
        """(t_G + t_Δ, R_G · R_Δ): the user position ``goal`` moved by ``delta``, its
        translation along the user axes, its rotation about the pivot in the object's axes."""
        g = _transform(goal, 'user position')
        d = _transform(delta, 'relative move')
        return Transform(g.p + d.p, g.R @ d.R)

    # -- requests --------------------------------------------------------------------------
    def resolve_goal(self, kind: str, frame_id: str, pose: PoseLike,
                     current_user_position: Transform | None,
                     mech: Mechanism) -> tuple[FloatArray, FloatArray]:
        """The platform goal in ``base`` (p (3,) m, unit q (4,) x, y, z, w) of a move request.

        ``kind`` ``'absolute'``: ``pose`` is the platform pose in ``base`` (frame_id
        ``'base'``, returned as is, validated and normalised), the machine pose (``'machine'``)
        or the user position G (``'user'``). ``'relative_user'`` (frame_id ``'user'`` or
        empty) and ``'relative_object'`` (``'object'`` or empty): ``pose`` is Δ, applied to
        ``current_user_position`` (G, the reference; needed only by relative moves). Anything
        else raises InputError naming the allowed frames.
        """
        if kind == ABSOLUTE:
            if frame_id == BASE_FRAME:
                return _pq(pose, 'base goal')
            if frame_id == MACHINE_FRAME:
                return self.base_from_machine(_transform(pose, 'machine goal'), mech)
            if frame_id == USER_FRAME:
                return self.base_goal_absolute(pose, mech)
            raise InputError(f'an absolute goal is given in one of the frames '
                             f'{_quoted(ABSOLUTE_FRAMES)}, not in frame_id {frame_id!r}')
        if kind not in (RELATIVE_USER, RELATIVE_OBJECT):
            raise InputError(f'move kind {kind!r} is not one of {_quoted(MOVE_KINDS)}')
        frame = USER_FRAME if kind == RELATIVE_USER else OBJECT_FRAME
        if frame_id not in (frame, ''):
            raise InputError(f'a {kind} move is given in the {frame} CS: frame_id must be '
                             f'{frame!r} (or empty), not {frame_id!r}')
        if current_user_position is None:
            raise InputError(f'a {kind} move needs the current user position (none known)')
        move = self.relative_user if kind == RELATIVE_USER else self.relative_object
        return self.base_goal_absolute(move(current_user_position, pose), mech)


def _quoted(names: tuple[str, ...]) -> str:
    return ', '.join(repr(n) for n in names)
