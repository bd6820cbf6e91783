"""Effects of the simulated machine outside the model the cell identifies (issue 23): drive
errors (:mod:`.drive_errors`), temperature (:mod:`.thermal`) and compliance
(:mod:`.compliance`), and the state history they need (:mod:`.history`). Only the simulators
read them: they belong to the truth (:mod:`positioning_cell.sim.truth`)."""
