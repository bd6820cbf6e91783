"""Whether the leg drives stopped a move on their own, from their status (the leg driver's
/diagnostics values, with its ``message``): the one rule the positioner that commands them and
the coordinator that watches every set both apply (a starved positioner does not report its
drives' stop in time: the coordinator hears the drives themselves)."""

from __future__ import annotations

from collections.abc import Mapping

from positioning_cell.moves.outcomes import ResultCode

#: The status value counting the moves the drives stopped for a silent commander.
SILENCE_STOPS = 'silence_stops'


def drives_stopped(status: Mapping[str, str],
                   silence_stops: str | None = None) -> tuple[ResultCode, str] | None:
    """Why drives whose status values are ``status`` no longer follow a move: in fault
    (ABORTED_FAULT), switched off (ABORTED_DRIVES_OFF) or, ``silence_stops`` given (their
    :data:`SILENCE_STOPS` when the move was sent), having stopped it for a commander they
    heard no heartbeat from (ABORTED_DRIVER_LOST); None while they follow it."""
    if status.get('state') == 'fault':
        return ResultCode.ABORTED_FAULT, f'drive fault: {status.get("message", "")}'
    if status.get('enabled', 'true').lower() == 'false':
        return (ResultCode.ABORTED_DRIVES_OFF,
                f'drives disabled during the move: {status.get("message", "")}')
    if silence_stops is not None and status.get(SILENCE_STOPS, '0') != silence_stops:
        return (ResultCode.ABORTED_DRIVER_LOST, 'the drives stopped the move: they heard no '
                f'heartbeat from their commander in time ({status.get("last_event", "")})')
    return None
