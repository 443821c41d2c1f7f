"""Argument parsing shared by the experiments: one-line errors, checked numbers."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from typing import NoReturn


class OneLineParser(argparse.ArgumentParser):
    """An experiment's argument parser: a bad argument is one line on stderr and exit 2 (no usage
    block, no traceback), like every other bad input of the command line."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"haptic-teleop: {self.prog.removeprefix('haptic-teleop ')}: {message}\n")

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        """An experiment takes no argument it does not know: say so here, in one line (argparse
        would hand them up to the top-level parser, which prints its usage block)."""
        ns, extras = super().parse_known_args(args, namespace)
        if extras and self._subparsers is None:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return ns, extras


def subset(text: str, allowed: Sequence[str], flag: str) -> list[str]:
    """An experiment's comma-separated choice among `allowed`; anything else is one line naming
    the flag, what was given and what is allowed."""
    from haptic_teleop.errors import InputError

    names = [c.strip() for c in text.split(",") if c.strip()]
    if not names or any(c not in allowed for c in names):
        raise InputError(f"{flag} {text}: allowed: a comma-separated subset of {', '.join(allowed)}")
    return names


def number(
    low: float, high: float, low_open: bool = False, kind: type[int] | type[float] = float
) -> Callable[[str], float]:
    """An argparse type: a finite number in [low, high] (or (low, high] when `low_open`); a bad
    value names itself and what is allowed."""
    lo = f"> {low:g}" if low_open else f">= {low:g}"
    allowed = f"allowed: {'a whole number' if kind is int else 'a number'} {lo} and <= {high:g}"

    def parse(text: str) -> float:
        try:
            x = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number; {allowed}") from None
        if not math.isfinite(x) or x < low or (low_open and x == low) or x > high:
            raise argparse.ArgumentTypeError(f"{text}: {allowed}")
        return x

    return parse
