"""The UR driver through the unmodified ur_rtde against the emulator (docs/ur.md): forceMode,
servoL, speedL, the stops, the watchdog, lost connections, protective, emergency and safeguard
stops, direct torque and the check that the joints apply it.

Durations are the controller's (its RTDE timestamps), never the host's clock; host time appears
only as generous safety nets. The emulator runs in real time on a shared machine, so the fault
tests assert what the driver concludes and says, never the physics of the run."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np
import pytest

from haptic_teleop.core.admittance import Admittance, AdmittanceParams
from haptic_teleop.emulators.ur.config import URConfig, WallConfig
from haptic_teleop.emulators.ur.process import URProcess, start_ur
from haptic_teleop.plants.hardware import HardwareError
from haptic_teleop.plants.ur.driver import URDriver, URState, URTorqueDriver

pytest.importorskip("rtde_control")

# the touch_ur5e_wall scene's table: 3 cm below the tool at the UR5e's start
WALL = WallConfig(point_m=(-0.49, -0.13, 0.4078), normal=(0.0, 0.0, 1.0), stiffness_n_per_m=1e4)
SAFETY_NET_S = 30.0
# The RTDE watchdog of the tests that are not about it: slack enough for a loaded test machine
# (a 10 Hz watchdog stops the program whenever the test process stalls for 0.1 s).
WATCHDOG_HZ = 2.0


def run_for(d: URDriver, controller_s: float, command: Callable[[URState], None]) -> URState:
    """Call `command` with each new state until the controller's clock has advanced controller_s."""
    s = d.state()
    t0, host0 = s.timestamp_s, time.monotonic()
    while s.timestamp_s - t0 < controller_s:
        command(s)
        time.sleep(0.002)
        s = d.state()
        assert time.monotonic() - host0 < SAFETY_NET_S, "safety net: the emulator stopped advancing"
    return s


def poll_state(d: URDriver) -> None:
    """Read until the driver raises (the safety net fails the test if it never does)."""
    host0 = time.monotonic()
    while time.monotonic() - host0 < SAFETY_NET_S:
        d.state()
        time.sleep(0.002)
    raise AssertionError("safety net: the driver never reported the fault")


def state_since(d: URDriver, controller_t_s: float) -> URState:
    """The first state the controller sent at or after controller_t_s: the receive interface's stream
    is not the control interface's, and on a busy machine it can still hold packages from before a
    command the control interface has seen done."""
    host0 = time.monotonic()
    while (s := d.state()).timestamp_s < controller_t_s - 1e-9:
        assert time.monotonic() - host0 < SAFETY_NET_S, "safety net: the emulator stopped advancing"
        time.sleep(0.002)
    return s


def wait_for(ur: URProcess, pred: Callable[[dict], bool]) -> dict:
    host0 = time.monotonic()
    while True:
        st = ur.state()
        if pred(st):
            return st
        assert time.monotonic() - host0 < SAFETY_NET_S, f"safety net: never true; last state {st}"
        time.sleep(0.01)


def at_rest(d: URDriver, ur: URProcess) -> tuple[URState, dict]:
    """The driver's state 0.3 s of controller time after the robot went to hold (the watchdog fed
    meanwhile), and the emulator's truth right after: holding, the readings stay what they are, so
    the two agree whatever the host's delay between them."""
    wait_for(ur, lambda st: st["mode"] == "hold")
    s = run_for(d, 0.3, lambda s: d.kick())
    return s, ur.state()


def test_force_mode_reaches_the_controller_and_the_tcp_force_reads_its_sensor():
    """forceMode through ur_rtde: the controller runs it, and the TCP force the driver reads is the
    controller's sensor (the contact, less zeroFtSensor's offset). What force mode does to the
    robot is asserted in simulated time (test_ur_robot_sim.py): here the emulator runs in real time."""
    with start_ur(URConfig(wall=WALL)) as ur, URDriver(ur.host, watchdog_hz=WATCHDOG_HZ) as d:
        d.start()
        run_for(d, 1.5, lambda s: d.force_mode([0, 0, -10.0, 0, 0, 0], selection=[0, 0, 1, 0, 0, 0]))
        assert ur.state()["mode"] == "force"
        d.force_mode_stop()
        assert ur.state()["mode"] == "hold" and ur.state()["program_running"]
        s, truth = at_rest(d, ur)
        np.testing.assert_allclose(s.tcp_wrench[:3], truth["contact_force_n"], atol=0.2)
        d.zero_ft_sensor()  # the contact now reads as zero: the sensor's offset is the contact then
        s = state_since(d, ur.state()["t_s"])
        assert abs(s.tcp_wrench[2]) < 0.05
        d.stop()
        assert not ur.state()["program_running"]  # stopScript


def test_servo_l_reaches_the_controller_and_servo_stop_stops_it():
    """servoL through ur_rtde: the controller servos, the driver's pose is the controller's, and
    servoStop leaves it holding (the motion itself: test_ur_robot_sim.py, in simulated time)."""
    with start_ur() as ur, URDriver(ur.host, watchdog_hz=WATCHDOG_HZ) as d:
        s0 = d.start()
        target = s0.tcp_pose.copy()
        target[:3] += [0.03, -0.02, 0.04]
        run_for(d, 0.5, lambda s: d.servo_l(target))
        assert ur.state()["mode"] == "servo"
        d.servo_stop()
        assert ur.state()["mode"] == "hold"
        assert ur.state()["program_running"]
        s, truth = at_rest(d, ur)
        np.testing.assert_allclose(s.tcp_pose[:3], truth["tcp_position_m"], atol=1e-3)
        assert np.linalg.norm(s.tcp_pose[:3] - s0.tcp_pose[:3]) > 0.01  # it did move toward the target


def test_speed_l_reaches_the_controller_and_speed_stop_stops_it():
    """speedL through ur_rtde: the controller moves the tool, the driver's speed is the
    controller's, speedStop brings it to a hold (the speed itself: test_ur_robot_sim.py)."""
    with start_ur() as ur, URDriver(ur.host, watchdog_hz=WATCHDOG_HZ) as d:
        s0 = d.start()
        v = 0.05
        run_for(d, 0.3, lambda s: d.speed_l([0, 0, v, 0, 0, 0], acceleration=1.0))
        assert ur.state()["mode"] == "speed"
        d.speed_stop(10.0)
        s, truth = at_rest(d, ur)
        assert abs(s.tcp_speed[2]) < 1e-3
        np.testing.assert_allclose(s.tcp_pose[:3], truth["tcp_position_m"], atol=1e-3)
        assert s.tcp_pose[2] > s0.tcp_pose[2]  # it went up


def test_admittance_through_speed_l_runs_a_host_loop_on_the_sensor_reading():
    """A host's admittance loop on the TCP force through speedL: the commands reach the controller
    each period and the loop ends holding, the driver's readings the controller's (where it
    settles: test_ur_robot_sim.py, in simulated time)."""
    with start_ur(URConfig(wall=WALL)) as ur, URDriver(ur.host, watchdog_hz=WATCHDOG_HZ) as d:
        d.start()
        adm = Admittance(AdmittanceParams(mass=(2.0,), damping=(400.0,), period_s=0.002))
        f_cmd = np.array([-8.0])
        sent = []

        def tick(s: URState) -> None:
            _, v = adm.step(f_cmd, s.tcp_wrench[2:3])
            sent.append(float(v[0]))
            d.speed_l([0.0, 0.0, float(v[0]), 0.0, 0.0, 0.0], acceleration=5.0)

        run_for(d, 1.0, tick)
        assert ur.state()["mode"] == "speed" and len(sent) > 10 and min(sent) < 0.0  # it moved down
        d.speed_stop(10.0)
        s, truth = at_rest(d, ur)
        np.testing.assert_allclose(s.tcp_wrench[:3], truth["contact_force_n"], atol=0.2)


def test_the_rtde_watchdog_stops_the_program_and_the_driver_reports_it():
    with start_ur() as ur, URDriver(ur.host, watchdog_hz=20.0) as d:
        d.start()
        assert ur.state()["watchdog_hz"] == 20.0
        # the host goes quiet: no command reaches the controller
        st = wait_for(ur, lambda st: not st["program_running"])
        assert "watchdog" in st["stop_reason"]
        # the driver sees it within a few packages and names the watchdog: the host was silent longer than it
        with pytest.raises(HardwareError, match=r"control script .* was stopped by its RTDE watchdog: no command for"):
            poll_state(d)
        assert ur.state()["mode"] == "hold"


def test_a_program_stopped_from_outside_the_session_is_not_blamed_on_the_watchdog():
    # no watchdog: the host's own pace cannot stop the program here, whatever the machine's load
    with start_ur() as ur, URDriver(ur.host, watchdog_hz=0.0) as d:
        d.start()
        run_for(d, 0.1, lambda s: d.kick())
        ur.inject("stop_program", reason="stopped on the pendant")
        with pytest.raises(HardwareError, match=r"control script .* was stopped from outside the session .* log"):
            run_for(d, 30.0, lambda s: d.kick())  # the host keeps sending
        st = ur.state()
        assert not st["program_running"] and st["mode"] == "hold"


# A host session in its own process, commanding at 500 Hz until the driver raises (the test stops it).
HOST_SESSION = """
import sys, time
from haptic_teleop.plants.hardware import HardwareError
from haptic_teleop.plants.ur.driver import URDriver
d = URDriver(sys.argv[1], watchdog_hz=10.0, stale_s=0.8)
d.start()
print("started", flush=True)
try:
    t0 = time.monotonic()
    while time.monotonic() - t0 < 30.0:
        d.kick()
        d.state()
        time.sleep(0.002)
    print("no stop")
except HardwareError as e:
    print(e)
finally:
    d.stop()
"""


def test_a_host_that_stalls_past_the_watchdog_is_told_it_was_the_watchdog():
    """The whole host process stops for 1 s (SIGSTOP: a machine under load, a debugger), over the
    10 Hz watchdog and the driver's 0.8 s staleness limit. The network is quiet over the stall and
    until 0.1 s after the host wakes (the emulator frozen): the SDK's receive thread has no newer data
    than before the stall, so the host's first command after it is accepted and its reads are stale.
    The driver must name the watchdog and the stall, not a stop from outside (the send gap that just
    ended is the cause), nor a lost connection (the SDK gets stale_s to catch up when the host
    wakes). With either rule undone, every round or about half of them misname it."""
    with start_ur() as ur:
        for _ in range(3):
            p = subprocess.Popen(
                [sys.executable, "-c", HOST_SESSION, ur.host], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
            assert p.stdout is not None and p.stdout.readline().strip() == "started", p.stderr
            time.sleep(0.2)
            ur.inject("freeze")
            os.kill(p.pid, signal.SIGSTOP)
            time.sleep(1.0)
            os.kill(p.pid, signal.SIGCONT)
            time.sleep(0.1)
            ur.inject("freeze", on=False)
            out, err = p.communicate(timeout=SAFETY_NET_S)
            m = re.search(r"stopped by its RTDE watchdog: no command for (\d+\.\d+) s", out)
            assert m is not None and float(m.group(1)) >= 1.0, out + err
            assert ur.state()["stop_reason"].startswith("RTDE watchdog")


@pytest.mark.parametrize("how", ["drop_connections", "kill"])
def test_a_lost_connection_ends_the_session_with_a_clear_error(how):
    with start_ur() as ur, URDriver(ur.host, watchdog_hz=WATCHDOG_HZ) as d:
        d.start()
        run_for(d, 0.1, lambda s: d.kick())
        if how == "kill":
            ur.proc.kill()  # the controller is gone: every socket closes
        else:
            ur.inject("drop_connections")  # the controller vanishes and refuses new connections
        with pytest.raises(HardwareError, match=r"lost the connection .* Check the controller and the cable") as exc:
            poll_state(d)
        assert "\n" not in str(exc.value)
        d.stop()  # again: idempotent, quiet


@pytest.mark.parametrize("poll_every_s", [0.0, 0.4])
def test_a_controller_that_stops_sending_is_a_lost_connection(poll_every_s):
    """Also for a host that reads less often than stale_s (0.25 s): each of its reads gives the
    receive thread stale_s to catch up, so a frozen stream is still found, not forgiven every time."""
    with start_ur() as ur, URDriver(ur.host, watchdog_hz=0.0) as d:
        d.start()
        ur.inject("freeze")
        with pytest.raises(HardwareError, match="no new RTDE data"):
            every = max(poll_every_s, 0.002)
            for _ in range(round(3.0 / every)):  # 3 s of reads (found within stale_s, or 2 x stale_s)
                time.sleep(every)
                d.state()
        # ur_rtde's receive thread, blocked on the silent socket, reconnects by itself (and uploads
        # its script) as soon as the socket closes: refuse it here, or it would reach the next
        # test's emulator on the same fixed ports (docs/ur.md, "Errors").
        ur.inject("drop_connections")
        wait_for(ur, lambda st: st["scripts_received"] == 1)


def test_a_protective_stop_mid_session_raises_after_stopping():
    with (
        start_ur(URConfig(wall=WALL, protective_stop_force_n=20.0)) as ur,
        URDriver(ur.host, watchdog_hz=WATCHDOG_HZ) as d,
    ):
        d.start()
        # push 40 N into the table: the controller's force limit (20 N) trips a protective stop
        with pytest.raises(HardwareError, match="protective stop: clear it on the teach pendant once its cause"):
            run_for(d, 5.0, lambda s: d.force_mode([0, 0, -40.0, 0, 0, 0]))
        st = ur.state()
        assert st["safety_mode"] == 3 and not st["program_running"] and st["mode"] == "hold"


@pytest.mark.parametrize(
    ("mode", "message"),
    [
        (7, r"was emergency-stopped: release the emergency stop, power the arm on and release the brakes"),
        (5, r"stopped in safety mode SAFEGUARD_STOP: a safeguard stop input opened .* clear it and reset it"),
    ],
)
def test_an_emergency_or_safeguard_stop_mid_session_is_named_with_what_to_do(mode, message):
    with start_ur() as ur, URDriver(ur.host, watchdog_hz=WATCHDOG_HZ) as d:
        d.start()
        run_for(d, 0.1, lambda s: d.kick())
        ur.inject("safety_stop", mode=mode, reason="injected")
        with pytest.raises(HardwareError, match=message):
            run_for(d, 30.0, lambda s: d.kick())
        st = ur.state()
        assert st["safety_mode"] == mode and not st["program_running"] and st["mode"] == "hold"
        assert st["robot_mode"] == (3 if mode == 7 else 7)  # an emergency stop removes the arm's power


@pytest.mark.parametrize(
    ("cfg", "message"),
    [
        ({"safety_mode": 3}, "protective stop: clear it on the teach pendant"),
        ({"robot_mode": 3}, "robot not powered on"),
        ({"robot_mode": 5}, "brakes are not released"),
        ({"safety_mode": 7}, "emergency-stopped"),
    ],
)
def test_start_refuses_a_robot_that_is_not_ready(cfg, message):
    with start_ur(URConfig.from_dict(cfg)) as ur:
        d = URDriver(ur.host)
        with pytest.raises(HardwareError, match=message):
            d.start()
        assert ur.state()["scripts_received"] == 0  # refused before any program was sent
        d.stop()


def test_direct_torque_needs_a_controller_whose_script_has_it():
    with (
        start_ur(URConfig(controller_version=(5.0, 23.0, 0.0, 0.0))) as ur,
        URDriver(ur.host, watchdog_hz=WATCHDOG_HZ) as d,
    ):
        d.start()
        assert ur.state()["has_direct_torque"] is False  # ur_rtde dropped the direct_torque() line
        with pytest.raises(HardwareError, match=r"5\.23 / 10\.10"):
            d.torque(np.zeros(6))


def test_direct_torque_joint_driver_turns_the_wrist():
    with start_ur(URConfig(controller_version=(5.0, 26.0, 0.0, 0.0))) as ur:
        j = URTorqueDriver(ur.host, watchdog_hz=WATCHDOG_HZ)
        try:
            first = j.start()
            assert ur.state()["has_direct_torque"] is True
            sent = j.write(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.3]))
            assert sent[5] == pytest.approx(0.3)
            host0 = time.monotonic()
            while True:
                s = j.read()
                j.write(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.3]))
                if s.q_rad[5] - first.q_rad[5] > 0.05:
                    break
                assert time.monotonic() - host0 < SAFETY_NET_S
                time.sleep(0.002)
            assert ur.state()["mode"] == "torque"
            clipped = j.write(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 500.0]))
            assert clipped[5] == pytest.approx(28.0)  # the wrist's rated torque
        finally:
            j.stop()
        st = ur.state()
        assert not st["program_running"] and st["mode"] == "hold"


@pytest.mark.parametrize(
    ("fault", "joint", "tau", "message"),
    [
        # the joint's drive silently applies nothing: only the reading shows it
        ("no_torque", 5, 1.0, r"joint wrist_3 .* is not applying the commanded torque: it reports [+-]0\.00 N m "
         r"\(actual_current_as_torque\) against \+1\.00 N m commanded for 25 reads in a row: its joint mode is "
         r"RUNNING and no stop is reported"),
        # its brake holds the elbow, motor off: the reading is the gravity the motor no longer carries
        ("brake", 2, 0.0, r"joint elbow .* is not applying the commanded torque: it reports [+-]\d+\.\d\d N m .* "
         r"against \+0\.00 N m commanded for 25 reads in a row: its joint mode is IDLE \(255\): .* brake"),
    ],
)  # fmt: skip
def test_a_joint_that_does_not_apply_its_torque_stops_the_session_naming_it(fault, joint, tau, message):
    with start_ur(URConfig(controller_version=(5.0, 26.0, 0.0, 0.0))) as ur:
        j = URTorqueDriver(ur.host, watchdog_hz=WATCHDOG_HZ)
        try:
            j.start()
            for _ in range(50):  # a healthy joint applies its command: no fault
                j.read()
                j.write(np.zeros(6))
                time.sleep(0.002)
            ur.inject("joint_fault", joint=joint, kind=fault)
            command = np.zeros(6)
            command[joint] = tau
            host0 = time.monotonic()
            with pytest.raises(HardwareError, match=message) as exc:
                while time.monotonic() - host0 < SAFETY_NET_S:
                    j.read()
                    j.write(command)
                    time.sleep(0.002)
            assert "\n" not in str(exc.value) and str(exc.value).endswith("the robot was stopped")
        finally:
            j.stop()
        st = ur.state()
        assert not st["program_running"] and st["mode"] == "hold"


def test_the_torque_driver_reads_back_what_the_joints_apply_not_the_command():
    """URTorqueDriver.read().tau_nm is the controller's actual_current_as_torque: the command while
    the joint applies it, what the joint really applies once a fault makes the two differ (the
    applied check is held off here so the session goes on). Only what the driver reports is
    asserted: the emulator runs in real time."""
    command = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.5])

    def poll(j: URTorqueDriver, done: Callable[[np.ndarray], bool]) -> np.ndarray:
        host0 = time.monotonic()
        while True:
            s = j.read()
            j.write(command)
            if s.measured and done(s.tau_nm):
                return s.tau_nm
            assert time.monotonic() - host0 < SAFETY_NET_S, f"safety net: the driver reports {s}"
            time.sleep(0.002)

    with start_ur(URConfig(controller_version=(5.0, 26.0, 0.0, 0.0))) as ur:
        j = URTorqueDriver(ur.host, watchdog_hz=WATCHDOG_HZ, applied_mismatch_reads=10**9)
        try:
            first = j.start()  # before the applied stream's first package: the command (zero), flagged
            assert first.measured or not first.tau_nm.any()
            healthy = poll(j, lambda tau: abs(tau[5] - 0.5) < 1e-6)
            assert healthy[5] == pytest.approx(0.5, abs=1e-6)
            ur.inject("joint_fault", joint=5, kind="no_torque")
            faulted = poll(j, lambda tau: abs(tau[5] - 0.5) > 0.4)
            assert j.write(command)[5] == 0.5  # still commanded
            applied = ur.state()["tau_nm"][5]  # what the emulated joint applies, as the controller reports it
            assert faulted[5] == pytest.approx(applied, abs=0.05)
        finally:
            j.stop()


def test_a_second_control_session_is_refused_and_a_read_only_one_uploads_nothing():
    # no watchdog on the first session: it sends nothing while the others start
    with start_ur() as ur, URDriver(ur.host, watchdog_hz=0.0) as a:
        a.start()
        b = URDriver(ur.host, watchdog_hz=WATCHDOG_HZ)
        with pytest.raises(HardwareError, match="in use by another client"):
            b.start()
        b.stop()
        r = URDriver(ur.host, control=False)
        s = r.start()
        assert s.robot_mode == 7 and r.state().q_rad.shape == (6,)
        with pytest.raises(HardwareError, match="no control session"):
            r.servo_l(s.tcp_pose)
        r.stop()
        r.stop()
        assert ur.state()["scripts_received"] == 1  # only the first session's
        a.state()  # the first session is untouched
        assert ur.state()["program_running"]


def test_no_controller_is_a_clear_error():
    import fcntl

    from haptic_teleop.emulators.ur.process import LOCK_PATH

    with open(LOCK_PATH, "a") as lock:  # no emulator runs while we hold it
        fcntl.flock(lock, fcntl.LOCK_EX)
        d = URDriver("127.0.0.1")
        with pytest.raises(HardwareError, match=r"cannot read the UR controller at 127\.0\.0\.1:30004"):
            d.start()
        d.stop()
