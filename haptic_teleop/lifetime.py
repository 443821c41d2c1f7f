"""Child processes that do not outlive their parent.

Linux's `prctl(PR_SET_PDEATHSIG, sig)` asks the kernel to send `sig` to the calling process when
the thread that created it ends, whatever ends it (SIGKILL included). The bag writer and every
node the launcher starts ask for SIGTERM, which they handle as a clean stop (the recorder closes
its bag). Elsewhere it does nothing; those children then rely on end of file on their pipes and,
for the nodes, on a thread that watches the parent id (`follow_launcher`).
"""

from __future__ import annotations

import _signal  # type: ignore[import-not-found]  # built in; typeshed has no stub
import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any

_PR_SET_PDEATHSIG = 1
_MAIN = threading.main_thread()


def die_with_parent(sig: int = signal.SIGTERM) -> None:
    """Have `sig` delivered to this process when its parent (the thread that started it) ends."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)


LAUNCHER_PID_ENV = "HAPTIC_TELEOP_LAUNCHER_PID"


PARENT_POLL_S = 0.5
GRACE_S = 20.0


HARDWARE_NICE = -10
"""The niceness an emulator process asks for: the device it stands in for is its own processor,
which the host's scheduler never delays; at -10 a busy host's ordinary processes (nice 0) get
about a tenth of the CPU beside it (CFS weights 9548 : 1024), so the emulator keeps its reply
times as a device would."""


def as_hardware() -> bool:
    """Run this process at `HARDWARE_NICE` (never raising its niceness); False where not permitted
    (neither root nor CAP_SYS_NICE): it then shares the CPU as any process does."""
    import os

    try:
        if os.getpriority(os.PRIO_PROCESS, 0) > HARDWARE_NICE:
            os.setpriority(os.PRIO_PROCESS, 0, HARDWARE_NICE)
        return True
    except (OSError, AttributeError):
        return False


def follow_launcher() -> bool:
    """In a process the launcher started (it names its pid in LAUNCHER_PID_ENV): stop with it.

    Asks for SIGTERM on the parent's death, and starts a daemon thread that also watches the
    parent id: a SIGTERM that lands while the main thread is stuck inside a C call (DDS
    participant creation can block for seconds) is only handled when the call returns, so the
    watcher sends SIGTERM again once the parent is gone and ends the process (exit 143) if it
    has not stopped GRACE_S later. Returns False if the launcher is gone already; True otherwise,
    and when no launcher started this process."""
    import os
    import threading
    import time

    pid = os.environ.get(LAUNCHER_PID_ENV)
    if not pid:
        return True
    die_with_parent(signal.SIGTERM)
    if str(os.getppid()) != pid:
        return False

    def watch() -> None:
        while str(os.getppid()) == pid:
            time.sleep(PARENT_POLL_S)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(GRACE_S)
        os._exit(128 + signal.SIGTERM)

    threading.Thread(target=watch, name="launcher-watch", daemon=True).start()
    return True


@contextlib.contextmanager
def deadline(seconds: float, on_expiry: Callable[[], None]) -> Iterator[None]:
    """Call `on_expiry()` (from a daemon timer thread) if the body is still running `seconds` after
    it started; never once the body has ended. For steps that may block in code that is not ours
    (numba compiling, a DDS participant being torn down)."""
    import threading

    timer = threading.Timer(seconds, on_expiry)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


class signals_held:
    """Hold the Python handlers of `sigs` for the body: a signal that comes inside is recorded and
    handed to the handler that was in place once the body has ended (the default action sent
    again). For a write that must not be cut in half: a KeyboardInterrupt raised in the middle of a
    message to the bag writer leaves the pipe out of step, and the close that follows would wait
    for a reply that never comes. Main thread only (where Python runs handlers); elsewhere, and for
    ignored signals, it holds nothing.

    The recorder enters it a few times per block of ticks, so it swaps the handlers through the
    interpreter's built-in `_signal` (the `signal` module's wrappers build enums on every call:
    about 40 us an entry and exit against 5 us; docs/recording_costs.md, "In the loop")."""

    __slots__ = ("_got", "_previous", "_sigs")

    def __init__(self, sigs: tuple[int, ...] = (int(signal.SIGINT), int(signal.SIGTERM))) -> None:
        self._sigs = sigs
        self._previous: dict[int, Any] = {}
        self._got: list[int] = []

    def _note(self, signum: int, frame: Any) -> None:
        self._got.append(signum)

    def __enter__(self) -> None:
        if threading.current_thread() is not _MAIN:
            return
        for sig in self._sigs:
            handler = _signal.getsignal(sig)
            if handler == _signal.SIG_IGN or handler is None:
                continue
            self._previous[sig] = handler
            _signal.signal(sig, self._note)

    def __exit__(self, *exc: object) -> None:
        previous, self._previous = self._previous, {}
        for sig, handler in previous.items():
            _signal.signal(sig, handler)
        got, self._got = self._got, []
        for sig in got:
            handler = previous[sig]
            if callable(handler):
                handler(sig, None)
            else:  # SIG_DFL: the default action, now
                os.kill(os.getpid(), sig)
