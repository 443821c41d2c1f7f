"""The excitation loop of friction identification (docs/identify.md), on any `JointDriver`.

Joint by joint: the joints not being identified are held where they were by a PD with gravity
compensation; the excited joint runs under a velocity PI with gravity compensation (and the
ramp's inertial feedforward) through the passes of core/friction.py's plan. Every torque beyond
gravity compensation is clamped to a fraction of the motor's limit (Excitation.torque_fraction,
default 30 %), the total to the limit. A range guard brakes the excited joint before it comes
within half the margin of an end (a pass's window the guard touched is discarded) and a joint
outside its range, a held joint pushed away, a runaway velocity or any driver error stops the run;
`driver.stop()` (torque off) runs on every exit path, Ctrl-C included.

Pacing: a driver with `lockstep = True` (the simulated one) is run as fast as it goes; any other
at the control period on an absolute deadline grid (time.perf_counter), a deadline missed by
more than 10 periods re-anchoring the grid (counted in `overruns`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from haptic_teleop.core.friction import (
    Z_DEFAULT,
    Excitation,
    FrictionFit,
    Pass,
    Plan,
    Window,
    brake_speed,
    choose_direction,
    fit_friction,
    plan_passes,
    reposition,
)
from haptic_teleop.errors import PlantError
from haptic_teleop.plants.hardware import JointDriver, JointSample
from haptic_teleop.plants.kinematics import ArmKinematics

MAX_CATCH_UP = 10  # periods a paced loop may lag before its deadline grid is re-anchored
STALL_S = 0.1  # clamped and nearly still this long while driven: the joint is blocked (an obstacle)
STALL_SPEED_SHARE = 0.25  # "nearly still": below this share of the speed reference
MAX_BLOCKS = 4  # obstacles found per joint before the joint is given up (each one narrows its range)
STEADY_SHARE = 0.2  # a window's speed may change by at most this share of the pass speed across it

# Why a measure window was not used (JointIdentification.rejected_by), in the order reported.
REASONS = ("blocked", "guard", "clamp", "stale", "speed", "unsteady", "no room")


class IdentifyFault(PlantError):
    """The excitation stopped the arm: a joint left its range, a held joint was pushed away, a
    velocity ran away. The driver's torque is off when this is raised."""


@dataclass(frozen=True)
class Gains:
    """The loops' bandwidths, turned into gains with each joint's inertia M_jj (at the start):
    velocity PI Kv = 2 M w, Ki = M w^2 (critically damped); hold PD Kp = M w^2, Kd = 2 M w.
    hold_tolerance_rad: a held joint further than this from its hold position is a fault."""

    velocity_bandwidth_hz: float = 5.0
    hold_bandwidth_hz: float = 5.0
    hold_tolerance_rad: float = 0.3
    start_hold_s: float = 0.3  # every joint held still before a joint's first pass


@dataclass(frozen=True)
class Progress:
    """Where the run is: joint `joint` (index of `joints`), pass `pass_index` of `passes`, and the
    ticks run so far over all joints (`ticks`, of about `total_ticks`)."""

    joint: str
    joint_index: int
    joints: int
    pass_index: int
    passes: int
    ticks: int
    total_ticks: int


@dataclass(frozen=True)
class JointIdentification:
    """One joint's result: the fit (None if it failed: `error` says why), the samples it used,
    the speeds left out for the range, the windows discarded and why (`rejected_by`, reason ->
    count, reasons of REASONS: "blocked" the joint stalled against an obstacle in that pass,
    "guard" the range guard braked it, "clamp" / "stale" the torque clamp bound or reads were
    stale in more than 5 % of the window, "speed" the mean speed was not within 20 % of the pass
    speed, "unsteady" the speed changed by more than 20 % of it across the window, "no room" no
    pass fitted where the joint was), and the range the passes were planned in (`range_rad`: the
    model's, narrowed to where an obstacle stopped the joint; `narrowed` then True)."""

    joint: str
    fit: FrictionFit | None
    velocity_rad_per_s: tuple[float, ...]
    friction_nm: tuple[float, ...]
    dropped_speeds_rad_per_s: tuple[float, ...]
    rejected_windows: int
    error: str | None = None
    rejected_by: tuple[tuple[str, int], ...] = ()
    range_rad: tuple[float, float] | None = None
    narrowed: bool = False  # an obstacle stopped the joint inside its model range


@dataclass
class IdentifyResult:
    joints: list[JointIdentification] = field(default_factory=list)
    interrupted: bool = False
    ticks: int = 0
    overruns: int = 0


class Identifier:
    """Runs the identification of `joints` (names, driver order; None: all) on `driver`.

    kin: the arm's kinematics in the driver's joint order (gravity torque and inertia); period_s:
    the control period; offset: fit an unmodelled constant bias too; progress: called at every
    pass and every 100 ticks; paced: whether to pace the loop on the period (None: unless the driver
    says `lockstep = True`; False for a device whose time advances with each write, as the bus
    emulator in lockstep mode). `request_stop()` (from a signal handler) ends the run at the next tick.
    """

    def __init__(
        self,
        driver: JointDriver,
        kin: ArmKinematics,
        period_s: float,
        excitation: Excitation | None = None,
        joints: Sequence[str] | None = None,
        z: float = Z_DEFAULT,
        offset: bool = False,
        gains: Gains | None = None,
        progress: Callable[[Progress], None] | None = None,
        paced: bool | None = None,
    ) -> None:
        if tuple(kin.joints) != tuple(driver.joints):
            raise PlantError(
                f"the kinematics' joints ({', '.join(kin.joints)}) are not the driver's ({', '.join(driver.joints)})"
            )
        if not (period_s > 0.0 and math.isfinite(period_s)):
            raise PlantError(f"period_s must be > 0, got {period_s}")
        names = tuple(driver.joints) if joints is None else tuple(joints)
        for name in names:
            if name not in driver.joints:
                raise PlantError(f"no joint {name!r}; allowed: {', '.join(driver.joints)}")
        self.driver = driver
        self.kin = kin
        self.period_s = period_s
        self.exc = excitation if excitation is not None else Excitation()
        self.names = names
        self.z = z
        self.offset = offset
        self.gains = gains if gains is not None else Gains()
        self.progress = progress
        self.lockstep = bool(getattr(driver, "lockstep", False)) if paced is None else not paced
        self.ranges = kin.joint_range_rad()
        self.limit = np.minimum(np.asarray(driver.torque_limit_nm, dtype=float), kin.torque_limit_nm())
        self.plans: dict[str, Plan] = {
            name: plan_passes(self.exc, self._range(driver.joints.index(name))) for name in names
        }
        hold = round(self.gains.start_hold_s / period_s)
        self.total_ticks = sum(round(p.duration_s / period_s) + hold for p in self.plans.values())
        self._stop = False

    def _range(self, j: int) -> tuple[float, float]:
        return float(self.ranges[j, 0]), float(self.ranges[j, 1])

    def request_stop(self) -> None:
        self._stop = True

    # ------------------------------------------------------------------------------ the run

    def run(self) -> IdentifyResult:
        result = IdentifyResult()
        self._result = result
        try:
            sample = self.driver.start()
            self._check_sample(sample)
            self._deadline = time.perf_counter()
            for k, name in enumerate(self.names):
                sample, ident = self._identify_joint(k, name, sample)
                if ident is not None:
                    result.joints.append(ident)
                if self._stop:
                    result.interrupted = True
                    break
        finally:
            self.driver.stop()
        return result

    def _check_sample(self, s: JointSample) -> None:
        n = len(self.driver.joints)
        if s.q_rad.shape != (n,) or s.qd_rad_per_s.shape != (n,):
            raise PlantError(f"the driver returned {s.q_rad.size} positions for {n} joints")
        if not (np.isfinite(s.q_rad).all() and np.isfinite(s.qd_rad_per_s).all()):
            raise PlantError("the driver returned a non-finite joint position or velocity")

    def _tick(self, tau: np.ndarray) -> tuple[np.ndarray, JointSample]:
        """Write the torques, wait for the next deadline (paced drivers), read the next state."""
        applied = np.asarray(self.driver.write(tau), dtype=float)
        if not self.lockstep:
            self._deadline += self.period_s
            now = time.perf_counter()
            if now > self._deadline + MAX_CATCH_UP * self.period_s:
                self._deadline = now
                self._result.overruns += 1
            while True:
                left = self._deadline - time.perf_counter()
                if left <= 0.0:
                    break
                if left > 0.0015:
                    time.sleep(left - 0.001)
        s = self.driver.read()
        self._check_sample(s)
        self._result.ticks += 1
        return applied, s

    def _identify_joint(self, k: int, name: str, sample: JointSample) -> tuple[JointSample, JointIdentification | None]:
        exc, g, dt = self.exc, self.gains, self.period_s
        j = self.driver.joints.index(name)
        plan = self.plans[name]
        lo, hi = self._range(j)  # the model's range: leaving it is a fault
        # Where the passes may go: the model's range, narrowed to where an obstacle (a wall, a cable,
        # the arm's own links) stopped the joint; the range guard brakes at its ends.
        free = [lo, hi]
        passes = list(plan.passes)
        self.kin.set_q(sample.q_rad)
        m_diag = np.maximum(np.diag(self.kin.mass_matrix()), 1e-9)
        wv = 2.0 * math.pi * g.velocity_bandwidth_hz
        wh = 2.0 * math.pi * g.hold_bandwidth_hz
        kv, ki = 2.0 * m_diag[j] * wv, m_diag[j] * wv * wv
        kp, kd = m_diag * wh * wh, 2.0 * m_diag * wh
        room = exc.torque_fraction * self.limit
        hold_q = sample.q_rad.copy()
        max_speed = max(exc.speeds_rad_per_s)
        state = {"integ": 0.0, "vref_prev": 0.0}

        def control(s: JointSample, vref: float | None) -> tuple[np.ndarray, bool]:
            """Torques for state s: hold every joint (vref None) or drive joint j at vref; and
            whether joint j's excitation torque hit its clamp."""
            self.kin.set_q(s.q_rad)
            grav = self.kin.gravity_torque()
            u = kp * (hold_q - s.q_rad) - kd * s.qd_rad_per_s
            saturated = False
            if vref is not None:
                acc = (vref - state["vref_prev"]) / dt
                state["vref_prev"] = vref
                e = vref - float(s.qd_rad_per_s[j])
                uj = kv * e + state["integ"] + m_diag[j] * acc
                if abs(uj) >= room[j]:
                    saturated = True
                    uj = math.copysign(room[j], uj)
                    if e * state["integ"] < 0.0:  # anti-windup: integrate only back from the clamp
                        state["integ"] += ki * e * dt
                else:
                    state["integ"] += ki * e * dt
                u[j] = uj
            u = np.clip(u, -room, room)
            return np.clip(grav + u, -self.limit, self.limit), saturated

        def guard(s: JointSample) -> None:
            q, qd = s.q_rad, s.qd_rad_per_s
            if not lo <= q[j] <= hi:
                raise IdentifyFault(
                    f"joint {name!r} left its range [{lo:.3g}, {hi:.3g}] rad at {q[j]:.4g} rad: stopped, torque off"
                )
            if abs(qd[j]) > 1.5 * max_speed + 0.5:
                raise IdentifyFault(
                    f"joint {name!r} ran away at {qd[j]:.3g} rad/s (the plan's fastest is {max_speed:g}): stopped, "
                    "torque off"
                )
            for i, other in enumerate(self.driver.joints):
                if i != j and abs(q[i] - hold_q[i]) > g.hold_tolerance_rad:
                    raise IdentifyFault(
                        f"held joint {other!r} was pushed {q[i] - hold_q[i]:+.3g} rad from its hold position "
                        f"(allowed {g.hold_tolerance_rad:g} rad): stopped, torque off"
                    )

        def report(pass_index: int) -> None:
            if self.progress is not None:
                self.progress(
                    Progress(name, k, len(self.names), pass_index, len(passes), self._result.ticks, self.total_ticks)
                )

        # Hold still first: the PD takes over from wherever the arm is.
        report(0)
        for _ in range(round(g.start_hold_s / dt)):
            if self._stop:
                return sample, None
            tau, _ = control(sample, None)
            _, sample = self._tick(tau)
            guard(sample)
        velocities: list[float] = []
        frictions: list[float] = []
        rejected = dict.fromkeys(REASONS, 0)
        stall_ticks = round(STALL_S / dt)

        def run_pass(p: Pass, sign: int) -> bool:
            """Run pass p in direction `sign`; False if an obstacle stopped the joint (the free
            range is narrowed to where it stood, the pass is cut short)."""
            nonlocal sample
            window = Window() if p.measure else None
            clamped = stale = still = 0
            guarded = False
            for step in range(round(p.duration_s / dt)):
                if self._stop:
                    return True
                t = step * dt
                q = float(sample.q_rad[j])
                edge = (free[1] - 0.5 * exc.margin_rad - q) if sign > 0 else (q - free[0] - 0.5 * exc.margin_rad)
                speed = p.velocity(t)
                cap = brake_speed(edge, exc.accel_rad_per_s2)
                if cap < speed:
                    speed, guarded = cap, guarded or p.in_window(t)
                tau, saturated = control(sample, sign * speed)
                # Blocked: the excitation torque at its clamp and the joint nearly still while driven.
                moving = sign * float(sample.qd_rad_per_s[j]) >= STALL_SPEED_SHARE * speed
                still = still + 1 if (saturated and speed > 0.0 and not moving) else 0
                if still >= stall_ticks:
                    if sign > 0:
                        free[1] = min(free[1], q)
                    else:
                        free[0] = max(free[0], q)
                    state["integ"] = 0.0  # let go of the obstacle
                    state["vref_prev"] = 0.0
                    if p.measure:
                        rejected["blocked"] += 1
                    return False
                applied, nxt = self._tick(tau)
                if window is not None and p.in_window(t):
                    clamped += int(saturated)
                    stale += int(getattr(sample, "stale", 0) > 0)  # a repeated (stale) read
                    window.add(
                        t,
                        float(sample.qd_rad_per_s[j]),
                        float(applied[j] - self.kin.gravity_torque()[j]),
                        sample.qd_rad_per_s,
                    )
                sample = nxt
                guard(sample)
                if self.progress is not None and self._result.ticks % 100 == 0:
                    report(pass_index)
            if window is None or window.count == 0:
                return True
            self.kin.set_q(sample.q_rad)
            v, tau_f = window.sample(self.kin.mass_matrix()[j])
            target = sign * p.speed_rad_per_s
            drift = abs(float(window.mean_acceleration()[j])) * p.measure_s  # speed change across it
            reason = (
                "guard"
                if guarded
                else "clamp"
                if clamped > 0.05 * window.count
                else "stale"
                if stale > 0.05 * window.count
                else "speed"
                if abs(v - target) > 0.2 * p.speed_rad_per_s
                else "unsteady"
                if drift > STEADY_SHARE * p.speed_rad_per_s
                else None
            )
            if reason is not None:
                rejected[reason] += 1
                return True
            velocities.append(v)
            frictions.append(tau_f)
            return True

        blocks = 0
        # Each pass goes the other way from the last one (the plan's +, -, +, ... from where the joint
        # really is): a pass the range turned round is followed by one the other way, so every speed
        # keeps its passes in both directions.
        last = -passes[0].prefer if passes else 1
        dropped = plan.dropped_speeds_rad_per_s
        pass_index = 0
        while pass_index < len(passes) and not self._stop:
            p = passes[pass_index]
            pass_index += 1
            report(pass_index - 1)
            rng = (free[0], free[1])
            sign = choose_direction(float(sample.q_rad[j]), rng, exc.margin_rad, p.travel_rad, -last)
            if sign == 0:
                move = reposition(
                    float(sample.q_rad[j]), rng, exc.margin_rad, p.travel_rad, p.speed_rad_per_s, exc.accel_rad_per_s2
                )
                if move is not None and not run_pass(move, move.prefer):
                    sign = 0  # the move found an obstacle: re-plan below
                else:
                    rng = (free[0], free[1])
                    sign = choose_direction(float(sample.q_rad[j]), rng, exc.margin_rad, p.travel_rad, -last)
                    if sign == 0:
                        rejected["no room"] += 1
                        continue
            if sign != 0:
                last = sign
                if run_pass(p, sign):
                    continue
            # An obstacle narrowed the free range: re-plan the passes in it and run them from the
            # start (the samples taken so far are kept: they were measured clear of it).
            blocks += 1
            if blocks > MAX_BLOCKS:
                break
            replanned = plan_passes(exc, (free[0], free[1]))
            passes, dropped, pass_index = list(replanned.passes), replanned.dropped_speeds_rad_per_s, 0
            self.total_ticks += round(replanned.duration_s / dt)
        if self._stop:
            return sample, None  # a joint not finished is left out
        fit: FrictionFit | None = None
        error = None
        try:
            fit = fit_friction(velocities, frictions, offset=self.offset, z=self.z)
        except ValueError as exc_:
            error = str(exc_)
        return sample, JointIdentification(
            name,
            fit,
            tuple(velocities),
            tuple(frictions),
            dropped,
            sum(rejected.values()),
            error,
            tuple((r, n) for r, n in rejected.items() if n),
            (free[0], free[1]),
            blocks > 0,
        )
