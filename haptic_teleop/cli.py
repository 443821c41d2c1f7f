"""`haptic-teleop run | analyze | bench`: the command line."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from haptic_teleop.errors import BagError, ConfigError, HapticTeleopError

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
TIMING_FILE = "timing.json"


def _json_default(o: Any) -> Any:
    return None if isinstance(o, float) and math.isnan(o) else str(o)


def _clean(summary: dict[str, Any]) -> dict[str, Any]:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in summary.items()}


def write_outputs(bag_dir: Path, out_dir: Path, plots: bool = True) -> dict[str, Any]:
    """Analyse a bag: summary.json and plots/ in out_dir. Same code for `run` and `analyze`."""
    from haptic_teleop.analysis.metrics import analyze_bag

    summary, sig = analyze_bag(bag_dir)
    timing = Path(bag_dir).parent / TIMING_FILE
    if timing.is_file():
        t = json.loads(timing.read_text())
        summary["realtime_factor"] = t["realtime_factor"]
        summary["engine_loop"] = t.get("loop", "python")
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "summary.json").write_text(json.dumps(_clean(summary), indent=2, sort_keys=True) + "\n")
    if plots:
        from haptic_teleop.analysis.plots import write_plots

        write_plots(sig, out_dir / "plots")
    return summary


def default_out(scene_name: str) -> Path:
    base = Path("runs")
    i = 1
    while (base / f"{scene_name}-{i:03d}").exists():
        i += 1
    return base / f"{scene_name}-{i:03d}"


def cmd_run(args: argparse.Namespace) -> int:
    from haptic_teleop.report import format_summary
    from haptic_teleop.scene import find_scene, load_scene

    scene = load_scene(find_scene(args.scene), overrides=args.set or (), seed=args.seed)
    out = Path(args.out) if args.out else default_out(scene.config.scene.name)
    if out.exists() and any(out.iterdir()):
        raise HapticTeleopError(f"output directory {out} exists and is not empty; choose another --out")
    from haptic_teleop.engine import record_run

    total = int(round(scene.config.scene.duration_s / scene.config.scene.period_s))
    bar = None
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
    last = [0]

    def progress(n: int) -> None:
        if bar is not None:
            bar.update(n - last[0])
            last[0] = n

    out.mkdir(parents=True, exist_ok=True)
    bag_dir = out / "bag"
    try:
        _, timing = record_run(scene, bag_dir, progress=progress, loop=args.loop)
    finally:
        if bar is not None:
            bar.close()
    # Timing lives beside the bag, not in it, so the same scene and seed give the same bag bytes.
    (out / TIMING_FILE).write_text(json.dumps(timing.as_dict(), indent=2, sort_keys=True) + "\n")
    summary = write_outputs(bag_dir, out, plots=not args.no_plots)
    print(format_summary(summary))
    print(
        f"\nbag:     {bag_dir}\nsummary: {out / 'summary.json'}"
        + ("" if args.no_plots else f"\nplots:   {out / 'plots'}")
    )
    return EXIT_INTERRUPTED if timing.interrupted else EXIT_OK


def cmd_analyze(args: argparse.Namespace) -> int:
    from haptic_teleop.report import format_summary

    bag = Path(args.bag)
    out = Path(args.out) if args.out else (bag.parent if (bag / "metadata.yaml").exists() else bag)
    summary = write_outputs(bag, out, plots=not args.no_plots)
    print(format_summary(summary))
    print(f"\nsummary: {out / 'summary.json'}")
    return EXIT_OK


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


def cmd_bench(args: argparse.Namespace) -> int:
    import importlib

    from haptic_teleop.benchmarks import BENCHMARKS

    return int(importlib.import_module(BENCHMARKS[args.what]).main(args))


def cmd_launch(args: argparse.Namespace) -> int:
    from haptic_teleop.launcher import launch_main

    return launch_main(args)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="haptic-teleop", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="simulate a scene in deterministic simulated time; write bag, summary, plots")
    r.add_argument("scene", help="scene YAML path, or a bundled scene name (e.g. wall_contact)")
    r.add_argument("--out", help="output directory (default runs/<scene>-NNN)")
    r.add_argument("--seed", type=int, help="override scene.seed")
    r.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override any scene key (repeatable)")
    r.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument(
        "--loop",
        choices=("auto", "compiled", "python"),
        default="auto",
        help="tick loop: compiled (numba) or python; both give the same bag (auto: compiled if the scene allows)",
    )
    r.set_defaults(func=cmd_run)

    a = sub.add_parser("analyze", help="metrics, summary.json and plots from a bag alone")
    a.add_argument("bag", help="rosbag2 directory")
    a.add_argument("--out", help="where summary.json and plots/ go (default: next to the bag)")
    a.add_argument("--no-plots", action="store_true")
    a.set_defaults(func=cmd_analyze)

    bg = sub.add_parser("bag", help="info BAG: topics, counts, QoS, integrity; recover BAG: rebuild a cut bag")
    bg.add_argument("action", choices=("info", "recover"))
    bg.add_argument("bag", help="rosbag2 directory (or its .mcap file)")
    bg.set_defaults(func=cmd_bag)

    from haptic_teleop import sweep

    sw = sub.add_parser("sweep", help="run every combination of parameter values and seeds; table, CSV, plot")
    sweep.add_arguments(sw)
    sw.set_defaults(func=sweep.main)

    b = sub.add_parser("bench", help="benchmarks that print figures")
    bsub = b.add_subparsers(dest="what", required=True, metavar="NAME")
    import importlib

    from haptic_teleop.benchmarks import BENCHMARKS

    for name, module in BENCHMARKS.items():
        mod = importlib.import_module(module)
        bp = bsub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(bp)
        bp.set_defaults(func=cmd_bench)

    from haptic_teleop.launcher import add_arguments as add_launch_arguments

    la = sub.add_parser("launch", help="run a scene live: ROS 2 nodes as processes over DDS")
    add_launch_arguments(la)
    la.set_defaults(func=cmd_launch)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except ConfigError as exc:
        print(f"haptic-teleop: config error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BagError as exc:
        print(f"haptic-teleop: bag error: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except HapticTeleopError as exc:
        print(f"haptic-teleop: {exc}", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
