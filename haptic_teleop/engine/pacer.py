"""Wall-clock pacing for a run with a real device on a side: each tick starts at its deadline (the
engine's loop, engine/loop.py, waits on it); late ticks and overruns counted for timing.json,
never in the bag (docs/hardware_plant.md)."""

from __future__ import annotations

import os
import time


class Pacer:
    """Absolute deadlines for a loop that drives real devices: tick n starts no earlier than
    t0 + n T on `time.perf_counter`. The first tick starts the devices (connecting, checking,
    configuring: a long tick), so the clock is anchored at the start of the second: t0 = its start
    minus T. A tick that starts more than one period after its deadline is late: counted, never made
    up (the loop does not drop ticks to catch up; scene time stays n T, so the bag is the same
    however late the ticks were). An overrun is a tick that took longer than one period. The
    counts go into timing.json, never into the bag."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self._stall = stall_for_test()
        self.t0 = 0.0
        self.late_ticks = 0
        self.overrun_ticks = 0
        self.max_late_s = 0.0
        self.ticks = 0
        self._last = 0.0

    def wait(self, n: int) -> None:
        every, stall_s = self._stall
        if every and n >= 2 and n % every == 0:
            time.sleep(stall_s)  # tests: a stalled host, the torque held on (docs/eba_many_joints.md, "Late ticks")
        now = time.perf_counter()
        if n >= 2 and now - self._last > self.period_s:
            self.overrun_ticks += 1
        if n <= 1:
            self.t0 = now - n * self.period_s
        deadline = self.t0 + n * self.period_s
        if now < deadline:
            time.sleep(deadline - now)
            now = time.perf_counter()
        else:
            late = now - deadline
            if late > self.period_s:
                self.late_ticks += 1
            self.max_late_s = max(self.max_late_s, late)
        self._last = now
        self.ticks = n + 1

    def facts(self) -> dict[str, float | int]:
        """What timing.json gets: ticks paced, late ticks, overruns and the largest lateness (s)."""
        return {
            "paced_ticks": self.ticks,
            "late_ticks": self.late_ticks,
            "overrun_ticks": self.overrun_ticks,
            "max_late_s": self.max_late_s,
        }


STALL_ENV = "HAPTIC_TELEOP_TEST_STALL"


def stall_for_test() -> tuple[int, float]:
    """With HAPTIC_TELEOP_TEST_STALL=EVERY:SECONDS in the environment the paced loop sleeps SECONDS
    before every EVERY-th tick (a host that stalls while the devices hold their torque); (0, 0)
    otherwise."""
    every, _, seconds = os.environ.get(STALL_ENV, "").partition(":")
    return (int(every), float(seconds)) if every else (0, 0.0)
