"""The Universal Robots driver over the unmodified ur_rtde 1.6.5 (docs/ur.md, "The driver").

`URDriver` reads the robot through `rtde_receive.RTDEReceiveInterface` (joint state, TCP pose,
speed and wrench, robot and safety status, at the controller's 500 Hz) and, with `control=True`,
commands it through `rtde_control.RTDEControlInterface`, which uploads ur_rtde's control script:
`force_mode` (the robot's own force control), `servo_l`/`speed_l` (position/velocity streaming, for
an admittance: core/admittance.py) or `torque` (direct joint torques, where the controller has
them). Every call checks the session: a protective stop, an emergency stop, another safety stop, a
lost connection or a control script that stopped ends it (`stop()`, then `HardwareError` naming
what happened and what to do), and in direct torque every fresh read compares the torque each
joint reports it applies (RTDE `actual_current_as_torque`) with the torque commanded (docs/ur.md,
"Applied, not commanded"). `stop()` is idempotent and never raises. `URTorqueDriver` is the
`JointDriver` (plants/hardware.py) of the direct-torque mode.

ur_rtde is imported inside functions only: this module imports without it.
"""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from haptic_teleop.plants.hardware import HardwareError, JointSample, import_sdk
from haptic_teleop.plants.ur.codes import (
    JOINT_MODE,
    JOINT_RUNNING,
    ROBOT_MODE,
    RUNNING,
    SAFETY_BIT_PROTECTIVE,
    SAFETY_BITS_EMERGENCY,
    SAFETY_MODE,
    SAFETY_STOP_WHAT_TO_DO,
)
from haptic_teleop.plants.ur.commands import clip_twist, direct_torque_supported, force_mode_args
from haptic_teleop.plants.ur.rtde_outputs import RTDEOutputError, RTDEOutputReader

JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
UR5E_TORQUE_LIMIT_NM = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)  # UR5e rated joint torques (ur5e.xml ctrlrange)
RTDE_PORT, DASHBOARD_PORT = 30004, 29999
APPLIED_OUTPUT = "actual_current_as_torque"  # N m per joint, gravity excluded; PolyScope 5.23 / 10.11 on
APPLIED_REL = 0.2  # a fifth of the command on top of the absolute tolerance (the Dynamixel driver's rule)
APPLIED_TOLERANCE_NM = tuple(0.02 * t for t in UR5E_TORQUE_LIMIT_NM)  # 2 % of the rated torque (docs/ur.md)
APPLIED_MISMATCH_READS = 25  # 50 ms of fresh reads at the controller's 500 Hz
# A send gap over the watchdog's period that ended this recently explains a program's end: the host
# stalled, sent again when it woke, and only then read that the controller had stopped the program.
OVERRUN_SEEN_WITHIN_S = 1.0


@dataclass(frozen=True)
class URState:
    """One read: joints (rad, rad/s), TCP pose [x, y, z, rx, ry, rz] (m, rotation vector), TCP speed
    (m/s, rad/s), TCP wrench (the environment's force and torque on the tool, N and N m, base
    frame), robot mode, safety mode and status bits, runtime state, the controller's timestamp (s)
    and the host's monotonic time of the read (s)."""

    q_rad: np.ndarray
    qd_rad_per_s: np.ndarray
    tcp_pose: np.ndarray
    tcp_speed: np.ndarray
    tcp_wrench: np.ndarray
    robot_mode: int
    safety_mode: int
    safety_status_bits: int
    runtime_state: int
    timestamp_s: float
    t_host_s: float


def _with_timeout(fn: Callable[[], Any], timeout_s: float) -> bool:
    """Run fn in a daemon thread; False if it did not return within timeout_s (it is abandoned:
    ur_rtde can block in a socket read when the robot stops answering without closing)."""
    done = threading.Event()

    def run() -> None:
        with contextlib.suppress(Exception):
            fn()
        done.set()

    threading.Thread(target=run, daemon=True).start()
    return done.wait(timeout_s)


def dashboard_query(host: str, command: str, port: int = DASHBOARD_PORT, timeout_s: float = 2.0) -> str:
    """One dashboard server command (a text line) and its one-line answer."""
    with socket.create_connection((host, port), timeout=timeout_s) as s:
        f = s.makefile("rb")
        f.readline()  # the greeting
        s.sendall((command + "\n").encode())
        return f.readline().decode(errors="replace").strip()


def parse_polyscope_version(text: str) -> tuple[int, int, int, int]:
    """ "URSoftware 5.11.1.108318 (...)" -> (5, 11, 1, 108318)."""
    import re

    m = re.search(r"(\d+)\.(\d+)\.(\d+)(?:\.(\d+))?", text)
    if m is None:
        raise HardwareError(f"the dashboard server's PolyscopeVersion answer is not a version: {text!r}")
    return (int(m.group(1)), int(m.group(2)), int(m.group(3)), int(m.group(4) or 0))


class URDriver:
    """A UR arm through ur_rtde. `host`: the controller's address; `control`: upload the control
    script and command the arm (False: read only); `watchdog_hz`: the RTDE input watchdog the
    script arms (the controller stops the program when no command arrives for 1/watchdog_hz s;
    0 = none); `stale_s`: a read whose controller timestamp has not moved for this long (host
    time) is a lost connection; `applied_tolerance_nm` (per joint, or one for all) and
    `applied_mismatch_reads`: in direct torque, a joint whose reported torque stays further than the
    tolerance plus a fifth of the command from the last two commands for that many fresh reads in a
    row is not applying what it is told (docs/ur.md, "Applied, not commanded")."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        control: bool = True,
        frequency_hz: float = 500.0,
        watchdog_hz: float = 10.0,
        stale_s: float = 0.25,
        max_force_n: float = 100.0,
        max_speed_m_per_s: float = 0.25,
        max_angular_rad_per_s: float = 1.0,
        applied_tolerance_nm: Sequence[float] | float = APPLIED_TOLERANCE_NM,
        applied_mismatch_reads: int = APPLIED_MISMATCH_READS,
    ) -> None:
        self.host = host
        self.control = control
        self.frequency_hz = frequency_hz
        self.watchdog_hz = watchdog_hz
        self.stale_s = stale_s
        self.max_force_n = max_force_n
        self.max_speed_m_per_s = max_speed_m_per_s
        self.max_angular_rad_per_s = max_angular_rad_per_s
        self.joints: tuple[str, ...] = JOINTS
        self.torque_limit_nm = np.array(UR5E_TORQUE_LIMIT_NM)
        self.version: tuple[int, int, int, int] | None = None
        self._r: Any = None
        self._c: Any = None
        self._modes: set[str] = set()
        self._stopped = False
        self._last_ts = -1.0
        self._last_change = 0.0
        self._last_poll_s = 0.0  # host time of the previous state() (a gap longer than stale_s is the host's own)
        self._connection_lost = False
        self._last_sent_s = 0.0  # host time of the last command the controller accepted (the watchdog's input)
        self._overrun: tuple[float, float] | None = None  # (host time it ended, length): the last send gap > 1/hz
        self.applied_tolerance_nm = np.broadcast_to(np.asarray(applied_tolerance_nm, dtype=float), (6,)).copy()
        self.applied_mismatch_reads = int(applied_mismatch_reads)
        self._applied: RTDEOutputReader | None = None
        self._applied_seq = 0
        # The reading of a read reflects the previous write, or the one before when the read comes
        # within a controller period of it: both are kept.
        self._commanded: deque[np.ndarray] = deque(maxlen=2)
        self._mismatch = np.zeros(6, dtype=int)

    # ------------------------------------------------------------------ start and checks
    def start(self) -> URState:
        """Connect, check the robot is running in normal safety mode, start the control script and
        its watchdog (control=True); returns the first state."""
        import atexit

        rtde_receive = import_sdk("rtde_receive")

        self._stopped = False
        self._connection_lost = False
        self._commanded.clear()
        self._mismatch[:] = 0
        atexit.register(self.stop)
        try:
            self._r = rtde_receive.RTDEReceiveInterface(self.host, self.frequency_hz)
        except RuntimeError as exc:
            raise HardwareError(
                f"cannot read the UR controller at {self.host}:{RTDE_PORT} (RTDE): {exc}; check that the robot is "
                "switched on, the network and the address"
            ) from None
        first = self._read()
        try:
            self._check_ready(first)
        except HardwareError:
            self.stop()
            raise
        if self.control:
            self._start_control()
        self._last_ts, self._last_change = first.timestamp_s, time.monotonic()
        self._last_poll_s = self._last_change
        return first

    def _check_ready(self, s: URState) -> None:
        if s.safety_mode == 3 or s.safety_status_bits & SAFETY_BIT_PROTECTIVE:
            raise HardwareError(
                f"robot at {self.host} is in protective stop: clear it on the teach pendant "
                "(or the dashboard's 'unlock protective stop' once its cause is removed), then start again"
            )
        if s.safety_status_bits & SAFETY_BITS_EMERGENCY or s.safety_mode in (6, 7):
            raise HardwareError(f"robot at {self.host} is emergency-stopped: release the emergency stop, then power on")
        if s.safety_mode not in (1, 2):
            raise HardwareError(
                f"robot at {self.host} is in safety mode {SAFETY_MODE.get(s.safety_mode, s.safety_mode)}: "
                "clear it on the teach pendant"
            )
        if s.robot_mode != RUNNING:
            what = ROBOT_MODE.get(s.robot_mode, str(s.robot_mode))
            if s.robot_mode in (3, 4):
                raise HardwareError(
                    f"robot not powered on (robot mode {what}): power it on and release the brakes on the teach pendant"
                )
            if s.robot_mode == 5:
                raise HardwareError(f"robot powered on but its brakes are not released (robot mode {what})")
            raise HardwareError(f"robot at {self.host} is not running (robot mode {what})")

    def _start_control(self) -> None:
        rtde_control = import_sdk("rtde_control")

        try:
            self.version = parse_polyscope_version(dashboard_query(self.host, "PolyscopeVersion"))
        except OSError as exc:
            self.stop()
            raise HardwareError(
                f"no dashboard server at {self.host}:{DASHBOARD_PORT} ({exc}); is this a UR controller?"
            ) from None
        try:
            self._c = rtde_control.RTDEControlInterface(self.host, self.frequency_hz)
        except RuntimeError as exc:
            self.stop()
            text = str(exc)
            if "remote control" in text:
                raise HardwareError(
                    f"robot at {self.host} is in local control: switch it to remote control on the teach pendant"
                ) from None
            if "control script" in text:
                raise HardwareError(
                    f"the ur_rtde control script did not start on {self.host} within 5 s ({text}); check the robot "
                    "is powered, brakes released, no protective stop, remote control"
                ) from None
            if "already in use" in text:
                raise HardwareError(
                    f"the RTDE input registers of {self.host} are in use by another client (a second control "
                    "session, or the EtherNet/IP adapter, PROFINET or a MODBUS unit configured on the robot): "
                    "end it or disable it in the installation"
                ) from None
            raise HardwareError(f"cannot start control on {self.host}: {text}") from None
        if self.watchdog_hz > 0.0 and not self._c.setWatchdog(self.watchdog_hz):
            self.stop()
            raise HardwareError(f"the controller at {self.host} refused the RTDE watchdog ({self.watchdog_hz} Hz)")
        self._last_sent_s = time.monotonic()

    # ------------------------------------------------------------------ reading
    def _read(self) -> URState:
        r = self._r
        return URState(
            q_rad=np.array(r.getActualQ()),
            qd_rad_per_s=np.array(r.getActualQd()),
            tcp_pose=np.array(r.getActualTCPPose()),
            tcp_speed=np.array(r.getActualTCPSpeed()),
            tcp_wrench=np.array(r.getActualTCPForce()),
            robot_mode=int(r.getRobotMode()),
            safety_mode=int(r.getSafetyMode()),
            safety_status_bits=int(r.getSafetyStatusBits()),
            runtime_state=int(r.getRuntimeState()),
            timestamp_s=float(r.getTimestamp()),
            t_host_s=time.monotonic(),
        )

    def state(self) -> URState:
        """The newest state; raises HardwareError (after stopping) on a fault."""
        if self._r is None or self._stopped:
            raise HardwareError(f"the UR driver for {self.host} is not running (start() it first)")
        if not self._r.isConnected():
            self._fail(
                f"lost the connection to the robot at {self.host}: the controller closed RTDE (it was switched off, "
                "restarted or unplugged, or the network dropped); the controller's RTDE watchdog stops the arm. Check "
                "the controller and the cable, then start a new process (ur_rtde reconnects by itself)",
                lost=True,
            )
        s = self._read()
        now = time.monotonic()
        if s.timestamp_s == self._last_ts and now - self._last_poll_s > self.stale_s:
            # the host itself was away (stalled, stopped, or polls slowly) longer than the staleness
            # limit: the SDK's receive thread may have stalled with it, so it gets stale_s to catch
            # up before the verdict (a frozen stream is still found, stale_s later)
            deadline = now + self.stale_s
            while s.timestamp_s == self._last_ts and now < deadline:
                time.sleep(0.002)
                s, now = self._read(), time.monotonic()
        self._last_poll_s = now
        if s.timestamp_s != self._last_ts:
            self._last_ts, self._last_change = s.timestamp_s, now
        elif now - self._last_change > self.stale_s:
            self._fail(
                f"lost the connection to the robot at {self.host}: no new RTDE data for "
                f"{now - self._last_change:.2f} s (the cable, the network or a stalled controller); the controller's "
                "RTDE watchdog stops the arm. Check the controller and the cable, then start a new process",
                lost=True,
            )
        self._check_safety(s)
        if self._c is not None and not self._c.isProgramRunning():
            self._diagnose()
            self._fail(self._program_stopped_text(now))
        if self._applied is not None and "torque" in self._modes:
            self._check_applied()
        return s

    def _program_stopped_text(self, now_s: float) -> str:
        """Why the control script ended, no safety stop being the cause: the RTDE watchdog when no
        command reached the controller for longer than its period (the host stalled or stopped
        sending), else a stop from outside the session."""
        quiet_s = now_s - self._last_sent_s
        if self._overrun is not None and now_s - self._overrun[0] < OVERRUN_SEEN_WITHIN_S:
            quiet_s = max(quiet_s, self._overrun[1])  # the host stalled, sent again, then saw the program end
        if self.watchdog_hz > 0.0 and quiet_s > 1.0 / self.watchdog_hz:
            return (
                f"the control script on {self.host} was stopped by its RTDE watchdog: no command for {quiet_s:.2f} s, "
                f"over the watchdog's {1.0 / self.watchdog_hz:.2f} s (the host stalled or stopped sending); give the "
                "loop a core of its own and keep other load off the machine, or raise hardware.rtde_watchdog_s, then "
                "start again; the robot was stopped"
            )
        return (
            f"the control script on {self.host} was stopped from outside the session (the teach pendant, the "
            "dashboard server, another program sent to the robot) or ended with a script error: read the log on the "
            "teach pendant, then start again; the robot was stopped"
        )

    def _diagnose(self) -> None:
        """The program ended or a command was refused: find out whether a safety stop is why. The
        control interface's stream can show the end before the receive interface shows the cause,
        so the receive side gets a few periods, then the dashboard server is asked."""
        for _ in range(10):
            time.sleep(0.002)
            self._check_safety(self._read())
        try:
            answer = dashboard_query(self.host, "safetystatus", timeout_s=1.0)
        except OSError:
            return
        if "PROTECTIVE_STOP" in answer:
            self._fail(self._protective_text())
        if "EMERGENCY_STOP" in answer:
            self._fail(self._emergency_text())
        status = answer.rsplit(":", 1)[-1].strip()  # "Safetystatus: SAFEGUARD_STOP"
        for mode in SAFETY_STOP_WHAT_TO_DO:
            if status == SAFETY_MODE[mode]:
                self._fail(self._safety_stop_text(mode))

    def _protective_text(self) -> str:
        return (
            f"robot at {self.host} is in protective stop: clear it on the teach pendant once its cause is removed "
            "(a collision, a force or joint torque over the safety limits, the program's request), or with the "
            "dashboard's 'unlock protective stop'; the session was stopped"
        )

    def _emergency_text(self) -> str:
        return (
            f"robot at {self.host} was emergency-stopped: release the emergency stop, power the arm on and release "
            "the brakes on the teach pendant, then start again; the session was stopped"
        )

    def _safety_stop_text(self, mode: int) -> str:
        return (
            f"robot at {self.host} stopped in safety mode {SAFETY_MODE.get(mode, mode)}: "
            f"{SAFETY_STOP_WHAT_TO_DO[mode]}, then start again; the session was stopped"
        )

    def _check_safety(self, s: URState) -> None:
        if s.safety_mode == 3 or s.safety_status_bits & SAFETY_BIT_PROTECTIVE:
            self._fail(self._protective_text())
        if s.safety_status_bits & SAFETY_BITS_EMERGENCY or s.safety_mode in (6, 7):
            self._fail(self._emergency_text())
        if s.safety_mode in SAFETY_STOP_WHAT_TO_DO:
            self._fail(self._safety_stop_text(s.safety_mode))

    def _check_applied(self) -> None:
        """The torque each joint reports it applies against the last two commands: a joint off both
        by more than its tolerance plus a fifth of the command for `applied_mismatch_reads` fresh
        reads in a row is not applying what the session records as applied: find why, stop, one
        error naming it (docs/ur.md, "Applied, not commanded")."""
        assert self._applied is not None
        if self._applied.closed_reason is not None:
            self._fail(
                f"lost the connection to the robot at {self.host}: its RTDE stream of {APPLIED_OUTPUT} ended "
                f"({self._applied.closed_reason}); check the controller and the cable, then start a new process",
                lost=True,
            )
        package = self._applied.latest()
        if package is None or package.seq == self._applied_seq or not self._commanded:
            return  # nothing fresh: a read between two controller packages repeats the last one
        self._applied_seq = package.seq
        reported = np.asarray(package.values[APPLIED_OUTPUT], dtype=float)
        commanded = np.array(self._commanded)
        err = np.min(np.abs(commanded - reported), axis=0)
        off = err > self.applied_tolerance_nm + APPLIED_REL * np.abs(commanded[-1])
        self._mismatch = np.where(off, self._mismatch + 1, 0)
        k = int(np.argmax(self._mismatch))
        if self._mismatch[k] >= self.applied_mismatch_reads:
            self._fail(self._applied_text(k, float(reported[k]), float(commanded[-1][k])))

    def applied_torque_nm(self) -> np.ndarray | None:
        """The torque each joint last reported it applies beyond gravity compensation (N m, RTDE
        `actual_current_as_torque`, the newest package of the stream `_check_applied` reads), or
        None: no direct torque session yet (the stream opens with the first `torque()`), or no
        package arrived yet."""
        reader = self._applied
        package = None if reader is None else reader.latest()
        if package is None:
            return None
        return np.asarray(package.values[APPLIED_OUTPUT], dtype=float).copy()

    def check_joints_running(self) -> None:
        """Every joint's RTDE joint mode: a joint not RUNNING (its brake holding it, not powered, a
        fault) follows no command, so the session stops naming it and what to do. The task-space
        modes' applied check: they have no joint-torque reading to set against the command
        (docs/ur.md, "Applied, not commanded")."""
        try:
            modes = [int(m) for m in self._r.getJointMode()]
        except (RuntimeError, TypeError, ValueError, AttributeError):
            return  # no state package yet: the next read looks again
        for k, mode in enumerate(modes[: len(JOINTS)]):
            if mode != JOINT_RUNNING:
                name, what = JOINT_MODE.get(mode, (str(mode), "read the log on the teach pendant"))
                self._fail(
                    f"joint {JOINTS[k]} of the robot at {self.host} is not under control: its joint mode is "
                    f"{name} ({mode}): {what}; the robot was stopped"
                )

    def _applied_text(self, k: int, reported_nm: float, commanded_nm: float) -> str:
        """Why joint k does not apply its command, from its RTDE joint mode."""
        seen = (
            f"joint {JOINTS[k]} of the robot at {self.host} is not applying the commanded torque: it reports "
            f"{reported_nm:+.2f} N m ({APPLIED_OUTPUT}) against {commanded_nm:+.2f} N m commanded for "
            f"{int(self._mismatch[k])} reads in a row"
        )
        try:
            mode = int(self._r.getJointMode()[k])
        except (RuntimeError, IndexError, TypeError, AttributeError):
            mode = -1
        name, what = JOINT_MODE.get(mode, (str(mode), "read the log on the teach pendant"))
        if mode == JOINT_RUNNING:
            why = (
                "its joint mode is RUNNING and no stop is reported, so the command did not reach the joint or the "
                "joint cannot produce it (another program or URCap commanding the arm, a joint drive fault): read the "
                "log on the teach pendant; raise hardware.applied_tolerance_nm if this robot's readings are noisier"
            )
        else:
            why = f"its joint mode is {name} ({mode}): {what}"
        return f"{seen}: {why}; the robot was stopped"

    def _fail(self, message: str, lost: bool = False) -> None:
        self._connection_lost = self._connection_lost or lost
        self.stop()
        raise HardwareError(message)

    # ------------------------------------------------------------------ commands
    def _require_control(self) -> Any:
        if self._c is None or self._stopped:
            raise HardwareError(f"the UR driver for {self.host} has no control session (control=True and start())")
        return self._c

    def _sent(self, ok: bool, what: str) -> None:
        if not ok:
            self.state()  # names the fault if there is one
            self._diagnose()
            self._fail(f"the controller at {self.host} refused {what}")
        now = time.monotonic()
        if self.watchdog_hz > 0.0 and now - self._last_sent_s > 1.0 / self.watchdog_hz:
            self._overrun = (now, now - self._last_sent_s)
        self._last_sent_s = now

    def force_mode(
        self,
        wrench: Sequence[float],
        task_frame: Sequence[float] = (0.0,) * 6,
        selection: Sequence[int] = (0, 0, 1, 0, 0, 0),
        limits: Sequence[float] = (0.1, 0.1, 0.1, 0.5, 0.5, 0.5),
    ) -> None:
        """The robot's force control: apply `wrench` (N, N m, task frame) to the environment along the
        compliant axes (`selection` 1), hold the others."""
        c = self._require_control()
        args = force_mode_args(wrench, task_frame, selection, limits, max_force_n=self.max_force_n)
        self._modes.add("force")
        self._sent(c.forceMode(*args.sdk_args()), "forceMode")

    def servo_l(
        self,
        pose: Sequence[float],
        speed: float = 0.25,
        acceleration: float = 0.5,
        time_s: float = 0.002,
        lookahead_s: float = 0.1,
        gain: float = 300.0,
    ) -> None:
        """Stream a TCP pose target [x, y, z, rx, ry, rz] (one per controller period)."""
        c = self._require_control()
        p = [float(v) for v in pose]
        if len(p) != 6 or not all(math.isfinite(v) for v in p):
            raise HardwareError(f"servo_l needs a finite 6-value pose, got {pose}")
        self._modes.add("servo")
        self._sent(c.servoL(p, speed, acceleration, time_s, lookahead_s, gain), "servoL")

    def speed_l(self, twist: Sequence[float], acceleration: float = 1.0, time_s: float = 0.0) -> None:
        """Command a TCP twist (m/s, rad/s, base frame), clipped to the driver's speed limits."""
        c = self._require_control()
        t = clip_twist(twist, self.max_speed_m_per_s, self.max_angular_rad_per_s)
        self._modes.add("speed")
        self._sent(c.speedL(t, acceleration, time_s), "speedL")

    def torque_available(self) -> bool:
        return self.version is not None and direct_torque_supported(self.version)

    def torque(self, tau_nm: Sequence[float] | np.ndarray) -> np.ndarray:
        """Direct joint torques beyond gravity compensation (N m), clipped to the joints' limits;
        returns them as sent."""
        c = self._require_control()
        if not self.torque_available():
            v = ".".join(str(x) for x in self.version or ())
            raise HardwareError(
                f"direct torque control needs PolyScope 5.23 / 10.10 or later, and ur_rtde 1.6.5's control script "
                f"calls direct_torque() only from 5.26 (10.10 on PolyScope X); the controller at {self.host} runs "
                f"{v or 'an unknown version'}: use force_mode or servo_l/speed_l with an admittance"
            )
        tau = np.clip(np.asarray(tau_nm, dtype=float), -self.torque_limit_nm, self.torque_limit_nm)
        tau = np.where(np.isfinite(tau), tau, 0.0)
        if self._applied is None:
            self._open_applied()
        self._modes.add("torque")
        self._sent(c.directTorque(list(map(float, tau)), [0.0] * 6, [0.0] * 6), "directTorque")
        self._commanded.append(tau.copy())
        return tau

    def _open_applied(self) -> None:
        """The RTDE stream of the torque each joint applies (ur_rtde 1.6.5's Python receive interface
        has no getter for it: plants/ur/rtde_outputs.py)."""
        reader = RTDEOutputReader(self.host, (APPLIED_OUTPUT,), self.frequency_hz, RTDE_PORT)
        try:
            reader.start()
        except RTDEOutputError as exc:
            self._fail(
                f"{exc} at {self.host}: it reports no applied joint torque, so direct torque cannot be checked; "
                "PolyScope 5.23 / 10.11 or later has it: update PolyScope or use force_mode"
            )
        except OSError as exc:
            self._fail(
                f"cannot read {APPLIED_OUTPUT} from the robot at {self.host}:{RTDE_PORT} ({exc}); check the "
                "controller and the network, then start again"
            )
        self._applied, self._applied_seq = reader, 0

    def servo_stop(self, deceleration: float = 10.0) -> None:
        """End servoL streaming; the arm decelerates and holds."""
        self._sent(self._require_control().servoStop(deceleration), "servoStop")
        self._modes.discard("servo")

    def speed_stop(self, deceleration: float = 10.0) -> None:
        """Ramp a speedL twist down to rest at `deceleration` (m/s^2)."""
        self._sent(self._require_control().speedStop(deceleration), "speedStop")
        self._modes.discard("speed")

    def force_mode_stop(self) -> None:
        """Leave force mode; the arm holds where it is."""
        self._sent(self._require_control().forceModeStop(), "forceModeStop")
        self._modes.discard("force")

    def force_mode_set_damping(self, damping: float) -> None:
        """UR's force-mode damping (URScript force_mode_set_damping: 0 none .. 1 full), for the next
        force mode."""
        if not (0.0 <= damping <= 1.0):
            raise HardwareError(f"force mode damping must be within 0..1, got {damping}")
        self._sent(self._require_control().forceModeSetDamping(float(damping)), "forceModeSetDamping")

    def zero_ft_sensor(self) -> None:
        """Take the present TCP wrench as the sensor's zero."""
        self._sent(self._require_control().zeroFtSensor(), "zeroFtSensor")

    def kick(self) -> None:
        """Feed the RTDE watchdog without a motion command."""
        if self._c is not None and not self._stopped:
            self._sent(self._c.kickWatchdog(), "kickWatchdog")

    # ------------------------------------------------------------------ stop
    def stop(self) -> None:
        """servoStop / speedStop / forceModeStop (whichever were used), zero torque, stopScript,
        disconnect. Idempotent, never raises; with the connection lost the SDK calls are skipped
        (the controller's RTDE watchdog stops the arm) and blocking SDK calls are abandoned after 2 s."""
        if self._stopped:
            return
        self._stopped = True
        import atexit

        atexit.unregister(self.stop)
        c, r = self._c, self._r
        self._c = self._r = None
        applied, self._applied = self._applied, None
        if applied is not None:
            applied.close()
        if c is not None:
            if not self._connection_lost:
                if "torque" in self._modes:
                    _with_timeout(lambda: c.directTorque([0.0] * 6, [0.0] * 6, [0.0] * 6), 2.0)
                if "servo" in self._modes:
                    _with_timeout(lambda: c.servoStop(10.0), 2.0)
                if "speed" in self._modes:
                    _with_timeout(lambda: c.speedStop(10.0), 2.0)
                if "force" in self._modes:
                    _with_timeout(c.forceModeStop, 2.0)
                _with_timeout(c.stopScript, 5.0)
            _with_timeout(c.disconnect, 2.0)
        if r is not None:
            _with_timeout(r.disconnect, 2.0)
        self._modes.clear()

    def __enter__(self) -> URDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class URTorqueDriver:
    """The JointDriver (plants/hardware.py) of a UR arm in direct torque mode. Every `read()` checks
    that the joints apply the torque the last `write()`s sent (`applied_tolerance_nm`,
    `applied_mismatch_reads`: URDriver), and its sample's `tau_nm` is the torque the joints report
    they apply (`actual_current_as_torque`, beyond gravity compensation, which the controller does),
    not the command: what the bag's measured effort and the ledger book (docs/ur.md, "Applied, not
    commanded"). The controller must have that output (PolyScope 5.23 / 10.11 on): without it the
    driver refuses direct torque at the first `torque()`. A sample taken before the first report
    arrived (the one `start()` returns, a read in the first controller period) carries the torque
    last commanded with `measured` False."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        watchdog_hz: float = 10.0,
        applied_tolerance_nm: Sequence[float] | float = APPLIED_TOLERANCE_NM,
        applied_mismatch_reads: int = APPLIED_MISMATCH_READS,
    ) -> None:
        self.ur = URDriver(
            host,
            control=True,
            watchdog_hz=watchdog_hz,
            applied_tolerance_nm=applied_tolerance_nm,
            applied_mismatch_reads=applied_mismatch_reads,
        )
        self.joints: tuple[str, ...] = JOINTS
        self.torque_limit_nm = np.array(UR5E_TORQUE_LIMIT_NM)
        self._tau = np.zeros(6)

    def _sample(self, s: URState) -> JointSample:
        reported = self.ur.applied_torque_nm()
        if reported is None:  # no report yet: the command, flagged
            return JointSample(s.q_rad, s.qd_rad_per_s, self._tau.copy(), s.t_host_s, measured=False)
        return JointSample(q_rad=s.q_rad, qd_rad_per_s=s.qd_rad_per_s, tau_nm=reported, t_s=s.t_host_s)

    def start(self) -> JointSample:
        first = self.ur.start()
        if not self.ur.torque_available():
            try:
                self.ur.torque(np.zeros(6))  # raises the version error, after which we stop
            finally:
                self.ur.stop()
        self._tau = self.ur.torque(np.zeros(6))
        return self._sample(first)

    def read(self) -> JointSample:
        return self._sample(self.ur.state())

    def write(self, tau_nm: np.ndarray) -> np.ndarray:
        self._tau = self.ur.torque(tau_nm)
        return self._tau.copy()

    def stop(self) -> None:
        self.ur.stop()


def wrench_from_torque(jac6: np.ndarray, tau_nm: np.ndarray) -> np.ndarray:
    """The tool wrench [f; m] (N, N m, base frame, torque about the tool point) whose joint torques
    are `tau_nm`: the solution of J^T w = tau, exact for a 6-joint arm with a full-rank 6 x 6
    Jacobian; least squares (the smallest wrench) near a singularity."""
    j = np.asarray(jac6, dtype=float)
    w, *_ = np.linalg.lstsq(j.T, np.asarray(tau_nm, dtype=float), rcond=1e-6)
    return np.asarray(w, dtype=float)


class URTaskDriver:
    """The JointDriver (plants/hardware.py) of a UR arm commanded in task space (docs/ur_control_modes.md, "Control
    modes in a session"): `write(tau)` turns the side's bounded joint torques into the tool wrench
    w = (J^T)^-1 tau (`jacobian`: the 6 x 6 Jacobian of the tool site at this tick's measured q,
    which the hardware arm has set) and sends

    - mode "force_mode": w through forceMode, every axis of the base frame compliant (the law's
      torque holds the orientation), UR's force-mode damping (`force_mode_damping`,
      force_mode_set_damping) and speed limits (`speed_limits`);
    - mode "admittance": the twist of the project's admittance (core/admittance.py) driven by w and
      the measured TCP wrench, through speedL.

    `write` returns J^T w as sent (w clipped at the driver's force and torque limits): the torque the
    ledger books. `read()`'s time is the controller's timestamp (the time the motion took on the
    robot's own clock); its torque is the torque last booked, flagged `measured` False: the robot's
    own force control (or speed loop) makes the joint torques, which are not the port torque
    J^T w the session commands, so no reading stands in for it (docs/ur.md, "Applied, not commanded").
    """

    MODES = ("force_mode", "admittance")

    def __init__(
        self,
        host: str,
        mode: str,
        jacobian: Callable[[], np.ndarray],
        period_s: float,
        watchdog_hz: float = 10.0,
        force_mode_damping: float = 0.025,
        speed_limits: Sequence[float] = (0.1, 0.1, 0.1, 0.5, 0.5, 0.5),
        admittance_mass: Sequence[float] = (2.0, 2.0, 2.0, 0.05, 0.05, 0.05),
        admittance_damping: Sequence[float] = (400.0, 400.0, 400.0, 5.0, 5.0, 5.0),
        speed_acceleration_m_per_s2: float = 5.0,
        max_force_n: float = 100.0,
        max_torque_nm: float = 10.0,
    ) -> None:
        from haptic_teleop.core.admittance import Admittance, AdmittanceParams

        if mode not in self.MODES:
            raise HardwareError(f"UR task-space mode {mode!r}: allowed {', '.join(self.MODES)}")
        self.mode = mode
        self.ur = URDriver(host, control=True, watchdog_hz=watchdog_hz, max_force_n=max_force_n)
        self.joints: tuple[str, ...] = JOINTS
        self.torque_limit_nm = np.array(UR5E_TORQUE_LIMIT_NM)
        self._jacobian = jacobian
        self.force_mode_damping = float(force_mode_damping)
        self.speed_limits = tuple(float(v) for v in speed_limits)
        self.admittance = Admittance(AdmittanceParams(tuple(admittance_mass), tuple(admittance_damping), period_s))
        self.acceleration = speed_acceleration_m_per_s2
        self.max_force_n, self.max_torque_nm = max_force_n, max_torque_nm
        self._tau = np.zeros(6)
        self.wrench_sent = np.zeros(6)  # the last wrench commanded (force mode: to forceMode; admittance: its input)
        self.twist_sent = np.zeros(6)
        self.last: URState | None = None

    def _sample(self, s: URState) -> JointSample:
        self.last = s
        return JointSample(s.q_rad, s.qd_rad_per_s, self._tau.copy(), s.timestamp_s, measured=False)

    def tcp_wrench(self) -> np.ndarray:
        """The environment's wrench on the tool at the last read (the controller's TCP force)."""
        return np.zeros(6) if self.last is None else self.last.tcp_wrench.copy()

    def start(self) -> JointSample:
        self.ur.start()
        try:
            # The wrist sensor's zero in free space (UR's advice before force control; the scene's
            # start-up check keeps the tool off the wall at start).
            self.ur.zero_ft_sensor()
            if self.mode == "force_mode":
                self.ur.force_mode_set_damping(self.force_mode_damping)
            self.admittance.reset()
            self._send(np.zeros(6))
        except BaseException:
            self.ur.stop()
            raise
        return self._sample(self.ur.state())

    def read(self) -> JointSample:
        s = self.ur.state()
        self.ur.check_joints_running()  # no joint torque to compare in task space: every joint under control
        return self._sample(s)

    def _clip(self, w: np.ndarray) -> np.ndarray:
        w = np.where(np.isfinite(w), w, 0.0)
        f, m = w[:3], w[3:]
        nf, nm = float(np.linalg.norm(f)), float(np.linalg.norm(m))
        if nf > self.max_force_n:
            f = f * (self.max_force_n / nf)
        if nm > self.max_torque_nm:
            m = m * (self.max_torque_nm / nm)
        return np.concatenate([f, m])

    def _send(self, w: np.ndarray) -> None:
        self.wrench_sent = w
        if self.mode == "force_mode":
            self.ur.force_mode(w.tolist(), (0.0,) * 6, (1, 1, 1, 1, 1, 1), self.speed_limits)
        else:
            _, v = self.admittance.step(w, self.tcp_wrench())
            self.twist_sent = v
            self.ur.speed_l(v.tolist(), self.acceleration, 0.0)

    def write(self, tau_nm: np.ndarray) -> np.ndarray:
        jac = np.asarray(self._jacobian(), dtype=float)
        w = self._clip(wrench_from_torque(jac, np.asarray(tau_nm, dtype=float)))
        self._send(w)
        self._tau = jac.T @ w
        return self._tau.copy()

    def stop(self) -> None:
        self.ur.stop()
