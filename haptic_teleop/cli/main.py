"""`haptic-teleop run | analyze | sweep | report | compile | bench | launch | ...`: the command line."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path
from typing import Any

from haptic_teleop import interrupt
from haptic_teleop.analysis.outputs import (
    SCENE_FILE,
    TIMING_FILE,
    check_out_dir,
    default_out,
    write_atomic,
    write_outputs,
)
from haptic_teleop.cli.arg_types import tcp_port
from haptic_teleop.errors import BagError, ConfigError, HapticTeleopError, InputError, PlantError

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def _say(args: argparse.Namespace, text: str) -> None:
    """Normal output (tables, paths): nothing with --quiet, which prints errors only."""
    if not getattr(args, "quiet", False):
        print(text)


def compile_notice(module: str) -> str:
    """What `run` says when a tick loop is compiled rather than loaded from numba's cache
    (`compiling.compile_message`)."""
    from haptic_teleop import compiling

    return compiling.compile_message(module)


def cmd_run(args: argparse.Namespace) -> int:
    from haptic_teleop.scene.load import find_scene, load_scene

    interrupt.pause_for_test("scene")
    overrides = list(args.set or ())
    if args.compression is not None:
        overrides.append(f"recording.compression={args.compression}")
    emulate = getattr(args, "emulate", None)
    if emulate is None:
        return _run_scene(args, load_scene(find_scene(args.scene), overrides=overrides, seed=args.seed))
    # --emulate: a Dynamixel bus emulator per side on servos, from the scene (haptic_teleop/assembly/emulation.py);
    # stopped on every way out, after the run has stopped the servos.
    from haptic_teleop.assembly.emulation import emulated

    first = load_scene(find_scene(args.scene), overrides=overrides, seed=args.seed, emulate=True)
    if args.dry_run:  # validated; no emulator needed to print it
        return _run_scene(args, first)
    with emulated(first.config, emulate) as ports:
        scene = load_scene(find_scene(args.scene), overrides=overrides + ports, seed=args.seed)
        return _run_scene(args, scene)


def _run_scene(args: argparse.Namespace, scene: Any) -> int:
    resolved = scene.to_yaml()
    if args.dry_run:
        sys.stdout.write(resolved)
        return EXIT_OK
    out = Path(args.out) if args.out else default_out(scene.config.scene.name)
    if getattr(args, "foxglove", None) is not None and scene.config.is_nve:
        raise InputError("--foxglove: a live view of NVE scenes is not built yet; allowed: a teleoperation scene")
    check_devices(scene)
    existed = out.is_dir()
    check_out_dir(out)
    try:
        return _record(args, scene, resolved, out)
    except Exception:
        # A start that failed (no tick recorded: a device that did not answer, an engine that could
        # not be built) leaves --out as it was, so the same command runs again as it is.
        if _ticks_recorded(out / "bag") == 0:
            _remove_outputs(out, existed)
        raise


def _ticks_recorded(bag_dir: Path) -> int:
    """How many ticks the bag in `bag_dir` holds, from its chunk indexes (a teleoperation run's
    master rows, an NVE run's object rows; 0: none, or no readable bag)."""
    from haptic_teleop.record.reader import BagReader

    try:
        with BagReader(bag_dir) as reader:
            topic = next((t for t in ("/master/joint_states", "/nve/object/joint_states") if reader.has(t)), None)
            return sum(block.size for block in reader.log_blocks(topic)) if topic is not None else 0
    except Exception:  # noqa: BLE001 - absent, empty or unreadable: nothing recorded
        return 0


def _remove_outputs(out: Path, existed: bool) -> None:
    """Empty `out` again (it was empty), or remove it (it was not there)."""
    import shutil

    if not existed:
        shutil.rmtree(out, ignore_errors=True)
        return
    for child in out.iterdir():
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child, ignore_errors=True)
        else:
            child.unlink(missing_ok=True)


def _record(args: argparse.Namespace, scene: Any, resolved: str, out: Path) -> int:
    from haptic_teleop.analysis.summary_table import format_summary
    from haptic_teleop.engine.run import record_run

    if not args.quiet and not scene.config.is_nve:
        from haptic_teleop.assembly.channel import arq_round_trip_notes

        for note in arq_round_trip_notes(scene.config):
            print(f"haptic-teleop: note: {note}", file=sys.stderr)

    # From here on the outputs exist: a first Ctrl-C / SIGTERM stops the loop and the rest is
    # still written; a second one aborts (haptic_teleop/interrupt.py).
    with interrupt.finishing():
        # The resolved scene: `haptic-teleop run DIR/scene.yaml` records the same bag again.
        write_atomic(out / SCENE_FILE, resolved)
        total = int(round(scene.config.scene.duration_s / scene.config.scene.period_s))
        bar: Any = None
        last = [0]

        def open_bar() -> None:  # once the engine is built (it may spend a minute compiling)
            nonlocal bar
            if not args.quiet:
                from tqdm import tqdm

                bar = tqdm(
                    total=total,
                    unit="tick",
                    unit_scale=True,
                    desc=scene.config.scene.name,
                    leave=False,
                    file=sys.stderr,
                    mininterval=0.2,
                )

        def progress(n: int) -> None:
            if last[0] == 0:
                interrupt.pause_for_test("loop")
            if bar is not None:
                bar.update(n - last[0])
            last[0] = n

        bag_dir = out / "bag"
        with contextlib.ExitStack() as stack:

            def on_engine(engine: Any) -> None:
                starting.close()
                if engine.pacer is not None and not args.quiet:
                    print(
                        f"haptic-teleop: a real device: the tick runs in Python ({engine.compiled_reason}), "
                        f"paced to the wall clock (late ticks: timing.json)",
                        file=sys.stderr,
                    )
                open_bar()
                stack.enter_context(interrupt.on_stop(engine.request_stop))  # Ctrl-C, SIGTERM: stop
                interrupt.pause_for_test("engine")

            starting = contextlib.ExitStack()
            if not args.quiet:  # said when a loop is really compiled (its first tick), not when loaded
                from haptic_teleop import compiling

                def notice(module: str) -> None:
                    if bar is not None:
                        bar.write(compile_notice(module), file=sys.stderr)  # above the bar, not on its line
                    else:
                        print(compile_notice(module), file=sys.stderr, flush=True)

                def waiting(module: str) -> None:
                    print(compiling.wait_message(module), file=sys.stderr, flush=True)

                compiling.compile_notice, compiling.wait_notice = notice, waiting
                stack.callback(setattr, compiling, "compile_notice", None)
                stack.callback(setattr, compiling, "wait_notice", None)
            try:
                with starting:
                    if scene.config.is_nve:
                        from haptic_teleop.engine.nve_loop import record_nve_run

                        _, timing = record_nve_run(
                            scene, bag_dir, progress=progress, handle_sigint=False, on_engine=on_engine
                        )
                    else:
                        _, timing = record_run(
                            scene, bag_dir, progress=progress, loop=args.loop, handle_sigint=False,
                            on_engine=on_engine, make_view=_view_maker(args),
                        )  # fmt: skip
            except BagError as exc:
                raise HapticTeleopError(str(exc)) from None  # writing failed: not an input error (exit 1)
            except PlantError:
                # A device failed mid-run (torque is off, the bag closed): analyse the ticks that ran,
                # then the error's one line and exit 1.
                with contextlib.suppress(Exception):
                    write_outputs(bag_dir, out, plots=not args.no_plots)
                raise
            finally:
                if bar is not None:
                    bar.close()
        # Timing lives beside the bag, not in it, so the same scene and seed give the same bag bytes.
        write_atomic(out / TIMING_FILE, json.dumps(timing.as_dict(), indent=2, sort_keys=True) + "\n")
        summary = write_outputs(bag_dir, out, plots=not args.no_plots)
    _say(args, format_summary(summary))
    _say(
        args,
        f"\nbag:     {bag_dir}\nsummary: {out / 'summary.json'}\nscene:   {out / SCENE_FILE}"
        + ("" if args.no_plots else f"\nplots:   {out / 'plots'}"),
    )
    return EXIT_INTERRUPTED if timing.interrupted else EXIT_OK


def _view_maker(args: argparse.Namespace) -> Any:
    """`--foxglove PORT`: how record_run makes the live view (record/foxglove_view.py), which says
    where it serves; None without the flag."""
    port = getattr(args, "foxglove", None)
    if port is None:
        return None

    def make(columns: Any, period_ns: int) -> Any:
        from haptic_teleop.core.link import FATE_NAMES
        from haptic_teleop.record.foxglove_view import serve_view

        def say(text: str) -> None:
            if not getattr(args, "quiet", False):
                print(f"haptic-teleop: {text}", file=sys.stderr, flush=True)

        return serve_view(columns, period_ns, FATE_NAMES, port, say)

    return make


def check_devices(scene: Any) -> None:
    """Every hardware side's device is there (its serial port exists and opens), before anything is
    written or built: a wrong port is one line and exit 2 at once, not after the engine's build,
    and leaves no output folder behind."""
    from haptic_teleop.plants.base import backend

    config = scene.config
    if not config.is_arm:
        return
    for side in ("master", "slave"):
        cfg = getattr(config, side)
        if cfg.hardware is None or not backend(cfg.backend).real:
            continue
        problem = cfg.hardware.absent()
        if problem is None and hasattr(cfg.hardware, "unopenable"):
            problem = cfg.hardware.unopenable()
        if problem is not None:
            raise ConfigError(scene.source, f"{side}.{problem.key}", problem.value, problem.allowed)


def cmd_analyze(args: argparse.Namespace) -> int:
    from haptic_teleop.analysis.summary_table import format_summary

    bag = Path(args.bag)
    if not bag.exists():
        raise BagError(f"{bag}: no such bag; allowed: a rosbag2 directory (the one that holds metadata.yaml)")
    if args.out:
        out = Path(args.out)
    elif (bag / "metadata.yaml").exists() or not bag.is_dir():
        out = bag.parent
    else:
        out = bag
    check_out_dir(out, empty=False)
    if (out / "summary.json").exists() and not args.force:
        raise InputError(
            f"{out / 'summary.json'} exists (the run's own analysis); allowed: --out NEW_DIR, or --force to write "
            "the summary and plots over it"
        )
    with interrupt.finishing():
        summary = write_outputs(bag, out, plots=not args.no_plots)
    _say(args, format_summary(summary))
    _say(args, f"\nsummary: {out / 'summary.json'}")
    return EXIT_OK


def cmd_scenes(args: argparse.Namespace) -> int:
    from haptic_teleop.scene.load import bundled_scenes

    rows = bundled_scenes()
    width = max((len(name) for name, _ in rows), default=0)
    for name, description in rows:
        print(f"{name:<{width}}  {description}".rstrip())
    return EXIT_OK


def package_version() -> str:
    """The installed distribution's version, or the package's own when not installed."""
    # Imported before the try: a signal inside this import must not leave the except clause's
    # name unbound (an UnboundLocalError traceback in place of the interrupt).
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("haptic_teleop")
    except PackageNotFoundError:
        from haptic_teleop import __version__

        return __version__


def cmd_bag(args: argparse.Namespace) -> int:
    """`bag info BAG` (exit 1 if the bag is damaged) and `bag recover BAG`; a bad path or an
    unusable file: one line, exit 2."""
    from haptic_teleop.record import tools

    try:
        if args.action == "info":
            text, sound = tools.info(Path(args.bag))
            print(text)
            return EXIT_OK if sound else EXIT_FAILURE
        print(tools.recover(Path(args.bag)).report())
        return EXIT_OK
    except BagError as exc:
        print(f"haptic-teleop: bag error: {exc}", file=sys.stderr)
        return EXIT_USAGE


def cmd_launch(args: argparse.Namespace) -> int:
    from haptic_teleop.cli.launch import launch_main

    return launch_main(args)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="haptic-teleop", description=__doc__)
    p.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="simulate a scene in deterministic simulated time; write bag, summary, plots")
    r.add_argument("scene", help="scene YAML path, or a bundled scene name (e.g. wall_contact)")
    r.add_argument("--out", help="output directory (default runs/<scene>-NNN)")
    r.add_argument("--seed", type=int, help="override scene.seed")
    r.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override any scene key (repeatable)")
    r.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    r.add_argument("--quiet", action="store_true", help="print nothing but errors (no progress bar, no table)")
    r.add_argument("--dry-run", action="store_true", help="validate the scene, print it resolved, write nothing")
    r.add_argument(
        "--emulate",
        action="store_const",
        const="lockstep",
        help="start an emulator for each side on hardware and run against it through the unmodified SDK: a "
        "Dynamixel bus per side on servos (backend dynamixel; lockstep time: the same scene and seed give the "
        "same bag), the UR emulator for a UR slave (backend ur; real time) (docs/hardware.md)",
    )
    r.add_argument(
        "--compression",
        choices=("none", "zstd", "lz4"),
        help="MCAP chunk compression of the bag (scene key recording.compression, default none)",
    )
    r.add_argument(
        "--loop",
        choices=("auto", "compiled", "python"),
        default="auto",
        help="tick loop: compiled (numba) or python; both give the same bag (auto: compiled if the scene allows)",
    )
    r.add_argument(
        "--foxglove",
        nargs="?",
        type=tcp_port,
        const=8765,
        metavar="PORT",
        help="serve a live view of the run to Foxglove on ws://127.0.0.1:PORT (default 8765) as it is recorded "
        "(docs/foxglove.md)",
    )
    r.set_defaults(func=cmd_run)

    a = sub.add_parser("analyze", help="metrics, summary.json and plots from a bag alone")
    a.add_argument("bag", help="rosbag2 directory")
    a.add_argument("--out", help="where summary.json and plots/ go (default: next to the bag)")
    a.add_argument("--no-plots", action="store_true")
    a.add_argument("--force", action="store_true", help="write over a summary.json (and plots) already in --out")
    a.add_argument("--quiet", action="store_true", help="print nothing but errors")
    a.set_defaults(func=cmd_analyze)

    sc = sub.add_parser("scenes", help="list the bundled scenes, one line each: name and description")
    sc.set_defaults(func=cmd_scenes)

    from haptic_teleop.engine.warm import KERNELS

    co = sub.add_parser(
        "compile",
        help="build the compiled tick loops into numba's cache now (else each compiles on its first run: seconds "
        "to about two minutes each on 2 cores)",
    )
    co.add_argument("--only", metavar="K1,K2", help=f"kernels to build (default all: {','.join(KERNELS)})")
    co.add_argument("--done-dir", help="touch NAME.done (NAME.failed) in this directory as each kernel is ready")
    co.set_defaults(func=cmd_compile)

    bg = sub.add_parser("bag", help="info BAG: topics, counts, QoS, integrity; recover BAG: rebuild a cut bag")
    bg.add_argument("action", choices=("info", "recover"))
    bg.add_argument("bag", help="rosbag2 directory (or its .mcap file)")
    bg.set_defaults(func=cmd_bag)

    from haptic_teleop.cli import sweep

    sw = sub.add_parser("sweep", help="run every combination of parameter values and seeds; table, CSV, plot")
    sweep.add_arguments(sw)
    sw.set_defaults(func=sweep.main)

    from haptic_teleop.cli import report as report_command

    rp = sub.add_parser("report", help="one self-contained HTML report (and a Markdown twin) of sweeps, runs and bags")
    report_command.add_arguments(rp)
    rp.set_defaults(func=report_command.main)

    from haptic_teleop.cli import bench

    bench.add_arguments(sub.add_parser("bench", help="benchmarks that print figures"))

    from haptic_teleop.cli import identify

    idp = sub.add_parser(
        "identify", help="excite an arm's joints, estimate their friction, print and write the damping EBA may assume"
    )
    identify.add_arguments(idp)
    idp.set_defaults(func=identify.main)

    from haptic_teleop.cli.experiment import add_arguments as add_experiment_arguments

    ex = sub.add_parser(
        "experiment",
        help="the seeds' experiments as commands: plot, CSV and table (docs/nve_experiments.md, docs/codec.md)",
    )
    add_experiment_arguments(ex)

    from haptic_teleop.cli.launch import add_arguments as add_launch_arguments

    la = sub.add_parser("launch", help="run a scene live: ROS 2 nodes as processes over DDS")
    add_launch_arguments(la)
    la.set_defaults(func=cmd_launch)

    em = sub.add_parser("emulate", help="serve an emulated device for the unmodified SDKs (docs/dynamixel.md)")
    emd = em.add_subparsers(dest="device", required=True, metavar="DEVICE").add_parser(
        "dynamixel", help="a Protocol 2.0 bus on a pseudo-terminal; prints PORT /dev/pts/N"
    )
    emd.add_argument("--config", required=True, help="a JSON file of the bus (BusConfig), or - for stdin")
    emd.add_argument("--die-with-stdin", action="store_true", help="also stop when stdin is closed")
    emd.set_defaults(func=cmd_emulate)
    return p


def cmd_compile(args: argparse.Namespace) -> int:
    from haptic_teleop.engine.warm import parse_names, warm

    try:
        names = parse_names(args.only)
    except ValueError as exc:
        raise InputError(f"--only: {exc}") from exc
    done = None if args.done_dir is None else Path(args.done_dir)
    if done is not None and not done.is_dir():
        raise InputError(f"--done-dir: {done} is not a directory")
    return warm(names, done)


def cmd_emulate(args: argparse.Namespace) -> int:
    from haptic_teleop.emulators.dynamixel.__main__ import main as emulate_dynamixel

    return emulate_dynamixel(["--config", args.config, *(["--die-with-stdin"] if args.die_with_stdin else [])])


def main(argv: list[str] | None = None) -> int:
    """The command line, for callers that imported this module (tests, scripts). The console script
    enters through `cli.entry.main`, which installs the signal handler before this module's
    imports and also ends quietly on a closed stdout."""
    restore = interrupt.install()
    try:
        return run_installed(argv)
    finally:
        restore()


def run_installed(argv: list[str] | None) -> int:
    """The command, with interrupt.install() already in place (`main` here, or cli.entry)."""
    command = None
    try:
        interrupt.pause_for_test("startup")
        args = build_parser().parse_args(argv)
        command = args.command
        code = int(args.func(args))
    except interrupt.Interrupted as exc:
        name = str(exc)
        if exc.abort:
            print("haptic-teleop: aborted by a second signal; outputs being written may be incomplete", file=sys.stderr)
        elif command in (None, "run", "analyze", "sweep", "scenes"):
            # these commands enter interrupt.finishing() before their first write
            print(f"haptic-teleop: interrupted ({name}) before anything was written", file=sys.stderr)
        else:
            print(f"haptic-teleop: interrupted ({name})", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:  # a SIGINT before the handler was installed, or raised by a library
        print("haptic-teleop: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except ConfigError as exc:
        print(f"haptic-teleop: config error: {exc}", file=sys.stderr)
        return exc.exit_code
    except BagError as exc:
        print(f"haptic-teleop: bag error: {exc}", file=sys.stderr)
        return exc.exit_code
    except HapticTeleopError as exc:
        print(f"haptic-teleop: {exc}", file=sys.stderr)
        return exc.exit_code
    signalled = interrupt.exit_code()
    if signalled is not None and code in (EXIT_OK, EXIT_INTERRUPTED):
        return signalled
    return code


if __name__ == "__main__":
    sys.exit(main())
