"""The Markov loss chains' runs over a window, compiled (numba) from their one definition
(core/loss.py `gilbert_run`, `four_state_run`, and the per-packet steps they call), for the
compiled loop's vectorized network schedule (axis_host.VectorizedSchedule hands them to
`Link.schedule_all`). A chain is sequential (each packet's state depends on the last), so the
plain functions run a packet at a time in the interpreter: about 0.5 us a packet, against some
nanoseconds compiled.
"""

from __future__ import annotations

from typing import Any

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import loss

RUNS: dict[str, Any] = {
    "gilbert_run": compile_tree(loss.gilbert_run),
    "four_state_run": compile_tree(loss.four_state_run),
}


def warm() -> None:
    """Compile (or load from numba's cache) both runs now, on a packet each."""
    import numpy as np

    lost = np.zeros(1, dtype=np.bool_)
    RUNS["gilbert_run"](False, np.zeros(2), 0.1, 0.2, 0.5, 0.0, lost)
    RUNS["four_state_run"](1, np.zeros(1), 0.1, 0.2, 0.3, 0.4, 0.1, lost)
