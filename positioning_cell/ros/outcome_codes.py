"""The MoveOutcome code of each of the library's result codes: the same names, upper case (the
positioner's outcomes and the coordinator's panel outcomes alike)."""

from __future__ import annotations

from positioning_cell_interfaces.msg import MoveOutcome

from positioning_cell.moves.outcomes import ResultCode

#: ResultCode → MoveOutcome's constant.
CODES = {code: int(getattr(MoveOutcome, code.name)) for code in ResultCode}
