"""Ctrl-C and SIGTERM for the command line: one path for both, at any moment of a command.

`install()` (first thing in `cli.main`) sets one handler for SIGINT and SIGTERM. What a signal
does depends on the phase the command is in:

- before anything is written (start-up, imports, scene loading, checks): it raises `Interrupted`
  at once; the command exits 130 (SIGINT) or 143 (SIGTERM) with one line and writes nothing.
- inside `finishing()` (from the moment an output directory is made: the loop, closing the bag,
  the summary, the plots): it only records the signal and calls the stop callbacks (the engine's
  `request_stop`), so the loop ends at the end of its tick and everything after it is still
  written for the ticks that ran; the command then exits 130 or 143.
- a second signal in any phase raises `Interrupted(abort=True)` at once: the command stops
  where it is, without a traceback, saying what may be incomplete.

The handler writes with `os.write`, never `print`: a signal that lands while the main thread is
writing to stderr (the progress bar) must not re-enter that buffered stream.

`pause_for_test(phase)` lets the tests deliver a signal in a chosen phase without sleeping: with
HAPTIC_TELEOP_TEST_PAUSE=PHASE[:N] in the environment the command prints `haptic-teleop: phase
PHASE` to stderr there and waits until N signals came. It does nothing otherwise.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from types import FrameType
from typing import Any

EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}
TEST_PAUSE_ENV = "HAPTIC_TELEOP_TEST_PAUSE"


class Interrupted(KeyboardInterrupt):
    """A SIGINT or SIGTERM stopped the command; `abort` when it was the second one."""

    def __init__(self, signum: int, abort: bool = False) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.abort = abort

    @property
    def exit_code(self) -> int:
        return EXIT_CODES.get(signal.Signals(self.signum), 128 + self.signum)


class _State:
    def __init__(self) -> None:
        self.owner = os.getpid()
        self.signals: list[int] = []
        self.finishing = 0
        self.stop_callbacks: list[Callable[[], None]] = []
        self.installed = False


_state = _State()


def _say(text: str) -> None:
    with suppress(OSError):
        os.write(2, f"haptic-teleop: {text}\n".encode())


def _handler(signum: int, frame: FrameType | None) -> None:
    if os.getpid() != _state.owner:
        return  # a forked child (the bag writer) inherited this handler: its parent finishes the bag
    _state.signals.append(signum)
    name = signal.Signals(signum).name
    if len(_state.signals) > 1:
        raise Interrupted(_state.signals[0], abort=True)
    for stop in list(_state.stop_callbacks):
        stop()
    if _state.finishing:
        _say(f"{name}: stopping; what ran is still written (bag, summary, plots); a second signal aborts now")
        return
    raise Interrupted(signum)


def _unraisable_hook(previous: Callable[[Any], object]) -> Callable[[Any], object]:
    """`sys.unraisablehook` that keeps quiet about an `Interrupted` raised where Python ignores
    exceptions (a finalizer, a weakref callback such as importlib's module locks): the signal is
    recorded already, and the command stops at its next check (`on_stop` calls a callback at
    once for a signal that came before it). Anything else goes to the hook before it."""

    def hook(args: Any) -> object:
        if isinstance(args.exc_value, Interrupted):
            return None
        return previous(args)

    return hook


def install() -> Callable[[], None]:
    """Handle SIGINT and SIGTERM alike from now on (the first thing `main` does); returns a
    function that puts the previous handlers back (for `main` called in a process that has its own)."""
    _state.__init__()  # type: ignore[misc]
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _unraisable_hook(previous_hook)
    for sig in previous:
        signal.signal(sig, _handler)
    _state.installed = True

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        sys.unraisablehook = previous_hook
        _state.installed = False

    return restore


def received() -> int | None:
    """The first signal received since `install`, or None."""
    return _state.signals[0] if _state.signals else None


def exit_code() -> int | None:
    sig = received()
    return None if sig is None else EXIT_CODES.get(signal.Signals(sig), 128 + sig)


@contextmanager
def finishing() -> Iterator[None]:
    """A phase where the first signal stops the loop but lets the outputs be written."""
    _state.finishing += 1
    try:
        yield
    finally:
        _state.finishing -= 1


@contextmanager
def on_stop(callback: Callable[[], None]) -> Iterator[None]:
    """Call `callback` when a signal comes while inside (at once if one came already)."""
    _state.stop_callbacks.append(callback)
    try:
        if _state.signals:
            callback()
        yield
    finally:
        _state.stop_callbacks.remove(callback)


def pause_for_test(phase: str) -> None:
    """With HAPTIC_TELEOP_TEST_PAUSE=PHASE[:N]: say the phase on stderr and wait there for N
    signals (default 1)."""
    want, _, count = os.environ.get(TEST_PAUSE_ENV, "").partition(":")
    if want != phase:
        return
    seen = len(_state.signals)
    _say(f"phase {phase}")
    deadline = time.monotonic() + 120.0
    while len(_state.signals) < seen + int(count or 1) and time.monotonic() < deadline:
        time.sleep(0.005)
