"""Child processes that do not outlive their parent.

Linux's `prctl(PR_SET_PDEATHSIG, sig)` asks the kernel to send `sig` to the calling process when
the thread that created it ends, whatever ends it (SIGKILL included). The bag writer and every
node the launcher starts ask for SIGTERM, which they handle as a clean stop (the recorder closes
its bag). Elsewhere it does nothing; those children then rely on end of file on their pipes.
"""

from __future__ import annotations

import contextlib
import signal
import sys

_PR_SET_PDEATHSIG = 1


def die_with_parent(sig: int = signal.SIGTERM) -> None:
    """Have `sig` delivered to this process when its parent (the thread that started it) ends."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)


LAUNCHER_PID_ENV = "HAPTIC_TELEOP_LAUNCHER_PID"


def follow_launcher() -> bool:
    """In a process the launcher started (it names its pid in LAUNCHER_PID_ENV): stop with it.

    Asks for SIGTERM on the parent's death and returns False if the launcher is gone already
    (it died before the request was made); True otherwise, and when no launcher started us."""
    import os

    pid = os.environ.get(LAUNCHER_PID_ENV)
    if not pid:
        return True
    die_with_parent(signal.SIGTERM)
    return str(os.getppid()) == pid
