"""Energy Bounding Algorithm (EBA): per-axis energy reservoirs and the force bound that keeps them >= 0.

The laws, their derivation and every parameter are in docs/eba.md. In short, for each axis i with
physical damping b_i and period T, with dx = x(n) - x(n-1) and F(n-1) the force held over it:

    E_i(n) = E_i(n-1) + (b_i / T) dx_i^2 - F_i(n-1) dx_i          (reservoir)
    |F_i(n)| <= 2 sqrt(b_i E_i(n) / T)                            (bound)

The bound makes E_i(n+1) >= 0 for *any* next displacement, because min over dx of
(b/T) dx^2 - F dx is -F^2 T / (4 b).

The tick path works on plain lists of floats: for the one to six axes of a haptic device that is
several times cheaper than numpy, and it is the same code for every n. One axis, the common case,
also has a scalar path (`step1`) that does the same arithmetic in the same order on floats, so
it gives the same bits (test_scalar_path_equals_the_general_path) without building lists.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

LAWS = ("position", "force")


# --------------------------------------------------------------------------------------------
# One-axis formulas on floats. The classes below call them on every tick, and the engine's
# compiled loop (haptic_teleop/fastloop.py) compiles these same functions with numba: each
# formula exists once. Keep them plain float arithmetic (no Python objects) so both can run them.


def reservoir1(energy: float, gain: float, held: float, dx: float) -> float:
    """E(n) = E(n-1) + (b/T) dx^2 - F(n-1) dx, with gain = b/T and held = F(n-1)."""
    return energy + (gain * dx * dx - held * dx)


def bounded1(force: float, energy: float, bound_gain: float) -> float:
    """`force` clamped to the EBA bound +-sqrt(4 b E / T) (bound_gain = 4 b / T); 0 when E <= 0."""
    limit = math.sqrt(bound_gain * energy) if energy > 0.0 else 0.0
    if force > limit:
        return limit
    if force < -limit:
        return -limit
    return force


def ramp_limit1(energy: float, bound_gain: float, force_limit: float, step: float) -> float:
    """The largest |F| the actuator may hold: at most `force_limit` (its clip), and one whose ramp
    down to 0 the reservoir `energy` still pays for (docs/eba.md, "Actuator limits inside the bound").

    The actuator can lower |F| by at most `step` = S T per period, so after holding F it holds at
    best |F| - step, |F| - 2 step, ... down to 0, and each of those periods can cost T F_k^2 / (4 b).
    With bound_gain = 4 b / T the reservoir covers the ramp when sum_k F_k^2 <= bound_gain * energy.
    The sum is piecewise quadratic in |F|: with |F| in [K step, (K+1) step] it is
    (K+1) F^2 - step K (K+1) F + step^2 K (K+1) (2K+1) / 6, whose root is the closed form below.
    `step` = inf (no slew limit) gives sqrt(bound_gain * energy), `bounded1`'s limit.
    """
    if not energy > 0.0:
        return 0.0
    e = bound_gain * energy
    if not step < math.inf:
        limit = math.sqrt(e)
    else:
        s2 = step * step
        # K: the whole steps below the limit, the largest K with step^2 K (K+1) (2K+1) / 6 <= e.
        k = math.floor((3.0 * e / s2) ** (1.0 / 3.0))
        while k > 0.0 and s2 * k * (k + 1.0) * (2.0 * k + 1.0) / 6.0 > e:
            k -= 1.0
        while s2 * (k + 1.0) * (k + 2.0) * (2.0 * k + 3.0) / 6.0 <= e:
            k += 1.0
        limit = 0.5 * step * k + math.sqrt(e / (k + 1.0) - s2 * k * (k + 2.0) / 12.0)
    return force_limit if limit > force_limit else limit


def actuator_bounded1(force: float, limit: float, held: float, step: float) -> float:
    """`force` clamped to +-limit (`ramp_limit1`), then to the reach of one period from the force
    the actuator held last (`held` +- step): a force the actuator applies as it is. The reach
    always meets the band +-limit (the reservoir paid for the ramp down from `held`), so the
    result stays inside it. With limit from `ramp_limit1` and both limits inf, this is `bounded1`."""
    if force > limit:
        force = limit
    elif force < -limit:
        force = -limit
    hi = held + step
    lo = held - step
    if force > hi:
        return hi
    if force < lo:
        return lo
    return force


def saturated1(force: float, limit: float) -> float:
    """`force` clamped to +-limit."""
    if force > limit:
        return limit
    if force < -limit:
        return -limit
    return force


def coupling1(c1: float, c2: float, remote_x: float, remote_v: float, x: float, v: float) -> float:
    """Position-position coupling: spring c1 and damper c2 towards the remote sample."""
    return c1 * (remote_x - x) + c2 * (remote_v - v)


def within2(a: float, b: float, limit_a: float, limit_b: float) -> bool:
    """Both values finite and within their limits (abs(v) <= limit is False for NaN and inf)."""
    return abs(a) <= limit_a and abs(b) <= limit_b


def within3(a: float, b: float, c: float, limit_a: float, limit_b: float, limit_c: float) -> bool:
    """`within2` for three values."""
    return abs(a) <= limit_a and abs(b) <= limit_b and abs(c) <= limit_c


@dataclass(frozen=True)
class EnergyBoundParams:
    """Parameters of one side's energy bound."""

    period_s: float
    damping_n_s_per_m: tuple[float, ...]
    initial_energy_j: float = 0.0
    enabled: bool = True
    # The actuator's limits downstream of the bound (docs/eba.md, "Actuator limits inside the
    # bound"): it clips |F| to force_limit_n and changes F by at most slew_rate_n_per_s * T per
    # period. None: no such limit (the bound is then the plain one, bit for bit).
    force_limit_n: float | None = None
    slew_rate_n_per_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("force_limit_n", "slew_rate_n_per_s"):
            v = getattr(self, name)
            if v is not None and not 0.0 < v < math.inf:
                raise ValueError(f"{name} must be finite and > 0 (or None), got {v}")
        if not self.period_s > 0.0:
            raise ValueError(f"period_s must be > 0, got {self.period_s}")
        if not self.damping_n_s_per_m or any(not b > 0.0 for b in self.damping_n_s_per_m):
            raise ValueError(f"damping_n_s_per_m must be > 0 on every axis, got {self.damping_n_s_per_m}")
        if not self.initial_energy_j >= 0.0:
            raise ValueError(f"initial_energy_j must be >= 0, got {self.initial_energy_j}")

    @property
    def axes(self) -> int:
        return len(self.damping_n_s_per_m)

    @property
    def limited(self) -> bool:
        """Whether the bound models an actuator limit (`actuator_bounded1`) or is the plain one."""
        return self.force_limit_n is not None or self.slew_rate_n_per_s is not None

    def actuator_limits(self) -> tuple[float, float]:
        """(force limit, slew step S T) of the actuator, inf where there is none."""
        f = math.inf if self.force_limit_n is None else self.force_limit_n
        s = math.inf if self.slew_rate_n_per_s is None else self.slew_rate_n_per_s * self.period_s
        return f, s

    def max_stiffness_n_per_m(self) -> tuple[float, ...]:
        """The stiffness the bounded force can grow with at most: 2 b / T per axis (Colgate)."""
        return tuple(2.0 * b / self.period_s for b in self.damping_n_s_per_m)


class EnergyBound:
    """One side's reservoirs and force bound; `step` is called once per tick, then `applied`
    (or `applied1`) with the force the actuator really applied over the period, which is the force
    the reservoir accounts for at the next tick (without the call, the force `step` returned)."""

    __slots__ = (
        "_bound_gain",
        "_bound_gain1",
        "_enabled",
        "_force_limit",
        "_gain",
        "_gain1",
        "_has_last1",
        "_held",
        "_held1",
        "_last1",
        "_last_x",
        "_limited",
        "_scalar",
        "_step_limit",
        "energy_j",
        "params",
    )

    def __init__(self, params: EnergyBoundParams) -> None:
        self.params = params
        n = params.axes
        t = params.period_s
        self._gain = [b / t for b in params.damping_n_s_per_m]
        self._bound_gain = [4.0 * b / t for b in params.damping_n_s_per_m]
        # The initial energy is per axis: each axis is its own port with its own damping.
        self.energy_j = [params.initial_energy_j] * n
        self._held = [0.0] * n
        self._last_x: list[float] | None = None
        self._enabled = params.enabled
        # One axis: `step` goes through `step1`, whose state is these floats (energy stays in energy_j).
        self._scalar = n == 1
        self._gain1 = self._gain[0]
        self._bound_gain1 = self._bound_gain[0]
        self._held1 = 0.0
        self._last1 = 0.0
        self._has_last1 = False
        self._limited = params.limited
        self._force_limit, self._step_limit = params.actuator_limits()

    def step1(self, x: float, force_desired: float) -> float:
        """`step` for a one-axis bound, on floats: the same arithmetic in the same order."""
        energy = self.energy_j
        if self._has_last1:
            energy[0] = reservoir1(energy[0], self._gain1, self._held1, x - self._last1)
        else:
            self._has_last1 = True
        self._last1 = x
        if not self._enabled:
            f = force_desired
        elif self._limited:
            step = self._step_limit
            limit = ramp_limit1(energy[0], self._bound_gain1, self._force_limit, step)
            f = actuator_bounded1(force_desired, limit, self._held1, step)
        else:
            f = bounded1(force_desired, energy[0], self._bound_gain1)
        self._held1 = f
        return f

    def applied1(self, force: float) -> None:
        """The force the actuator applied over the period that follows the last `step1`: the
        reservoir's next update accounts with it (after the plant's clip and any actuator effect)."""
        self._held1 = force

    def applied(self, force: Sequence[float]) -> None:
        """`applied1` for every axis (after `step`)."""
        if self._scalar:
            self._held1 = force[0]
        else:
            self._held = list(force)

    def step(self, x: Sequence[float], force_desired: Sequence[float]) -> list[float]:
        """Account for the motion since the last tick, then bound the desired force.

        Returns the force to hold over the next period. With the bound disabled the reservoir is
        still kept (so the unprotected variant can be inspected) but the force passes unchanged.
        """
        if self._scalar:
            return [self.step1(x[0], force_desired[0])]
        return self._step_axes(x, force_desired)

    def _step_axes(self, x: Sequence[float], force_desired: Sequence[float]) -> list[float]:
        """The general n-axis path (also what `step1` must agree with, bit for bit)."""
        energy = self.energy_j
        held = self._held
        last = self._last_x
        if last is not None:
            gain = self._gain
            for i in range(len(energy)):
                energy[i] = reservoir1(energy[i], gain[i], held[i], x[i] - last[i])
        self._last_x = list(x)
        if not self._enabled:
            out = list(force_desired)
        elif self._limited:
            bound_gain, fl, sl = self._bound_gain, self._force_limit, self._step_limit
            out = [
                actuator_bounded1(force_desired[i], ramp_limit1(energy[i], bound_gain[i], fl, sl), held[i], sl)
                for i in range(len(energy))
            ]
        else:
            bound_gain = self._bound_gain
            out = [bounded1(force_desired[i], energy[i], bound_gain[i]) for i in range(len(energy))]
        self._held = out
        return out

    @property
    def total_energy_j(self) -> float:
        return sum(self.energy_j)


@dataclass(frozen=True)
class RemoteLimits:
    """The largest magnitudes a remote sample may carry; anything beyond is a fault, not physics.

    A remote sample with a value that is not finite or beyond its limit is rejected by the
    receiving controller (docs/eba.md, "Bad values in packets"). The engine derives the limits
    from the scene (`haptic_teleop.engine.remote_limits`).
    """

    position_m: float  # workspace bound on |x|
    velocity_m_per_s: float  # bound on |v|
    force_n: float  # force sensor range: bound on |f_env|

    def __post_init__(self) -> None:
        for name in ("position_m", "velocity_m_per_s", "force_n"):
            v = getattr(self, name)
            if not 0.0 < v < math.inf:
                raise ValueError(f"{name} must be finite and > 0, got {v}")


class SampleGuard:
    """Checks remote samples element by element against per-element limits; counts rejections.

    `accept(payload)` is False, and `rejected` grows by one, when the payload has the wrong
    length or any value is NaN, infinite or beyond its element's limit.
    """

    __slots__ = ("limits", "rejected")

    def __init__(self, limits: Sequence[float]) -> None:
        if not limits or any(not 0.0 < lim < math.inf for lim in limits):
            raise ValueError(f"limits must be finite and > 0, got {tuple(limits)}")
        self.limits = tuple(limits)
        self.rejected = 0

    def accept(self, payload: Sequence[float]) -> bool:
        # abs(v) <= limit is False for NaN and +-inf too. The one-axis layouts (2 and 3 values)
        # are spelled out: a loop (or zip) costs three times as much per sample.
        lim = self.limits
        n = len(lim)
        if len(payload) == n:
            if n == 2:
                if within2(payload[0], payload[1], lim[0], lim[1]):
                    return True
            elif n == 3:
                if within3(payload[0], payload[1], payload[2], lim[0], lim[1], lim[2]):
                    return True
            else:
                for i in range(n):
                    if not abs(payload[i]) <= lim[i]:
                        break
                else:
                    return True
        self.rejected += 1
        return False


@dataclass(frozen=True)
class ControllerParams:
    """One side's control law (before the energy bound) and its saturation."""

    role: str  # "master" or "slave"
    law: str = "position"  # "position": spring-damper on the remote sample; "force": force reflection
    stiffness_n_per_m: float = 1000.0  # c1
    damping_n_s_per_m: float = 10.0  # c2
    force_gain: float = 1.0  # force reflection gain (master with law "force")
    force_limit_n: float = 20.0
    remote_limits: RemoteLimits | None = None  # None: remote samples are not checked

    def __post_init__(self) -> None:
        if self.role not in ("master", "slave"):
            raise ValueError(f"role must be 'master' or 'slave', got {self.role!r}")
        if self.law not in LAWS:
            raise ValueError(f"law must be one of {LAWS}, got {self.law!r}")
        if self.law == "force" and self.role != "master":
            raise ValueError("force reflection ('force' law) is a master law; the slave tracks position")
        if not self.force_limit_n > 0.0:
            raise ValueError(f"force_limit_n must be > 0, got {self.force_limit_n}")


class TeleopController:
    """Control law on the latest remote sample, saturation, then the energy bound.

    Remote payloads (flat tuples, n = axes):
      master -> slave: (x_1..x_n, v_1..v_n)
      slave -> master: (f_env_1..f_env_n, x_1..x_n, v_1..v_n), f_env the environment's force on
      the robot (negative when the robot pushes a wall at +x).
    """

    __slots__ = (
        "_c1",
        "_c2",
        "_force_law",
        "_gain",
        "_limit",
        "_n",
        "_off",
        "_params",
        "_remote",
        "bound",
        "force_applied",
        "force_desired",
        "guard",
    )

    def __init__(self, params: ControllerParams, bound: EnergyBoundParams) -> None:
        self.bound = EnergyBound(bound)
        self._n = bound.axes
        self._remote: tuple[float, ...] | None = None
        # The controller's own lists, overwritten in place every tick (copy them to keep a value).
        self.force_desired = [0.0] * self._n
        self.force_applied = [0.0] * self._n
        self.params = params
        # Remote payload layout (class docstring): master receives (f_env, x, v), slave (x, v).
        self.guard: SampleGuard | None = None
        lim = params.remote_limits
        if lim is not None:
            kinds = (lim.force_n, lim.position_m, lim.velocity_m_per_s)
            per_kind = kinds if params.role == "master" else kinds[1:]
            self.guard = SampleGuard([k for k in per_kind for _ in range(self._n)])

    @property
    def rejected_samples(self) -> int:
        """Remote samples rejected by the guard so far (0 without a guard)."""
        return 0 if self.guard is None else self.guard.rejected

    @property
    def params(self) -> ControllerParams:
        return self._params

    @params.setter
    def params(self, params: ControllerParams) -> None:
        """Replace the parameters (a watchdog lowers force_limit_n this way) between ticks."""
        self._params = params
        # Constants of the law, looked up once here (the tick reads them as plain attributes).
        self._force_law = params.law == "force"
        self._gain = params.force_gain
        self._c1 = params.stiffness_n_per_m
        self._c2 = params.damping_n_s_per_m
        self._limit = params.force_limit_n
        self._off = self._n if params.role == "master" else 0  # master payload starts with forces

    def set_remote(self, payload: tuple[float, ...]) -> None:
        """The newest remote sample the playout buffer released.

        With a guard, a sample carrying a non-finite or out-of-range value is rejected and
        counted; the controller keeps the sample it had.
        """
        guard = self.guard
        if guard is not None and not guard.accept(payload):
            return
        self._remote = payload

    def desired_force(self, x: Sequence[float], v: Sequence[float]) -> list[float]:
        """The control law alone (no saturation, no bound)."""
        n = self._n
        r = self._remote
        if r is None:
            return [0.0] * n
        if self._force_law:
            g = self._gain
            return [g * r[i] for i in range(n)]
        off = self._off
        c1 = self._c1
        c2 = self._c2
        return [coupling1(c1, c2, r[off + i], r[off + n + i], x[i], v[i]) for i in range(n)]

    def step(self, x: Sequence[float], v: Sequence[float]) -> list[float]:
        """One tick: returns the force to apply (held until the next tick)."""
        if self._n == 1:
            return [self.step1(x[0], v[0])]
        desired = self.desired_force(x, v)
        lim = self._limit
        sat = [saturated1(f, lim) for f in desired]
        self.force_desired[:] = desired
        applied = self.bound.step(x, sat)
        self.force_applied[:] = applied
        return applied

    def step1(self, x: float, v: float) -> float:
        """`step` for one axis on floats (same arithmetic, same order): returns the force to apply."""
        r = self._remote
        if r is None:
            f = 0.0
        elif self._force_law:
            f = self._gain * r[0]
        else:
            off = self._off
            f = coupling1(self._c1, self._c2, r[off], r[off + 1], x, v)
        self.force_desired[0] = f
        f = self.bound.step1(x, saturated1(f, self._limit))
        self.force_applied[0] = f
        return f
