"""A panel held by several positioners (issue 27): the coordinated cell. Pure numpy/scipy; no
ROS.

- :mod:`.attachments`: how a positioner's platform holds the panel (a clamp, a ball, a ball in
  a slot or on a flat) as the relative freedoms it leaves and the wrenches it can carry;
- :mod:`.mobility`: the assembled cell's mobility by screw theory (seed 001 §3): the panel's
  freedom, the idle and the redundant inputs, the internal force systems of an
  over-constrained cell; checked by a velocity analysis of the closed loops;
- :mod:`.internal_forces`: the forces in the panel when the positioners disagree (seed 002's
  deformation compatibility), their self-equilibrated part per pair, the worst pair named;
- :mod:`.base_calibration`: each positioner's base in the cell frame from tracker readings of
  its attachment point, with its covariance;
- :mod:`.cell_calibration`: the cell's calibration: every base and each ball's socket in the
  panel from one tracker's readings of the panel's targets, its model's shortfall said;
- :mod:`.panel_motion`: the panel's pose as each positioner's platform pose and back, and how
  far each pair of attachments is pulled apart;
- :mod:`.coordinator`: a panel move with every positioner as one (checked by all first, one
  time base, a fault or stop of one stops all);
- :mod:`.force_watch`: the panel's internal force while it moves, from the trackers' readings
  against the positioners' plans at their instant;
- :mod:`.settings`: the coordinator's and its node's settings;
- :mod:`.cell_file`: the cell configuration (positioners, their bases and attachments).
"""
