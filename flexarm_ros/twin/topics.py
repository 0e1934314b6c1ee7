"""The topic contract of the twin (node-relative names under the namespace, default
``/flexarm``; ros2_control's names so a user's effort or forward-command controller runs
against the twin unchanged). Standard message types only.

| topic | type | from → to | content |
|---|---|---|---|
| ``/clock`` | rosgraph_msgs/Clock | sim → all | simulation time (the only publisher) |
| ``joint_states`` | sensor_msgs/JointState | sim → ctrl | from the quantized encoders (rad; rate by backward difference over the control period), effort = applied joint torque (N·m) |
| ``encoders/counts`` | std_msgs/Int32MultiArray | sim → ctrl, log | raw counts, joint order |
| ``accelerometers/batch`` | std_msgs/Float64MultiArray | sim → log | [sample, channel] in the sensors' output units (V with a sensitivity, else m/s²), samples of (t − T, t], uniform 1/fs spacing, the last at the message time |
| ``strain/batch``, ``potentiometer/batch`` | std_msgs/Float64MultiArray | sim → log | same layout |
| ``tip_position/batch`` | std_msgs/Float64MultiArray | sim → log | same layout, two channels per ``tip_position`` sensor: x, y of the last beam tip (m, world frame) |
| ``tool/contact`` | std_msgs/Bool | sim → ctrl | in contact (scenes with a wall) |
| ``tool/wrench`` | geometry_msgs/WrenchStamped | sim → ctrl | frame ``wall``: x = normal force on the tool (N, ≥ 0), y = friction force along the wall's tangent t = E·n |
| ``ground_truth/joint_states`` | sensor_msgs/JointState | sim → analysis | exact link-side joint angles ``<link>_joint`` and drive coordinates ``<link>_drive`` (rad, rad/s) |
| ``ground_truth/tip`` | geometry_msgs/PointStamped | sim → analysis | tip position (m, ``world``) |
| ``ground_truth/coordinates`` | sensor_msgs/JointState | sim → analysis, views | every generalized coordinate of the model by name (``Chain.names``: joint/motor angles, beam coordinates ``<link>_w1``, …; SI) and its rate, effort = the input torque acting on it (N·m, 0 where none acts) — with the scene embedded in the bag, enough to redraw the deformed arm (``Chain.centerlines``) |
| ``arm_markers`` | visualization_msgs/MarkerArray | sim → RViz2, Foxglove, log | the deformed arm for a viewer, frame ``world``, stamped with the simulation time, at ``marker_rate_hz`` (default 30 Hz; 0: none): ``links`` LINE_STRIP per link centerline (``Chain.centerlines``), ``hubs`` SPHERE per hub, ``wall`` LINE_LIST, ``tool`` SPHERE, ``contact_force`` ARROW from the tool while in contact (DELETE otherwise); stable namespaces and ids |
| ``motor_driver/commands`` | std_msgs/Float64MultiArray | ctrl → driver | V per joint (A for a valve, N·m for a joint without a drive) |
| ``controller/joint_targets`` | sensor_msgs/JointState | ctrl → log | position and sanding control: the commanded joint angles ``<link>_joint`` (rad), the commanded rates (rad/s; 0 for a step target) and the PD torque demanded (N·m, Eq. 5.16), one per command (none in open loop) |
| ``controller/parameter_changes`` | std_msgs/String | ctrl → log | one JSON object per accepted live parameter set, applied at the tick it names: ``{"time": s, "kp": [...], "kd": [...], "joint_target": [...]}`` (what changed) — a ``control.changes`` entry of the scene, so the scene with a bag's entries reruns the run |
| ``robot_state/joint_states`` | sensor_msgs/JointState | sim → robot_state_publisher, log | at the marker rate: the values of the URDF's joints (``<link>_joint``, the beams' virtual ``<link>_bend<i>`` and ``<link>_tip_slope``; :mod:`flexarm_ros.twin.robot_description`) |
| ``robot_description`` | std_msgs/String | sim → RViz2, robot_state_publisher | once, transient local | the URDF of the arm; the recorder writes it, ``/tf_static`` and ``/tf`` (tf2_msgs/TFMessage, from robot_state) into the bag |
| ``effort_controller/commands`` | std_msgs/Float64MultiArray | driver → sim | N·m at the gearbox outputs |
| ``motor_driver/motor_states`` | sensor_msgs/JointState | driver → log | motor-shaft angle/speed (× gear ratio), effort = armature current (A) or load pressure (Pa) |
| ``diagnostics/rejected`` | std_msgs/String | recorder → bag only | one JSON object per message a node refused or rejected (``topic``, ``reason``, ``publisher``, ``data`` as text); written into the bag by the recorder, never published |

How a foreign node plugs in (QoS, time, how lockstep pairs messages, the start condition):
docs/topic_contract.md.

Each input topic has one source (:data:`SOURCE`: the node expected to publish it); a
message from a second publisher is refused (``flexarm_ros.nodes._wire``).
"""

CLOCK = "/clock"
JOINT_STATES = "joint_states"
ENCODER_COUNTS = "encoders/counts"
ACCEL_BATCH = "accelerometers/batch"
STRAIN_BATCH = "strain/batch"
POT_BATCH = "potentiometer/batch"
TIP_BATCH = "tip_position/batch"
TOOL_CONTACT = "tool/contact"
TOOL_WRENCH = "tool/wrench"
GT_JOINT_STATES = "ground_truth/joint_states"
GT_TIP = "ground_truth/tip"
GT_COORDINATES = "ground_truth/coordinates"
ARM_MARKERS = "arm_markers"
COMMANDS = "motor_driver/commands"
EFFORTS = "effort_controller/commands"
MOTOR_STATES = "motor_driver/motor_states"
JOINT_TARGETS = "controller/joint_targets"
PARAMETER_CHANGES = "controller/parameter_changes"
#: the URDF's joint values (robot_state_publisher's input, remapped): the arm's joints and
#: the beams' virtual joints (flexarm_ros.twin.robot_description), at the marker rate
ROBOT_JOINT_STATES = "robot_state/joint_states"
#: the URDF (std_msgs/String, transient local, as robot_state_publisher publishes it)
ROBOT_DESCRIPTION = "robot_description"
TF = "/tf"
TF_STATIC = "/tf_static"
#: written into the bag by the recorder from what it has (the scene, robot_state), never
#: subscribed to: topic -> type
BAG_ONLY_TYPES = {ROBOT_DESCRIPTION: "std_msgs/msg/String",
                  TF: "tf2_msgs/msg/TFMessage", TF_STATIC: "tf2_msgs/msg/TFMessage"}
REJECTED = "diagnostics/rejected"
#: the controller's trajectory input (joint_trajectory_controller's message): a user's
#: node publishes it; the twin does not record it (the targets it produces are
#: controller/joint_targets)
JOINT_TRAJECTORY = "controller/joint_trajectory"

#: Sensor batch topic -> the scene sensor kind whose channels it carries (scene order).
BATCH_KINDS = {ACCEL_BATCH: "accelerometer", STRAIN_BATCH: "strain",
               POT_BATCH: "potentiometer", TIP_BATCH: "tip_position"}


def batch_columns(sensors) -> list[str]:
    """The column names of a batch topic carrying ``sensors`` (scene sensor specs of one
    kind, in scene order): the sensor's name, or ``<name>_x``, ``<name>_y`` for a
    ``tip_position``."""
    out = []
    for s in sensors:
        out += [f"{s.name}_x", f"{s.name}_y"] if s.kind == "tip_position" else [s.name]
    return out

TYPES = {
    CLOCK: "rosgraph_msgs/msg/Clock",
    JOINT_STATES: "sensor_msgs/msg/JointState",
    ENCODER_COUNTS: "std_msgs/msg/Int32MultiArray",
    ACCEL_BATCH: "std_msgs/msg/Float64MultiArray",
    STRAIN_BATCH: "std_msgs/msg/Float64MultiArray",
    POT_BATCH: "std_msgs/msg/Float64MultiArray",
    TIP_BATCH: "std_msgs/msg/Float64MultiArray",
    TOOL_CONTACT: "std_msgs/msg/Bool",
    TOOL_WRENCH: "geometry_msgs/msg/WrenchStamped",
    GT_JOINT_STATES: "sensor_msgs/msg/JointState",
    GT_TIP: "geometry_msgs/msg/PointStamped",
    GT_COORDINATES: "sensor_msgs/msg/JointState",
    ARM_MARKERS: "visualization_msgs/msg/MarkerArray",
    COMMANDS: "std_msgs/msg/Float64MultiArray",
    EFFORTS: "std_msgs/msg/Float64MultiArray",
    MOTOR_STATES: "sensor_msgs/msg/JointState",
    JOINT_TARGETS: "sensor_msgs/msg/JointState",
    PARAMETER_CHANGES: "std_msgs/msg/String",
    ROBOT_JOINT_STATES: "sensor_msgs/msg/JointState",
}

#: What the estimator node publishes (not recorded by the twin's recorder; a bag of a
#: run with it records them with ``ros2 bag`` or a recorder of one's own): topic -> type.
EST_JOINT_STATES = "estimator/joint_states"
EST_TIP = "estimator/tip"
EST_DEFLECTIONS = "estimator/tip_deflections"
EST_NIS = "estimator/nis"
EST_EVENTS = "estimator/events"
ESTIMATOR_TYPES = {EST_JOINT_STATES: "sensor_msgs/msg/JointState",
                   EST_TIP: "geometry_msgs/msg/PointStamped",
                   EST_DEFLECTIONS: "std_msgs/msg/Float64MultiArray",
                   EST_NIS: "std_msgs/msg/Float64MultiArray",
                   EST_EVENTS: "std_msgs/msg/String"}

#: Inputs from a user's node, not published by the twin: topic -> type.
INPUT_TYPES = {JOINT_TRAJECTORY: "trajectory_msgs/msg/JointTrajectory"}

#: Topic -> the twin's node that publishes it (the "from" column above).
SOURCE = {topic: "simulator" for topic in TYPES}
SOURCE.update({COMMANDS: "controller", JOINT_TARGETS: "controller",
               PARAMETER_CHANGES: "controller", EFFORTS: "motor_driver",
               MOTOR_STATES: "motor_driver"})


def resolve(namespace: str, topic: str) -> str:
    """Absolute topic name: ``/clock`` stays global, the rest go under the namespace."""
    if topic.startswith("/"):
        return topic
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{topic}"
