"""`haptic-teleop bench NAME`: benchmarks that print figures (never asserted in tests).

Each module in this package is one benchmark with `add_arguments(parser)` and `main(args) -> int`.
The table below is the only place that lists them, so the CLI needs no change when one is added.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

BENCHMARKS = {
    "speed": "haptic_teleop.benchmarks.speed",
    "live": "haptic_teleop.benchmarks.live",
    "effects": "haptic_teleop.benchmarks.effects",
    "network": "haptic_teleop.benchmarks.network",
    "accuracy": "haptic_teleop.benchmarks.accuracy",
    "memory": "haptic_teleop.benchmarks.memory",
    "recording": "haptic_teleop.benchmarks.recording",
    "hardware": "haptic_teleop.benchmarks.hardware",
    "codec": "haptic_teleop.benchmarks.codec",
    "sweep": "haptic_teleop.benchmarks.sweep",
}


def add_scene_argument(p: Any, help: str = "scene YAML path or bundled name") -> None:
    p.add_argument("--scene", default="wall_contact", help=help)


def positive(kind: type[int] | type[float]) -> Callable[[str], Any]:
    """An argparse type: a number of `kind` > 0 (argparse turns a refusal into one line, exit 2)."""

    allowed = f"allowed: {'a whole number' if kind is int else 'a number'} > 0"

    def parse(text: str) -> Any:
        import argparse

        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number; {allowed}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"{text} is not > 0; {allowed}")
        return value

    parse.__name__ = f"positive {kind.__name__}"
    return parse
