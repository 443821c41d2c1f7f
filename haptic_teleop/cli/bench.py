"""`haptic-teleop bench NAME`: benchmarks that print figures (never asserted in tests).

Each benchmark is a module of studies/benchmarks/ with `HELP`, `add_arguments(parser)` and
`main(args) -> int`; the table below is the only place that lists them.
"""

from __future__ import annotations

import argparse
import importlib

BENCHMARKS = {
    "speed": "haptic_teleop.studies.benchmarks.speed",
    "live": "haptic_teleop.studies.benchmarks.live",
    "effects": "haptic_teleop.studies.benchmarks.effects",
    "network": "haptic_teleop.studies.benchmarks.network",
    "accuracy": "haptic_teleop.studies.benchmarks.accuracy",
    "memory": "haptic_teleop.studies.benchmarks.memory",
    "recording": "haptic_teleop.studies.benchmarks.recording",
    "hardware": "haptic_teleop.studies.benchmarks.hardware",
    "codec": "haptic_teleop.studies.benchmarks.codec",
    "sweep": "haptic_teleop.studies.benchmarks.batch_scale",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    """One subcommand per benchmark on `p` (the `bench` parser)."""
    sub = p.add_subparsers(dest="what", required=True, metavar="NAME")
    for name, module in BENCHMARKS.items():
        mod = importlib.import_module(module)
        bp = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(bp)
        bp.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    return int(importlib.import_module(BENCHMARKS[args.what]).main(args))
