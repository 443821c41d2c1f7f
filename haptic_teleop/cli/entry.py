"""The `haptic-teleop` console script's entry: nothing but the standard library before the signal
handler is in place.

`main` installs the Ctrl-C/SIGTERM handler (interrupt.py, standard library only) before it imports
the command line (numpy, the analysis, the parser): a signal that lands while those imports run is
the same `Interrupted` as one in any later phase, exit 130 or 143 and one line, never a traceback
from inside an import. Output cut by a closed pipe (`haptic-teleop bag info BAG | head`) ends the
command quietly with 141, the code a shell shows for a tool ended by SIGPIPE.

Before this module runs, a signal is CPython's: killed by the signal (a shell shows 130 or 143),
or in its own start-up (site import, tens of milliseconds) "Fatal Python error: init_..." with exit
1, or a KeyboardInterrupt at the console script's import line (README, "Exit codes").
"""

from __future__ import annotations

# The console script's first import of this package is this module: from here until main()
# installs the handler, a signal is only noted (and acted on by main at once). Only when the
# process is the console script (its argv[0]), so a program that imports this module keeps its own
# signal handling. The early handler is set through the interpreter's built-in `_signal` (no import
# to run: `os` and `sys` are loaded before any script, and `signal` itself builds enums for tens of
# microseconds, long enough for a Ctrl-C to land inside it with a traceback, seen in CI).
# The statements before the handler is set are kept to the fewest and no Python-level call (the
# check is C string methods): a signal landing in them is CPython's KeyboardInterrupt at this
# module's first lines, the one window no Python code can close (README, "Exit codes").
import _signal  # type: ignore[import-not-found]  # built in; typeshed has no stub
import sys

_EARLY: list[int] = []


def _note(signum: int, frame: object) -> None:
    _EARLY.append(signum)


_ARGV0 = sys.argv[0] if sys.argv else ""
if _ARGV0 == "haptic-teleop" or _ARGV0.endswith("/haptic-teleop"):
    for _sig, _default in ((_signal.SIGINT, _signal.default_int_handler), (_signal.SIGTERM, _signal.SIG_DFL)):
        if _signal.getsignal(_sig) == _default:
            _signal.signal(_sig, _note)

import os  # noqa: E402 (after the early handler)
import signal  # noqa: E402 (after the early handler)

from haptic_teleop import interrupt  # noqa: E402 (after the early handler: standard library only)

EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE


def main(argv: list[str] | None = None) -> int:
    restore = interrupt.install()
    try:
        try:
            if _EARLY:  # a signal before install(): handled as one that came now
                os.kill(os.getpid(), _EARLY[0])
            from haptic_teleop.cli.main import run_installed

            return run_installed(argv)
        except interrupt.Interrupted as exc:  # during the import above
            print(f"haptic-teleop: interrupted ({exc}) before anything was written", file=sys.stderr)
            return exc.exit_code
        except KeyboardInterrupt:
            print("haptic-teleop: interrupted", file=sys.stderr)
            return interrupt.EXIT_CODES[signal.SIGINT]
        except BrokenPipeError:
            return _quiet_broken_pipe()
        except Exception:
            # A library may turn the interrupt that landed inside it into an error of its own (an
            # extension module's import: "ImportError: initialization failed"): after a signal,
            # that is the signal's doing, not a failure to report with a traceback.
            code = interrupt.exit_code()
            if code is None:
                raise
            print("haptic-teleop: interrupted before anything was written", file=sys.stderr)
            return code
    finally:
        restore()


def _quiet_broken_pipe() -> int:
    """The reader of stdout went away: point stdout at /dev/null so that the interpreter's own
    flush at exit does not raise again, and end with 141."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    return EXIT_BROKEN_PIPE
