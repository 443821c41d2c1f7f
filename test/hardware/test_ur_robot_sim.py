"""The emulated UR5e's controller loops in simulated time (docs/ur_emulator.md, "What it emulates"):
`SimulatedUR` stepped one controller cycle (2 ms) at a time, no sockets and no clock, so what its
physics does is asserted as it is, whatever the machine's load. The same commands over RTDE, through
the unmodified ur_rtde, are in test_ur_driver.py, which asserts there what the driver reads, sends
and says (the emulator's server runs its cycles in real time), not the physics."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from haptic_teleop.core.admittance import Admittance, AdmittanceParams
from haptic_teleop.emulators.ur.config import URConfig, WallConfig
from haptic_teleop.emulators.ur.robot import SimulatedUR
from haptic_teleop.plants.arm import WallSpec

# the touch_ur5e_wall scene's table: 3 cm below the tool at the UR5e's start (as test_ur_driver.py)
WALL = WallConfig(point_m=(-0.49, -0.13, 0.4078), normal=(0.0, 0.0, 1.0), stiffness_n_per_m=1e4)
DOWN = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])


def robot(wall: WallConfig | None = WALL) -> SimulatedUR:
    """The emulator's robot as its server builds it from the default config (with `wall`)."""
    cfg = URConfig(wall=wall)
    spec = None
    if wall is not None:
        p, n = wall.point_m, wall.normal
        spec = WallSpec((p[0], p[1], p[2]), (n[0], n[1], n[2]), wall.stiffness_n_per_m, wall.damping_n_s_per_m)
    return SimulatedUR(
        cfg.model, cfg.start_q_rad, 1.0 / cfg.frequency_hz, cfg.substeps, spec,
        cfg.force_mode_damping_n_s_per_m, cfg.force_mode_damping_nm_s_per_rad,
    )  # fmt: skip


def cycles(r: SimulatedUR, seconds: float, each: Callable[[SimulatedUR], None] | None = None) -> None:
    """Run the controller for `seconds` of its time, calling `each` before every cycle (a host
    that commands once a cycle)."""
    for _ in range(round(seconds / r.period_s)):
        if each is not None:
            each(r)
        r.cycle()


def test_force_mode_presses_the_commanded_force_into_the_wall_and_regulates_the_sensor_reading():
    r = robot()
    start = r.tcp_pose()
    r.force_mode(np.zeros(6), DOWN, np.array([0, 0, -10.0, 0, 0, 0]), np.array([0.1, 0.1, 0.1, 0.5, 0.5, 0.5]))
    cycles(r, 1.5)
    f = r.tcp_force()
    assert r.mode == "force"
    assert f[2] == pytest.approx(10.0, abs=0.3)  # the table pushes back the commanded 10 N
    assert r.tcp_pose()[2] < WALL.point_m[2]  # pressed into the compliant table
    np.testing.assert_allclose(r.tcp_pose()[:2], start[:2], atol=2e-3)  # x, y held (not compliant)
    before = r.arm.contact_wrench()[0][2]
    r.zero_ft()  # the contact now reads as zero
    assert abs(r.tcp_force()[2]) < 1e-9
    # UR's force mode regulates the sensor's reading: it presses harder until it reads 10 N again
    cycles(r, 1.0)
    assert r.tcp_force()[2] == pytest.approx(10.0, abs=0.5)
    assert r.arm.contact_wrench()[0][2] == pytest.approx(before + 10.0, abs=0.5)
    r.hold()
    assert r.mode == "hold"


def test_servo_l_reaches_the_pose():
    r = robot(wall=None)
    target = r.tcp_pose().copy()
    target[:3] += [0.03, -0.02, 0.04]
    r.servo_l(target, 300.0)
    cycles(r, 1.0, lambda r: r.servo_l(target, 300.0))
    np.testing.assert_allclose(r.tcp_pose()[:3], target[:3], atol=1e-3)
    np.testing.assert_allclose(r.tcp_pose()[3:], target[3:], atol=1e-2)


def test_speed_l_moves_at_the_speed_and_speed_stop_stops_it():
    r = robot(wall=None)
    v = 0.05
    twist = np.array([0.0, 0.0, v, 0.0, 0.0, 0.0])
    cycles(r, 0.3, lambda r: r.speed_l(twist, 1.0))  # past the 0.05 s ramp
    z0 = r.tcp_pose()[2]
    cycles(r, 0.5, lambda r: r.speed_l(twist, 1.0))
    assert (r.tcp_pose()[2] - z0) / 0.5 == pytest.approx(v, rel=0.03)
    assert r.tcp_speed()[2] == pytest.approx(v, rel=0.03)
    r.speed_stop(10.0)
    cycles(r, 0.2)
    assert abs(r.tcp_speed()[2]) < 1e-3


def _admittance(damping_n_s_per_m: float, mass_kg: float, seconds: float) -> tuple[SimulatedUR, list[float]]:
    """A host's admittance through speedL, once a cycle: v from the commanded -8 N and the sensor."""
    r = robot()
    adm = Admittance(AdmittanceParams(mass=(mass_kg,), damping=(damping_n_s_per_m,), period_s=r.period_s))
    forces: list[float] = []

    def tick(r: SimulatedUR) -> None:
        _, v = adm.step(np.array([-8.0]), r.tcp_force()[2:3])
        r.speed_l(np.array([0.0, 0.0, float(v[0]), 0.0, 0.0, 0.0]), 5.0)
        forces.append(float(r.arm.contact_wrench()[0][2]))

    cycles(r, seconds, tick)
    return r, forces


def test_admittance_through_speed_l_settles_on_the_wall_at_the_commanded_force():
    r, forces = _admittance(400.0, 2.0, 2.5)
    assert r.tcp_force()[2] == pytest.approx(8.0, abs=0.8)
    assert np.ptp(forces[-100:]) < 0.5  # settled: the last 0.2 s within half a newton


def test_admittance_damping_below_k_t_over_2_bounces_on_the_table():
    """The lag condition D > K T / 2 (the robot's velocity loop lags about 27 ms: K T / 2 = 135
    N s/m against the 1e4 N/m table): with D = 10 N s/m the tool does not settle but bounces,
    leaving the table and striking it again, and the table receives work (the plant's own
    signal) that a settled press never gives it."""
    r_bad, f_bad = _admittance(10.0, 0.2, 2.5)
    r_ok, f_ok = _admittance(400.0, 2.0, 2.5)
    tail_bad, tail_ok = np.array(f_bad[-500:]), np.array(f_ok[-100:])  # its last second; the settled 0.2 s
    assert np.min(tail_bad) < 0.5 < 8.0 < np.max(tail_bad)  # off the table and hard on it, again and again
    assert np.ptp(tail_ok) < 0.5
    assert r_bad.max_env_work_j > 3.0 * r_ok.max_env_work_j
