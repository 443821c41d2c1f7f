"""The energy bound of an arm: the joints are the ports, pooled into one reservoir per side, the
torque vector scaled by one factor (docs/eba_many_joints.md, "Many joints"); its actuator limits (motor room,
slew) inside the bound.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from haptic_teleop.core.eba import actuator_bounded1, bounded1, ramp_limit1, reservoir1

# --------------------------------------------------------------------------------------------
# Many joints: the joints are the ports, pooled into one reservoir per side (docs/eba_many_joints.md, "Many
# joints"). With D = diag(d_i) the joints' physical damping, dq = q(n) - q(n-1), tau(n-1) the
# torque applied over it:
#
#     E(n) = E(n-1) + dq.T D dq / T - tau(n-1).T dq         (pooled reservoir)
#     (T/4) tau.T D^-1 tau <= E(n)                            (bound: tau scaled by one lambda)
#
# and with tau = J.T F the same bound reads (T/4) F.T B^-1 F <= E, B^-1 = J D^-1 J.T.
# The functions below are plain loops over float64 arrays (compilable with numba as they are);
# `CoupledEnergyBound` keeps the state for the Python loop and calls them.

LIMIT_MODES = ("scale", "clip")
# A real arm's default `max_hold_s`, in periods (docs/eba_many_joints.md, "Late ticks on a real clock").
DEFAULT_MAX_HOLD_PERIODS = 3
_SLEW_SEARCH_STEPS = 50  # bisection steps for the slew-aware bound (2^-50: below float resolution)


def coupled_reservoir(
    energy: float, gain: npt.NDArray[np.float64], held: npt.NDArray[np.float64], dq: npt.NDArray[np.float64]
) -> float:
    """E + sum_i (d_i/T) dq_i^2 - tau_i dq_i (gain_i = d_i / T, held = the torque applied over dq).

    `reservoir1` joint after joint, so one joint gives the 1-DoF reservoir's bits.
    """
    for i in range(dq.shape[0]):
        energy = reservoir1(energy, gain[i], held[i], dq[i])
    return energy


def coupled_demand(tau: npt.NDArray[np.float64], bound_gain: npt.NDArray[np.float64]) -> float:
    """(T/4) tau.T D^-1 tau = sum_i tau_i^2 / bound_gain_i (bound_gain_i = 4 d_i / T).

    The most energy holding `tau` for one period can take out of the pooled reservoir, over every
    joint displacement (the minimum over dq of dq.T D dq / T - tau.T dq).
    """
    s = 0.0
    for i in range(tau.shape[0]):
        s += tau[i] * tau[i] / bound_gain[i]
    return s


def descent_cost1(torque: float, step: float, bound_gain: float) -> float:
    """The most energy one joint can take while its torque falls to 0 by at most `step` per period.

    sum_{k >= 0} (|torque| - k step)_+^2 / bound_gain: the one-period demand of the held torque
    and of every torque of the fastest descent after it. `step` = slew limit * T (inf: no slew
    limit, the first term alone). Closed form, every term positive (no cancellation): with
    |torque| = (K - 1 + r) step, K terms (r + j) step, j = 0..K-1.
    """
    a = abs(torque)
    if a <= step:
        return a * a / bound_gain
    u = a / step
    kf = math.floor(u)
    r = u - kf
    k = kf + 1.0
    return step * step * (k * r * r + r * k * (k - 1.0) + (k - 1.0) * k * (2.0 * k - 1.0) / 6.0) / bound_gain


def coupled_descent_cost(
    tau: npt.NDArray[np.float64], step: npt.NDArray[np.float64], bound_gain: npt.NDArray[np.float64]
) -> float:
    """sum over the joints of `descent_cost1`: the reservoir the slew-aware bound keeps for `tau`."""
    s = 0.0
    for i in range(tau.shape[0]):
        s += descent_cost1(tau[i], step[i], bound_gain[i])
    return s


def coupled_scale(tau: npt.NDArray[np.float64], energy: float, bound_gain: npt.NDArray[np.float64]) -> float:
    """The largest lambda in [0, 1] with (T/4) (lambda tau).T D^-1 (lambda tau) <= E (0 when E <= 0)."""
    demand = coupled_demand(tau, bound_gain)
    if demand <= energy:
        return 1.0
    if energy <= 0.0:
        return 0.0
    return math.sqrt(energy / demand)


def coupled_bounded(
    out: npt.NDArray[np.float64], tau: npt.NDArray[np.float64], energy: float, bound_gain: npt.NDArray[np.float64]
) -> float:
    """out = lambda tau (direction kept) within the pooled bound; returns lambda.

    One joint goes through `bounded1`, the 1-DoF bound, bit for bit.
    """
    n = tau.shape[0]
    if n == 1:
        out[0] = bounded1(tau[0], energy, bound_gain[0])
        return 1.0 if out[0] == tau[0] else out[0] / tau[0]
    lam = coupled_scale(tau, energy, bound_gain)
    for i in range(n):
        out[i] = lam * tau[i]
    return lam


def joint_limited(
    out: npt.NDArray[np.float64],
    tau: npt.NDArray[np.float64],
    low: npt.NDArray[np.float64],
    high: npt.NDArray[np.float64],
    keep_direction: bool,
) -> None:
    """`tau` brought within [low_i, high_i] per joint (normally low_i <= 0 <= high_i).

    keep_direction: one factor on the whole vector, the largest that fits every joint (the
    direction of the task force survives); else each joint clipped alone, as a motor does (the
    direction can turn). A joint whose room excludes 0 (its gravity torque beyond the motor's
    limit: the motor cannot hold the arm) takes no part in the factor and is clipped alone.
    """
    n = tau.shape[0]
    if keep_direction and n > 1:  # one joint: the clip (the same bits as the one-axis bound's clip)
        f = 1.0
        for i in range(n):
            t = tau[i]
            if t > high[i] >= 0.0:
                f = min(f, high[i] / t)
            elif t < low[i] <= 0.0:
                f = min(f, low[i] / t)
        for i in range(n):
            out[i] = f * tau[i]
            # f * t can round past the limit by one ulp: the motor must not clip what was accounted.
            out[i] = min(max(out[i], low[i]), high[i])
    else:
        for i in range(n):
            out[i] = min(max(tau[i], low[i]), high[i])


def _slew_segment(
    out: npt.NDArray[np.float64],
    tau: npt.NDArray[np.float64],
    held: npt.NDArray[np.float64],
    step: npt.NDArray[np.float64],
    fraction: float,
) -> None:
    """out = base + fraction (target - base): the point `fraction` of the way from the fastest
    descent of `held` (base) to the slew-limited `tau` (target), per joint (`slew_bounded`)."""
    for i in range(tau.shape[0]):
        h = held[i]
        base = 0.0 if abs(h) <= step[i] else (h - step[i] if h > 0.0 else h + step[i])
        target = min(max(tau[i], h - step[i]), h + step[i])
        out[i] = base + fraction * (target - base)


def slew_bounded(
    out: npt.NDArray[np.float64],
    tau: npt.NDArray[np.float64],
    held: npt.NDArray[np.float64],
    energy: float,
    step: npt.NDArray[np.float64],
    bound_gain: npt.NDArray[np.float64],
) -> float:
    """The bound for joints whose torque can change by at most step_i = S_i T per period.

    Keeps E >= descent cost of the torque it returns (`coupled_descent_cost`), which guarantees
    that the fastest descent from it stays admissible at every later tick whatever the motion, so
    the reservoir never goes below 0 although the torque cannot drop at once. The torque is `tau`
    moved into the slew box around `held`; if that costs too much, the point of the segment from
    the fastest descent of `held` (admissible by the invariant) to it with the largest admissible
    fraction (the cost is convex: bisection). Returns that fraction (1: the slew-limited `tau`).
    One joint goes through the one-axis actuator-aware bound (`ramp_limit1`, `actuator_bounded1`):
    the same criterion in closed form, the same bits.
    """
    n = tau.shape[0]
    if n == 1:
        out[0] = actuator_bounded1(tau[0], ramp_limit1(energy, bound_gain[0], math.inf, step[0]), held[0], step[0])
        return 1.0 if out[0] == tau[0] else 0.0
    # the slew-limited target (into out), its cost, then the bisection recomputing the segment's
    # ends (the same arithmetic as with arrays of them: nothing allocated)
    for i in range(n):
        out[i] = min(max(tau[i], held[i] - step[i]), held[i] + step[i])
    if coupled_descent_cost(out, step, bound_gain) <= energy:
        return 1.0
    lo = 0.0
    hi = 1.0
    for _ in range(_SLEW_SEARCH_STEPS):
        mid = 0.5 * (lo + hi)
        _slew_segment(out, tau, held, step, mid)
        if coupled_descent_cost(out, step, bound_gain) <= energy:
            lo = mid
        else:
            hi = mid
    _slew_segment(out, tau, held, step, lo)
    return lo


def late_hold_excess_j(
    held: npt.NDArray[np.float64], bound_gain: npt.NDArray[np.float64], hold_s: float, max_hold_s: float
) -> float:
    """The most energy a torque held `hold_s` can take beyond the `max_hold_s` the bound budgeted
    (bound_gain_i = 4 d_i / max_hold_s): ((hold_s - max_hold_s) / 4) held.T D^-1 held, 0 when
    hold_s <= max_hold_s. The reservoir after such a hold is at least minus this (docs/eba_many_joints.md,
    "Late ticks on a real clock"): over a hold h the ledger's change is dq.T D dq / h - tau.T dq,
    whose minimum over dq is -(h/4) tau.T D^-1 tau, and the bound kept (max_hold_s/4) tau.T D^-1 tau <= E."""
    if not hold_s > max_hold_s:  # also NaN
        return 0.0
    return (hold_s / max_hold_s - 1.0) * coupled_demand(held, bound_gain)


def task_demand(
    jac: npt.NDArray[np.float64], force: npt.NDArray[np.float64], bound_gain: npt.NDArray[np.float64]
) -> float:
    """(T/4) F.T B^-1 F with B^-1 = J D^-1 J.T: the pooled bound's demand of the task force F."""
    m, n = jac.shape
    s = 0.0
    for j in range(n):
        t = 0.0
        for i in range(m):
            t += jac[i, j] * force[i]
        s += t * t / bound_gain[j]
    return s


@dataclass(frozen=True)
class CoupledEnergyBoundParams:
    """Parameters of one side's pooled joint bound.

    damping_nm_s_per_rad: the joints' physical damping (the compiled MjModel's dof_damping), each
    > 0. torque_limit_nm: the motors' limits (empty: none); limit_mode "scale" (keep the
    direction) or "clip" (per joint, like the motor). slew_nm_per_s: how fast each motor's torque
    can change (empty: instantly); with it the bound keeps the reserve the descent needs.
    joint_names: for messages. max_hold_s: the longest time a torque may be held before the next
    tick replaces it (a real arm's late ticks; docs/eba_many_joints.md, "Late ticks on a real clock"): the bound
    budgets that hold, (max_hold_s / 4) tau.T D^-1 tau <= E, instead of one period; None: one period
    (a simulated or lockstep arm, whose torque is held exactly T: the same bits as before).
    """

    period_s: float
    damping_nm_s_per_rad: tuple[float, ...]
    initial_energy_j: float = 0.0
    enabled: bool = True
    torque_limit_nm: tuple[float, ...] = ()
    limit_mode: str = "scale"
    slew_nm_per_s: tuple[float, ...] = ()
    joint_names: tuple[str, ...] = ()
    max_hold_s: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.period_s) and self.period_s > 0.0):
            raise ValueError(f"period_s must be finite and > 0, got {self.period_s}")
        n = len(self.damping_nm_s_per_rad)
        if n == 0:
            raise ValueError("damping_nm_s_per_rad needs one value per joint, got none")
        if self.joint_names and len(self.joint_names) != n:
            raise ValueError(f"joint_names must name the {n} joints, got {self.joint_names}")
        for i, d in enumerate(self.damping_nm_s_per_rad):
            if not (math.isfinite(d) and d > 0.0):
                raise ValueError(
                    f"joint {self.joint_name(i)!r}: damping must be finite and > 0 N m s/rad for the energy "
                    f"bound (without damping, the work a nonzero torque can do in one period is unbounded), got {d}"
                )
        if not (math.isfinite(self.initial_energy_j) and self.initial_energy_j >= 0.0):
            raise ValueError(f"initial_energy_j must be finite and >= 0, got {self.initial_energy_j}")
        h = self.max_hold_s
        if h is not None and not (math.isfinite(h) and h >= self.period_s):
            raise ValueError(
                f"max_hold_s must be finite and at least the period ({self.period_s} s), or None (one period), got {h}"
            )
        if self.limit_mode not in LIMIT_MODES:
            raise ValueError(f"limit_mode must be one of {LIMIT_MODES}, got {self.limit_mode!r}")
        for name in ("torque_limit_nm", "slew_nm_per_s"):
            values = getattr(self, name)
            if values and len(values) != n:
                raise ValueError(f"{name} must have one value per joint ({n}) or none, got {values}")
            for i, v in enumerate(values):
                if not v > 0.0:  # inf allowed: no limit on that joint
                    raise ValueError(f"joint {self.joint_name(i)!r}: {name} must be > 0, got {v}")

    @property
    def joints(self) -> int:
        return len(self.damping_nm_s_per_rad)

    def joint_name(self, i: int) -> str:
        return self.joint_names[i] if self.joint_names else f"joint {i}"

    @property
    def hold_s(self) -> float:
        """The hold the bound budgets: max_hold_s, or one period."""
        return self.period_s if self.max_hold_s is None else self.max_hold_s


@dataclass(frozen=True)
class CoupledBoundConstants:
    """What a `CoupledEnergyBound` computes once from its parameters and uses every tick (copies:
    `CoupledEnergyBound.constants`); the compiled arm loop (engine/compiled/arm_host.py) takes them from here.

    gain: d_i / T per joint (`coupled_reservoir`); bound_gain: 4 d_i / h (`coupled_bounded`; h the
    hold budgeted, `CoupledEnergyBoundParams.hold_s`: one period unless max_hold_s says more);
    low, high: the default torque range per joint, -+torque_limit_nm (inf: none);
    keep_direction: limit_mode "scale"; slew_step_nm: S_i T per joint, None without a slew limit.
    """

    gain: npt.NDArray[np.float64]
    bound_gain: npt.NDArray[np.float64]
    low: npt.NDArray[np.float64]
    high: npt.NDArray[np.float64]
    keep_direction: bool
    slew_step_nm: npt.NDArray[np.float64] | None


@dataclass(frozen=True)
class CoupledBoundState:
    """What a `CoupledEnergyBound` carries from one tick to the next: the pooled reservoir, the
    torque applied over the current period (the ledger's tau(n-1)), the joint positions of the
    last step and whether there was one, and the last lambda (`scale`).
    `CoupledEnergyBound.state` gives copies, `set_state` restores (the compiled arm loop carries it)."""

    energy_j: float
    held_nm: npt.NDArray[np.float64]
    last_q_rad: npt.NDArray[np.float64]
    has_last: bool
    scale: float
    extra: tuple[float, ...] = ()  # another law's state (TDPA's: core/tdpa_coupled.TDPA_EXTRA)


class CoupledEnergyBound:
    """One side's pooled joint reservoir and torque bound; `step` is called once per tick.

    step(q, tau_desired): account for the motion since the last tick with the torque applied
    over it, bring tau_desired within the motor limits, then scale it by one lambda so that the
    bound holds (with a slew limit: the slew-aware bound). Returns the torque to apply, held
    until the next tick (the object's own array, overwritten every tick). With the bound off,
    the reservoir is still kept and the limited torque passes unscaled.

    kernels: the array functions to call, by name (`haptic_teleop.assembly.parts.arm_kernels()`
    gives them compiled); None: this module's, interpreted. Same results either way.
    """

    __slots__ = (
        "_bound_gain",
        "_dq",
        "_f_bounded",
        "_f_limited",
        "_f_reservoir",
        "_f_slew",
        "_gain",
        "_has_last",
        "_high",
        "_keep_direction",
        "_last_q",
        "_limited",
        "_low",
        "_out",
        "_step",
        "_stretch",
        "energy_j",
        "held",
        "params",
        "scale",
    )

    def __init__(
        self, params: CoupledEnergyBoundParams, kernels: Mapping[str, Callable[..., Any]] | None = None
    ) -> None:
        self.params = params
        n = params.joints
        t = params.period_s
        d = np.array(params.damping_nm_s_per_rad, dtype=float)
        self._gain = d / t
        # The bound budgets the longest hold (one period unless max_hold_s says more): every demand,
        # the slew-aware descent's per-step ones included, is (h/4) tau.T D^-1 tau = sum tau_i^2 / bound_gain_i.
        self._bound_gain = 4.0 * d / params.hold_s
        lim = np.array(params.torque_limit_nm or (math.inf,) * n, dtype=float)
        self._high = lim
        self._low = -lim
        self._keep_direction = params.limit_mode == "scale"
        self._step = np.array(params.slew_nm_per_s, dtype=float) * t if params.slew_nm_per_s else None
        self.energy_j = params.initial_energy_j
        self.held = np.zeros(n)  # the torque applied over the current period (the ledger's tau(n-1))
        self._out = np.zeros(n)
        self._limited = np.zeros(n)
        self._last_q = np.zeros(n)
        self._dq = np.zeros(n)
        self._has_last = False
        # The last lambda (1: the limited desired torque passed unchanged); with a slew limit, the
        # fraction of the way from the fastest descent to the slew-limited desired torque.
        self.scale = 1.0
        self._stretch = 1.0  # the next update's period, in periods (`stretch`)
        k = kernels or {}
        self._f_reservoir = k.get("coupled_reservoir", coupled_reservoir)
        self._f_limited = k.get("joint_limited", joint_limited)
        self._f_bounded = k.get("coupled_bounded", coupled_bounded)
        self._f_slew = k.get("slew_bounded", slew_bounded)

    def step(
        self,
        q: npt.NDArray[np.float64],
        tau_desired: npt.NDArray[np.float64],
        low: npt.NDArray[np.float64] | None = None,
        high: npt.NDArray[np.float64] | None = None,
    ) -> npt.NDArray[np.float64]:
        """One tick: q the joint positions now, tau_desired the law's torque (gravity compensation not
        included). low/high: this tick's torque range per joint for the bounded part (low <= 0 <= high),
        e.g. the motor's range minus the gravity compensation the caller adds after; default
        -+torque_limit_nm."""
        last = self._last_q
        if self._has_last:
            dq = self._dq
            np.subtract(q, last, out=dq)
            gain = self._gain if self._stretch == 1.0 else self._gain / self._stretch
            self.energy_j = self._f_reservoir(self.energy_j, gain, self.held, dq)
        else:
            self._has_last = True
        self._stretch = 1.0
        last[:] = q
        self._f_limited(
            self._limited,
            tau_desired,
            self._low if low is None else low,
            self._high if high is None else high,
            self._keep_direction,
        )
        out = self._out
        step = self._step
        if not self.params.enabled:
            if step is None:
                out[:] = self._limited
            else:  # the motor's slew limit acts anyway
                np.clip(self._limited, self.held - step, self.held + step, out=out)
            self.scale = 1.0
        elif step is None:
            self.scale = self._f_bounded(out, self._limited, self.energy_j, self._bound_gain)
        else:
            self.scale = self._f_slew(out, self._limited, self.held, self.energy_j, step, self._bound_gain)
        self.held[:] = out
        return out

    def applied(self, tau: npt.NDArray[np.float64]) -> None:
        """The torque the motors really applied over the period after the last `step` (if it differs
        from what `step` returned): the next update of the reservoir accounts with it."""
        self.held[:] = tau

    def stretch(self, elapsed_s: float) -> None:
        """The motion the next `step` books took `elapsed_s` of wall time (a real arm whose tick came
        late): that update credits the damping with d_i dq_i^2 / elapsed_s, the least the damper
        dissipated over that time (Cauchy-Schwarz), instead of d_i dq_i^2 / T, which would be up to
        elapsed / T times too much. Shorter than a period (or not finite) changes nothing: T is then
        the conservative one. The torque bound budgets a hold of `params.hold_s`; a longer one is
        `hold_excess_j`'s."""
        periods = elapsed_s / self.params.period_s
        self._stretch = periods if periods > 1.0 and math.isfinite(periods) else 1.0

    def hold_excess_j(self, elapsed_s: float) -> float:
        """The most energy the torque held now (`held`) can have taken beyond what the bound budgeted,
        if it was held `elapsed_s` (`late_hold_excess_j`): 0 within `params.hold_s`."""
        return late_hold_excess_j(self.held, self._bound_gain, elapsed_s, self.params.hold_s)

    def constants(self) -> CoupledBoundConstants:
        """The per-joint constants the tick uses (copies)."""
        return CoupledBoundConstants(
            gain=self._gain.copy(),
            bound_gain=self._bound_gain.copy(),
            low=self._low.copy(),
            high=self._high.copy(),
            keep_direction=self._keep_direction,
            slew_step_nm=None if self._step is None else self._step.copy(),
        )

    def state(self) -> CoupledBoundState:
        """The state the next `step` goes on from (copies): what `set_state` restores."""
        return CoupledBoundState(self.energy_j, self.held.copy(), self._last_q.copy(), self._has_last, self.scale)

    def set_state(self, state: CoupledBoundState) -> None:
        """Restore the state, e.g. after a loop that ran the same ledger elsewhere (the compiled arm
        loop); `held` keeps its identity (its values are copied in)."""
        self.energy_j = state.energy_j
        self.held[:] = state.held_nm
        self._last_q[:] = state.last_q_rad
        self._has_last = state.has_last
        self.scale = state.scale

    def restart(self, energy_j: float) -> None:
        """Start the ledger afresh from `energy_j`, as a new bound: the next `step` takes its q as
        the first (no update for the period before it). With `energy_j` <= the reservoir this only
        discards energy; the live nodes restart at scene time 0 with min(reservoir, initial
        energy), so the ledger from there is the one the bag's analysis recomputes (docs/live_arms.md)."""
        self.energy_j = float(energy_j)
        self._has_last = False

    def task_demand(self, jac: npt.NDArray[np.float64], force: npt.NDArray[np.float64]) -> float:
        """(T/4) F.T J D^-1 J.T F: what task force F at a point with Jacobian `jac` asks of the reservoir."""
        return task_demand(jac, force, self._bound_gain)
