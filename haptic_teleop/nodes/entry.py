"""The nodes' entry: their console scripts (`master_eba`, `recorder`, ...: `entry:<executable>`)
and the launcher's processes (`python -m haptic_teleop.nodes.entry EXECUTABLE --ros-args ...`):
nothing but the standard library before a Ctrl-C or SIGTERM is noted rather than CPython's.

A launcher that stops every node because one failed (a hardware fault at start, say) sends SIGINT
to nodes that may still be importing rclpy, numpy or MuJoCo. CPython's own handler then raises
KeyboardInterrupt inside an import: a traceback and exit -2, where the nodes already running exit
0. Here the signal is only noted, from this module's first line (the built-in `_signal`: no import
to run), and `base.run_nodes` ends the process with 0 and one line before it builds anything.
Only when the process is a node's (its console script's argv[0], or this module run as `-m`), so
that a program importing this module keeps its own signal handling.
"""

from __future__ import annotations

import _signal  # type: ignore[import-not-found]  # built in; typeshed has no stub
import os
import sys
from collections.abc import Callable

from haptic_teleop.nodes import EXECUTABLES

EARLY: list[int] = []  # signals that came before run_nodes took over


def _note(signum: int, frame: object) -> None:
    EARLY.append(signum)


if __name__ == "__main__":  # `python -m haptic_teleop.nodes.entry EXECUTABLE ...` (the launcher's)
    sys.modules.setdefault("haptic_teleop.nodes.entry", sys.modules[__name__])  # one EARLY for run_nodes
if __name__ == "__main__" or os.path.basename(sys.argv[0] if sys.argv else "") in EXECUTABLES:
    for _sig, _default in ((_signal.SIGINT, _signal.default_int_handler), (_signal.SIGTERM, _signal.SIG_DFL)):
        if _signal.getsignal(_sig) == _default:
            _signal.signal(_sig, _note)


def _run(executable: str) -> None:
    import importlib

    importlib.import_module(EXECUTABLES[executable]).main()


def __getattr__(name: str) -> Callable[[], None]:
    """`entry.<executable>`: that node's `main` (console_scripts: `master_eba = ...entry:master_eba`)."""
    if name in EXECUTABLES:
        return lambda: _run(name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] not in EXECUTABLES:
        print(f"usage: python -m {__spec__.name if __spec__ else 'entry'} EXECUTABLE [--ros-args ...]; "
              f"EXECUTABLE one of {', '.join(EXECUTABLES)}", file=sys.stderr)  # fmt: skip
        sys.exit(2)
    _executable = sys.argv.pop(1)
    _run(_executable)
