"""The simulated machine and instruments, the only code that knows the truth.

- :mod:`.truth`: the machine as it really is (geometric errors, clearance);
- :mod:`.axes`, :mod:`.paths`, :mod:`.servo`, :mod:`.encoders`, :mod:`.faults`: the six leg
  drives, their setpoint paths, encoders and injected faults; :mod:`.drives`: the leg driver;
- :mod:`.tracker`: noisy tracker readings and measurement faults; :mod:`.pose_measurement`:
  the truth turned into true poses and measured;
- :mod:`.panel`, :mod:`.cell_installation`: the coordinated cell's panel on the true
  platforms, and the cell as installed (its bases, the panel's sockets and sag, the tracker
  reading the panel's targets).
"""
