"""The two-condition energy bound (the EBA as published: a ZOH energy condition and a controller
energy condition), beside `core.eba.EnergyBound` (one pooled reservoir). Derivations, the reserve
the controller condition needs to hold for every motion, and how the two laws compare: docs/eba_two_condition.md,
"The published two-condition law".

Per axis, with b the physical damping, T the period, dx = x(n) - x(n-1), f = F(n-1) the force the
actuator applied over dx and F = F(n) the force chosen now (held over the next period), the work
the actuator did over dx splits exactly into

    f dx = (f + F)/2 dx        (the controller: the force ramped from f to F, a continuous element)
         + (f - F)/2 dx        (the zero-order hold: what holding f instead of the ramp added)

and the law keeps, at every tick,

    ZOH energy condition        (f - F)/2 dx <= (b/T) dx^2        i.e. the stiffness
                                gamma = -(F - f)/dx <= gamma_max = 2 b / T   (dx != 0)
    controller energy, reserved E_c(n) = E_c(n-1) - (f + F)/2 dx >= T F^2 / (4 b),   E_c(0) = E0

The first charges the ZOH's energy to what the damper certainly dissipated over the same step; the
second keeps the controller's ledger non-negative with a reserve for the next step's worst case
(without it the two conditions can have no common solution on the next step, and the port then
delivers more than E0: docs/eba_two_condition.md). Both are bounds on F alone, so the allowed set is an interval
(`two_condition_interval1`); the law returns its point nearest the desired force. The interval is
never empty: F = f - (2b/T) dx meets both (docs/eba_two_condition.md has the proof). The actuator's clip
(`force_limit_n`) is a third interval; it always meets the other two. A slew limit is not modelled:
`EnergyBoundParams` refuses it for this law.

Like `core.eba`, the formulas are plain float functions and the class keeps per-axis floats.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from haptic_teleop.core.eba_state import EBA_LAWS, AxisBoundState, EnergyBoundParams


def two_condition_interval1(
    energy: float, gain: float, bound_gain: float, held: float, dx: float, force_limit: float, reserve: bool = True
) -> tuple[float, float]:
    """The forces F the two-condition law allows now, as (lo, hi) (lo > hi: none).

    energy: E_c(n-1); gain: b / T; bound_gain: 4 b / T; held: the force applied over dx;
    force_limit: the actuator's clip (inf: none). reserve=False drops the controller condition's
    reserve (E_c(n) >= 0 only, the conditions as they are usually stated): the interval the tests
    compare, not one the law uses (it is not passive for every motion, docs/eba_two_condition.md)."""
    return two_condition_room_interval1(energy, gain, bound_gain, held, dx, -force_limit, force_limit, reserve)


def two_condition_room_interval1(
    energy: float, gain: float, bound_gain: float, held: float, dx: float, low: float, high: float, reserve: bool = True
) -> tuple[float, float]:
    """`two_condition_interval1` with the actuator's room [low, high] (low <= 0 <= high) in place of
    the symmetric clip: an arm's joint, whose motor carries the gravity compensation too."""
    a = gain * dx  # (b/T) dx
    lo = low
    hi = high
    # ZOH: -(F - f) dx <= 2 (b/T) dx^2, a half-line bounded at f - 2a.
    z = held - 2.0 * a
    if dx > 0.0:
        lo = max(lo, z)
    elif dx < 0.0:
        hi = min(hi, z)
    rest = energy - 0.5 * held * dx  # E_c(n) = rest - F dx / 2
    if reserve:
        # T F^2 / (4b) + F dx / 2 <= rest  <=>  (F + a)^2 <= bound_gain * rest + a^2
        disc = bound_gain * rest + a * a
        if not disc >= 0.0:
            return (math.inf, -math.inf)
        r = math.sqrt(disc)
        lo = max(lo, -a - r)
        hi = min(hi, -a + r)
    elif dx > 0.0:  # F dx / 2 <= rest
        hi = min(hi, 2.0 * rest / dx)
    elif dx < 0.0:
        lo = max(lo, 2.0 * rest / dx)
    elif not rest >= 0.0:
        return (math.inf, -math.inf)
    return (lo, hi)


def two_condition1(
    force: float, energy: float, gain: float, bound_gain: float, held: float, dx: float, force_limit: float
) -> float:
    """The force the two-condition law holds next: `force` brought into `two_condition_interval1`.

    When rounding leaves the interval empty by a few ulps (the reserve met with equality), the
    point of the ZOH and clip intervals nearest the reserve's centre -a is returned, which is
    within rounding of the always-admissible f - 2a."""
    return two_condition_room1(force, energy, gain, bound_gain, held, dx, -force_limit, force_limit)


def two_condition_room1(
    force: float, energy: float, gain: float, bound_gain: float, held: float, dx: float, low: float, high: float
) -> float:
    """`two_condition1` within the actuator's room [low, high] (`two_condition_room_interval1`).

    The interval meets the room whenever the room holds the held force f and its mirror -f (the
    one-axis proof, docs/eba_two_condition.md); an arm joint's room, its motor's range less its
    gravity torque, can be smaller than |f| on one side and then leave none: the force is the room's
    point nearest the reserve's centre within the ZOH condition, what the motor can do
    (docs/stabilizers_arms.md, "The two conditions, joint by joint")."""
    lo, hi = two_condition_room_interval1(energy, gain, bound_gain, held, dx, low, high)
    if not lo <= hi:
        a = gain * dx
        lo, hi = low, high
        z = held - 2.0 * a
        if dx > 0.0:
            lo = max(lo, z)
        elif dx < 0.0:
            hi = min(hi, z)
        force = -a
    if force > hi:
        force = hi
    elif force < lo:
        force = lo
    return min(max(force, low), high)


def controller_energy1(energy: float, held: float, force: float, dx: float) -> float:
    """E_c(n) = E_c(n-1) - (f + F)/2 dx: the controller's ledger after choosing F."""
    return energy - 0.5 * (held + force) * dx


def two_condition_bound1(
    energy: float, held: float, dx: float, force_desired: float, enabled: bool, gain: float, bound_gain: float,
    force_limit: float,
) -> tuple[float, float]:  # fmt: skip
    """One axis, one tick of the law (`TwoConditionBound.step1`, and the compiled one-axis loop):
    the force held next (`two_condition1`; disabled: the desired force) and the ledger after it,
    (E_c(n), F)."""
    f = two_condition1(force_desired, energy, gain, bound_gain, held, dx, force_limit) if enabled else force_desired
    return controller_energy1(energy, held, f, dx), f


def contact_force_slope_n_per_s(
    law: str,
    coupling_stiffness_n_per_m: float,
    damping_n_s_per_m: float,
    period_s: float,
    speed_m_per_s: float,
    bound_binding: bool = True,
) -> float:
    """The predicted rate at which the bounded force grows when the device is pushed at a constant
    speed into a coupling spring c1 whose far end does not move (the seed's premise: the slave held
    by the wall), in N/s, >= 0 (docs/eba_two_condition.md, "Force slope in contact").

    two_condition: min(c1, 2b/T) |v| from the first tick of contact: the ZOH condition caps the
    stiffness at gamma_max = 2b/T whatever the stored energy. reservoir: c1 |v| while the pooled
    reservoir still covers the force (`bound_binding` False), min(c1, 2b/T) |v| once the bound binds
    (the bound's stiffness 2b/T, exactly, per period; a softer spring unbinds it)."""
    if law not in EBA_LAWS[:2]:
        raise ValueError(f"law must be one of {', '.join(EBA_LAWS[:2])}, got {law!r}")
    gains = (("coupling_stiffness_n_per_m", coupling_stiffness_n_per_m), ("damping_n_s_per_m", damping_n_s_per_m))
    for name, v in gains:
        if not 0.0 <= v < math.inf:
            raise ValueError(f"{name} must be finite and >= 0, got {v}")
    if not 0.0 < period_s < math.inf:
        raise ValueError(f"period_s must be finite and > 0, got {period_s}")
    if not math.isfinite(speed_m_per_s):
        raise ValueError(f"speed_m_per_s must be finite, got {speed_m_per_s}")
    cap = 2.0 * damping_n_s_per_m / period_s
    if law == "reservoir" and not bound_binding:
        return coupling_stiffness_n_per_m * abs(speed_m_per_s)
    return min(coupling_stiffness_n_per_m, cap) * abs(speed_m_per_s)


class TwoConditionBound:
    """One side's two-condition bound, with `core.eba.EnergyBound`'s interface: `step1`/`step` once
    per tick, then `applied1`/`applied` with the force the actuator really applied (the next tick's
    f). `energy_j` holds each axis's controller energy E_c(n) (after the force chosen at tick n), the
    ledger the engine records; the port's own margin (from plant signals) is at least that.
    With the bound disabled the force passes unchanged and the ledger is still kept."""

    __slots__ = (
        "_bound_gain",
        "_enabled",
        "_force_limit",
        "_gain",
        "_has_last",
        "_held",
        "_last_x",
        "energy_j",
        "params",
    )

    def __init__(self, params: EnergyBoundParams) -> None:
        if params.slew_rate_n_per_s is not None:
            raise ValueError("the two_condition law does not model an actuator slew limit (use law reservoir)")
        self.params = params
        n = params.axes
        self._gain = [b / params.period_s for b in params.damping_n_s_per_m]
        self._bound_gain = [4.0 * b / params.period_s for b in params.damping_n_s_per_m]
        self._force_limit = math.inf if params.force_limit_n is None else params.force_limit_n
        self._enabled = params.enabled
        self.energy_j = [params.initial_energy_j] * n
        self._held = [0.0] * n
        self._last_x = [0.0] * n
        self._has_last = False

    def step1(self, x: float, force_desired: float) -> float:
        """`step` for one axis, on floats."""
        dx = x - self._last_x[0] if self._has_last else 0.0
        self._has_last = True
        self._last_x[0] = x
        return self._axis(0, dx, force_desired)

    def _axis(self, i: int, dx: float, force_desired: float) -> float:
        self.energy_j[i], f = two_condition_bound1(
            self.energy_j[i], self._held[i], dx, force_desired, self._enabled, self._gain[i], self._bound_gain[i],
            self._force_limit,
        )  # fmt: skip
        self._held[i] = f
        return f

    def step(self, x: Sequence[float], force_desired: Sequence[float]) -> list[float]:
        """Account for the motion since the last tick, then bound each axis's desired force."""
        first = not self._has_last
        self._has_last = True
        last = self._last_x
        out = []
        for i in range(len(last)):
            dx = 0.0 if first else x[i] - last[i]
            last[i] = x[i]
            out.append(self._axis(i, dx, force_desired[i]))
        return out

    def applied1(self, force: float) -> None:
        """The force the actuator applied over the period after the last `step1`."""
        self._held[0] = force

    def applied(self, force: Sequence[float]) -> None:
        """`applied1` for every axis."""
        self._held[:] = [float(f) for f in force]

    @property
    def total_energy_j(self) -> float:
        return sum(self.energy_j)

    def axis_state(self) -> AxisBoundState:
        """A one-axis bound's state (ValueError for more axes), as `EnergyBound.axis_state`: the
        controller ledger E_c, the force held, the last position and whether there was one."""
        self._one_axis()
        return AxisBoundState(self.energy_j[0], self._held[0], self._last_x[0], self._has_last)

    def set_axis_state(self, state: AxisBoundState) -> None:
        """Restore a one-axis bound's state (ValueError for more axes), e.g. the in-contact start's
        holding energy (contact_assembly.apply_contact_start): the next `step1` goes on from it."""
        self._one_axis()
        self.energy_j[0] = state.energy_j
        self._held[0] = state.held_n
        self._last_x[0] = state.last_x_m
        self._has_last = state.has_last

    def _one_axis(self) -> None:
        if len(self.energy_j) != 1:
            raise ValueError(f"the axis state is that of a one-axis bound; this one has {len(self.energy_j)} axes")
