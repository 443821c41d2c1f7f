"""A real arm as the engine's arm plant: a `JointDriver` (the device) and an `ArmKinematics` of the
same MJCF model (docs/hardware_plant.md, "The hardware arm plant").

`HardwareArm` has the interface the arm tick uses on `MujocoArm` (engine/loop.py,
nodes/arm_side.py): `read()`, `point()`, `jacobian()`, `orientation()`, `angular_velocity()`,
`gravity_torque()`, `torque_room()`, `step()`, `contact_wrench()`, `joint_damping()`, `close()`.
Per tick:

- `read()` reads the driver once (one sync read of the bus) and sets the kinematics' q; every
  other query of the tick is of that configuration (further `read()` calls before `step()` return
  the same sample, as `MujocoArm.read` does within a tick);
- `safe_torque(tau)`, which the tick calls on the desired torque before the energy bound: the
  safety guards of core/safety.py (`SafetyGuard`: the start-up ramp-in, the joint-limit zone,
  stale reads, a hold longer than the energy bound budgets), each only shrinking a joint's torque;
  a guard's fault stops the arm (torque off) and raises HardwareError with its message. The
  guards' clock is scene time (ticks x period), so a run against the lockstep emulator is
  deterministic;
- `step(tau)` takes the port torque (beyond gravity compensation), keeps each joint's total within
  the motor's limit (as `MujocoArm` does: compensation spends the motor's real torque), adds the
  gravity torque and writes the total through the driver (one sync write). It returns the port
  torque commanded (after the device's quantisation and clip): the joint_states effort.

Applied, not commanded (docs/hardware_plant.md): each read also gives `port_torque_nm`, the port torque
the motors really applied over the hold that ended at this read, as the device reports it (the
sample's `tau_nm`, the motors' torque) minus the gravity compensation written with the command
that hold answered (zero before the first write). The engine records it (`/<side>/measured_effort`)
and sets the energy bound's `held` from it before the bound books the hold's motion. Where the
device gives no report (`JointSample.measured` False: a UR in task space, a read before a UR's
first report) it is the port torque last commanded, `torque_measured` is False for that tick and
`unmeasured_reads` counts it, `unmeasured_after_report` those after the device's first report (the
run facts carry both).

The driver starts at the first `read()` (not when the plant is built): the engine builds both
sides, warms up its kernels and opens the bag before the first tick, longer than a servo's bus
watchdog may wait, and a live node builds the other side's plant only for its start point. Until
then the plant's state is the scene's start configuration (`start_q_rad`), which the start-up check
then compares with the measured pose (`SafetyGuard.start`): within `start_tolerance_rad` the run
goes on and the torque ramps in over `ramp_in_s`; farther, the run is refused with each joint's
distance (StartPoseError, torque off: never a jump).

Damping: a real arm's viscous damping cannot be read from a simulator; `joint_damping()` returns
what the scene says EBA may assume (`<side>.damping_nm_s_per_rad`, measured by `haptic-teleop
identify`): at most what the hardware dissipates, or the bound is not passive.

Contact: a Dynamixel arm has no force sensor. A slave's `contact_wrench()` is the quasi-static
estimate from the motors' measured torques: with tau_port = tau_measured - g(q) the torque the
motors apply beyond gravity, the arm at rest balances the environment's force f on the tool,
J^T f + tau_port = 0, so f = -(J^T)^+ tau_port (least squares; the torque about the tool point is
not estimated: zero). Its errors: the joint friction (Coulomb and viscous: the estimate sees
friction as contact while the arm moves, and misses up to the friction torque at rest), the
inertial and Coriolis torques of a moving arm, the torque constant (current to torque, +-10 %
from the datasheet unless identified), the gravity model (masses), and a singular Jacobian (a force
along a direction the joints cannot resist is invisible). The recorded `s_contact_n` of a hardware
slave is this estimate (`contact_estimated` is True). A master has no environment: zero, and
`contact_estimated` False.

The operator's hand on a master is a real hand (or the emulator's operator): `step` refuses a
commanded hand force. Faults from the driver (HardwareError) propagate: the plant never swallows
them; the engine stops both sides and ends the run.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from haptic_teleop.core.eba_coupled import DEFAULT_MAX_HOLD_PERIODS, late_hold_excess_j
from haptic_teleop.core.safety import SafetyGuard, SafetyParams
from haptic_teleop.errors import PlantError
from haptic_teleop.plants.hardware import HardwareError, JointDriver, JointSample

if TYPE_CHECKING:
    from haptic_teleop.plants.arm import WallSpec
    from haptic_teleop.plants.kinematics import ArmKinematics


class HardwareArm:
    """One real arm (master device or slave), joints in the driver's order.

    driver: the device (not started yet); kinematics: an `ArmKinematics` of the arm's MJCF with
    the driver's joints and the side's point site ("handle" or "tool"); damping_nm_s_per_rad: what
    EBA may assume, per joint; start_q_rad: where the arm must be at start (within
    start_tolerance_rad); period_s: the control period (the ramp's clock counts ticks);
    torque_limit_nm: the scene's limit per joint (the smaller of it and the driver's is used);
    wall: the slave's wall as the scene places it (for the analysis and the emulator; nothing
    here simulates it); role: "master" or "slave"; wrench_source: the device's own measure of
    the environment's wrench on the tool (force, then torque; e.g. a UR's TCP wrench), used for
    a slave's contact instead of the estimate from the motor torques; lockstep_clock: the device
    advances one period per command (the bus emulator in lockstep time), so `read_interval_s`, the
    time the motion between two reads took, is one period; else the driver's read times give it.
    max_hold_s: the longest hold the side's energy bound budgets on a real clock (`hold_budget_s`;
    None: DEFAULT_MAX_HOLD_PERIODS periods; a lockstep clock: one period, whatever it says); a longer hold of a nonzero
    torque is the safety guard's "hold" fault (docs/eba_many_joints.md, "Late ticks on a real clock").
    """

    def __init__(
        self,
        driver: JointDriver,
        kinematics: ArmKinematics,
        damping_nm_s_per_rad: Sequence[float],
        start_q_rad: Sequence[float],
        period_s: float,
        role: str,
        torque_limit_nm: Sequence[float] | None = None,
        gravity_compensation: bool = True,
        wall: WallSpec | None = None,
        start_tolerance_rad: float = 0.05,
        ramp_in_s: float = 0.5,
        source: str = "",
        wrench_source: Callable[[], np.ndarray] | None = None,
        lockstep_clock: bool = False,
        max_hold_s: float | None = None,
    ) -> None:
        if tuple(driver.joints) != tuple(kinematics.joints):
            raise PlantError(
                f"{role}: the driver's joints {list(driver.joints)} and the model's {list(kinematics.joints)} differ"
            )
        self.driver = driver
        self.kinematics = kinematics
        self.role = role
        self.joints = tuple(kinematics.joints)
        self.n = len(self.joints)
        self.source = source or role
        for name, v in (("damping_nm_s_per_rad", damping_nm_s_per_rad), ("start_q_rad", start_q_rad)):
            if len(v) != self.n:
                raise PlantError(f"{role}: {name} has {len(v)} values for {self.n} joints")
        self._damping = np.array(damping_nm_s_per_rad, dtype=float)
        self._start_q = np.array(start_q_rad, dtype=float)
        limit = np.asarray(driver.torque_limit_nm, dtype=float).copy()
        if torque_limit_nm is not None:
            if len(torque_limit_nm) != self.n:
                raise PlantError(f"{role}: torque_limit_nm has {len(torque_limit_nm)} values for {self.n} joints")
            limit = np.minimum(limit, np.asarray(torque_limit_nm, dtype=float))
        if not np.all(np.isfinite(limit)) or np.any(limit <= 0.0):
            raise PlantError(f"{role}: every motor needs a finite torque limit > 0, got {limit.tolist()}")
        self.torque_lo, self.torque_hi = -limit, limit
        self._gravity = gravity_compensation
        self.wall = wall
        self.tool_radius_m = 0.0
        self.contact_estimated = role == "slave" and wrench_source is None
        self._wrench_source = wrench_source if role == "slave" else None
        self._period_s = period_s
        if lockstep_clock:  # the device advances one period per command: every hold is one period
            max_hold_s = period_s
        elif max_hold_s is None:
            max_hold_s = DEFAULT_MAX_HOLD_PERIODS * period_s
        if not (math.isfinite(max_hold_s) and max_hold_s >= period_s):
            raise PlantError(f"{role}: max_hold_s must be finite and >= the period {period_s} s, got {max_hold_s}")
        self.hold_budget_s = float(max_hold_s)  # the hold the energy bound budgets (assembly passes it on)
        # (h/4) tau.T D^-1 tau = sum tau_i^2 / hold_gain_i: the bound's gains (CoupledEnergyBound)
        self._hold_gain = 4.0 * self._damping / self.hold_budget_s
        rng = kinematics.joint_range_rad()
        self.safety = SafetyGuard(
            SafetyParams(
                joint_names=self.joints,
                period_s=period_s,
                limit_low_rad=tuple(float(v) for v in rng[:, 0]),
                limit_high_rad=tuple(float(v) for v in rng[:, 1]),
                side=role,
                start_tolerance_rad=(start_tolerance_rad,) * self.n,
                ramp_in_s=ramp_in_s,
                max_hold_s=self.hold_budget_s,
            )
        )
        self._stale = False
        self._lockstep = lockstep_clock
        self.read_interval_s = period_s  # how long the motion since the previous read took
        self._started = False  # driver.start() attempted (stop() is then owed)
        self._ticks = 0  # steps written since the start (the ramp's clock)
        self._fresh = True  # the state below is this tick's (the start pose until the first read)
        self._q = self._start_q.copy()
        self._qd = np.zeros(self.n)
        self._tau_measured = np.zeros(self.n)
        self._applied = np.zeros(self.n)  # the port torque last commanded (written - g)
        self._g_written = np.zeros(self.n)  # the gravity compensation written with it (0 before a write)
        self._port = np.zeros(self.n)  # the port torque of the hold that ended at the last read
        self.torque_measured = True  # `port_torque_nm` is the device's report (False: the command)
        self.unmeasured_reads = 0  # reads whose sample carried no report (the command stood in)
        self.unmeasured_after_report = 0  # of those, the reads after the device's first report
        self._reported = False  # a read has carried a report
        self._sample_t_s = -math.inf
        self.kinematics.set_q(self._q)
        self.stale_ticks = 0  # ticks whose read failed (the driver repeated its last good sample)
        # Holds on a real clock (the time between two reads): longer than two periods, longer than
        # the budget (with a nonzero torque that is the guard's fault), and the longest.
        self.long_holds = 0
        self.over_budget_holds = 0
        self.longest_hold_s = 0.0
        self.read_times_s: list[float] | None = None  # a list: each read's driver time is appended (tests)

    # ---------------------------------------------------------------------------------- state

    @property
    def damping_nm_s_per_rad(self) -> np.ndarray:
        """The joint damping EBA may assume (the scene's; for hardware never read from a model)."""
        return self._damping.copy()

    def joint_damping(self) -> list[float]:
        """The Plant protocol's name for `damping_nm_s_per_rad` (N m s/rad per joint)."""
        return [float(b) for b in self._damping]

    @property
    def started(self) -> bool:
        return self._started

    def _take(self, s: JointSample) -> None:
        q = np.asarray(s.q_rad, dtype=float)
        if q.shape != (self.n,) or not np.all(np.isfinite(q)):
            raise HardwareError(f"{self.source}: the driver read {q.tolist()} for {self.n} joints")
        self._q = q.copy()
        self._qd = np.asarray(s.qd_rad_per_s, dtype=float).copy()
        self._tau_measured = np.asarray(s.tau_nm, dtype=float).copy()
        # The port torque of the hold that ended at this read: the report minus the compensation
        # written with the command it answers; without a report, that command (flagged).
        self.torque_measured = bool(getattr(s, "measured", True))
        if self.torque_measured:
            self._port = self._tau_measured - self._g_written
            self._reported = True
        else:
            self._port = self._applied.copy()
            self.unmeasured_reads += 1
            self.unmeasured_after_report += self._reported
        if not self._lockstep and math.isfinite(self._sample_t_s):
            h = float(s.t_s - self._sample_t_s)
            self.read_interval_s = h
            if self._ticks >= 1:  # the start's hold (connecting, the first tick) is not a tick's
                self.longest_hold_s = max(self.longest_hold_s, h)
                self.long_holds += h > 2.0 * self._period_s
                self.over_budget_holds += h > self.hold_budget_s
        self._sample_t_s = s.t_s
        if self.read_times_s is not None:
            self.read_times_s.append(float(s.t_s))
        self._stale = bool(getattr(s, "stale", 0))
        self.stale_ticks += self._stale
        self.kinematics.set_q(self._q)

    def _start(self) -> None:
        self._started = True
        sample = self.driver.start()
        try:
            self._take(sample)
            self.safety.start(0.0, self._q, self._start_q)
        except BaseException:
            self.driver.stop()  # refused: torque off before the error goes on
            raise

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions (rad) and velocities (rad/s) of this tick: the driver is read once per
        tick (the first call after a `step`); the first read starts the driver."""
        if not self._started:
            self._start()
        elif not self._fresh:
            self._take(self.driver.read())
        self._fresh = True
        return self._q.copy(), self._qd.copy()

    def point(self) -> tuple[np.ndarray, np.ndarray]:
        """The handle/tool point's position (m) and velocity J qd (m/s), world frame, this tick."""
        jac = self.kinematics.jacobian()
        return self.kinematics.point(), jac @ self._qd

    def jacobian(self, rotational: bool = False) -> np.ndarray:
        """d(point)/dq, 3 x n (6 x n with the rotational rows under it), this tick (a copy)."""
        return self.kinematics.jacobian(rotational=rotational)

    def orientation(self) -> np.ndarray:
        return self.kinematics.orientation()

    def angular_velocity(self) -> np.ndarray:
        return self.kinematics.jacobian(rotational=True)[3:] @ self._qd

    def gravity_torque(self) -> np.ndarray:
        """Torque per joint the motors add to hold the arm against gravity (the model's), this tick."""
        if not self._gravity:
            return np.zeros(self.n)
        return self.kinematics.gravity_torque()

    def torque_room(self) -> tuple[np.ndarray, np.ndarray]:
        """The range of port torque (beyond gravity compensation) each motor has left, this tick."""
        g = self.gravity_torque()
        return self.torque_lo - g, self.torque_hi - g

    @property
    def measured_torque_nm(self) -> np.ndarray:
        """The motors' torque this tick as the device reports it (from its current), gravity included."""
        return self._tau_measured.copy()

    @property
    def port_torque_nm(self) -> np.ndarray:
        """The port torque (beyond gravity compensation, N m per joint) the motors applied over the
        hold that ended at this tick's read: the device's report minus the gravity compensation
        written with the command that hold answered; the command where the device reports none
        (`torque_measured` False). What the bag's measured effort holds and the ledger books."""
        return self._port.copy()

    # ---------------------------------------------------------------------------------- step

    def step(self, torque_nm: Sequence[float] | np.ndarray, hand_force_n: Sequence[float] | None = None) -> np.ndarray:
        """Hold the port torques (beyond gravity compensation) until the next tick; returns them as the
        device applies them. NaN becomes 0, each total is kept within its motor's limit, the
        safety guards act (start-up ramp, joint limits), then one write through the driver."""
        if hand_force_n is not None:
            raise PlantError(
                f"{self.source}: a real arm's operator is a real hand: the plant takes no commanded hand force"
            )
        if not self._started:
            self.read()
        g = self.gravity_torque()
        lo, hi = self.torque_lo - g, self.torque_hi - g
        tau = np.asarray(torque_nm, dtype=float)
        tau = np.minimum(np.maximum(np.where(np.isnan(tau), 0.0, tau), lo), hi)
        written = np.asarray(self.driver.write(tau + g), dtype=float)
        applied: np.ndarray = written - g
        self._applied = applied
        self._g_written = np.asarray(g, dtype=float).copy()
        self._ticks += 1
        self._fresh = False
        return applied

    def safe_torque(self, tau: np.ndarray) -> np.ndarray:
        """The safety guards on this tick's desired port torque, before the energy bound
        (core/safety.py): each joint's torque times factors in [0, 1] (ramp-in, joint-limit zone,
        stale read). A fault (a joint past its range, too many stale reads) turns the torque off
        and raises HardwareError naming it."""
        if not self._started:
            self.read()
        hold = self.read_interval_s
        # The first tick's hold straddles the start (its torque the ramp's 0): from the second on.
        excess = 0.0
        if self._ticks >= 2:
            excess = late_hold_excess_j(self._applied, self._hold_gain, hold, self.hold_budget_s)
        out, fault = self.safety.step(
            self._ticks * self._period_s, self._q, np.asarray(tau, dtype=float), self._stale, hold, excess
        )
        if fault is not None:
            self.driver.stop()
            raise HardwareError(f"{self.source}: {fault.message}")
        return out.copy()

    def contact_wrench(self) -> tuple[np.ndarray, np.ndarray]:
        """The environment's force (N) on the tool and its torque about the tool point (N m, zero:
        not estimated), world frame: a slave's quasi-static estimate from the measured motor
        torques, f = -(J^T)^+ (tau_measured - g(q)) (module docstring: its error sources); a
        master's zero."""
        if self._wrench_source is not None:  # a force-torque sensor: the device's own wrench
            w = np.asarray(self._wrench_source(), dtype=float)
            return w[:3].copy(), w[3:6].copy()
        if not self.contact_estimated or self._ticks == 0:
            # Before the first write the motors hold nothing (torque on with zero current): no estimate.
            return np.zeros(3), np.zeros(3)
        tau_port = self._tau_measured - self.gravity_torque()
        jt = self.kinematics.jacobian().T
        f, *_ = np.linalg.lstsq(jt, -tau_port, rcond=1e-6)
        return np.asarray(f, dtype=float), np.zeros(3)

    def contact_penetration_m(self) -> float:
        """How far the tool point is behind the scene's wall surface (m; negative in free space)."""
        if self.wall is None:
            return -math.inf
        x = self.kinematics.point()
        return float(np.dot(np.asarray(self.wall.point_m) - x, self.wall.normal))

    def close(self) -> None:
        """Torque off (the driver's stop: idempotent, never raises)."""
        if self._started:
            self.driver.stop()
