"""`haptic-teleop launch SCENE`: a scene live, its nodes as processes over DDS (or composed in one
process), through the project's launcher (live/launcher.py); with `--record DIR`, the recorded bag
analysed afterwards as `run` analyses its own (summary.json, plots, the summary table)."""

from __future__ import annotations

import dataclasses
import os
import sys
from pathlib import Path
from typing import Any

from haptic_teleop.cli.arg_types import tcp_port
from haptic_teleop.live.launcher import (
    DEVICES,
    EXIT_FAILURE,
    SIDES,
    Launcher,
    node_plan,
    run_single_process,
    temporary_params_dir,
)
from haptic_teleop.nodes import DEVICE_TOPICS


def launch_main(args: Any) -> int:
    """`haptic-teleop launch` (argparse namespace from cli/main.py)."""
    from haptic_teleop import interrupt
    from haptic_teleop.errors import HapticTeleopError, InputError
    from haptic_teleop.scene.load import find_scene, load_scene

    overrides = list(args.set or ())
    if args.duration is not None:
        overrides.append(f"scene.duration_s={float(args.duration)}")
    if args.compression is not None:
        overrides.append(f"recording.compression={args.compression}")
    scene = load_scene(find_scene(args.scene), overrides=overrides, seed=args.seed)
    record = Path(args.record) if args.record else None
    if record is not None:
        problem = record_dir_problem(record)
        if problem is not None:
            raise InputError(f"--record {record}: {problem}")
    rate = args.sim_time_rate
    try:
        topics = (args.state_topic, args.command_topic) if args.device == "topic" else None
        plan = node_plan(
            scene, record_dir=record, side=args.side, device=args.device, sim_time_rate=rate, device_topics=topics
        )
    except ValueError as exc:
        raise HapticTeleopError(str(exc)) from None
    if args.foxglove is not None:  # the recorder serves the live view of what it records
        if record is None or not any(s.name == "recorder" for s in plan):
            raise InputError("--foxglove shows what the recorder records; allowed: with --record DIR")
        plan = [
            dataclasses.replace(s, params={**s.params, "view": {"foxglove_port": args.foxglove}})
            if s.name == "recorder" else s
            for s in plan
        ]  # fmt: skip
    params_dir = Path(args.params_dir) if args.params_dir else temporary_params_dir()
    warm_side_tick(scene)
    # From here on a first signal stops the nodes (their own handlers while they run) and still
    # lets the bag, summary and plots be written (the CLI's handler once they have stopped).
    with interrupt.finishing():
        return _launch_and_report(args, scene, plan, params_dir, record, rate)


def warm_side_tick(scene: Any) -> None:
    """An arm scene's compiled side tick built (or loaded) here, before its nodes start, saying so
    when numba really compiles it: a node compiling it cold would keep the others waiting past
    their start timeout (assembly/compiled_side.warm)."""
    from haptic_teleop.assembly import compiled_side

    compiled_side.warm_saying(scene.config, lambda text: print(text, file=sys.stderr, flush=True))


def _launch_and_report(args: Any, scene: Any, plan: Any, params_dir: Path, record: Path | None, rate: Any) -> int:
    if args.single_process:
        os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        code = run_single_process(plan, params_dir)
    else:
        # Discovery, the operator's settling delay and the scene itself; then give up.
        # (a device session, like the slave host's side, runs until it is stopped)
        timeout = scene.config.scene.duration_s / (rate or 1.0) + 60.0
        if args.side == "slave" or args.device == "topic":
            timeout = None
        result = Launcher(plan, params_dir, timeout_s=timeout).run()
        code = result.exit_code
    bag = record / "bag" if record is not None else None
    if bag is not None and bag.exists() and not (bag / "metadata.yaml").exists():
        # The recorder was killed: its flushed chunks are there, the summary section is not.
        print(
            f"haptic-teleop: the recorder did not finish {bag} (killed?); `haptic-teleop bag recover {bag}` "
            "rebuilds it from every complete chunk",
            file=sys.stderr,
        )
        code = code or EXIT_FAILURE
    elif record is not None and bag is not None and bag.exists():
        # write_outputs tells an NVE run's bag from a teleoperation one (analysis/outputs.py)
        from haptic_teleop.analysis.outputs import write_outputs
        from haptic_teleop.analysis.summary_table import format_summary

        summary = write_outputs(bag, record, plots=not args.no_plots)
        print(format_summary(summary))
        print(f"\nbag:     {bag}\nsummary: {record / 'summary.json'}")
    elif record is not None:
        print(f"haptic-teleop: no bag was written to {record / 'bag'}", file=sys.stderr)
        code = code or EXIT_FAILURE
    return code


def record_dir_problem(record: Path) -> str | None:
    """What makes `record` unusable as `--record DIR`, or None (then DIR exists, empty and writable).

    Checked before any node starts, by doing what the recorder will do: create the directory and a
    file in it (a permission check alone would pass for root on a read-only file system)."""
    allowed = "allowed: a new or empty directory this user can write"
    if record.exists() and not record.is_dir():
        return f"is a file, not a directory; {allowed}"
    if record.is_dir() and any(record.iterdir()):
        return f"exists and is not empty; {allowed}"
    try:
        record.mkdir(parents=True, exist_ok=True)
        probe = record / ".haptic_teleop_write_check"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        return f"cannot be written ({exc.strerror or exc}); {allowed}"
    return None


def add_arguments(p: Any) -> None:
    p.add_argument("scene", help="scene YAML path, or a bundled scene name (e.g. wall_contact)")
    p.add_argument("--duration", type=float, metavar="S", help="seconds of scene time to run (scene.duration_s)")
    p.add_argument("--record", metavar="DIR", help="record a bag to DIR/bag, then write DIR/summary.json")
    p.add_argument(
        "--compression",
        choices=("none", "zstd", "lz4"),
        help="MCAP chunk compression of the recorded bag (scene key recording.compression)",
    )
    p.add_argument(
        "--single-process",
        action="store_true",
        help="all nodes composed in this process, their 1 kHz loops run by one shared thread (recommended on a "
        "machine with few cores: docs/live.md)",
    )
    p.add_argument("--side", choices=SIDES, default="all", help="two hosts: the nodes of one side only")
    p.add_argument(
        "--device",
        choices=DEVICES,
        default="plant",
        help="topic: the master on a real haptic device driver's topics, no simulated operator, until Ctrl-C "
        "(the hardware variant, as teleop_hardware_launch.py; docs/live.md)",
    )
    p.add_argument(
        "--state-topic", default=DEVICE_TOPICS[0], help="--device topic: the driver's sensor_msgs/JointState"
    )
    p.add_argument(
        "--command-topic",
        default=DEVICE_TOPICS[1],
        help="--device topic: the force command to the driver (WrenchStamped)",
    )
    p.add_argument("--seed", type=int, help="override scene.seed")
    p.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override any scene key (repeatable)")
    p.add_argument("--params-dir", help="where the parameter files go (default: a temporary directory)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots of the recorded run")
    p.add_argument(
        "--foxglove",
        nargs="?",
        type=tcp_port,
        const=8765,
        metavar="PORT",
        help="the recorder serves a live view to Foxglove on ws://127.0.0.1:PORT (default 8765); needs --record "
        "(docs/foxglove.md)",
    )
    p.add_argument(
        "--sim-time-rate",
        type=float,
        metavar="R",
        help="simulated time: a clock_source publishes /clock at R simulated s per wall s (e.g. 0.5 on a "
        "loaded machine) and every node follows it (use_sim_time)",
    )
