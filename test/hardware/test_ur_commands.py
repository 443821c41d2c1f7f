"""The UR stack's pure parts: the admittance against its closed form and its energy balance, the
force-mode argument packing, the rotation vectors, the RTDE recipes, the control-script check."""

from __future__ import annotations

import math

import numpy as np
import pytest

from haptic_teleop.core.admittance import Admittance, AdmittanceParams, delayed_wall_damping_margin, step_response
from haptic_teleop.core.spatial import matrix_to_rotvec, orientation_error, rotvec_to_matrix
from haptic_teleop.emulators.ur.script import ControlScript, Registers, ScriptError, parse_script
from haptic_teleop.errors import InputError
from haptic_teleop.plants.ur import rtde_wire as w
from haptic_teleop.plants.ur.commands import clip_twist, direct_torque_supported, force_mode_args
from haptic_teleop.plants.ur.driver import parse_polyscope_version


def test_admittance_step_response_equals_the_closed_form_at_every_sample():
    p = AdmittanceParams(mass=(2.0, 0.5, 8.0), damping=(40.0, 5.0, 20.0), period_s=0.002)
    a = Admittance(p)
    f = np.array([10.0, -3.0, 1.0])
    for k in range(1, 2001):
        x, v = a.step(f, np.zeros(3))
        xc, vc = step_response(p, f, k * p.period_s)
        np.testing.assert_allclose(v, vc, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(x, xc, rtol=1e-9, atol=1e-12)
    # the lag it adds: after one time constant M/D the velocity is at 1 - 1/e of f/D
    tau = p.time_constant_s
    np.testing.assert_allclose(tau, [0.05, 0.1, 0.4])
    xc, vc = step_response(p, f, float(tau[0]))
    assert vc[0] == pytest.approx(f[0] / 40.0 * (1.0 - math.exp(-1.0)))


def test_admittance_is_passive_for_any_force_sequence():
    rng = np.random.default_rng(7)
    p = AdmittanceParams(mass=(1.0,), damping=(3.0,), period_s=0.001)
    a = Admittance(p)
    energy_in = 0.0
    for _ in range(5000):
        f = rng.normal(0.0, 20.0, size=1)
        x0 = a.x.copy()
        a.step(f, np.zeros(1))
        energy_in += float(f @ (a.x - x0))  # force held over the period times the displacement
        assert energy_in >= a.energy_j() - 1e-9
    assert energy_in - a.energy_j() > 0.0  # the damper dissipated


def test_admittance_rejects_zero_damping_and_a_wall_needs_damping_beyond_its_lag():
    with pytest.raises(ValueError, match="damping"):
        AdmittanceParams(mass=(1.0,), damping=(0.0,), period_s=0.001)
    assert delayed_wall_damping_margin(1e4, 0.01) == pytest.approx(50.0)


def test_admittance_settles_where_the_wall_pushes_back_the_commanded_force():
    p = AdmittanceParams(mass=(1.0,), damping=(200.0,), period_s=0.002)
    a = Admittance(p)
    k_wall = 2000.0
    f_ext = np.zeros(1)
    for _ in range(5000):
        x, _ = a.step(np.array([-10.0]), f_ext)
        f_ext = np.array([k_wall * max(0.0, -x[0])])  # a wall at x = 0 pushing back
    assert f_ext[0] == pytest.approx(10.0, rel=1e-6)


def test_force_mode_arguments_are_checked_and_packed_in_ur_rtde_order():
    args = force_mode_args([0, 0, -10, 0, 0, 0], selection=[0, 0, 1, 0, 0, 0])
    frame, sel, wrench, typ, limits = args.sdk_args()
    assert sel == [0, 0, 1, 0, 0, 0] and wrench == [0.0, 0.0, -10.0, 0.0, 0.0, 0.0] and typ == 2
    assert frame == [0.0] * 6 and all(v > 0 for v in limits)
    with pytest.raises(InputError, match="selection"):
        force_mode_args([0] * 6, selection=[0, 0, 2, 0, 0, 0])
    with pytest.raises(InputError, match="beyond"):
        force_mode_args([0, 0, -500, 0, 0, 0])
    with pytest.raises(InputError, match="6 values"):
        force_mode_args([0, 0, 1])
    with pytest.raises(InputError, match="finite"):
        force_mode_args([0, 0, math.nan, 0, 0, 0])


def test_twist_clip_and_torque_versions():
    t = clip_twist([0.3, 0.4, 0.0, 0.0, 0.0, 2.0], 0.25, 1.0)
    assert math.hypot(t[0], t[1]) == pytest.approx(0.25) and t[5] == pytest.approx(1.0)
    assert not direct_torque_supported((5, 23, 0, 0))
    assert direct_torque_supported((5, 26, 0, 0))
    assert not direct_torque_supported((10, 9, 0, 0)) and direct_torque_supported((10, 10, 0, 0))
    assert parse_polyscope_version("URSoftware 5.11.1.108318 (Jul 13 2021)") == (5, 11, 1, 108318)


def test_rotation_vectors_round_trip():
    rng = np.random.default_rng(3)
    for _ in range(200):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        r = axis * rng.uniform(0.0, math.pi - 1e-3)
        m = rotvec_to_matrix(r)
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(matrix_to_rotvec(m), r, atol=1e-9)
    np.testing.assert_allclose(orientation_error(rotvec_to_matrix([0, 0, 0.3]), np.eye(3)), [0, 0, 0.3], atol=1e-12)


def test_rtde_recipe_packs_and_unpacks_big_endian():
    r = w.Recipe(3, ("actual_q", "robot_mode", "timestamp"), ("VECTOR6D", "INT32", "DOUBLE"))
    pkg = r.pack({"actual_q": (1.0, 2, 3, 4, 5, 6), "robot_mode": 7, "timestamp": 0.5})
    size, kind = w.HEADER.unpack(pkg[:3])
    assert size == len(pkg) == 3 + 1 + 48 + 4 + 8 and kind == ord("U") and pkg[3] == 3
    assert pkg[4:12].hex() == "3ff0000000000000"  # 1.0, big-endian IEEE 754
    back = r.unpack(pkg[4:])
    assert back["actual_q"] == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0) and back["robot_mode"] == 7
    assert w.resolve_names(["actual_q", "no_such_thing"], w.OUTPUT_TYPES) == ["VECTOR6D", w.NOT_FOUND]


SCRIPT = (
    "def rtde_control():\n    global reg_offset_float = # float register offset\n24    global reg_offset_int = "
    '# int register offset\n24    global x = 0\n    textmsg("RTDE Control Script Loaded (x)")\nend\n'
)


class _Robot:
    def __init__(self) -> None:
        self.calls: list[str] = []

    def hold(self) -> None:
        self.calls.append("hold")

    def servo_l(self, pose, gain):  # type: ignore[no-untyped-def]
        self.calls.append(f"servo {pose[0]} {gain}")

    def speed_l(self, twist, accel):  # type: ignore[no-untyped-def]
        self.calls.append(f"speed {twist[2]} {accel}")

    def speed_stop(self, decel):  # type: ignore[no-untyped-def]
        self.calls.append("speed_stop")

    def force_mode(self, frame, selection, wrench, limits):  # type: ignore[no-untyped-def]
        self.calls.append(f"force {[float(s) for s in selection]} {wrench[2]}")

    def direct_torque(self, tau):  # type: ignore[no-untyped-def]
        self.calls.append("torque")

    def zero_ft(self) -> None:
        self.calls.append("zero")

    def joint_torques(self):  # type: ignore[no-untyped-def]
        return np.zeros(6)


def test_control_script_handshake_with_the_upper_register_range():
    s = parse_script(SCRIPT)
    assert s.reg_offset == 24 and not s.has_direct_torque
    regs = Registers()
    cs = ControlScript(s, regs)
    robot = _Robot()
    assert regs.out_int[24] == 1  # ready
    regs.in_int[24] = 24  # SERVOL, real-time: processed every cycle, stays ready
    regs.in_double[24:35] = [0.1, 0, 0, 0, 0, 0, 0.5, 0.5, 0.002, 0.1, 300.0]
    cs.step(robot)
    cs.step(robot)
    assert robot.calls == ["servo 0.1 300.0", "servo 0.1 300.0"] and regs.out_int[24] == 1
    regs.in_int[24] = 16  # SERVO_STOP: once, then done (2) until the client clears the register
    cs.step(robot)
    cs.step(robot)
    assert robot.calls[-1] == "hold" and robot.calls.count("hold") == 1 and regs.out_int[24] == 2
    regs.in_int[24] = 0
    cs.step(robot)
    assert regs.out_int[24] == 1
    regs.in_int[24] = 6  # FORCE_MODE: type in int 1, selection in int 2..7, wrench in double 6..11
    regs.in_int[26:32] = [0, 0, 1, 0, 0, 0]
    regs.in_double[30:36] = [0, 0, -5.0, 0, 0, 0]
    cs.step(robot)
    assert robot.calls[-1] == "force [0.0, 0.0, 1.0, 0.0, 0.0, 0.0] -5.0"
    regs.in_int[24] = 255
    cs.step(robot)
    assert not cs.running and regs.out_int[24] == 1  # STOP_SCRIPT ends the program without "done"


def test_foreign_programs_are_refused():
    with pytest.raises(ScriptError, match="rtde_control"):
        parse_script("def prog():\n  movej([0,0,0,0,0,0])\nend\n")
    with pytest.raises(ScriptError, match="offset"):
        parse_script(SCRIPT.replace("# int register offset\n24", "# int register offset\n"))
