"""Sensor and actuator effects of one plant side: pure, seeded discrete-time objects.

Each object works on the per-axis lists of floats the `Plant` protocol uses and is called once
per control period. Measurement effects (`GaussianNoise`, `Quantizer`, `LowPassFilter`,
`MovingAverage`) map a true value to the value a sensor reports; `ActuatorLimit` maps a
commanded force to the force the actuator really applies (which the caller must report as
applied). Physical effects (gravity, friction) are not here: they act inside the simulator.

Randomness: every random effect draws from its own `numpy.random.Generator`, made by
`sensing_rng(seed, side, effect)` from the scene seed, the side ("master"/"slave") and the
effect's name, so naming one more effect never changes another's draws. The laws and their
discretisation are in docs/effects.md.
"""

from __future__ import annotations

import math
import zlib
from collections import deque
from collections.abc import Callable

import numpy as np

_BLOCK = 4096  # normal numbers drawn per numpy call: a numpy call per tick costs about 1 us


def sensing_rng(seed: int, side: str, effect: str) -> np.random.Generator:
    """An independent random stream for one sensing effect of one side of one run.

    The spawn key starts with crc32("sensing"), so these streams never coincide with the network
    effects' streams (`core.uniform.effect_rng`, keyed by direction and effect)."""
    key = (zlib.crc32(b"sensing"), zlib.crc32(side.encode()), zlib.crc32(effect.encode()))
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


class GaussianNoise:
    """Adds zero-mean Gaussian noise with standard deviation `std` (in the signal's SI unit) to
    every axis; the normal numbers are drawn from `rng` in blocks."""

    __slots__ = ("_it", "_rng", "name", "std")

    def __init__(self, std: float, rng: np.random.Generator, name: str = "noise") -> None:
        if not (std > 0.0 and math.isfinite(std)):
            raise ValueError(f"noise std must be a finite number > 0, got {std}")
        self.std = std
        self.name = name
        self._rng = rng
        self._it: Callable[[], float] = iter(()).__next__

    def _normal(self) -> float:
        try:
            return float(self._it())
        except StopIteration:
            self._it = iter(self._rng.standard_normal(_BLOCK).tolist()).__next__
            return float(self._it())

    def apply(self, values: list[float]) -> list[float]:
        s = self.std
        if len(values) == 1:  # the common one-axis case, without a comprehension
            try:
                z: float = self._it()
            except StopIteration:
                z = self._normal()
            return [values[0] + s * z]
        return [x + s * self._normal() for x in values]


class Quantizer:
    """Encoder quantization: reports `resolution * round(x / resolution)` (round half to even),
    so the error is within +-resolution/2 and the reported values are whole counts."""

    __slots__ = ("name", "resolution")

    def __init__(self, resolution: float, name: str = "encoder") -> None:
        if not (resolution > 0.0 and math.isfinite(resolution)):
            raise ValueError(f"encoder resolution must be a finite number > 0, got {resolution}")
        self.resolution = resolution
        self.name = name

    def apply(self, values: list[float]) -> list[float]:
        r = self.resolution
        if len(values) == 1:
            return [r * round(values[0] / r)]
        return [r * round(x / r) for x in values]


class LowPassFilter:
    """First-order low-pass with cutoff `cutoff_hz` (time constant tau = 1 / (2 pi f_c)),
    discretised exactly for an input held constant over each period that ends at the sample:

        y(n) = a y(n-1) + (1 - a) u(n),   a = exp(-T / tau)

    so a unit step applied at sample 0 gives y(n) = 1 - exp(-(n + 1) T / tau), the continuous
    filter's response sampled exactly. The state starts at the first input (no start-up
    transient from zero)."""

    __slots__ = ("_a", "_b", "_y", "cutoff_hz", "name", "period_s")

    def __init__(self, cutoff_hz: float, period_s: float, name: str = "lowpass") -> None:
        if not (cutoff_hz > 0.0 and math.isfinite(cutoff_hz)):
            raise ValueError(f"cutoff_hz must be a finite number > 0, got {cutoff_hz}")
        if not period_s > 0.0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.cutoff_hz = cutoff_hz
        self.period_s = period_s
        self.name = name
        self._a = math.exp(-2.0 * math.pi * cutoff_hz * period_s)
        self._b = 1.0 - self._a
        self._y: list[float] | None = None

    @property
    def time_constant_s(self) -> float:
        return 1.0 / (2.0 * math.pi * self.cutoff_hz)

    def apply(self, values: list[float]) -> list[float]:
        y = self._y
        if y is None:
            y = list(values)
        elif len(y) == 1 and len(values) == 1:
            y = [self._a * y[0] + self._b * values[0]]
        else:
            a, b = self._a, self._b
            y = [a * yi + b * u for yi, u in zip(y, values, strict=True)]
        self._y = y
        return list(y)


class MovingAverage:
    """Mean of the last `window_samples` inputs (fewer while the window fills up). Its delay on
    a ramp is (window_samples - 1) / 2 periods."""

    __slots__ = ("_buf", "_sum", "name", "window_samples")

    def __init__(self, window_samples: int, name: str = "moving_average") -> None:
        if window_samples < 1:
            raise ValueError(f"window_samples must be >= 1, got {window_samples}")
        self.window_samples = window_samples
        self.name = name
        self._buf: deque[list[float]] = deque()
        self._sum: list[float] | None = None

    def apply(self, values: list[float]) -> list[float]:
        buf = self._buf
        s = self._sum
        if s is None:
            s = [0.0] * len(values)
        s = [a + b for a, b in zip(s, values, strict=True)]
        buf.append(list(values))
        if len(buf) > self.window_samples:
            old = buf.popleft()
            s = [a - b for a, b in zip(s, old, strict=True)]
        self._sum = s
        n = len(buf)
        return [a / n for a in s]


class ActuatorLimit:
    """Actuator saturation: the commanded force is clipped to +-`force_limit_n`, then the change
    from the force applied over the previous period is limited to `slew_rate_n_per_s * T`
    (the actuator starts at rest, 0 N). `apply` returns the force the actuator applies; a NaN
    command applies the previous force moved toward 0 N, never NaN.

    Either limit may be None (not applied); at least one must be given."""

    __slots__ = ("_last", "_max_step", "force_limit_n", "name", "slew_rate_n_per_s")

    def __init__(
        self,
        period_s: float,
        axes: int,
        force_limit_n: float | None = None,
        slew_rate_n_per_s: float | None = None,
        name: str = "saturation",
    ) -> None:
        if force_limit_n is None and slew_rate_n_per_s is None:
            raise ValueError("actuator saturation needs force_limit_n, slew_rate_n_per_s or both")
        if force_limit_n is not None and not force_limit_n > 0.0:
            raise ValueError(f"force_limit_n must be > 0, got {force_limit_n}")
        if slew_rate_n_per_s is not None and not slew_rate_n_per_s > 0.0:
            raise ValueError(f"slew_rate_n_per_s must be > 0, got {slew_rate_n_per_s}")
        if not period_s > 0.0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.force_limit_n = force_limit_n
        self.slew_rate_n_per_s = slew_rate_n_per_s
        self.name = name
        self._max_step = None if slew_rate_n_per_s is None else slew_rate_n_per_s * period_s
        self._last = [0.0] * axes

    def apply(self, force_n: list[float]) -> list[float]:
        lim = self.force_limit_n
        step = self._max_step
        last = self._last
        if len(force_n) == 1 and len(last) == 1:  # one axis: the same arithmetic on floats
            f = force_n[0]
            if math.isnan(f):
                f = 0.0
            if lim is not None:
                f = lim if f > lim else (-lim if f < -lim else f)
            if step is not None:
                lo, hi = last[0] - step, last[0] + step
                f = hi if f > hi else (lo if f < lo else f)
            self._last = [f]
            return [f]
        out = []
        for i, command in enumerate(force_n):
            f = 0.0 if math.isnan(command) else command
            if lim is not None:
                f = lim if f > lim else (-lim if f < -lim else f)
            if step is not None:
                lo, hi = last[i] - step, last[i] + step
                f = hi if f > hi else (lo if f < lo else f)
            out.append(f)
        self._last = out
        return list(out)
