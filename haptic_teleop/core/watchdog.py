"""Remote-data watchdog: stale remote samples fade the controller's force to zero, and back.

Pure (time is passed in): the live nodes use it; the engine does not need it, since its links
are lockstep. The bound it guarantees is derived in docs/live.md.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any


class Watchdog:
    """Age of the newest remote arrival -> a gain in [0, 1] that fades force out and back in.

    While the last arrival is at most `timeout_ns` old the gain rises by period/fade per tick up
    to 1; once it is older the gain falls by the same step down to 0. So the force is zero at
    most timeout + fade + one period after the last arrival (the bound in docs/live.md), and it
    comes back over `fade_ns` when data returns. Before the first arrival the gain is 0.
    """

    __slots__ = ("_fresh", "_step", "fade_ns", "gain", "last_arrival_ns", "timeout_ns", "trips")

    def __init__(self, timeout_ns: int, fade_ns: int, period_ns: int) -> None:
        if timeout_ns <= 0 or fade_ns < 0 or period_ns <= 0:
            raise ValueError("watchdog needs timeout_ns > 0, fade_ns >= 0, period_ns > 0")
        self.timeout_ns = timeout_ns
        self.fade_ns = fade_ns
        self._step = 1.0 if fade_ns == 0 else min(1.0, period_ns / fade_ns)
        self.gain = 0.0
        self.last_arrival_ns: int | None = None
        self.trips = 0  # fresh -> stale transitions
        self._fresh = False

    def feed(self, arrival_ns: int) -> None:
        self.last_arrival_ns = arrival_ns

    def update(self, now_ns: int) -> float:
        last = self.last_arrival_ns
        fresh = last is not None and now_ns - last <= self.timeout_ns
        if fresh:
            g = self.gain + self._step
            self.gain = 1.0 if g > 1.0 else g
        else:
            if self._fresh:
                self.trips += 1
            g = self.gain - self._step
            self.gain = 0.0 if g < 1e-12 else g
        self._fresh = fresh
        return self.gain

    @property
    def stale(self) -> bool:
        return not self._fresh

    def bound_s(self, period_s: float) -> float:
        """Longest time from the last arrival to zero force."""
        return self.timeout_ns * 1e-9 + self.fade_ns * 1e-9 + period_s


class ForceFade:
    """Applies a watchdog gain to a TeleopController by lowering its saturation limit.

    The limit acts before the energy bound, so the reservoir accounts for exactly the force that
    is applied (scaling the output afterwards would not). At gain 0 the limit is the smallest
    positive float: the commanded force is zero for every practical purpose.
    """

    __slots__ = ("_base", "_ctrl", "_gain")

    def __init__(self, controller: Any) -> None:
        self._ctrl = controller
        self._base = controller.params
        self._gain = 1.0

    def set_gain(self, gain: float) -> None:
        if gain == self._gain:
            return
        self._gain = gain
        if gain >= 1.0:
            self._ctrl.params = self._base
        else:
            limit = max(self._base.force_limit_n * gain, math.ulp(0.0))
            self._ctrl.params = dataclasses.replace(self._base, force_limit_n=limit)
