"""Independent references, synthetic data and in-process cells for the tests and benchmarks: a
second forward kinematics solver (:mod:`.reference_kinematics`), a synthetic recorded run
(:mod:`.synthetic_run`), and the procedures' port on the positioner's own move logic over the
instant simulated cell (:mod:`.instant_port`, with faults: :mod:`.instant_faults`). Never used
by the cell itself."""
