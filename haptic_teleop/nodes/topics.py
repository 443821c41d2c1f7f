"""Topic names, joint names and QoS of the live nodes (names match the bag, haptic_teleop.record,
where the meaning is the same), and the DDS discovery range nodes started by hand keep."""

from __future__ import annotations

import os
from typing import Any

# ---------------------------------------------------------------------------------------------
# Environment: DDS stays on this host unless the user chose otherwise.


def ensure_local_discovery() -> None:
    """Nodes started by hand keep DDS on this host too, unless the user chose a range."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


# ---------------------------------------------------------------------------------------------
# Topics. Names match the bag (haptic_teleop.record) where the meaning is the same.

OPERATOR_STATE = "/operator/joint_states"
MASTER_STATE = "/master/joint_states"
SLAVE_STATE = "/slave/joint_states"
SLAVE_CONTACT = "/slave/contact_wrench"
MASTER_EBA = "/master/eba"
SLAVE_EBA = "/slave/eba"
DIAGNOSTICS = "/diagnostics"
DIRECTIONS = ("forward", "backward")
EBA_LABELS = ("reservoir_j", "force_desired_n")
# Joint names and frame: the recorder decodes raw bytes with record/layouts.py's fixed layouts, which
# were made with exactly these strings.
OPERATOR_JOINT = "operator_x"
MASTER_JOINT = "master_x"
SLAVE_JOINT = "slave_x"
WALL_FRAME = "wall"


def sent_topic(direction: str) -> str:
    return f"/{direction}/sent"


def sample_topic(direction: str) -> str:
    """Sending side -> recorder, an arm scene's direction with a codec only: the sample of every tick
    in the bag's /<direction>/sent layout (/<direction>/sent carries the encoder's packets then)."""
    return f"/{direction}/sample"


def delivered_topic(direction: str) -> str:
    """Relay -> sync buffer: what the network delivered, in arrival order."""
    return f"/{direction}/delivered"


def received_topic(direction: str) -> str:
    """Sync buffer -> controller: the sample released for this tick (as in the bag)."""
    return f"/{direction}/received"


READER_DEPTH = 50  # local history of readers that must not drop samples while busy


def packets_topic(direction: str) -> str:
    return f"/{direction}/packets"


def playout_topic(direction: str) -> str:
    """Sync buffer -> recorder: what the buffer decided for each packet it received (played or late)."""
    return f"/{direction}/playout"


SCENE_TOPIC = "/haptic_teleop/scene"  # the resolved scene (std_msgs/String, YAML), latched
# The operator source's scene time 0 (std_msgs/Header, stamp = the tick it started at), latched: the
# recorder's grid starts there even if the operator's first samples did not reach it.
SCENE_START_TOPIC = "/haptic_teleop/scene_start"
# The recorder, once it has taken a sample of every stream that defines its grid (latched,
# std_msgs/Header): a device session's master starts scene time only then (nodes/master_eba.py).
RECORDER_LISTENING_TOPIC = "/haptic_teleop/recorder_listening"


def scene_start_header(stamp_ns: int) -> Any:
    """The SCENE_START_TOPIC message for scene time 0 at `stamp_ns` (node clock): what the operator
    source, the NVE server and, in a device session, master_eba publish (`scene_start_ns` reads it)."""
    from std_msgs.msg import Header  # type: ignore[import-untyped]  # no stubs

    h = Header(frame_id="scene_time_0")
    h.stamp.sec, h.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return h


def scene_start_ns(header: Any, period_ns: int) -> int:
    """Scene time 0 on the node clock, from a SCENE_START_TOPIC message: its stamp, on the tick
    grid (a whole number of periods). The one definition the relays (their links run in scene
    time, node clock - this) and the recorder (its grid starts here) share."""
    st = header.stamp
    return (int(st.sec) * 1_000_000_000 + int(st.nanosec)) // period_ns * period_ns


def latched_qos() -> Any:
    """Reliable, keep last 1, transient local: a subscriber that joins later gets the last message."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


# A direction's payload, in the order the core controllers expect (TeleopController docstring),
# and where each value sits in the sensor_msgs/JointState that carries it.
PAYLOAD_FIELDS = {
    "forward": ("position", "velocity"),  # master -> slave: (x_m, v_m)
    "backward": ("effort", "position", "velocity"),  # slave -> master: (f_env, x_s, v_s)
}
DIRECTION_JOINT = {"forward": MASTER_JOINT, "backward": SLAVE_JOINT}
JOINT_ORDER = ("position", "velocity", "effort")  # JointState's value arrays
# The JointState fields a direction's messages fill, on /<dir>/sent, /delivered and /received
# alike (JointState order; PAYLOAD_FIELDS says which value is which).
WIRE_FIELDS = {"forward": ("position", "velocity"), "backward": ("position", "velocity", "effort")}


def wire_names(direction: str, task_axes: int = 1) -> str | tuple[str, ...]:
    """The JointState name(s) of a direction's samples: one joint for a one-axis scene, one name
    per task axis for an arm scene (record.columns.forward_names / backward_names: master_x,
    master_y, master_z; slave_x, ...)."""
    if task_axes == 1:
        return DIRECTION_JOINT[direction]
    prefix = "master" if direction == "forward" else "slave"
    return tuple(f"{prefix}_{a}" for a in ("x", "y", "z")[:task_axes])


def payload_fields(direction: str, task_axes: int = 1) -> tuple[str, ...]:
    """The JointState fields of a direction's payload in the core's order: PAYLOAD_FIELDS for one
    axis; for an arm scene the wire's own order, which is the arm tick's payload
    (forward: x[a], v[a]; backward: x[a], v[a], contact force[a]; docs/arms.md)."""
    return PAYLOAD_FIELDS[direction] if task_axes == 1 else WIRE_FIELDS[direction]


TASK_AXES_PARAM = "task_axes"  # relay and buffer: values per payload field (1: one axis; 3: an arm scene)


def stream_qos(depth: int = 1) -> Any:
    """1 kHz streams: best effort, keep last, depth 1, volatile (docs/architecture.md, "Live mode").

    A reader that must see every sample rather than the newest (relay, sync buffer, recorder)
    keeps a deeper local history: still compatible with depth-1 writers.
    """
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def reliable_qos(depth: int = 100) -> Any:
    """Commands and batched logs: reliable, keep last `depth`, volatile."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


# ---------------------------------------------------------------------------------------------
# NVE scenes (docs/live_nve.md, "NVE scenes live"). A client's link pair is the directions
# "<client>/up" and "<client>/down": /<client>/up/sent, /delivered, /received, /packets, /playout
# as teleoperation's. The per-tick topics are the NVE bag's (docs/recording_nve.md, "Per-tick topics").

NVE_OBJECT_STATE = "/nve/object/joint_states"  # JointState object_x..: position, velocity, effort (net coupling force)


def nve_hip_topic(client: str) -> str:
    """JointState <client>_hip_x..: position, velocity (the HIP at t), effort (the force fed back)."""
    return f"/nve/{client}/hip/joint_states"


def nve_pose_topic(client: str) -> str:
    """PoseStamped: the object as the client uses it at t (NaN before the first)."""
    return f"/nve/{client}/object_pose"


def nve_twist_topic(client: str) -> str:
    """TwistStamped: the object's velocity as the client uses it (NaN before the first)."""
    return f"/nve/{client}/object_twist"


def nve_wrench_topic(client: str) -> str:
    """WrenchStamped: the force fed back to the user."""
    return f"/nve/{client}/feedback_wrench"


def nve_coupling_topic(client: str) -> str:
    """Float64MultiArray spring_n_per_m, rtt_s, up_rx_seq, down_rx_seq, up_occupancy, down_occupancy
    (record/nve_columns.COUPLING_GROUPS; what the client node does not know: NaN)."""
    return f"/nve/{client}/coupling"
