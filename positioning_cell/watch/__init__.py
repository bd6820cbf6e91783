"""The live watch window: what the terminal watch (``cell watch``) and the Foxglove live view
(``live_view_node``) show of the running cell, computed from what the cell publishes.

- :mod:`.deviation`: the 6-D deviation of the measured pose from the commanded one in the
  ``base`` or ``user`` frame, with the tolerances and the measurement's uncertainty.
- :mod:`.scene`: the positioner drawn in 3-D (legs coloured by stroke used, the commanded
  platform as a ghost, the error as a magnified arrow, the tolerance as a sphere).
- :mod:`.state`: the latest of each input, thread-safe, and what is still missing.
- :mod:`.table`: the watch window's rows as text, with an in/out marker per axis.

Both views are read-only: nothing here commands the cell.
"""
