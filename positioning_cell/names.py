"""Every name the cell uses on the wire, declared once: nodes and their executables, topics,
services, frames and diagnostic status names (the tables of docs/conventions/interfaces.md;
generated: docs/reference/interfaces.md). Topic and service
names are absolute, so the cell stays whole under a namespace remap of single nodes."""

from __future__ import annotations

from typing import NamedTuple

# -- frames (REP-103: metres, radians, right-handed) ----------------------------------------------
BASE_FRAME = 'base'
PLATFORM_FRAME = 'platform'
TRACKER_FRAME = 'tracker'
#: The machine CS: at the platform's home pose, axes parallel to ``base``.
MACHINE_FRAME = 'machine'
#: The user CS (T_machine_user).
USER_FRAME = 'user'
#: The object CS (T_platform_object); its origin is the pivot.
OBJECT_FRAME = 'object'
#: The platform where the tracker measures it and where the running trajectory commands it
#: (children of ``base``; ``platform`` is the estimate from the encoders): on /tf and in the
#: live view.
PLATFORM_MEASURED_FRAME = 'platform_measured'
PLATFORM_COMMANDED_FRAME = 'platform_commanded'
#: The frames an absolute goal may be given in.
ABSOLUTE_FRAMES = (BASE_FRAME, MACHINE_FRAME, USER_FRAME)
#: The frames a watch window shows deviations in.
WATCH_FRAMES = (BASE_FRAME, USER_FRAME)

# -- joints ---------------------------------------------------------------------------------------
#: Joint names on the wire, kinematics.md order.
JOINT_NAMES = (
    'leg1_length', 'leg2_length', 'leg3_length', 'leg1_theta', 'leg2_theta', 'leg3_theta',
)


# -- nodes ----------------------------------------------------------------------------------------
class CellNode(NamedTuple):
    """An executable (``ros2 run positioning_cell <executable>``) and the node it starts."""

    executable: str
    name: str


NODE_POSITIONER = 'positioner'
NODE_DRIVER = 'leg_driver'
NODE_MEASUREMENT = 'pose_measurement'
NODE_MONITOR = 'accuracy_monitor'
NODE_RECORDER = 'recorder'
NODE_PLAYER = 'bag_player'
NODE_CALIBRATOR = 'calibrator'
NODE_LIVE_VIEW = 'live_view'
NODE_COORDINATOR = 'cell_coordinator'
NODE_PANEL_SIMULATOR = 'panel_simulator'

#: The simulated leg drives (actuators and encoders).
DRIVER = CellNode('leg_driver_node', NODE_DRIVER)
#: The simulated laser tracker and the positioner (kinematics, limits, compensation).
MEASUREMENT = CellNode('pose_measurement_node', NODE_MEASUREMENT)
POSITIONER = CellNode('kinematics_node', NODE_POSITIONER)
#: The accuracy monitor (commanded against measured poses, ISO 9283 figures, verdicts).
MONITOR = CellNode('accuracy_monitor_node', NODE_MONITOR)
#: The cell's nodes in start order: the launch file and the run driver start these.
CELL_NODES = (DRIVER, MEASUREMENT, POSITIONER, MONITOR)
#: The nodes of one positioner's set in a coordinated cell (positioning_cell.ros.node_sets), in
#: start order: the drives, the tracker, the positioner (a single cell's accuracy monitor
#: judges one positioner's moves; the coordinated cell's figures are the panel's).
SET_NODES = (DRIVER, MEASUREMENT, POSITIONER)
RECORDER = CellNode('recorder_node', NODE_RECORDER)
PLAYER = CellNode('bag_player_node', NODE_PLAYER)
CALIBRATOR = CellNode('calibrator_node', NODE_CALIBRATOR)
#: The Foxglove live view (read-only; its WebSocket server on 127.0.0.1:8765 by default).
LIVE_VIEW = CellNode('live_view_node', NODE_LIVE_VIEW)
#: Several positioners holding one panel (docs/howto/coordinated.md): moves them as one.
COORDINATOR = CellNode('cell_coordinator_node', NODE_COORDINATOR)
#: The coordinated cell's panel as it really is (simulation truth).
PANEL_SIMULATOR = CellNode('panel_simulator_node', NODE_PANEL_SIMULATOR)
#: Every node executable of the package.
NODE_EXECUTABLES = (*CELL_NODES, RECORDER, PLAYER, CALIBRATOR, LIVE_VIEW, COORDINATOR,
                    PANEL_SIMULATOR)
#: The nodes a cell brought up may add to CELL_NODES (``cell up``, ``launch/cell.launch.py``):
#: each with its switch (``cell up --record``/``--no-record``, ``record:=true``) and whether
#: it is on by default. The recorder first, as ``make run`` starts it.
OPTIONAL_NODES = ((RECORDER, 'record', True), (LIVE_VIEW, 'live_view', False),
                  (CALIBRATOR, 'calibrator', False))
#: The executable that runs several of the nodes above in one process (ROS 2's composition:
#: ``cell_container [node name ...] --ros-args ...``; by default the CELL_NODES).
CONTAINER = 'cell_container'

# -- topics ---------------------------------------------------------------------------------------
JOINT_TRAJECTORY = '/legs/joint_trajectory'
JOINT_STATES = '/legs/joint_states'
#: The drives' answer to each trajectory: accepted or refused, keyed by its fingerprint.
TRAJECTORY_STATUS = '/legs/trajectory_status'
TRUE_JOINT_STATES = '/sim/legs/true_joint_states'
#: The positioner's heartbeat to the leg driver (std_msgs/Header, stamped when sent): the
#: drives stop a move when it falls silent.
HEARTBEAT = '/positioner/heartbeat'
TARGET = '/positioner/target'
#: Where the running trajectory commands the platform now (PoseStamped, base; only while one
#: runs, at the pose rate): what `cell watch` judges the measured pose against while moving.
SETPOINT = '/positioner/setpoint'
#: The plan of every trajectory the positioner sends its drives (nav_msgs/Path, base; latched):
#: its platform poses, each stamped at its commanded instant (the drives' clock). What the
#: coordinated cell's force watch judges each tracker reading against, at any instant, however
#: the positioner's own stream of setpoints is held up.
PLANNED_PATH = '/positioner/planned_path'
ESTIMATED_POSE = '/positioner/pose'
MARKERS = '/positioner/markers'
#: The user and object coordinate systems in force (latched; positioning_cell_interfaces
#: CoordinateSystems), published at start and on every change.
COORDINATE_SYSTEMS = '/positioner/coordinate_systems'
#: The live range of each user axis from the current user position, the others held
#: (positioning_cell_interfaces AxisRanges; latched, at operator.axis_ranges.rate_hz): what
#: ``cell status`` and ``cell watch`` show. Not recorded, as COORDINATE_SYSTEMS.
AXIS_RANGES = '/positioner/axis_ranges'
MEASURED_POSE = '/metrology/pose'
#: The tracker's located registration (its pose in ``base`` and that pose's covariance, the part
#: common to every reading on MEASURED_POSE), latched: published on each locate.
TRACKER_REGISTRATION = '/metrology/registration'
TRUE_POSE = '/sim/platform/true_pose'
#: The machine as ROS tools (RViz, Foxglove's 3-D panel, robot_state_publisher) see it
#: (docs/conventions/robot-description.md): the URDF of the positioner's model
#: (std_msgs/String, latched), every joint's value, actuated and passive (sensor_msgs/JointState,
#: the estimate's), the tree's transforms and the platform's measured pose (tf2_msgs/TFMessage)
#: and the static frames (tf2_msgs/TFMessage, latched: the tree's fixed joints, base → machine,
#: user, tracker as located; platform → object).
ROBOT_DESCRIPTION = '/robot_description'
ROBOT_JOINT_STATES = '/joint_states'
TF = '/tf'
TF_STATIC = '/tf_static'
#: The cell's air temperature (sensor_msgs/Temperature, °C, frame ``base``): the sensor's
#: reading, with its own error (the pose_measurement simulator publishes it); what the
#: compensation, the tracker's refraction correction and each calibration pose's conditions
#: use.
AIR_TEMPERATURE = '/cell/air_temperature'
POSITION_ERROR = '/accuracy/position_error'
ORIENTATION_ERROR = '/accuracy/orientation_error'
DIAGNOSTICS = '/diagnostics'
#: The run driver's current step (make run): mode, cycle, pose (JSON in std_msgs/String).
PROGRAM = '/cell/program'
#: A calibration run's measured poses (calibrate_cell): which readings belong to which pose
#: (JSON in std_msgs/String).
CALIBRATION = '/cell/calibration'
#: An axis test's measured stops (run_cell --axis-test): axis, target, direction, cycle,
#: commanded, tracker and true values (JSON in std_msgs/String).
AXIS_TEST = '/cell/axis_test'
#: A static compliance test's load steps (run_cell with a program's compliance: block, ISO
#: 9283 §10): direction, load, averaged tracker position and its covariance (JSON in
#: std_msgs/String).
COMPLIANCE_TEST = '/cell/compliance_test'
#: The topics procedures send their markers on (the program steps, the calibration poses, the
#: axis-test stops, the compliance-test steps): JSON text, kept for a recorder that joins late.
MARKER_TOPICS = (PROGRAM, CALIBRATION, AXIS_TEST, COMPLIANCE_TEST)
#: The static load rig of the compliance test (a force actuator on the platform origin, with
#: its own load cell; simulated by the pose_measurement node): the force it is commanded to
#: apply and its load cell's reading of the force it applies (geometry_msgs/WrenchStamped,
#: frame ``base``, N; latched).
LOAD_COMMAND = '/load_rig/command'
LOAD_FORCE = '/load_rig/force'

#: Every topic of the cell, in the order of the docs' topic table: what the recorder takes by
#: default (not COORDINATE_SYSTEMS nor AXIS_RANGES: their types, of
#: positioning_cell_interfaces, are not in the bags' Jazzy typestore).
CELL_TOPICS = (
    JOINT_TRAJECTORY, TRAJECTORY_STATUS, JOINT_STATES, TRUE_JOINT_STATES, TARGET,
    ESTIMATED_POSE, MARKERS, MEASURED_POSE, TRACKER_REGISTRATION, TRUE_POSE, AIR_TEMPERATURE,
    POSITION_ERROR, ORIENTATION_ERROR, DIAGNOSTICS, PROGRAM, CALIBRATION, AXIS_TEST,
    COMPLIANCE_TEST, LOAD_COMMAND, LOAD_FORCE, ROBOT_DESCRIPTION, ROBOT_JOINT_STATES, TF,
    TF_STATIC,
)

#: Parameter changes of every node (rcl_interfaces ParameterEvent, ROS's own topic): the watch
#: windows follow the accuracy monitor's dynamic tolerances on it.
PARAMETER_EVENTS = '/parameter_events'

# -- Foxglove live view channels (live_view_node's WebSocket server, not ROS topics) ----------
#: The positioner in 3-D (foxglove.SceneUpdate).
LIVE_SCENE = '/live/scene'
#: base → platform (estimated), platform_commanded, platform_measured, user; platform → object
#: (foxglove.FrameTransforms).
LIVE_TRANSFORMS = '/live/transforms'
#: The 6-D deviation, |Δp|, |Δθ| and the in/out verdict (JSON).
LIVE_DEVIATION = '/live/deviation'
#: The positioner's state and the accuracy monitor's last verdict (JSON).
LIVE_STATUS = '/live/status'

# -- services (positioning_cell_interfaces unless named otherwise) ------------------------------
#: Move and return when settled (srv MoveToPose).
MOVE_TO_POSE = '/positioner/move_to_pose'
#: The checks of a move without moving, with the validity bits (srv CheckPose).
CHECK_POSE = '/positioner/check_pose'
#: Reference and home, blocking (std_srvs/srv/Trigger).
HOME = '/positioner/home'
#: Controlled stop of whatever runs (std_srvs/srv/Trigger).
STOP = '/positioner/stop'
#: Stop the running move along its path from a given instant over a given duration
#: (positioning_cell_interfaces/srv/StopAlongPath): how the coordinated cell stops every
#: positioner together, the panel kept rigid (moves/stopping.py).
STOP_ALONG_PATH = '/positioner/stop_along_path'
SET_COORDINATE_SYSTEMS = '/positioner/set_coordinate_systems'
GET_COORDINATE_SYSTEMS = '/positioner/get_coordinate_systems'
DEFINE_COORDINATE_SYSTEM = '/positioner/define_coordinate_system'
SELECT_COORDINATE_SYSTEMS = '/positioner/select_coordinate_systems'
SET_LIMITS = '/positioner/set_limits'
GET_LIMITS = '/positioner/get_limits'
SET_SPEED = '/positioner/set_speed'
JOG = '/positioner/jog'
DRIVER_ENABLE = '/leg_driver/enable'
DRIVER_REFERENCE = '/leg_driver/reference'
#: Re-locate the tracker on the base reference targets (std_srvs/srv/Trigger).
LOCATE_TRACKER = '/pose_measurement/locate'
MONITOR_REPORT = '/accuracy_monitor/report'
MONITOR_RESET = '/accuracy_monitor/reset'
RECORDER_PAUSE = '/recorder/pause'
RECORDER_RESUME = '/recorder/resume'


# -- actions (positioning_cell_interfaces) --------------------------------------------------------
#: Move with feedback; cancel = controlled stop (action MoveToPose).
MOVE_ACTION = '/positioner/move'
#: Reference and home with feedback (action Home).
HOME_ACTION = '/positioner/homing'
#: Calibrate the machine from its own measurements, progress per pose (action Calibrate,
#: served by calibrator_node).
CALIBRATE_ACTION = '/calibrator/calibrate'


# -- the coordinated cell (issue 27) --------------------------------------------------------------
#: Move the panel (action MoveToPose: the goal is the panel frame in the ``cell`` frame, mode
#: ABSOLUTE); cancel = every positioner stops.
COORDINATED_MOVE_ACTION = '/cell_coordinator/move'
#: Stop every positioner of the cell (std_srvs/srv/Trigger).
COORDINATED_STOP = '/cell_coordinator/stop'
#: Relax the panel at rest: each positioner moved onto the rigid placement its tracker's
#: readings imply, all as one, and keeping that correction (std_srvs/srv/Trigger).
COORDINATED_RELAX = '/cell_coordinator/relax'
#: Relax the panel at rest from the legs' load cells: each positioner stepped, all as one,
#: until the internal force they give is within the relax settings (std_srvs/srv/Trigger).
COORDINATED_RELAX_FORCES = '/cell_coordinator/relax_forces'
#: The coordinated cell's own frame (the cell file's bases are in it) and the panel's.
CELL_FRAME = 'cell'
PANEL_FRAME = 'panel'
STATUS_COORDINATOR = 'cell_coordinator'
#: The wrench the panel puts on a set's platform (simulation truth, geometry_msgs/
#: WrenchStamped, frame ``base``, about the platform origin): from the panel simulator to the
#: set's leg driver, whose load cells read it with the rest of the load (in each set: SET_TOPICS).
PANEL_WRENCH = '/sim/platform/panel_wrench'
#: The panel's internal forces (simulation truth, for judging: std_msgs/String JSON, each
#: pair's force N and the largest at one attachment).
PANEL_FORCES = '/sim/panel/internal_forces'
#: The panel's pose as the cell's tracker measures its targets (geometry_msgs/
#: PoseWithCovarianceStamped, frame ``cell``: the panel frame in the cell frame), and as it
#: really is (simulation truth, for judging: geometry_msgs/PoseStamped, frame ``cell``).
PANEL_MEASURED_POSE = '/panel/metrology/pose'
PANEL_TRUE_POSE = '/sim/panel/true_pose'
#: The coordinated run's program steps (std_msgs/String, JSON of positioning_cell.procedures.
#: panel_program.PanelStep, reliable, transient-local), each as its move ends and is measured.
PANEL_PROGRAM = '/cell/panel_program'

#: What one positioner's node set uses on the wire: under a namespace ``ns`` every one of these
#: becomes ``/ns<name>`` (:func:`in_set`; positioning_cell.ros.node_sets remaps them), every
#: name but ROS's own PARAMETER_EVENTS and /rosout.
SET_TOPICS = (*CELL_TOPICS, HEARTBEAT, SETPOINT, PLANNED_PATH, COORDINATE_SYSTEMS, AXIS_RANGES,
              PANEL_WRENCH)
SET_SERVICES = (
    MOVE_TO_POSE, CHECK_POSE, HOME, STOP, STOP_ALONG_PATH, SET_COORDINATE_SYSTEMS,
    GET_COORDINATE_SYSTEMS, DEFINE_COORDINATE_SYSTEM, SELECT_COORDINATE_SYSTEMS, SET_LIMITS,
    GET_LIMITS, SET_SPEED, JOG,
    DRIVER_ENABLE, DRIVER_REFERENCE, LOCATE_TRACKER, MONITOR_REPORT, MONITOR_RESET,
    RECORDER_PAUSE, RECORDER_RESUME,
)
SET_ACTIONS = (MOVE_ACTION, HOME_ACTION, CALIBRATE_ACTION)
#: The topics and services an action is made of (rcl_action's, under the action's name): Jazzy
#: remaps an action through these, not by its own name (ros2/rcl#1170 came later).
ACTION_ENDPOINTS = ('_action/send_goal', '_action/cancel_goal', '_action/get_result',
                    '_action/feedback', '_action/status')


def in_set(name: str, namespace: str) -> str:
    """Wire name ``name`` (absolute) of the node set under ``namespace`` (a name, no slashes;
    '': the single positioner's cell, the name itself)."""
    return f'/{namespace}{name}' if namespace else name


def set_parameters_service(node: str) -> str:
    """The parameter service rclpy gives node ``node``."""
    return f'/{node}/set_parameters'


# -- diagnostic status names (DiagnosticStatus.name on /diagnostics) ------------------------------
STATUS_POSITIONER = 'positioner: state'
#: The positioner status's ``calibration`` value while no calibration file is in force.
NO_CALIBRATION = 'none'
#: Who publishes the positioner's inputs: other nodes on them are reported (and ignored).
STATUS_POSITIONER_INPUTS = 'positioner: inputs'
#: The conditions the positioner compensates under (air temperature, approach) and the last
#: move's warnings (outside the calibration's envelope, a stale temperature): WARN while any.
STATUS_POSITIONER_COMPENSATION = 'positioner: compensation'
STATUS_DRIVER = 'leg_driver'
STATUS_TRAJECTORY = 'leg_driver: trajectory'
STATUS_MEASUREMENT = 'pose_measurement'
STATUS_MONITOR_VERDICT = 'accuracy_monitor: settled pose'
STATUS_MONITOR_INPUT = 'accuracy_monitor: input'
#: The monitor's reading of the recorder (positioning_cell.recording.status.recording).
STATUS_MONITOR_RECORDING = 'accuracy_monitor: recording'
STATUS_RECORDER = 'recorder'
STATUS_LIVE_VIEW = 'live_view'
