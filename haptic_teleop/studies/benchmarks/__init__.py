"""The benchmarks of `haptic-teleop bench NAME` (cli/bench.py lists them): figures printed, never
asserted in tests. Each module is one benchmark with `HELP`, `add_arguments(parser)` and
`main(args) -> int`; this package's own helpers are their shared arguments."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


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
