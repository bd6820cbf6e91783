"""Moving the platform: timed, limit-checked paths (:mod:`.trajectory`), the closed loop on the
tracker (:mod:`.correction`) and the move state machine of the positioner (:mod:`.mover`)."""
