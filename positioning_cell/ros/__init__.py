"""The ROS adapter shared by the nodes and the tools: message conversions (:mod:`.messages`,
:mod:`.operator_messages`), QoS (:mod:`.qos`), parameters from settings (:mod:`.parameters`),
spinning and entry points (:mod:`.spin`, :mod:`.entry`), input readers (:mod:`.latest`,
:mod:`.senders`, :mod:`.watch_inputs`), the client of a running cell (:mod:`.client`), the
cell port the procedures run through (:mod:`.port`), the goal runner of action servers
(:mod:`.goals`) and process plumbing (:mod:`.processes`, :mod:`.domains`). With ``nodes/``,
the only place that imports rclpy or ROS message types."""
