"""The machine as ROS tools see it: its URDF, every joint's value and the transform tree
(docs/conventions/robot-description.md). Pure numpy; no ROS.

- :mod:`.urdf`: the URDF of a :class:`~positioning_cell.core.mechanism.Mechanism`, the closed
  chain cut at the S joints of legs 2 and 3 (the platform hangs from leg 1's S joint);
- :mod:`.joints`: every joint's value, actuated and passive (U and S angles), at platform poses;
- :mod:`.tree`: a URDF's kinematic tree: each joint's transform for joint values, as
  robot_state_publisher computes them for /tf and /tf_static, and any link's pose in the root.
"""
