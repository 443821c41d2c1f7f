"""Simulated human operator: an arm impedance pulled along an intended trajectory.

The hand is a spring-damper (k_h, b_h) between the intended position x_d(t) and the device, plus the
arm's mass m_h, which moves rigidly with the device and is therefore added to the device's mass by
the plant (no algebraic loop). The force on the device along each axis is

    F_h = k_h (x_d - x) + b_h (v_d - v)

The intended trajectory acts along axis 0; other axes are held at their start position. In 3-D
(arms, `intended_along`), the same profile moves the intended point from an origin along a unit
direction of the task frame.

Profile "imposed" (seed 000's premise, docs/transparency.md) is no hand: the device's position IS
the trajectory (constant velocity for duration_s from start_s, then hold). The loops step the
device with no hand force and then set its position and velocity to the trajectory's at the next
tick (`imposed_force1` gives the force such a position source applies, for the record), so the
master moves at exactly v_m whatever its actuator does. One axis only.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

PROFILES = ("push", "sinusoid", "hold", "trace", "imposed")


# One-axis formulas on floats, called by `Operator` and compiled by the engine's compiled loop
# (haptic_teleop/engine/compiled/axis_host.py): each exists once.


def push1(tau: float, x0: float, speed: float, t_end: float, x_end: float) -> tuple[float, float]:
    """Constant-velocity push `tau` s after its start: position and velocity (held at x_end after t_end)."""
    if tau < 0.0:
        return x0, 0.0
    if tau >= t_end:
        return x_end, 0.0
    return x0 + speed * tau, speed


def sinusoid1(tau: float, x0: float, amplitude: float, w: float) -> tuple[float, float]:
    """x0 + A sin(w tau) and its derivative; held at x0 before the start (tau < 0)."""
    if tau < 0.0:
        return x0, 0.0
    return x0 + amplitude * math.sin(w * tau), amplitude * w * math.cos(w * tau)


def imposed_force1(mass: float, damping: float, period: float, v: float, v_next: float, actuator: float) -> float:
    """The force a position source applies over one period so that the device (mass, viscous
    damping, both in the integrator's implicit form) goes from velocity v to v_next while its own
    actuator holds `actuator`: m (v_next - v) / T + b v_next - actuator."""
    return mass * (v_next - v) / period + damping * v_next - actuator


def hand1(k: float, b: float, xd: float, vd: float, x: float, v: float) -> float:
    """The hand's spring-damper force towards the intended position and velocity."""
    return k * (xd - x) + b * (vd - v)


@dataclass(frozen=True)
class OperatorParams:
    profile: str = "push"
    axes: int = 1
    mass_kg: float = 0.5
    stiffness_n_per_m: float = 200.0
    damping_n_s_per_m: float = 10.0
    start_position_m: float = 0.0
    start_s: float = 0.5
    # push: constant velocity for distance_m, then hold
    speed_m_per_s: float = 0.02
    distance_m: float = 0.04
    # sinusoid: x_d = start + amplitude * sin(2 pi f (t - start_s)) after start_s
    amplitude_m: float = 0.02
    frequency_hz: float = 0.5
    # imposed: the device moves at speed_m_per_s for duration_s, then holds (a position source)
    duration_s: float = 1.0
    # trace: piecewise-linear (time_s, position_m) samples
    trace_time_s: tuple[float, ...] = ()
    trace_position_m: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            raise ValueError(f"profile must be one of {PROFILES}, got {self.profile!r}")
        if self.profile == "trace":
            ts = self.trace_time_s
            if len(ts) < 2 or len(ts) != len(self.trace_position_m):
                raise ValueError("trace needs at least two (time_s, position_m) rows of equal length")
            if any(b <= a for a, b in itertools.pairwise(ts)):
                raise ValueError("trace time_s must be strictly increasing")
        if self.profile == "imposed" and not (self.duration_s >= 0.0 and math.isfinite(self.duration_s)):
            raise ValueError(f"imposed duration_s must be finite and >= 0, got {self.duration_s}")


@dataclass(frozen=True)
class OperatorConstants:
    """The numbers an `Operator` resolves from its parameters once and uses every tick
    (`Operator.constants`); the compiled loops take them from here.

    profile: the profile it runs ("push" with speed 0 runs as "hold"); x0_m: the start position;
    stiffness/damping: the hand's (`hand1`); start_s: when the profile starts; speed_m_per_s,
    t_end_s, x_end_m: `push1`'s arguments (the push's duration, 0 unless the profile is "push"
    or "imposed", and its end point). "imposed" runs `push1` as the device's own trajectory.
    """

    profile: str
    x0_m: float
    stiffness_n_per_m: float
    damping_n_s_per_m: float
    start_s: float
    speed_m_per_s: float
    t_end_s: float
    x_end_m: float


class Operator:
    """Intended trajectory and hand force; `hand_force` is called once per tick."""

    __slots__ = ("_b", "_k", "_profile", "_speed", "_start", "_t_end", "_x0", "_x_end", "params")

    def __init__(self, params: OperatorParams) -> None:
        self.params = params
        self._x0 = params.start_position_m
        self._k = params.stiffness_n_per_m
        self._b = params.damping_n_s_per_m
        self._start = params.start_s
        # "push" with speed 0 is a hold; the push's end time and end point are fixed numbers.
        profile = params.profile
        if profile == "push" and params.speed_m_per_s == 0.0:
            profile = "hold"
        self._profile = profile
        self._speed = params.speed_m_per_s
        if profile == "imposed":
            self._t_end = params.duration_s
            self._x_end = self._x0 + params.speed_m_per_s * params.duration_s
        else:
            self._t_end = abs(params.distance_m / params.speed_m_per_s) if profile == "push" else 0.0
            self._x_end = self._x0 + math.copysign(abs(params.distance_m), params.speed_m_per_s)

    def constants(self) -> OperatorConstants:
        """The resolved profile and its numbers, as the tick uses them."""
        return OperatorConstants(
            self._profile, self._x0, self._k, self._b, self._start, self._speed, self._t_end, self._x_end
        )

    def intended(self, t: float) -> tuple[float, float]:
        """Intended position (m) and velocity (m/s) along axis 0 at time t."""
        profile = self._profile
        tau = t - self._start
        if profile in {"push", "imposed"}:
            return push1(tau, self._x0, self._speed, self._t_end, self._x_end)
        x0 = self._x0
        if profile == "hold":
            return x0, 0.0
        p = self.params
        if profile == "sinusoid":
            return sinusoid1(tau, x0, p.amplitude_m, 2.0 * math.pi * p.frequency_hz)
        ts, xs = p.trace_time_s, p.trace_position_m
        if t <= ts[0]:
            return xs[0], 0.0
        if t >= ts[-1]:
            return xs[-1], 0.0
        j = bisect.bisect_right(ts, t) - 1
        slope = (xs[j + 1] - xs[j]) / (ts[j + 1] - ts[j])
        return xs[j] + slope * (t - ts[j]), slope

    def intended_along(
        self, t: float, origin: Sequence[float], direction: Sequence[float]
    ) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The intended point and velocity in 3-D: origin + (x_d(t) - x_0) * direction, x_d from the
        profile (`intended`), direction a unit vector of the task frame."""
        xd, vd = self.intended(t)
        s = xd - self._x0
        return (
            tuple(o + s * u for o, u in zip(origin, direction, strict=True)),
            tuple(vd * u for u in direction),
        )

    @property
    def imposed(self) -> bool:
        """The device is driven along the trajectory (profile "imposed"), not pulled by a hand."""
        return self._profile == "imposed"

    def hand_force(self, t: float, x: Sequence[float], v: Sequence[float]) -> list[float]:
        """Force of the hand on the device, per axis (N)."""
        return self.hand_force_and_intended(t, x, v)[0]

    def hand_force_and_intended(
        self, t: float, x: Sequence[float], v: Sequence[float]
    ) -> tuple[list[float], float, float]:
        """`hand_force` and the intended position and velocity it used, from one evaluation."""
        xd, vd = self.intended(t)
        if self._profile == "imposed":  # no hand: the loop drives the device (module docstring)
            return [0.0] * len(x), xd, vd
        k, b = self._k, self._b
        out = [hand1(k, b, xd, vd, x[0], v[0])]
        if len(x) > 1:
            x0 = self._x0
            for i in range(1, len(x)):
                out.append(k * (x0 - x[i]) - b * v[i])
        return out, xd, vd
