"""Live mode: thin rclpy shells around the core objects (see docs/live.md).

The node modules import rclpy; this file does not, so the launcher and the ROS 2 launch files can
read the node table below without ROS 2 being importable.
"""

# Executable (console script, also the default node name) -> module with `main()`.
EXECUTABLES = {
    "master_eba": "haptic_teleop.nodes.master_eba",
    "slave_eba": "haptic_teleop.nodes.slave_eba",
    "network_relay": "haptic_teleop.nodes.network_relay",
    "sync_buffer": "haptic_teleop.nodes.sync_buffer",
    "operator_source": "haptic_teleop.nodes.operator_source",
    "recorder": "haptic_teleop.nodes.recorder",
    "clock_source": "haptic_teleop.nodes.clock_source",
    "nve_server": "haptic_teleop.nodes.nve_server",
    "nve_client": "haptic_teleop.nodes.nve_client",
}

# The scene sections each executable reads as parameters ("" is the whole scene; {direction}
# is the node's `direction` parameter).
SCENE_SECTIONS = {
    # Both EBA nodes read the whole loop's physical limits: the packet guard's bounds on remote
    # samples come from the workspace, the operator's speed and every force limit (engine.remote_limits).
    # Arm scenes: both EBA nodes and the operator build the scene's arm parts (the workspace
    # mapping's default offset comes from both arms' start points).
    # Each EBA node reads the codec of the direction it sends (its encoder, nodes/codec_stage.py)
    # with that direction's buffer (a codec needs buffer.policy none); the sync buffer, the codec
    # of its direction (its decoder). HLI's N_HLI1 comes from the direction's Gilbert loss, so the
    # encoder's and decoder's nodes read that direction's loss model too.
    "master_eba": (
        "scene",
        "operator",
        "master",
        "slave",
        "simulation",
        "controllers",
        "mapping",
        "network.forward.buffer",
        "network.forward.codec",
        "network.forward.effects.loss",
    ),
    "slave_eba": (
        "scene",
        "operator",
        "master",
        "slave",
        "simulation",
        "controllers",
        "mapping",
        "network.backward.buffer",
        "network.backward.codec",
        "network.backward.effects.loss",
    ),
    # A relay reads its direction's codec too: a packet's size on the wire is its codec's (HLI's
    # own message, nodes/codec_stage.py), for the packet records and the links' rate limits. Both
    # read the stabilizer of both sides (the scene checks they agree), which shapes a one-axis
    # scene's samples (nodes/wire.py: TDPA's energy joint, a wave port's wave).
    "network_relay": (
        "scene",
        "network.{direction}.effects",
        "network.{direction}.codec",
        "controllers.master.eba",
        "controllers.slave.eba",
    ),
    "sync_buffer": (
        "scene",
        "controllers.master.eba",
        "controllers.slave.eba",
        "network.{direction}.buffer",
        "network.{direction}.codec",
        "network.{direction}.effects.loss",
    ),
    "operator_source": ("scene", "operator", "master", "slave", "simulation", "controllers", "mapping"),
    "recorder": ("",),
    "clock_source": ("scene",),
    # An NVE scene (docs/live_nve.md, "NVE scenes live"): the server and each client read the whole
    # nve section (the same build_nve_parts as the engine).
    "nve_server": ("scene", "nve"),
    "nve_client": ("scene", "nve"),
}

# The sections a relay or a sync buffer reads for an NVE direction `<client>/up|down` ({client},
# {link}: its parts).
NVE_SCENE_SECTIONS = {
    "network_relay": ("scene", "nve.clients.{client}.{link}.effects"),
    "sync_buffer": ("scene", "nve.clients.{client}.{link}.buffer"),
}

# A node process prints its loop's figures on a line starting with this as it exits (JSON after
# it); the launcher reads them for its table at the end of a launch.
LOOP_FIGURES_MARK = "loop figures: "

# Watchdog defaults (docs/live.md): remote data older than this starts a fade to zero force.
WATCHDOG_TIMEOUT_S = 0.1
WATCHDOG_FADE_S = 0.05

# network_relay `scene_start`: where its link's scene time 0 comes from (the operator source's
# /haptic_teleop/scene_start, or the first sample's stamp when there is no operator source).
RELAY_SCENE_STARTS = ("topic", "first_sample")
# master_eba's `device.source` (and the recorder's): the scene's simulated device, or a driver's
# topics (a device session: no operator source; master_eba publishes scene time 0).
DEVICE_SOURCES = ("plant", "topic")
# A driver's topics, by default: its sensor_msgs/JointState, and the force command to it (WrenchStamped).
DEVICE_TOPICS = ("/haptic_device/joint_states", "/haptic_device/force_command")

# QoS of the hardware variant's force command (master_eba `device.command_reliability`, `device.command_depth`).
RELIABILITIES = ("reliable", "best_effort")
DEFAULT_COMMAND_DEPTH = 10
