"""What the ROS 2 launch files in `launch/` run: the scene's node plan as `launch_ros` Node actions.

The plan is `haptic_teleop.live.launcher.node_plan`, the one `haptic-teleop launch` starts, so a
full-ROS user and a PyPI-wheels user get the same processes with the same parameter files.
`launch` and `launch_ros` are imported inside `launch_actions` only: the rest of this module (and
its tests) works without them.
"""

from __future__ import annotations

import signal
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from haptic_teleop.errors import ConfigError
from haptic_teleop.live.launcher import DEVICES, SIDES, NodeSpec, node_plan, temporary_params_dir, write_params_files
from haptic_teleop.nodes import DEFAULT_COMMAND_DEPTH, RELIABILITIES

# Launch arguments (name, default, description): every launch file takes these...
ARGUMENTS = (
    ("scene", "wall_contact", "scene YAML path, or a bundled scene name"),
    ("record", "", "directory for the bag (DIR/bag); empty: no recording"),
    ("side", "all", "all | master | slave (two hosts: the nodes of one side)"),
    ("seed", "", "override scene.seed"),
    ("duration", "", "override scene.duration_s (seconds)"),
    ("sim_time", "false", "true: the nodes follow /clock (a clock_source publishes it)"),
)
# ... and the hardware variant (device "topic") these too.
DEVICE_ARGUMENTS = (
    ("state_topic", "/haptic_device/joint_states", "the device driver's sensor_msgs/JointState"),
    ("command_topic", "/haptic_device/force_command", "force command to the driver (WrenchStamped)"),
    ("command_reliability", "reliable", "QoS of the force command: reliable | best_effort"),
    ("command_depth", "10", "QoS history depth of the force command"),
    (
        "set",
        "",
        "scene overrides KEY=VALUE separated by ';', e.g. an arm on servos: "
        "slave.backend=dynamixel;slave.hardware.port=/dev/ttyUSB0 (docs/hardware.md)",
    ),
)


# An NVE scene's launch file (nve_launch.py) takes these: no device or side yet.
NVE_ARGUMENTS = (
    ("scene", "nve_push", "an NVE scene: YAML path, or a bundled scene name (nve_push, nve_two_clients)"),
    ("record", "", "directory for the bag (DIR/bag); empty: no recording"),
    ("seed", "", "override scene.seed"),
    ("duration", "", "override scene.duration_s (seconds)"),
    ("sim_time", "false", "true: the nodes follow /clock (a clock_source publishes it)"),
    (
        "set",
        "",
        "scene overrides KEY=VALUE separated by ';', e.g. the first client's delays: "
        "nve.clients.0.up.effects.delay.delay_s=0.05;nve.clients.0.down.effects.delay.delay_s=0.05",
    ),
)
# The nodes whose exit 0 ends a run (the scene is over): teleoperation's operator source, an NVE
# scene's server.
FINISHING_NODES = ("operator_source", "nve_server")


def launch_description(device: str, scene_type: str = "teleop") -> Any:
    """The LaunchDescription of a launch file: its arguments and the node set (`launch_actions`).
    `scene_type` "nve": the NVE launch file's arguments (NVE_ARGUMENTS)."""
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction

    if scene_type == "nve":
        table = NVE_ARGUMENTS
    else:
        table = ARGUMENTS + (DEVICE_ARGUMENTS if device == "topic" else ())
    args = [DeclareLaunchArgument(name, default_value=default, description=text) for name, default, text in table]
    return LaunchDescription([*args, OpaqueFunction(function=launch_actions, kwargs={"device": device})])


def plan_from_arguments(values: Mapping[str, str], device: str, params_dir: str | Path) -> list[tuple[NodeSpec, Path]]:
    """Launch arguments (strings, as `ros2 launch` passes them) -> [(node spec, its parameter file)].

    Raises ConfigError naming the argument for a bad value, as `haptic-teleop launch` would.
    """
    from haptic_teleop.scene.load import find_scene, load_scene

    def arg(name: str) -> str:
        return str(values.get(name, "")).strip()

    overrides = []
    if arg("duration"):
        try:
            overrides.append(f"scene.duration_s={float(arg('duration'))}")
        except ValueError:
            raise ConfigError("launch arguments", "duration", arg("duration"), "allowed: seconds (a number)") from None
    seed = None
    if arg("seed"):
        try:
            seed = int(arg("seed"))
        except ValueError:
            raise ConfigError("launch arguments", "seed", arg("seed"), "allowed: an integer >= 0") from None
    side = arg("side") or "all"
    if side not in SIDES:
        raise ConfigError("launch arguments", "side", side, "allowed: one of " + ", ".join(SIDES))
    if device not in DEVICES:
        raise ConfigError("launch file", "device", device, "allowed: one of " + ", ".join(DEVICES))
    sim = arg("sim_time").lower() or "false"
    if sim not in ("true", "false"):
        raise ConfigError("launch arguments", "sim_time", sim, "allowed: true or false")
    overrides += [part.strip() for part in arg("set").split(";") if part.strip()]
    scene = load_scene(find_scene(arg("scene") or "wall_contact"), overrides=overrides, seed=seed)
    if device == "topic" and scene.config.is_arm:
        # An arm scene's sides host their arms in master_eba and slave_eba: MuJoCo, or a real arm
        # through its driver (`<side>.backend`, docs/hardware.md); no device topics.
        device = "plant"
    topics = (arg("state_topic"), arg("command_topic")) if device == "topic" and arg("state_topic") else None
    qos = None
    if device == "topic" and (arg("command_reliability") or arg("command_depth")):
        reliability = arg("command_reliability") or "reliable"
        if reliability not in RELIABILITIES:
            raise ConfigError(
                "launch arguments", "command_reliability", reliability, "allowed: one of " + ", ".join(RELIABILITIES)
            )
        try:
            depth = int(arg("command_depth") or DEFAULT_COMMAND_DEPTH)
        except ValueError:
            depth = 0
        if not 1 <= depth <= 10_000:
            raise ConfigError(
                "launch arguments", "command_depth", arg("command_depth"), "allowed: an integer 1 to 10000"
            )
        qos = (reliability, depth)
    plan = node_plan(
        scene,
        record_dir=arg("record") or None,
        side=side,
        device=device,
        sim_time_rate=1.0 if sim == "true" else None,
        device_topics=topics,
        command_qos=qos,
    )
    files = write_params_files(plan, params_dir)
    return [(spec, files[spec.name]) for spec in plan]


class NodeFailed(RuntimeError):
    """A node of the launch exited non-zero: raised from its exit handler, so that ROS 2's launch
    stops every node and `ros2 launch` exits 1 (launch returns 1 for an exception in an event
    handler; a Shutdown event alone ends the launch with 0)."""


# Exit codes of a node stopped by the launch's own shutdown (SIGINT, then SIGTERM): not a failure.
STOPPED_BY_SHUTDOWN = (-signal.SIGINT, -signal.SIGTERM)


def exit_verdict(name: str, code: int, shutting_down: bool) -> str | None:
    """What a node's exit means for the launch: "finished" (a finishing node's exit 0: the scene is
    over, stop the others), "failed" (any non-zero exit, except a node the launch itself is
    stopping, killed by its SIGINT or SIGTERM), or None (nothing to do)."""
    if name in FINISHING_NODES and code == 0:
        return "finished"
    if code != 0 and not (shutting_down and code in STOPPED_BY_SHUTDOWN):
        return "failed"
    return None


def launch_actions(context: Any, device: str = "plant") -> list[Any]:
    """OpaqueFunction body of the launch files: Node actions plus the shutdown rules.

    The run ends when the operator source (an NVE scene: the server) exits 0 (scene over): the
    launch stops the others and exits 0. A node exiting non-zero raises `NodeFailed` naming it:
    the launch stops every node (the others reach their safe state on their own watchdogs) and
    `ros2 launch` exits 1 (`exit_verdict`).
    """
    from launch.actions import EmitEvent, LogInfo, RegisterEventHandler, SetEnvironmentVariable
    from launch.event_handlers import OnProcessExit
    from launch.events import Shutdown
    from launch_ros.actions import Node

    values = dict(context.launch_configurations)
    folder = temporary_params_dir()
    actions: list[Any] = []
    if "ROS_AUTOMATIC_DISCOVERY_RANGE" not in context.environment:
        actions.append(SetEnvironmentVariable("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST"))
    for spec, params_file in plan_from_arguments(values, device, folder):
        node = Node(
            package="haptic_teleop",
            executable=spec.executable,
            name=spec.name,
            parameters=[str(params_file)],
            remappings=list(spec.remaps),
            output="screen",
            emulate_tty=True,
        )
        actions.append(node)

        def on_exit(event: Any, ctx: Any, name: str = spec.name) -> list[Any]:
            code = event.returncode
            verdict = exit_verdict(name, code, bool(getattr(ctx, "is_shutdown", False)))
            if verdict == "finished":
                return [LogInfo(msg="scene finished; stopping every node"), EmitEvent(event=Shutdown(reason="done"))]
            if verdict == "failed":
                raise NodeFailed(f"{name} exited with code {code}; stopping every node (the launch exits 1)")
            return []

        actions.append(RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit)))
    return actions
