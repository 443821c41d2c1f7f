"""Friction identification end to end on the simulated arms (engine/excitation.py on
plants/sim_driver.py), and the `haptic-teleop identify` command (docs/identify.md).

The simulator's friction is the truth: MuJoCo's dof_damping (viscous) and dof_frictionloss
(Coulomb), chosen here (not the models' own values), with a servo's sensing: white velocity noise
and, for the Dynamixel arm, the velocity register's 0.229 rpm resolution."""

from __future__ import annotations

import math

import numpy as np
import pytest

from haptic_teleop.cli.identify import format_table
from haptic_teleop.cli.main import main
from haptic_teleop.core.friction import Excitation, Pass, Plan
from haptic_teleop.engine.excitation import Gains, Identifier, IdentifyFault
from haptic_teleop.plants.hardware import HardwareError
from haptic_teleop.plants.kinematics import ArmKinematics
from haptic_teleop.plants.sim_driver import MujocoJointDriver
from haptic_teleop.scene.load import find_scene, load_scene

DXL_RPM_UNIT = 0.229 * 2.0 * math.pi / 60.0  # Present Velocity (128) unit: 0.229 rpm (ROBOTIS e-Manual, XM430)
DXL = {
    "model": "dxl_arm.xml",
    "site": "tool",
    "start": [0.0, 0.6, -1.2],  # the touch_dynamixel_wall slave's start
    "b": [0.08, 0.12, 0.05],
    "c": [0.2, 0.1, 0.04],
    "noise": 0.02,
    "resolution": DXL_RPM_UNIT,
}
TOUCH = {
    "model": "touch.xml",
    "site": "handle",
    "start": [0.0, 0.2, 0.0],
    "b": [0.0209, 0.01121, 0.01121],  # touch.xml's damping
    "c": [0.01, 0.012, 0.008],
    "noise": 0.005,
    "resolution": 0.0,
}


class Logged(MujocoJointDriver):
    """The simulated driver, keeping every state it reported and every torque it applied."""

    def __init__(self, *args, **kw) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*args, **kw)
        self.q_log: list[np.ndarray] = []
        self.tau_log: list[np.ndarray] = []

    def start(self):  # type: ignore[no-untyped-def]
        s = super().start()
        self.q_log.append(self.arm.read()[0].copy())
        return s

    def read(self):  # type: ignore[no-untyped-def]
        s = super().read()
        self.q_log.append(self.arm.read()[0].copy())  # the true position, not the quantized one
        return s

    def write(self, tau_nm):  # type: ignore[no-untyped-def]
        applied = super().write(tau_nm)
        self.tau_log.append(applied.copy())
        return applied


def _driver(case: dict, seed: int = 1, cls: type = MujocoJointDriver, **kw) -> MujocoJointDriver:  # type: ignore[type-arg]
    return cls(
        case["model"],
        case["site"],
        start_q_rad=case["start"],
        damping_nm_s_per_rad=case["b"],
        frictionloss_nm=case["c"],
        velocity_noise_rad_per_s=case["noise"],
        velocity_resolution_rad_per_s=case["resolution"],
        rng=np.random.default_rng(seed),
        **kw,
    )


def _identify(driver: MujocoJointDriver, **kw):  # type: ignore[no-untyped-def]
    kin = ArmKinematics(driver.model_name, driver.joints, driver.point_site)
    return Identifier(driver, kin, driver.sim.period_s, **kw).run()


@pytest.mark.parametrize("case", [DXL, TOUCH], ids=["dxl_arm slave", "touch master"])
def test_recovers_the_true_friction(case: dict) -> None:  # type: ignore[type-arg]
    """Every joint's viscous and Coulomb friction within 10 % of the simulator's; the safe damping
    below the true one (and the interval b +- 3 se holds the truth)."""
    driver = _driver(case)
    result = _identify(driver)
    assert driver.stopped
    assert [ji.joint for ji in result.joints] == list(driver.joints)
    for k, ji in enumerate(result.joints):
        f = ji.fit
        assert f is not None, ji.error
        b, c = case["b"][k], case["c"][k]
        assert f.viscous_nm_s_per_rad == pytest.approx(b, rel=0.10), ji.joint
        assert f.coulomb_nm == pytest.approx(c, rel=0.10), ji.joint
        assert 0.0 < f.safe_damping_nm_s_per_rad < b, ji.joint
        assert f.n >= 16


def test_inertial_term_in_accelerating_windows() -> None:
    """Windows that start at the end of the ramp (no settling) under a slow velocity loop: the
    velocity still changes in them, and only with the inertial residual M qdd taken out does the
    estimate stay within 10 %."""
    driver = _driver(DXL)
    result = _identify(driver, excitation=Excitation(settle_s=0.0), gains=Gains(velocity_bandwidth_hz=2.0))
    for k, ji in enumerate(result.joints):
        f = ji.fit
        assert f is not None, ji.error
        assert f.viscous_nm_s_per_rad == pytest.approx(DXL["b"][k], rel=0.10), ji.joint
        assert f.coulomb_nm == pytest.approx(DXL["c"][k], rel=0.10), ji.joint


def test_safety_range_and_torque() -> None:
    """On the Touch (small ranges, weak motors): the true position of every joint never leaves its
    range less half the margin, and every torque beyond gravity compensation stays within the
    torque fraction of the motor's limit (here 20 %)."""
    exc = Excitation(torque_fraction=0.2, repeats=1)
    driver = _driver(TOUCH, cls=Logged)
    kin = ArmKinematics(driver.model_name, driver.joints, driver.point_site)
    result = Identifier(driver, kin, driver.sim.period_s, excitation=exc).run()
    assert all(ji.fit is not None for ji in result.joints)
    q = np.array(driver.q_log)
    rng = kin.joint_range_rad()
    assert (q >= rng[:, 0] + 0.5 * exc.margin_rad - 1e-3).all()
    assert (q <= rng[:, 1] - 0.5 * exc.margin_rad + 1e-3).all()
    for k in range(rng.shape[0]):  # and each joint was moved over most of its range
        assert np.ptp(q[:, k]) > 0.5 * (rng[k, 1] - rng[k, 0])
    beyond = []
    for qk, tau in zip(driver.q_log[:-1], driver.tau_log, strict=True):
        kin.set_q(qk)
        beyond.append(tau - kin.gravity_torque())
    assert (np.abs(np.array(beyond)) <= 0.2 * kin.torque_limit_nm() + 1e-9).all()


class Understated(Pass):
    """A pass planned wrong: it claims a tenth of the distance it covers."""

    @property
    def travel_rad(self) -> float:
        return 0.1 * super().travel_rad


def test_range_guard_brakes_a_pass_planned_too_long() -> None:
    """A pass that would run 2.3 rad on the Touch's yaw (2.1 rad of range): the guard brakes the
    joint toward half the margin from the end (overshooting by its loop's lag only), and the window it
    cut is discarded."""
    exc = Excitation(repeats=1)
    driver = _driver(TOUCH, cls=Logged)
    kin = ArmKinematics(driver.model_name, driver.joints, driver.point_site)
    ident = Identifier(driver, kin, 0.001, excitation=exc, joints=["yaw"])
    long_pass = Understated(1.0, exc.accel_rad_per_s2, 0.3, 1.8, 0.05, 1)
    assert long_pass.speed_rad_per_s * (long_pass.ramp_s + long_pass.hold_s) > 2.2
    ident.plans["yaw"] = Plan((long_pass,), ())
    result = ident.run()
    q = np.array(driver.q_log)[:, 0]
    hi = kin.joint_range_rad()[0, 1]
    assert q.max() < hi - 0.25 * exc.margin_rad  # braked toward hi - margin / 2, a few mrad of lag past it
    assert q.max() >= hi - exc.margin_rad  # it did run to the end
    assert result.joints[0].rejected_windows == 1
    assert result.joints[0].rejected_by == (("guard", 1),)  # the reason, counted


def test_torque_clamp_binds() -> None:
    """A torque fraction of 4 % (0.31 N m on the XM540s, 0.12 N m on the XM430): the fastest
    speeds need more and are not reached (their windows rejected), and no torque beyond gravity
    compensation ever exceeds the clamp."""
    exc = Excitation(torque_fraction=0.04, repeats=1)
    driver = _driver(DXL, cls=Logged)
    kin = ArmKinematics(driver.model_name, driver.joints, driver.point_site)
    result = Identifier(driver, kin, 0.001, excitation=exc).run()
    assert sum(ji.rejected_windows for ji in result.joints) > 0
    reasons = {r for ji in result.joints for r, _ in ji.rejected_by}
    assert "clamp" in reasons, reasons
    for ji in result.joints:
        assert sum(n for _, n in ji.rejected_by) == ji.rejected_windows
    table = format_table(result, None, driver.joints)  # the command says why, joint by joint
    assert any(
        line.startswith(f"{ji.joint}: windows rejected: ") and "clamp (" in line
        for line in table.splitlines()
        for ji in result.joints
        if dict(ji.rejected_by).get("clamp")
    )
    beyond = []
    for qk, tau in zip(driver.q_log[:-1], driver.tau_log, strict=True):
        kin.set_q(qk)
        beyond.append(tau - kin.gravity_torque())
    assert (np.abs(np.array(beyond)) <= 0.04 * kin.torque_limit_nm() + 1e-9).all()


def test_a_joint_outside_its_range_stops_with_torque_off() -> None:
    """The arm starts beyond the shoulder's range: a fault naming the joint, and the driver stopped."""
    driver = MujocoJointDriver("dxl_arm.xml", "tool", start_q_rad=[0.0, 1.95, -1.2])
    kin = ArmKinematics("dxl_arm.xml", driver.joints, "tool")
    with pytest.raises(IdentifyFault, match="'shoulder' left its range"):
        Identifier(driver, kin, 0.001).run()
    assert driver.stopped


class Failing(MujocoJointDriver):
    """The simulated driver whose bus fails after `after` writes (as a real driver raises)."""

    after = 3000

    def write(self, tau_nm):  # type: ignore[no-untyped-def]
        if self._ticks >= self.after:
            raise HardwareError("servo 2: no status packet (the bus went quiet)")
        return super().write(tau_nm)


def test_a_driver_fault_stops_with_torque_off() -> None:
    driver = Failing("dxl_arm.xml", "tool", start_q_rad=DXL["start"])
    kin = ArmKinematics("dxl_arm.xml", driver.joints, "tool")
    with pytest.raises(HardwareError, match="servo 2"):
        Identifier(driver, kin, 0.001).run()
    assert driver.stopped
    assert (driver.arm.data.ctrl == 0.0).all()


def test_stop_request_ends_the_run() -> None:
    """A stop requested during the second joint: the first joint's result is kept, the run says it
    was interrupted, the driver is stopped."""
    driver = _driver(DXL)
    kin = ArmKinematics(driver.model_name, driver.joints, driver.point_site)
    ident: Identifier

    def progress(p) -> None:  # type: ignore[no-untyped-def]
        if p.joint_index == 1 and p.pass_index == 3:
            ident.request_stop()

    ident = Identifier(driver, kin, 0.001, progress=progress)
    result = ident.run()
    assert result.interrupted
    assert [ji.joint for ji in result.joints] == ["base_yaw"]
    assert driver.stopped


class Paced(MujocoJointDriver):
    lockstep = False


def test_paced_driver_runs_on_the_period() -> None:
    """A driver that is not lockstep is paced on the period (no rate asserted: only that it works)."""
    driver = Paced("dxl_arm.xml", "tool", start_q_rad=DXL["start"], velocity_noise_rad_per_s=0.01)
    kin = ArmKinematics("dxl_arm.xml", driver.joints, "tool")
    exc = Excitation(speeds_rad_per_s=(0.5, 1.0), settle_s=0.05, measure_s=0.1, repeats=1)
    result = Identifier(driver, kin, 0.001, excitation=exc, joints=["elbow"], gains=Gains(start_hold_s=0.05)).run()
    assert result.joints[0].joint == "elbow"
    assert result.joints[0].fit is not None
    assert driver.stopped


# ------------------------------------------------------------------------------- the command


def _cli(capsys, argv):  # type: ignore[no-untyped-def]
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_command_end_to_end(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """`identify touch_dynamixel_wall --side slave`: exit 0, a table row per joint with the true
    values beside the estimates; the written scene loads and holds the safe values, each below the
    model's true damping; the plot is a PNG."""
    out = tmp_path / "identified.yaml"
    png = tmp_path / "friction.png"
    code, text, err = _cli(
        capsys, ["identify", "touch_dynamixel_wall", "--side", "slave", "--write", str(out), "--plot", str(png)]
    )
    assert code == 0, err
    lines = text.splitlines()
    assert lines[0].split()[:2] == ["joint", "b"]
    rows = {ln.split()[0]: ln.split() for ln in lines[2:5]}
    assert set(rows) == {"base_yaw", "shoulder", "elbow"}
    true_b = {"base_yaw": 0.1, "shoulder": 0.1, "elbow": 0.04}  # dxl_arm.xml's damping
    scene = load_scene(out)
    written = scene.config.slave.damping_nm_s_per_rad
    assert written is not None and len(written) == 3
    for name, value in zip(["base_yaw", "shoulder", "elbow"], written, strict=True):
        assert float(rows[name][7]) == pytest.approx(value, rel=1e-4)  # the table's safe b is what was written
        assert 0.9 * true_b[name] < value < true_b[name]
    # everything else is the scene as it was
    original = load_scene(find_scene("touch_dynamixel_wall")).config
    assert scene.config.master == original.master
    assert scene.config.slave.wall == original.slave.wall
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_command_one_joint_keeps_the_others(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """--joint elbow: only the elbow is identified and written; the other joints keep the model's damping."""
    out = tmp_path / "s.yaml"
    code, text, err = _cli(
        capsys,
        ["identify", "touch_dynamixel_wall", "--side", "master", "--joint", "elbow", "--write", str(out), "--quiet"],
    )
    assert code == 0, err
    assert text == ""
    written = load_scene(out).config.master.damping_nm_s_per_rad
    assert written is not None
    assert written[:2] == (0.0209, 0.01121)
    assert 0.9 * 0.01121 < written[2] < 0.01121


@pytest.mark.parametrize(
    ("argv", "expect"),
    [
        (["identify", "wall_contact", "--side", "slave"], "a one-axis scene"),
        (["identify", "touch_dynamixel_wall", "--side", "slave", "--joint", "wrist"], "--joint wrist"),
        (["identify", "touch_dynamixel_wall", "--side", "slave", "--torque-fraction", "2"], "torque_fraction"),
        (["identify", "touch_dynamixel_wall", "--side", "slave", "--speeds", "fast"], "--speeds fast"),
        (["identify", "touch_dynamixel_wall", "--side", "slave", "--set", "slave.backend=ur"], "slave.backend"),
        (["identify", "no_such_scene", "--side", "slave"], "no_such_scene"),
    ],
)
def test_command_bad_input(capsys, argv, expect) -> None:  # type: ignore[no-untyped-def]
    code, _text, err = _cli(capsys, argv)
    assert code == 2
    assert expect in err
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err


def test_command_ctrl_c_stops_and_prints_the_joints_done(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """SIGINT once the first joint is done: the run stops, the first joint's row is printed, the
    scene is not written, exit 130, no traceback."""
    import os
    import signal
    import subprocess
    import sys

    out = tmp_path / "s.yaml"
    env = dict(os.environ, PYTHONUNBUFFERED="1", HAPTIC_TELEOP_TEST_PAUSE="second_joint")
    p = subprocess.Popen(
        [sys.executable, "-m", "haptic_teleop.cli", "identify", "touch_dynamixel_wall", "--side", "slave",
         "--write", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    assert p.stderr is not None
    seen = ""
    while "phase second_joint" not in seen:  # the marker, not a timing (the read blocks until it comes)
        line = p.stderr.readline()
        assert line, f"no phase line; stderr: {seen}"
        seen += line
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=120)
    assert p.returncode == 130, stderr
    rows = [ln.split()[0] for ln in stdout.splitlines()[2:] if ln.split()]
    assert rows[0] == "base_yaw" and "shoulder" not in rows and "elbow" not in rows
    assert "stopped by a signal" in stderr and "not written" in stderr
    assert "Traceback" not in stderr
    assert not out.exists()


def test_sim_driver_is_a_joint_driver() -> None:
    """The simulated driver keeps the JointDriver contract: no read or write before start or after
    stop, stop idempotent with the torque off; the Touch's gravcomp bodies weigh again (torque 0:
    the arm falls); a sensor's velocity resolution is what it reports."""
    from haptic_teleop.errors import PlantError

    d = MujocoJointDriver("touch.xml", "handle", start_q_rad=[0.0, 0.2, 0.0], velocity_resolution_rad_per_s=0.05)
    with pytest.raises(PlantError, match="before start"):
        d.read()
    s0 = d.start()
    assert s0.t_s == 0.0
    for _ in range(200):
        d.write(np.zeros(3))
    s = d.read()
    assert s.t_s == pytest.approx(0.2)
    assert np.abs(s.q_rad - s0.q_rad).max() > 0.01  # nothing holds it: it falls
    np.testing.assert_allclose(s.qd_rad_per_s / 0.05, np.round(s.qd_rad_per_s / 0.05), atol=1e-9)
    applied = d.write(np.array([1.0, -1.0, 0.1]))
    np.testing.assert_allclose(applied, [0.44, -0.44, 0.1])  # clipped at the ctrlrange
    d.stop()
    d.stop()
    assert (d.arm.data.ctrl == 0.0).all()
    with pytest.raises(PlantError, match="after stop"):
        d.write(np.zeros(3))
