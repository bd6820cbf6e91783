"""What the coordinated cell's watch window shows (``cell watch --panel``; issue 27 item 6),
from what the cell publishes and nothing the simulators hold: the coordinator's status, the
panel as its tracker measures it (cell frame), each positioner's state and drives (its set's
/diagnostics), and the internal force the legs' load cells give (seed 002's statics,
:func:`~positioning_cell.coordinated.load_cells.attachment_forces`: a figure of the panel at
rest; while it moves the legs also carry its acceleration). Written by ROS callbacks (any
thread) and read as one consistent :class:`PanelSnapshot`. Plain data, no ROS
(:mod:`positioning_cell.ros.panel_watch_inputs` converts the messages)."""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import NamedTuple

import numpy as np

from positioning_cell.coordinated.load_cells import attachment_forces, internal_forces
from positioning_cell.coordinated.settings import CellCoordinatorSettings
from positioning_cell.core.kinematics import forward
from positioning_cell.core.poses import FloatArray
from positioning_cell.errors import PositioningError
from positioning_cell.watch.state import Pose, Status

#: Joint states of each set averaged for its load cells (at the sets' 50-100 Hz, 0.1-0.2 s:
#: the coordinator's relax averages 0.5 s at rest).
LOAD_CELL_READINGS = 10


class PanelForces(NamedTuple):
    """The internal force at each attachment from the load cells: the positioners' ``names``
    (the cell file's order), ``internal`` (N, 3) N on the panel, cell frame, and the cell
    file's ``limit`` N."""

    names: tuple[str, ...]
    internal: FloatArray
    limit: float

    @property
    def sizes(self) -> FloatArray:
        """(N,) N: each attachment's internal force's size."""
        out: FloatArray = np.linalg.norm(self.internal, axis=1)
        return out


@dataclass(frozen=True)
class PanelSnapshot:
    """Everything the panel's watch window draws, at one instant. ``settings``: the
    coordinator's parameters (its cell file and nominal machine), None until it answered;
    ``coordinator``: its latest status; ``panel``: the panel's measured pose in the cell frame
    (m, unit quaternion x, y, z, w) and ``panel_stamp`` its header stamp (s); per positioner
    (by name) its positioner's and its drives' latest status, and its latest joint states as
    (encoders (K, 6) m / rad, load cells (K, 6) N / N·m) in JOINT_NAMES order."""

    settings: CellCoordinatorSettings | None = None
    coordinator: Status | None = None
    panel: Pose | None = None
    panel_stamp: float = 0.0
    positioners: Mapping[str, Status] = field(default_factory=dict)
    drives: Mapping[str, Status] = field(default_factory=dict)
    readings: Mapping[str, tuple[FloatArray, FloatArray]] = field(default_factory=dict)

    @property
    def names(self) -> tuple[str, ...]:
        """The positioners of the coordinator's cell file, in its order; none while unknown."""
        if self.settings is None:
            return ()
        try:
            return tuple(e.name for e in self.settings.cell().positioners)
        except PositioningError:
            return ()

    def forces(self) -> PanelForces | str:
        """Each attachment's internal force from each set's load cells (the mean of its
        latest joint states) through the cell file's statics, or why there is none yet (a
        str); worked out once per snapshot."""
        return self._forces

    @cached_property
    def _forces(self) -> PanelForces | str:
        if self.settings is None:
            return 'the coordinator\'s cell file not known yet'
        try:
            cell = self.settings.cell()
        except PositioningError as err:
            return f'the coordinator\'s cell file: {err}'
        names = [e.name for e in cell.positioners]
        missing = [n for n in names if n not in self.readings]
        if missing:
            return f'no load cells heard of {", ".join(missing)}'
        joints = np.array([self.readings[n][0].mean(axis=0) for n in names])
        efforts = np.array([self.readings[n][1].mean(axis=0) for n in names])
        try:
            forces = attachment_forces(cell, self.settings.mechanism, joints, efforts)
        except PositioningError as err:
            return f'the load cells give no forces: {err}'
        return PanelForces(tuple(names), internal_forces(cell, self.settings.mechanism, forces),
                           cell.panel.internal_force_limit)

    def platforms(self) -> dict[str, Pose]:
        """Each positioner's platform pose in its base (position m, quaternion), from the
        mean of its latest encoder readings through the nominal machine's forward kinematics
        (those not heard from, or whose encoders give no pose, left out); once per
        snapshot."""
        return self._platforms

    @cached_property
    def _platforms(self) -> dict[str, Pose]:
        if self.settings is None:
            return {}
        heard = [n for n in self.names if n in self.readings]
        if not heard:
            return {}
        q = np.array([self.readings[n][0].mean(axis=0) for n in heard])
        fk = forward(self.settings.mechanism, q[:, :3], q[:, 3:])
        return {n: (fk.position[i], fk.quaternion[i]) for i, n in enumerate(heard)
                if fk.converged[i]}

    def internal_force(self) -> float | str:
        """The largest internal force at one attachment, N (:meth:`forces`), or why there is
        none yet (a str)."""
        found = self.forces()
        return found if isinstance(found, str) else float(found.sizes.max())

    def waiting_for(self) -> list[str]:
        """What has not come yet, in words (empty: everything)."""
        waiting = [] if self.settings is not None else ["the coordinator's parameters"]
        if self.panel is None:
            waiting.append("the panel's tracker")
        waiting += [f'{n} load cells' for n in self.names if n not in self.readings]
        return waiting


class PanelWatchState:
    """The latest of each input of the panel's watch window (thread-safe setters)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._snapshot = PanelSnapshot()
        self._readings: dict[str, deque[tuple[FloatArray, FloatArray]]] = {}

    def snapshot(self) -> PanelSnapshot:
        """The state now, as one consistent value."""
        with self._lock:
            readings = {n: (np.array([q for q, _ in r]), np.array([t for _, t in r]))
                        for n, r in self._readings.items() if r}
            return replace(self._snapshot, readings=readings)

    def coordinator_settings(self, settings: CellCoordinatorSettings) -> None:
        """The coordinator's parameters (as answered, and after each change)."""
        with self._lock:
            self._snapshot = replace(self._snapshot, settings=settings)

    def coordinator(self, status: Status) -> None:
        """The coordinator's status."""
        with self._lock:
            self._snapshot = replace(self._snapshot, coordinator=status)

    def panel(self, pose: Pose, stamp: float) -> None:
        """The panel's measured pose (cell frame) and its stamp (s)."""
        with self._lock:
            self._snapshot = replace(self._snapshot, panel=pose, panel_stamp=stamp)

    def set_status(self, name: str, positioner: Status | None = None,
                   drives: Status | None = None) -> None:
        """Positioner ``name``'s positioner status and / or its drives' status."""
        with self._lock:
            s = self._snapshot
            self._snapshot = replace(
                s, positioners={**s.positioners, **({name: positioner} if positioner else {})},
                drives={**s.drives, **({name: drives} if drives else {})})

    def joints(self, name: str, joints: FloatArray, efforts: FloatArray) -> None:
        """A joint state of positioner ``name``'s set: encoders (6,) and load cells (6,)."""
        with self._lock:
            self._readings.setdefault(name, deque(maxlen=LOAD_CELL_READINGS)).append(
                (np.asarray(joints, float), np.asarray(efforts, float)))
