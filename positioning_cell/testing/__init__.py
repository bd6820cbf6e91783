"""Independent references and synthetic data for the tests and benchmarks: a second forward
kinematics solver (:mod:`.reference_kinematics`) and a synthetic recorded run
(:mod:`.synthetic_run`). Never used by the cell itself."""
