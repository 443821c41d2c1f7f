"""What the ROS 2 launch files in `launch/` run: the scene's node plan as `launch_ros` Node actions.

The plan is `haptic_teleop.live.launcher.node_plan`, the one `haptic-teleop launch` starts, so a
full-ROS user and a PyPI-wheels user get the same processes with the same parameter files: one
process per node, or with `single_process:=true` one process running the whole plan composed
(`composed`, as `haptic-teleop launch --single-process`). Which processes start is decided by
`launch_processes`, pure; `launch` and `launch_ros` are imported inside `launch_description` and
`launch_actions` only: the rest of this module (and its tests) works without them.
"""

from __future__ import annotations

import signal
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from haptic_teleop.errors import ConfigError
from haptic_teleop.live.composed import write_plan
from haptic_teleop.live.launcher import (
    DEVICES,
    EXIT_SIGNAL,
    RECORDER_STOP_TIMEOUT_S,
    SIDES,
    STOP_TIMEOUT_S,
    NodeSpec,
    node_plan,
    temporary_params_dir,
    write_params_files,
)
from haptic_teleop.nodes import DEFAULT_COMMAND_DEPTH, DEVICE_TOPICS, RELIABILITIES

# Every launch file's `single_process`: the plan composed in one process (`launch_processes`).
SINGLE_PROCESS = (
    "single_process",
    "false",
    "true: every node in one process with one shared loop thread (haptic-teleop launch --single-process; "
    "recommended on a small machine, 2 vCPUs)",
)
# Launch arguments (name, default, description): every launch file takes these...
ARGUMENTS = (
    ("scene", "wall_contact", "scene YAML path, or a bundled scene name"),
    ("record", "", "directory for the bag (DIR/bag); empty: no recording"),
    ("side", "all", "all | master | slave (two hosts: the nodes of one side)"),
    ("seed", "", "override scene.seed"),
    ("duration", "", "override scene.duration_s (seconds)"),
    ("sim_time", "false", "true: the nodes follow /clock (a clock_source publishes it)"),
    SINGLE_PROCESS,
)
# ... and the hardware variant (device "topic") these too.
DEVICE_ARGUMENTS = (
    ("state_topic", DEVICE_TOPICS[0], "the device driver's sensor_msgs/JointState"),
    ("command_topic", DEVICE_TOPICS[1], "force command to the driver (WrenchStamped)"),
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
    SINGLE_PROCESS,
    (
        "set",
        "",
        "scene overrides KEY=VALUE separated by ';', e.g. the first client's delays: "
        "nve.clients.0.up.effects.delay.delay_s=0.05;nve.clients.0.down.effects.delay.delay_s=0.05",
    ),
)
# The composed process (`single_process:=true`): its console script, and its name in the exit rule.
COMPOSED = "composed"
# The processes whose exit 0 ends a run (the scene is over): teleoperation's operator source, an NVE
# scene's server, the composed process (it exits 0 when one of its nodes has finished the scene).
FINISHING_NODES = ("operator_source", "nve_server", COMPOSED)


def launch_description(device: str, scene_type: str = "teleop") -> Any:
    """The LaunchDescription of a launch file: its arguments and the node set (`launch_actions`).
    `scene_type` "nve": the NVE launch file's arguments (NVE_ARGUMENTS)."""
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction

    table = argument_table(device, scene_type)
    args = [DeclareLaunchArgument(name, default_value=default, description=text) for name, default, text in table]
    return LaunchDescription([*args, OpaqueFunction(function=launch_actions, kwargs={"device": device})])


def argument_table(device: str, scene_type: str = "teleop") -> tuple[tuple[str, str, str], ...]:
    """The arguments (name, default, description) a launch file declares (`ros2 launch -s` lists them)."""
    if scene_type == "nve":
        return NVE_ARGUMENTS
    return ARGUMENTS + (DEVICE_ARGUMENTS if device == "topic" else ())


def plan_from_arguments(
    values: Mapping[str, str], device: str, params_dir: str | Path, warm: bool = False
) -> list[tuple[NodeSpec, Path]]:
    """Launch arguments (strings, as `ros2 launch` passes them) -> [(node spec, its parameter file)].
    `warm`: then an arm scene's compiled side tick is built (or loaded) in this process before any
    node starts (`warm_before_nodes`).

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
    sim = switch_argument(values, "sim_time")
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
        sim_time_rate=1.0 if sim else None,
        device_topics=topics,
        command_qos=qos,
    )
    if warm:
        warm_before_nodes(scene.config)
    files = write_params_files(plan, params_dir)
    return [(spec, files[spec.name]) for spec in plan]


def warm_before_nodes(config: Any) -> str | None:
    """An arm scene's compiled side tick built here, in the launch's own process, before any node
    starts, saying so on stderr when numba really compiles it (after a fresh install or colcon
    build: numba's cache is per install path). A node compiling it itself would keep the others
    waiting past their start timeout (`start.timeout_s`); the nodes then load it from the cache.
    What `haptic-teleop launch` does too (assembly/compiled_side.warm_saying)."""
    import sys

    from haptic_teleop.assembly import compiled_side

    return compiled_side.warm_saying(config, lambda text: print(text, file=sys.stderr, flush=True))


def switch_argument(values: Mapping[str, str], name: str) -> bool:
    """A true | false launch argument (empty: false); ConfigError naming it for anything else."""
    value = str(values.get(name, "")).strip().lower() or "false"
    if value not in ("true", "false"):
        raise ConfigError("launch arguments", name, value, "allowed: true or false")
    return value == "true"


@dataclass(frozen=True)
class LaunchProcess:
    """One process the launch starts: a `launch_ros` Node of this package (`launch_actions`)."""

    label: str  # the node's name, or COMPOSED: what the exit rule and the messages call it
    executable: str  # console script in lib/haptic_teleop
    arguments: tuple[str, ...] = ()  # its own command-line arguments
    # One node's process: its name, parameter file and remappings, as ROS arguments. None for the
    # composed process: ROS arguments on its command line would apply to every node in it.
    node_name: str | None = None
    params_file: str | None = None
    remaps: tuple[tuple[str, str], ...] = ()
    sigterm_timeout_s: float | None = None  # SIGINT to SIGTERM on shutdown; None: launch's default (5 s)

    def command(self) -> list[str]:
        """Its command line, as launch_ros builds it (the executable found in lib/haptic_teleop)."""
        cmd = [self.executable, *self.arguments, "--ros-args"]
        if self.node_name is not None:
            cmd += ["-r", f"__node:={self.node_name}"]
        if self.params_file is not None:
            cmd += ["--params-file", self.params_file]
        for a, b in self.remaps:
            cmd += ["-r", f"{a}:={b}"]
        return cmd


def launch_processes(
    values: Mapping[str, str], device: str, folder: str | Path, warm: bool = True
) -> list[LaunchProcess]:
    """Launch arguments -> the processes to start: one per node of the plan, or with
    `single_process:=true` one `composed` process running the plan written to `folder` (the nodes'
    parameter files and the plan file, `composed.write_plan`). ConfigError for a bad argument.
    `warm`: an arm scene's compiled side tick is built first (`warm_before_nodes`)."""
    composed = switch_argument(values, "single_process")
    pairs = plan_from_arguments(values, device, folder, warm=warm)
    if not composed:
        return [
            LaunchProcess(spec.name, spec.executable, node_name=spec.name, params_file=str(path), remaps=spec.remaps)
            for spec, path in pairs
        ]
    plan = [spec for spec, _ in pairs]
    remapped = [spec.name for spec in plan if spec.remaps]
    if remapped:  # run_single_process gives each node its parameter file only
        allowed = f"{', '.join(remapped)} remap topics, which one process does not apply yet; allowed: false"
        raise ConfigError("launch arguments", "single_process", "true", allowed)
    # The nodes stop on SIGINT, the recorder last (closing the bag): SIGTERM only after the
    # launcher's own bounds, as `haptic-teleop launch` gives them (then SIGKILL, launch's default
    # 5 s later).
    recorder = any(spec.executable == "recorder" for spec in plan)
    stop_s = STOP_TIMEOUT_S + (RECORDER_STOP_TIMEOUT_S if recorder else 0.0)
    return [LaunchProcess(COMPOSED, COMPOSED, arguments=(str(write_plan(plan, folder)),), sigterm_timeout_s=stop_s)]


class NodeFailed(RuntimeError):
    """A node of the launch exited non-zero: raised from its exit handler, so that ROS 2's launch
    stops every node and `ros2 launch` exits 1 (launch returns 1 for an exception in an event
    handler; a Shutdown event alone ends the launch with 0)."""


# Exit codes of a process stopped by the launch's own shutdown (SIGINT, then SIGTERM): not a failure.
# Killed by the signal (-2, -15; a node process, or the composed one before its nodes are built) or
# reporting it (130, 143: the composed process, as `haptic-teleop launch`).
STOPPED_BY_SHUTDOWN = (-signal.SIGINT, -signal.SIGTERM, *sorted(EXIT_SIGNAL.values()))


def exit_verdict(name: str, code: int, shutting_down: bool) -> str | None:
    """What a process's exit means for the launch: "finished" (a finishing process's exit 0: the
    scene is over, stop the others), "failed" (any non-zero exit, except a process the launch itself
    is stopping, stopped by its SIGINT or SIGTERM: STOPPED_BY_SHUTDOWN), or None (nothing to do)."""
    if name in FINISHING_NODES and code == 0:
        return "finished"
    if code != 0 and not (shutting_down and code in STOPPED_BY_SHUTDOWN):
        return "failed"
    return None


def launch_actions(context: Any, device: str = "plant") -> list[Any]:
    """OpaqueFunction body of the launch files: a Node action per process of `launch_processes`
    (one per node, or the one composed process), plus the shutdown rules.

    The run ends when the operator source (an NVE scene: the server; composed: the one process)
    exits 0 (scene over): the launch stops the others and exits 0. A process exiting non-zero
    raises `NodeFailed` naming it: the launch stops every node (the others reach their safe state
    on their own watchdogs) and `ros2 launch` exits 1 (`exit_verdict`).
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
    for process in launch_processes(values, device, folder):
        options: dict[str, Any] = {}
        if process.node_name is not None:  # one node: its name, parameter file and remappings
            options.update(name=process.node_name, remappings=list(process.remaps))
        if process.params_file is not None:
            options["parameters"] = [process.params_file]
        if process.sigterm_timeout_s is not None:
            options["sigterm_timeout"] = str(process.sigterm_timeout_s)
        node = Node(
            package="haptic_teleop",
            executable=process.executable,
            arguments=list(process.arguments),
            output="screen",
            emulate_tty=True,
            **options,
        )
        actions.append(node)

        def on_exit(event: Any, ctx: Any, name: str = process.label) -> list[Any]:
            code = event.returncode
            verdict = exit_verdict(name, code, bool(getattr(ctx, "is_shutdown", False)))
            if verdict == "finished":
                return [LogInfo(msg="scene finished; stopping every node"), EmitEvent(event=Shutdown(reason="done"))]
            if verdict == "failed":
                raise NodeFailed(f"{name} exited with code {code}; stopping every node (the launch exits 1)")
            return []

        actions.append(RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit)))
    return actions
