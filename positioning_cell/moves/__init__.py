"""What a move is, below everything that plans, runs or judges one: the planned trajectory
(:mod:`.trajectory`), how a command ends (:mod:`.outcomes`) and the closed loop on the
tracker (:mod:`.correction`)."""
