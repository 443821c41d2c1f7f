"""The runs over a window that `Link.schedule_all` hands to its effects, compiled (numba) from
their one definition: the loss rules' (core/loss.py: the Markov chains' `gilbert_run` and
`four_state_run`, the netem-correlated Bernoulli loss's `bernoulli_run`, the replayed pattern's
`trace_run`) and the delay's (core/delay.py `delay_run`: jitter, netem reordering and the
time-varying part `profile_run` gives;
`token_run`: a rate limit's queue), with the per-packet steps they call, for the compiled loop's
vectorized network schedule (axis_host.VectorizedSchedule and buffer_schedule.BufferedSchedule hand them to
`Link.schedule_all`). Each is sequential (a packet's state or arrival depends on the last), so
the plain functions run a packet at a time in the interpreter: about 0.5 us a packet, against
some nanoseconds compiled.
"""

from __future__ import annotations

from typing import Any

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import delay, loss

RUNS: dict[str, Any] = {
    "gilbert_run": compile_tree(loss.gilbert_run),
    "four_state_run": compile_tree(loss.four_state_run),
    "bernoulli_run": compile_tree(loss.bernoulli_run),
    "trace_run": compile_tree(loss.trace_run),
    "delay_run": compile_tree(delay.delay_run),
    "profile_run": compile_tree(delay.profile_run),
    "token_run": compile_tree(delay.token_run),
}


def warm() -> None:
    """Compile (or load from numba's cache) the runs now, on a packet each (with the argument types
    the effects' `apply_all` pass)."""
    import numpy as np

    lost = np.zeros(1, dtype=np.bool_)
    RUNS["gilbert_run"](False, np.zeros(2), 0.1, 0.2, 0.5, 0.0, lost)
    RUNS["four_state_run"](1, np.zeros(1), 0.1, 0.2, 0.3, 0.4, 0.1, lost)
    RUNS["bernoulli_run"](np.zeros(1), 0.25, 0.5, 0.1, lost)
    RUNS["trace_run"](np.ones(2), 0, True, lost)
    arrivals, delivered = np.zeros(1, dtype=np.int64), np.ones(1, dtype=np.bool_)
    RUNS["delay_run"](
        arrivals, delivered, np.zeros(1), 0.25, 0.5, np.zeros(2), 2, 1e6, 1e5, True, 0,
        np.zeros(1), 0.25, 0.5, 0.1, 3, 0, np.zeros(1),
    )  # fmt: skip
    out = np.zeros(1)
    RUNS["profile_run"](
        delay.PROFILE_PIECEWISE, np.zeros(2, dtype=np.int64), np.zeros(2), True, 0.0, 0.0, 0.0, 0.0, arrivals, out
    )
    tokens = np.zeros(delay.TB_SIZE, dtype=np.int64)
    RUNS["token_run"](tokens, np.zeros(1, dtype=np.int64), arrivals, lost, delivered, 8, 16, 1, 1)
