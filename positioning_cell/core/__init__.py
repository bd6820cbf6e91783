"""The machine and its kinematics: geometry and limits (:mod:`.mechanism`), pose batches and
rotations (:mod:`.poses`), inverse and forward kinematics and the Jacobian (:mod:`.kinematics`),
limit checks (:mod:`.limits`), compiled kernels of the hot paths (:mod:`.compiled`)."""
