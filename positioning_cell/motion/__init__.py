"""Moving the platform: the positioner's move state machine (:mod:`.mover`), its operator
surface (:mod:`.controller`), its settings (:mod:`.settings`), its watch on inputs and on
standstill (:mod:`.inputs`, :mod:`.hearing`, :mod:`.standstill`, :mod:`.watch`). What a move
is (trajectory, outcome, correction) lies below, in :mod:`positioning_cell.moves`."""
