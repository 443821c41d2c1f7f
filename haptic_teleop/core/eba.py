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

from haptic_teleop.core.eba_state import AxisBoundState, EnergyBoundParams

# --------------------------------------------------------------------------------------------
# One-axis formulas on floats. The classes below call them on every tick, and the engine's
# compiled loop (haptic_teleop/engine/compiled/axis_host.py) compiles these same functions with numba: each
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
    down to 0 the reservoir `energy` still pays for (docs/eba_actuator_limits.md, "Actuator limits inside the bound").

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


def within1(a: float, limit: float) -> bool:
    """The value finite and within its limit (abs(v) <= limit is False for NaN and inf)."""
    return abs(a) <= limit


def within2(a: float, b: float, limit_a: float, limit_b: float) -> bool:
    """Both values finite and within their limits (abs(v) <= limit is False for NaN and inf)."""
    return abs(a) <= limit_a and abs(b) <= limit_b


def within3(a: float, b: float, c: float, limit_a: float, limit_b: float, limit_c: float) -> bool:
    """`within2` for three values."""
    return abs(a) <= limit_a and abs(b) <= limit_b and abs(c) <= limit_c


def command1(
    has_remote: bool, force_law: bool, gain: float, c1: float, c2: float, ra: float, rb: float, x: float, v: float,
    limit: float,
) -> tuple[float, float]:  # fmt: skip
    """One axis's law before its bound: 0 before a remote sample; force reflection `gain` ra (ra
    the remote force); or the coupling towards the remote position ra and velocity rb. Returns
    (desired, desired clamped to +-limit)."""
    if not has_remote:
        f = 0.0
    elif force_law:
        f = gain * ra
    else:
        f = coupling1(c1, c2, ra, rb, x, v)
    return f, saturated1(f, limit)


def bound1(
    energy: float, gain: float, held: float, last: float, has_last: bool, x: float, force: float, enabled: bool,
    limited: bool, bound_gain: float, force_limit: float, step: float,
) -> tuple[float, float]:  # fmt: skip
    """One tick of a one-axis bound: the reservoir's update for the motion since the last tick
    (`last`, none at the first), then `force` bounded (with the actuator's clip and slew limits
    when `limited`; unchanged when not `enabled`). Returns (energy, the force to hold); the caller
    keeps x as the next `last` and the force (or the one applied) as the next `held`."""
    if has_last:
        energy = reservoir1(energy, gain, held, x - last)
    if not enabled:
        f = force
    elif limited:
        f = actuator_bounded1(force, ramp_limit1(energy, bound_gain, force_limit, step), held, step)
    else:
        f = bounded1(force, energy, bound_gain)
    return energy, f


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
        self._gain = list(params.reservoir_gains())
        self._bound_gain = list(params.bound_gains())
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
        """`step` for a one-axis bound, on floats (`bound1`): the same arithmetic in the same order."""
        energy = self.energy_j
        energy[0], f = bound1(
            energy[0], self._gain1, self._held1, self._last1, self._has_last1, x, force_desired,
            self._enabled, self._limited, self._bound_gain1, self._force_limit, self._step_limit,
        )  # fmt: skip
        self._has_last1 = True
        self._last1 = x
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

    def axis_state(self) -> AxisBoundState:
        """The state of a one-axis bound (ValueError for more axes): what `set_axis_state` restores."""
        self._one_axis()
        return AxisBoundState(self.energy_j[0], self._held1, self._last1, self._has_last1)

    def set_axis_state(self, state: AxisBoundState) -> None:
        """Restore a one-axis bound's state (ValueError for more axes), e.g. after a loop that ran
        the same ledger elsewhere (the compiled loop): the next `step1` goes on from it."""
        self._one_axis()
        self.energy_j[0] = state.energy_j
        self._held1 = state.held_n
        self._last1 = state.last_x_m
        self._has_last1 = state.has_last

    def _one_axis(self) -> None:
        if not self._scalar:
            raise ValueError(f"the axis state is that of a one-axis bound; this one has {self.params.axes} axes")
