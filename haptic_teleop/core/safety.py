"""Safety of a hardware arm side: start-up check and ramp-in, joint-limit guard, stale reads (docs/safety.md).

Pure: no I/O, no wall clock; the caller passes the time (s, the driver's monotonic read time) and
the measured joint positions. The guards sit *before* the side's energy bound
(`core/eba.py`, `CoupledEnergyBound`), which keeps the torque and slew (step) clamps inside its
own accounting (docs/eba_many_joints.md, "Motor limits", "Slew limit"). Per tick the arm plant calls

    tau_safe, fault = guard.step(t_s, q, tau, stale)

and hands `tau_safe` to the bound. Every guard only ever multiplies each joint's torque by a
factor in [0, 1], so |tau_safe_i| <= |tau_i| for every joint, on every tick.

Why this keeps the port passive: the bound is passive for *any* sequence of desired torques. Its
reservoir books the torque the motors really applied (`CoupledEnergyBound.applied`) against the
measured motion and never lets the reservoir go below 0 (docs/eba_many_joints.md, "Many joints"); the guards
change only what the bound is asked for, never what the ledger books, so they cannot break that
argument. They add safety, not passivity: they lower a torque that is still inside the bound
(scaling a torque down before the bound can only lower what the port applies: the bound's
lambda <= 1 acts on a smaller vector, and with a slew limit the fastest descent stays admissible
whatever the target, docs/eba_many_joints.md, "Slew limit").

- Start-up: `check_start_pose` refuses to start, with each joint's distance (rad and deg) and
  the fix, when the measured pose is farther than the tolerance from the pose the scene expects;
  within it the port torque ramps in from 0 to 1 over `ramp_in_s` (raised cosine: continuous and
  monotone, exactly 1 at `ramp_in_s`), never a jump.
- Joint limits: inside a margin zone before a joint's range end, the torque component pushing
  further out is scaled linearly down to 0 at the end; the component pointing back in passes. A
  joint past its end by more than `overshoot_tolerance_rad` is a fault.
- Stale reads (the driver's read failed, the sample repeats the last good one): the torque is
  held at 0 while stale, through `core/watchdog.py`'s `Watchdog` (its gain, fed by fresh reads;
  with `stale_fade_s` > 0 it fades out and back in linearly over that time); `max_stale_reads`
  consecutive stale reads or `max_stale_s` since the last fresh one are a fault.

- Late holds (a real clock): the energy bound budgets a hold of at most `max_hold_s`
  (`CoupledEnergyBoundParams.max_hold_s`); a nonzero torque held longer may have delivered up to
  `CoupledEnergyBound.hold_excess_j` beyond the reservoir, which no later torque can take back:
  the tick that sees it is a fault (torque off, the run ends), so the excess is at most that one
  hold's (docs/eba_many_joints.md, "Late ticks on a real clock").

A fault latches: from then on `step` returns zero torque and the same fault; the caller stops the
side cleanly (torque off) with `fault.message`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from haptic_teleop.core.watchdog import Watchdog
from haptic_teleop.errors import PlantError

FAULT_KINDS = ("limit", "stale", "position", "hold")


class StartPoseError(PlantError):
    """The measured pose is too far from the pose the scene expects to start from: the message names
    each joint's distance (rad and deg) and what to do."""


@dataclass(frozen=True)
class SafetyFault:
    """Why the guard stopped the side: `kind` one of FAULT_KINDS ("limit": a joint past its range;
    "stale": too many stale reads; "position": a position that is not a finite number; "hold": a torque
    held longer than the energy bound budgets, `max_hold_s`), the joint
    (None for a fault of the whole chain), the time (s) and one line for the user."""

    kind: str
    joint: str | None
    t_s: float
    message: str


HOLD_EXCESS_TOLERANCE_J = 1e-9
"""An over-long hold whose excess is below this is not a fault: a hold a few microseconds past the
budget with a tiny torque costs ~1e-16 J, rounding-level (docs/robustness.md, "Epsilon": 1e-15 to
1e-11 J), a nanojoule is far below any physical effect and far above rounding."""


@dataclass(frozen=True)
class SafetyParams:
    """One side's safety settings, per joint in the plant's joint order.

    joint_names: for messages. period_s: the side's control period (the watchdog's step).
    side: "master" or "slave" (for messages). start_tolerance_rad: the largest distance per joint
    from the expected start pose. ramp_in_s: the ramp-in time (0: none).
    limit_low_rad, limit_high_rad: each joint's range (the MJCF's `range`; -inf/inf: none).
    limit_margin_rad: the width of the zone before each end in which the outward torque fades.
    overshoot_tolerance_rad: how far past an end a joint may be before it is a fault.
    max_stale_reads: consecutive stale reads that make a fault (>= 1). max_stale_s: time since the
    last fresh read that makes a fault. stale_fade_s: the watchdog's fade (0: zero torque at the
    first stale read and full torque at the first fresh one). max_hold_s: the longest hold of a
    nonzero torque the side's energy bound budgets (`CoupledEnergyBoundParams.max_hold_s`; inf: no
    check); a longer one is a fault (docs/eba_many_joints.md, "Late ticks on a real clock").
    """

    joint_names: tuple[str, ...]
    period_s: float
    limit_low_rad: tuple[float, ...]
    limit_high_rad: tuple[float, ...]
    side: str = "slave"
    start_tolerance_rad: tuple[float, ...] = ()
    ramp_in_s: float = 1.0
    limit_margin_rad: tuple[float, ...] = ()
    overshoot_tolerance_rad: float = 0.05
    max_stale_reads: int = 5
    max_stale_s: float = 0.02
    stale_fade_s: float = 0.0
    max_hold_s: float = math.inf

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        if n == 0:
            raise ValueError("joint_names must name at least one joint")
        if not (math.isfinite(self.period_s) and self.period_s > 0.0):
            raise ValueError(f"period_s must be finite and > 0, got {self.period_s}")
        for name in ("limit_low_rad", "limit_high_rad"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} must have one value per joint ({n}), got {getattr(self, name)}")
        for name in ("start_tolerance_rad", "limit_margin_rad"):
            values = getattr(self, name)
            if values and len(values) != n:
                raise ValueError(f"{name} must have one value per joint ({n}) or none (the default), got {values}")
        for i, (lo, hi) in enumerate(zip(self.limit_low_rad, self.limit_high_rad, strict=True)):
            if math.isnan(lo) or math.isnan(hi) or not lo < hi:
                raise ValueError(f"joint {self.joint_names[i]!r}: the range must have low < high, got [{lo}, {hi}]")
        for i, m in enumerate(self.margins_rad()):
            lo, hi = self.limit_low_rad[i], self.limit_high_rad[i]
            if not (math.isfinite(m) and m > 0.0):
                raise ValueError(f"joint {self.joint_names[i]!r}: limit_margin_rad must be finite and > 0, got {m}")
            if math.isfinite(lo) and math.isfinite(hi) and 2.0 * m > hi - lo:
                raise ValueError(
                    f"joint {self.joint_names[i]!r}: limit_margin_rad {m} leaves no free range in [{lo}, {hi}]; "
                    f"allowed: at most half the range ({(hi - lo) / 2:.4g} rad)"
                )
        for i, tol in enumerate(self.tolerances_rad()):
            if not (math.isfinite(tol) and tol >= 0.0):
                raise ValueError(
                    f"joint {self.joint_names[i]!r}: start_tolerance_rad must be finite and >= 0, got {tol}"
                )
        if not (math.isfinite(self.ramp_in_s) and self.ramp_in_s >= 0.0):
            raise ValueError(f"ramp_in_s must be finite and >= 0, got {self.ramp_in_s}")
        if not (math.isfinite(self.overshoot_tolerance_rad) and self.overshoot_tolerance_rad >= 0.0):
            raise ValueError(f"overshoot_tolerance_rad must be finite and >= 0, got {self.overshoot_tolerance_rad}")
        if self.max_stale_reads < 1:
            raise ValueError(f"max_stale_reads must be >= 1, got {self.max_stale_reads}")
        if not (math.isfinite(self.max_stale_s) and self.max_stale_s > 0.0):
            raise ValueError(f"max_stale_s must be finite and > 0, got {self.max_stale_s}")
        if not (math.isfinite(self.stale_fade_s) and self.stale_fade_s >= 0.0):
            raise ValueError(f"stale_fade_s must be finite and >= 0, got {self.stale_fade_s}")
        if not self.max_hold_s >= self.period_s:
            raise ValueError(f"max_hold_s must be at least the period ({self.period_s} s), got {self.max_hold_s}")

    @property
    def joints(self) -> int:
        return len(self.joint_names)

    def tolerances_rad(self) -> tuple[float, ...]:
        """start_tolerance_rad per joint (default: DEFAULT_START_TOLERANCE_RAD)."""
        return self.start_tolerance_rad or (DEFAULT_START_TOLERANCE_RAD,) * self.joints

    def margins_rad(self) -> tuple[float, ...]:
        """limit_margin_rad per joint (default: DEFAULT_LIMIT_MARGIN_RAD)."""
        return self.limit_margin_rad or (DEFAULT_LIMIT_MARGIN_RAD,) * self.joints


DEFAULT_START_TOLERANCE_RAD = 0.1  # about 5.7 deg
DEFAULT_LIMIT_MARGIN_RAD = 0.15  # about 8.6 deg


def _deg(rad: float) -> float:
    return math.degrees(rad)


def check_start_pose(
    measured_q_rad: Sequence[float] | npt.NDArray[np.float64],
    expected_q_rad: Sequence[float] | npt.NDArray[np.float64],
    tolerance_rad: Sequence[float],
    joint_names: Sequence[str],
    side: str = "slave",
) -> None:
    """Refuse to start (StartPoseError) if any joint is farther than its tolerance from the expected
    pose, or reads a position that is not a finite number. The one-line message names every joint's
    distance in rad and deg (those beyond the tolerance marked) and what to do."""
    n = len(joint_names)
    if len(measured_q_rad) != n or len(expected_q_rad) != n or len(tolerance_rad) != n:
        raise ValueError(
            f"check_start_pose needs one value per joint ({n}): measured {len(measured_q_rad)}, "
            f"expected {len(expected_q_rad)}, tolerance {len(tolerance_rad)}"
        )
    parts = []
    beyond = []
    for i, name in enumerate(joint_names):
        q, e, tol = float(measured_q_rad[i]), float(expected_q_rad[i]), float(tolerance_rad[i])
        if not math.isfinite(q):
            raise StartPoseError(
                f"{side} arm: joint {name!r} reads a position that is not a number ({q}); check the device's "
                "wiring and its position sensor before starting"
            )
        d = q - e
        far = not abs(d) <= tol
        if far:
            beyond.append(name)
        parts.append(
            f"{name} {d:+.3f} rad ({_deg(d):+.1f} deg)"
            + (f" > {tol:.3g} rad ({_deg(tol):.1f} deg)" if far else "")
            + f" [measured {q:.3f}, start {e:.3f}]"
        )
    if beyond:
        raise StartPoseError(
            f"{side} arm is too far from its start pose at joint{'s' if len(beyond) > 1 else ''} "
            f"{', '.join(beyond)}: {'; '.join(parts)}. Move the arm to the start pose (start_q_rad) "
            f"before starting, or raise {side}.hardware.start_tolerance_rad"
        )


def ramp_gain(elapsed_s: float, ramp_in_s: float) -> float:
    """Raised cosine from 0 at elapsed 0 to 1 at `ramp_in_s` (and after; 0 before): continuous,
    monotone, slope 0 at both ends. `ramp_in_s` = 0: 1 from elapsed 0 on."""
    if not elapsed_s > 0.0:
        return 1.0 if ramp_in_s == 0.0 and elapsed_s == 0.0 else 0.0
    if elapsed_s >= ramp_in_s:
        return 1.0
    return 0.5 - 0.5 * math.cos(math.pi * (elapsed_s / ramp_in_s))


def limit_factors(
    out: npt.NDArray[np.float64],
    q: npt.NDArray[np.float64],
    tau: npt.NDArray[np.float64],
    low: npt.NDArray[np.float64],
    high: npt.NDArray[np.float64],
    margin: npt.NDArray[np.float64],
) -> None:
    """out_i = the factor in [0, 1] on joint i's torque: 1 unless tau_i pushes towards the nearer
    end of the range within `margin` of it, then (distance left) / margin, 0 at or past the end."""
    for i in range(q.shape[0]):
        t = tau[i]
        f = 1.0
        if t > 0.0:
            room = high[i] - q[i]
            if room < margin[i]:
                f = room / margin[i] if room > 0.0 else 0.0
        elif t < 0.0:
            room = q[i] - low[i]
            if room < margin[i]:
                f = room / margin[i] if room > 0.0 else 0.0
        out[i] = f


@dataclass(frozen=True)
class SafetyState:
    """The guard's state after the last tick: the ramp-in gain, the stale-read gain (the watchdog's),
    the consecutive stale reads, the limit factors per joint, the latched fault (or None)."""

    ramp_gain: float
    stale_gain: float
    stale_reads: int
    limit_factor: npt.NDArray[np.float64]
    fault: SafetyFault | None


class SafetyGuard:
    """One side's safety guards, called once per tick before the energy bound.

    `start(t_s, q, expected_q)` once: the start-pose check (StartPoseError), then the ramp-in
    begins at `t_s`. Per tick `step(t_s, q, tau, stale)` -> (tau_safe, fault): tau_safe =
    ramp x stale gain x limit factor per joint x tau (NaN torques -> 0), every factor in [0, 1];
    fault is None, or the first fault (latched: zero torque from then on).
    `tau_safe` is the guard's own array, overwritten every tick.
    """

    __slots__ = (
        "_factor",
        "_fault",
        "_high",
        "_low",
        "_margin",
        "_out",
        "_ramp",
        "_stale_gain",
        "_stale_reads",
        "_t0",
        "_watchdog",
        "params",
    )

    def __init__(self, params: SafetyParams) -> None:
        self.params = params
        n = params.joints
        self._low = np.array(params.limit_low_rad, dtype=float)
        self._high = np.array(params.limit_high_rad, dtype=float)
        self._margin = np.array(params.margins_rad(), dtype=float)
        self._factor = np.ones(n)
        self._out = np.zeros(n)
        period_ns = max(1, round(params.period_s * 1e9))
        # A fresh read feeds the watchdog at its own time, so the age of a fresh tick is 0 and that of
        # a stale one at least a period: a timeout of 1 ns makes "stale" exactly "this read was stale".
        self._watchdog = Watchdog(1, round(params.stale_fade_s * 1e9), period_ns)
        self._t0: float | None = None
        self._ramp = 0.0
        self._stale_gain = 0.0
        self._stale_reads = 0
        self._fault: SafetyFault | None = None

    # ------------------------------------------------------------------------------------ start

    def start(
        self,
        t_s: float,
        q: Sequence[float] | npt.NDArray[np.float64],
        expected_q: Sequence[float] | npt.NDArray[np.float64],
    ) -> None:
        """Check the measured pose against the expected one (StartPoseError beyond the tolerance),
        and against the range ends (StartPoseError past an end by more than the overshoot
        tolerance); then begin the ramp-in at `t_s`."""
        p = self.params
        check_start_pose(q, expected_q, p.tolerances_rad(), p.joint_names, p.side)
        tol = p.overshoot_tolerance_rad
        for i, name in enumerate(p.joint_names):
            qi, lo, hi = float(q[i]), p.limit_low_rad[i], p.limit_high_rad[i]
            if qi > hi + tol or qi < lo - tol:
                raise StartPoseError(
                    f"{p.side} arm: joint {name!r} starts at {qi:.3f} rad ({_deg(qi):.1f} deg), outside its range "
                    f"[{lo:.3f}, {hi:.3f}] rad by more than {tol:.3g} rad; move it back into its range"
                )
        self._t0 = float(t_s)
        t_ns = round(t_s * 1e9)
        self._watchdog.feed(t_ns)
        self._watchdog.update(t_ns)
        self._watchdog.gain = 1.0  # fresh from the start: the ramp-in is the start's fade
        self._stale_gain = 1.0
        self._ramp = ramp_gain(0.0, p.ramp_in_s)

    # ------------------------------------------------------------------------------------ tick

    def step(
        self,
        t_s: float,
        q: npt.NDArray[np.float64],
        tau: npt.NDArray[np.float64],
        stale: bool = False,
        hold_s: float = 0.0,
        hold_excess_j: float = 0.0,
    ) -> tuple[npt.NDArray[np.float64], SafetyFault | None]:
        """One tick: `q` the positions read this tick (the last good ones when `stale`), `tau` the
        port torque the law asks for (gravity compensation not included); `hold_s` how long the torque
        of the last tick was held (the time between this read and the last), `hold_excess_j` the most
        energy that hold can have taken beyond the bound's budget (`CoupledEnergyBound.hold_excess_j`).
        Returns the torque to hand to the energy bound and the fault, if there is one (then the
        torque is 0)."""
        t0 = self._t0
        if t0 is None:
            raise RuntimeError("SafetyGuard.step before start(): the start-pose check must run first")
        out = self._out
        if self._fault is not None:
            out[:] = 0.0
            return out, self._fault
        p = self.params
        fault = self._hold(t_s, hold_s, hold_excess_j)
        if fault is None:
            fault = self._stale(t_s, stale)
        if fault is None:
            fault = self._limits(t_s, q)
        if fault is not None:
            self._fault = fault
            out[:] = 0.0
            return out, fault
        self._ramp = ramp_gain(t_s - t0, p.ramp_in_s)
        limit_factors(self._factor, q, tau, self._low, self._high, self._margin)
        g = self._ramp * self._stale_gain
        np.multiply(self._factor, tau, out=out)
        out *= g
        np.nan_to_num(out, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
        return out, None

    def _hold(self, t_s: float, hold_s: float, excess_j: float) -> SafetyFault | None:
        """A nonzero torque held longer than the bound budgets: the port may have delivered up to
        `excess_j` beyond its reservoir, and only stopping caps it there (docs/eba_many_joints.md, "Late ticks
        on a real clock"). A zero torque held any time delivers nothing: no fault."""
        p = self.params
        if not (hold_s > p.max_hold_s and excess_j > HOLD_EXCESS_TOLERANCE_J):
            return None
        return SafetyFault(
            "hold",
            None,
            t_s,
            f"{p.side} arm: the torque was held {hold_s * 1e3:.1f} ms, longer than the {p.max_hold_s * 1e3:.3g} ms "
            f"the energy bound budgets ({p.side}.hardware.max_hold_s): the port may have delivered up to "
            f"{excess_j:.3g} J beyond its reservoir; stopped, torque off. Keep the loop on time (load, "
            f"scheduling), or raise {p.side}.hardware.max_hold_s (the holdable torque shrinks by "
            "sqrt(period / max_hold_s))",
        )

    def _stale(self, t_s: float, stale: bool) -> SafetyFault | None:
        p = self.params
        wd = self._watchdog
        t_ns = round(t_s * 1e9)
        if stale:
            self._stale_reads += 1
        else:
            self._stale_reads = 0
            wd.feed(t_ns)
        self._stale_gain = wd.update(t_ns)
        if not stale:
            return None
        last = wd.last_arrival_ns
        since = (t_ns - last) * 1e-9 if last is not None else math.inf
        if self._stale_reads >= p.max_stale_reads or since > p.max_stale_s:
            return SafetyFault(
                "stale",
                None,
                t_s,
                f"{p.side} arm: {self._stale_reads} consecutive stale reads, {since * 1e3:.1f} ms since the last "
                f"good one (allowed: fewer than {p.max_stale_reads} reads and at most {p.max_stale_s * 1e3:.1f} ms); "
                "check the cable, the power supply and the bus settings",
            )
        return None

    def _limits(self, t_s: float, q: npt.NDArray[np.float64]) -> SafetyFault | None:
        p = self.params
        tol = p.overshoot_tolerance_rad
        for i, name in enumerate(p.joint_names):
            qi = float(q[i])
            if not math.isfinite(qi):
                return SafetyFault(
                    "position",
                    name,
                    t_s,
                    f"{p.side} arm: joint {name!r} reads a position that is not a number ({qi}); stopped",
                )
            lo, hi = p.limit_low_rad[i], p.limit_high_rad[i]
            past = qi - hi if qi > hi else lo - qi if qi < lo else 0.0
            if past > tol:
                end = hi if qi > hi else lo
                return SafetyFault(
                    "limit",
                    name,
                    t_s,
                    f"{p.side} arm: joint {name!r} at {qi:.3f} rad ({_deg(qi):.1f} deg) is {past:.3f} rad past its "
                    f"limit {end:.3f} rad ({_deg(end):.1f} deg) (allowed overshoot {tol:.3g} rad); stopped. Move it "
                    "back into its range by hand with the torque off",
                )
        return None

    # ------------------------------------------------------------------------------------ state

    @property
    def fault(self) -> SafetyFault | None:
        return self._fault

    @property
    def started(self) -> bool:
        return self._t0 is not None

    def state(self) -> SafetyState:
        """The state after the last tick (copies)."""
        return SafetyState(self._ramp, self._stale_gain, self._stale_reads, self._factor.copy(), self._fault)
