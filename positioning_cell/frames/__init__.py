"""The operator's coordinate systems (Symétrie hexapod controller semantics): the machine, user
and object CS over the ``base`` and platform frames, and poses as six numbers. Pure
numpy/scipy; no ROS.

- :mod:`.transforms`: rigid transforms, six numbers (SI ``pose6`` m, rad; ``human`` mm, deg;
  R = Rz·Ry·Rx);
- :mod:`.systems`: the machine CS, the user and object CS, user positions and move requests
  resolved to the platform goal in ``base``;
- :mod:`.named`: several user and object systems stored by name, one active of each;
- :mod:`.file`: the coordinate systems file (YAML, written atomically).
"""

from positioning_cell.frames.file import CoordinateSystemsFileError, load, write
from positioning_cell.frames.systems import (
    ABSOLUTE,
    ABSOLUTE_FRAMES,
    MACHINE_FRAME,
    MOVE_KINDS,
    OBJECT_FRAME,
    RELATIVE_OBJECT,
    RELATIVE_USER,
    USER_FRAME,
    CoordinateSystems,
    PoseLike,
    machine_origin,
)
from positioning_cell.frames.transforms import (
    EULER_SEQUENCE,
    MM_PER_M,
    Transform,
    compose_poses,
    distance,
    format_human,
    human_from_pose6,
    pose6_from_human,
    pose6_from_pq,
    pq_from_pose6,
)

__all__ = [
    'ABSOLUTE',
    'ABSOLUTE_FRAMES',
    'EULER_SEQUENCE',
    'MACHINE_FRAME',
    'MM_PER_M',
    'MOVE_KINDS',
    'OBJECT_FRAME',
    'RELATIVE_OBJECT',
    'RELATIVE_USER',
    'USER_FRAME',
    'CoordinateSystems',
    'CoordinateSystemsFileError',
    'PoseLike',
    'Transform',
    'compose_poses',
    'distance',
    'format_human',
    'human_from_pose6',
    'load',
    'machine_origin',
    'pose6_from_human',
    'pose6_from_pq',
    'pq_from_pose6',
    'write',
]
