"""Accuracy prediction of the 3-UPS positioner (seeds 004 and 003), pure numpy / scipy: an
instance of the general tolerance engine (:mod:`positioning_cell.tolerance`), whose T, worst
case, RSS, yield and draws it uses, with the 3-UPS's own loops, sources and closure kernel.

- :mod:`.sources`: the error sources of the machine and the tolerance spec (YAML) that bounds them.
- :mod:`.sensitivity`: first-order closure expansion, sensitivity T = C − D·U⁻¹·A (seed 004
  eq. 14), worst case (eq. 15), root-sum-square.
- :mod:`.montecarlo`: the nonlinear closure model over sampled sources, yield with its
  confidence interval, and the worst case / RSS / Monte Carlo comparison.
- :mod:`.maps`: the same predictions over a workspace grid, and their maps (PNG).
- :mod:`.angular`: platform-normal angle statistics and the stacked-stage model of seed 003.
"""
