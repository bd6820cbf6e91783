"""The coordinated cell's messages: a panel move's outcome as a MoveOutcome (the coordinator's
MoveToPose result) and its state as the coordinator's diagnostic values."""

from __future__ import annotations

from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from positioning_cell_interfaces.msg import MoveCommand, MoveOutcome

from positioning_cell import names
from positioning_cell.coordinated.coordinator import PanelOutcome, PanelRequest
from positioning_cell.moves.correction import deviation
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.ros.messages import pose_arrays, pose_stamped
from positioning_cell.ros.outcome_codes import CODES


def panel_request(command: MoveCommand) -> PanelRequest | PanelOutcome:
    """The panel goal of a MoveCommand (ABSOLUTE, in the ``cell`` frame; an empty frame is
    it), or the refusal of another (REFUSED_INVALID_GOAL, naming what it got)."""
    frame = command.pose.header.frame_id or names.CELL_FRAME
    if command.mode != command.ABSOLUTE or frame != names.CELL_FRAME:
        return PanelOutcome(ResultCode.REFUSED_INVALID_GOAL, f'a panel goal is ABSOLUTE in '
                            f'frame {names.CELL_FRAME!r} (got mode {command.mode}, frame '
                            f'{frame!r})')
    p, q = pose_arrays(command.pose.pose)
    return PanelRequest(p, q, float(command.tolerance), float(command.speed_scale))


def panel_outcome(outcome: PanelOutcome, goal: tuple[Any, Any], stamp: Time) -> MoveOutcome:
    """The MoveOutcome of a panel move: its code and reason; the mean panel pose the
    positioners' attained poses imply (frame ``cell``, source ``estimated``) and its error
    against ``goal`` (position, quaternion); NaN errors and no pose when not settled."""
    out = MoveOutcome(code=CODES[outcome.code], code_name=outcome.code.value,
                      reason=outcome.reason)
    out.position_error, out.orientation_error = [np.nan] * 3, [np.nan] * 3
    out.uncertainty = [np.nan] * 6
    if outcome.panel is not None:
        out.attained = pose_stamped(*outcome.panel.to_pq(), stamp, names.CELL_FRAME)
        out.attained_source = 'estimated'
        e_p, e_r = deviation(*outcome.panel.to_pq(), *goal)
        out.position_error = [float(v) for v in e_p]
        out.orientation_error = [float(v) for v in e_r]
    return out


def coordinator_values(state: str, positioners: str, last: PanelOutcome | None
                       ) -> dict[str, str]:
    """The coordinator's diagnostic values: its state, its positioners, the last outcome, and
    when an internal force excess ended it, the stamp of the reading that showed it."""
    values = {'state': state, 'positioners': positioners,
              'last_code': last.code.value if last else '',
              'last_reason': last.reason if last else ''}
    if last is not None and last.excess is not None:
        values['internal_force_exceeded_at'] = f'{last.excess.stamp:.6f}'
        values['internal_force_seen_at'] = f'{last.excess.seen:.6f}'
    return values
