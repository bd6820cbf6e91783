"""The cell's procedures, without ROS: the calibration run, the program run, the axis test and
the fault trials, each written against one small :class:`~.port.CellPort` (home, move, jog,
compensation mode, tracker readings, the latest joints, markers, stop), with ``say`` (a line
of progress) and a stop signal injected, returning typed outcomes. The ROS port
(:mod:`positioning_cell.ros.port`) drives the live cell; the in-process port over the instant
cell (:mod:`positioning_cell.testing.instant_port`) runs each procedure in a unit test in
seconds. The coordinated cell's calibration (:mod:`.panel_calibration`) is written against its
own small port: the panel's moves and the cell tracker's readings of it."""
