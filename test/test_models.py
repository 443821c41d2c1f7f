"""The bundled MJCF models (haptic_teleop/models): they compile in real MuJoCo, carry the names the
plants rely on, and their kinematics, masses and limits are the published ones (docs/models.md).

Forward kinematics is checked against an independent implementation: UR's DH table with the
standard DH convention for the UR5e, closed-form link-length formulas for the masters and the
Dynamixel arm, at random configurations."""

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

MODELS = Path(__file__).resolve().parents[1] / "haptic_teleop" / "models"
RNG_SEED = 20261124
N_CONFIGS = 50


def load(name: str) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(MODELS / name))


def names(model: mujoco.MjModel, obj: mujoco.mjtObj, count: int) -> list[str]:
    return [mujoco.mj_id2name(model, obj, i) for i in range(count)]


def random_configs(model: mujoco.MjModel, n: int = N_CONFIGS) -> np.ndarray:
    """n joint vectors drawn uniformly inside the joint ranges."""
    rng = np.random.default_rng(RNG_SEED)
    lo, hi = model.jnt_range[:, 0], model.jnt_range[:, 1]
    return rng.uniform(lo, hi, size=(n, model.nq))


def site_pose(model: mujoco.MjModel, site: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    s = data.site(site)
    return s.xpos.copy(), s.xmat.reshape(3, 3).copy()


# --- UR5e: UR's published DH parameters (standard convention) -----------------------------------

UR5E_DH = {  # a [m], d [m], alpha [rad] per joint
    "a": (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0),
    "d": (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996),
    "alpha": (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0),
}
UR5E_TOOL_OFFSET_M = 0.05  # the probe: site `tool` this far along the flange z axis
UR5E_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
UR5E_MASSES_KG = {
    "shoulder_link": 3.761,
    "upper_arm_link": 8.058,
    "forearm_link": 2.846,
    "wrist_1_link": 1.37,
    "wrist_2_link": 1.3,
    "wrist_3_link": 0.365,
}
UR5E_COM_M = {  # published in DH frame i (the frame after joint i's transform)
    "shoulder_link": (0.0, -0.02561, 0.00193),
    "upper_arm_link": (0.2125, 0.0, 0.11336),
    "forearm_link": (0.15, 0.0, 0.0265),
    "wrist_1_link": (0.0, -0.0018, 0.01634),
    "wrist_2_link": (0.0, 0.0018, 0.01634),
    "wrist_3_link": (0.0, 0.0, -0.001159),
}


def dh(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """Standard DH: Rot_z(theta) Trans_z(d) Trans_x(a) Rot_x(alpha)."""
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def ur5e_frames(q: np.ndarray, dh_table: dict = UR5E_DH) -> list[np.ndarray]:
    """The base-to-frame-i transforms T_0i, i = 1..6."""
    t, frames = np.eye(4), []
    for i in range(6):
        t = t @ dh(q[i], dh_table["d"][i], dh_table["a"][i], dh_table["alpha"][i])
        frames.append(t)
    return frames


# --- the masters and the Dynamixel arm: closed forms ---------------------------------------------


def yaw_shoulder_elbow(q: np.ndarray, l1: float, l2: float) -> np.ndarray:
    """Handle of a yaw/shoulder/elbow chain with the shoulder on the yaw axis: upper arm l1
    horizontal and forearm l2 hanging down at q = 0, shoulder and elbow raising positive."""
    yaw, s, e = q
    r = l1 * math.cos(s) + l2 * math.sin(s + e)
    return np.array([r * math.cos(yaw), r * math.sin(yaw), l1 * math.sin(s) - l2 * math.cos(s + e)])


def yaw_shoulder_elbow_ik(p: np.ndarray, l1: float, l2: float) -> np.ndarray:
    """The inverse of yaw_shoulder_elbow (forearm on the side it hangs at q = 0)."""
    x, y, z = p
    yaw, r = math.atan2(y, x), math.hypot(x, y)
    e = math.asin((r * r + z * z - l1 * l1 - l2 * l2) / (2 * l1 * l2))
    s = math.atan2(z, r) - math.atan2(-l2 * math.cos(e), l1 + l2 * math.sin(e))
    return np.array([yaw, s, e])


def dxl_tool(q: np.ndarray) -> np.ndarray:
    """Tool point of the Dynamixel arm: shoulder DXL_H0_M above the base, both links straight
    out at q = 0, shoulder and elbow raising positive."""
    yaw, s, e = q
    reach = DXL_L3_M + DXL_PROBE_M
    r = DXL_L2_M * math.cos(s) + reach * math.cos(s + e)
    z = DXL_H0_M + DXL_L2_M * math.sin(s) + reach * math.sin(s + e)
    return np.array([r * math.cos(yaw), r * math.sin(yaw), z])


# Published facts (docs/models.md cites each) and the stated estimates the models are built from.
MASTERS = {
    # file: (upper arm = forearm length [m], peak handle force range [N] in the nominal pose,
    #        published workspace W x H x D [m], workspace centre in the base frame [m])
    "touch.xml": (0.13335, (3.0, 3.6), (0.160, 0.120, 0.070), (0.11, 0.0, -0.10)),
    "premium.xml": (0.215, (8.0, 12.0), (0.381, 0.267, 0.191), (0.20, 0.0, -0.10)),
}
DXL_JOINTS = ("base_yaw", "shoulder", "elbow")
DXL_H0_M, DXL_L2_M, DXL_L3_M, DXL_PROBE_M = 0.077, 0.25, 0.22, 0.03
GOAL_CURRENT_UNIT_A = 2.69e-3
DXL_SERVOS = {  # stall torque [N m] and stall current [A] at 12 V, gear ratio, mass [kg]
    "XM540-W270": (10.6, 4.4, 272.5, 0.165),
    "XM430-W350": (4.1, 2.3, 353.5, 0.082),
}
DXL_CONFIG = {  # joint: (servo, configured Current Limit [units], rotor inertia estimate [kg m^2])
    "base_yaw": ("XM540-W270", 1200, 5e-7),
    "shoulder": ("XM540-W270", 1200, 5e-7),
    "elbow": ("XM430-W350", 640, 1e-7),
}
DXL_MASSES_KG = {"turret": 0.2, "upper_arm": 0.161, "forearm": 0.055}
SLAVES = {"ur5e.xml": UR5E_JOINTS, "dxl_arm.xml": DXL_JOINTS}


def peak_force_per_axis(model: mujoco.MjModel, q: np.ndarray) -> np.ndarray:
    """The largest handle force along each device axis that the motors can hold in pose q:
    tau = J^T F within each motor's ctrlrange (gear 1)."""
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    jac = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jac, None, model.site("handle").id)
    tau_max = model.actuator_ctrlrange[:, 1]
    out = []
    for axis in np.eye(3):
        per_unit = np.abs(jac.T @ axis)
        out.append(min(t / u for t, u in zip(tau_max, per_unit) if u > 1e-12))
    return np.array(out)


# --- every model ---------------------------------------------------------------------------------


def test_every_model_compiles_and_steps():
    found = sorted(p.name for p in MODELS.glob("*.xml"))
    for want in (*MASTERS, *SLAVES):
        assert want in found
    for name in (*MASTERS, *SLAVES):
        model = load(name)
        data = mujoco.MjData(model)
        for _ in range(500):  # half a second unpowered from the zero pose: finite, no warnings
            mujoco.mj_step(model, data)
        assert np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all(), name
        assert not any(w.number for w in data.warning), name
        assert model.opt.timestep == 0.001, name


# --- masters -------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(MASTERS))
def test_master_names(name):
    model = load(name)
    assert names(model, mujoco.mjtObj.mjOBJ_JOINT, model.njnt) == ["yaw", "shoulder", "elbow"]
    assert all(t == mujoco.mjtJoint.mjJNT_HINGE for t in model.jnt_type)
    assert names(model, mujoco.mjtObj.mjOBJ_ACTUATOR, model.nu) == ["yaw", "shoulder", "elbow"]
    for i in range(model.nu):
        assert model.actuator_trnid[i, 0] == i  # motor i drives joint i
        assert model.actuator_gear[i, 0] == 1.0
        assert model.actuator_ctrllimited[i]
    assert model.site("handle").bodyid[0] == model.body("handle_body").id
    assert np.allclose(model.site("handle").pos, 0.0)  # the handle point is handle_body's origin
    assert not model.geom_contype.any() and not model.geom_conaffinity.any()
    assert (model.dof_damping > 0).all()


@pytest.mark.parametrize("name", sorted(MASTERS))
def test_master_forward_kinematics_closed_form(name):
    model, length = load(name), MASTERS[name][0]
    for q in random_configs(model):
        pos, _ = site_pose(model, "handle", q)
        assert np.abs(pos - yaw_shoulder_elbow(q, length, length)).max() < 1e-9


@pytest.mark.parametrize("name", sorted(MASTERS))
def test_master_peak_force_in_nominal_pose(name):
    """Nominal pose q = 0 (upper arm horizontal, forearm vertical): the peak handle force along
    each axis is the published peak force."""
    model = load(name)
    lo, hi = MASTERS[name][1]
    peak = peak_force_per_axis(model, np.zeros(3))
    assert ((peak >= lo) & (peak <= hi)).all(), peak


@pytest.mark.parametrize("name", sorted(MASTERS))
def test_master_joint_ranges_cover_published_workspace(name):
    """Every point of a 5 x 5 x 5 grid over the published workspace box (width along y, height
    along z, depth along x, around the stated centre) is reached inside the joint ranges."""
    model, length = load(name), MASTERS[name][0]
    (w, h, d), centre = MASTERS[name][2], np.array(MASTERS[name][3])
    half = np.array([d, w, h]) / 2
    lo, hi = model.jnt_range[:, 0], model.jnt_range[:, 1]
    for corner in np.stack(np.meshgrid(*[np.linspace(-1, 1, 5)] * 3), -1).reshape(-1, 3):
        p = centre + half * corner
        q = yaw_shoulder_elbow_ik(p, length, length)
        assert np.abs(yaw_shoulder_elbow(q, length, length) - p).max() < 1e-9
        assert ((q >= lo) & (q <= hi)).all(), (p, q)
        assert np.abs(site_pose(model, "handle", q)[0] - p).max() < 1e-9


MASTER_DECLARED = {  # docs/models.md: body masses [kg], joint ranges [rad], torque limit [N m],
    # damping [N m s/rad], armature [kg m^2]
    "touch.xml": (
        {"turret": 0.18, "upper_arm": 0.035, "forearm": 0.03, "handle_body": 0.025},
        ((-1.05, 1.05), (-0.5, 1.1), (-1.2, 0.9)),
        0.44,
        (0.0209, 0.01121, 0.01121),
        0.00012,
    ),
    "premium.xml": (
        {"turret": 0.45, "upper_arm": 0.045, "forearm": 0.03, "handle_body": 0.015},
        ((-1.2, 1.2), (-0.5, 1.75), (-1.2, 1.3)),
        1.83,
        0.0809,
        0.0002,
    ),
}


@pytest.mark.parametrize("name", sorted(MASTERS))
def test_master_masses_and_limits_as_declared(name):
    model = load(name)
    masses, ranges, torque_nm, damping, armature = MASTER_DECLARED[name]
    for body, mass in masses.items():
        assert model.body(body).mass[0] == pytest.approx(mass, abs=1e-12), body
    assert np.abs(model.jnt_range - np.array(ranges)).max() < 1e-12
    assert model.jnt_limited.all()
    assert np.abs(model.actuator_ctrlrange - np.array([[-torque_nm, torque_nm]] * 3)).max() < 1e-12
    assert np.allclose(model.dof_damping, damping, rtol=0, atol=1e-15)
    assert np.allclose(model.dof_armature, armature, rtol=0, atol=1e-15)


@pytest.mark.parametrize("name", sorted(MASTERS))
def test_master_is_gravity_balanced(name):
    """Counterbalanced device: under gravity, with the motors off, the arm stays where it is put
    (gravcomp cancels the weight of every moving body)."""
    model = load(name)
    assert model.opt.gravity[2] < -9
    data = mujoco.MjData(model)
    q0 = np.array([0.3, 0.6, -0.4])
    data.qpos[:] = q0
    for _ in range(1000):
        mujoco.mj_step(model, data)
    assert np.abs(data.qpos - q0).max() < 1e-9


# Published stiffness per device axis [N/m] (docs/models.md): what the device renders stably at
# 1 kHz, so by Colgate's condition K < 2 b / T its damping along that axis is at least K T / 2.
PUBLISHED_STIFFNESS_N_PER_M = {"touch.xml": (1260.0, 2350.0, 730.0), "premium.xml": (3500.0, 3500.0, 3500.0)}


@pytest.mark.parametrize("name", sorted(MASTERS))
def test_master_damping_makes_the_published_stiffness_passive(name):
    """The joint damping D gives, in the nominal pose (q = 0), a task-space damping
    B = J^-T D J^-1 for a motion along each device axis; every published stiffness K_a must satisfy
    K_a <= 2 B_aa / T (passive at T = 1 ms), and the damping is the least that does: the tightest
    axis needs it within 1 %."""
    model = load(name)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    jac = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jac, None, model.site("handle").id)
    j_inv = np.linalg.inv(jac)
    b_task = j_inv.T @ np.diag(model.dof_damping) @ j_inv
    need = np.array(PUBLISHED_STIFFNESS_N_PER_M[name]) * 1e-3 / 2.0
    assert (np.diag(b_task) >= need).all(), (np.diag(b_task), need)
    assert (np.diag(b_task) / need).min() < 1.01, (np.diag(b_task), need)


# --- slaves --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(SLAVES))
def test_slave_names_and_sensors(name):
    model, joints = load(name), SLAVES[name]
    assert tuple(names(model, mujoco.mjtObj.mjOBJ_JOINT, model.njnt)) == joints
    assert tuple(names(model, mujoco.mjtObj.mjOBJ_ACTUATOR, model.nu)) == joints
    for i in range(model.nu):
        assert model.actuator_trnid[i, 0] == i and model.actuator_gear[i, 0] == 1.0
        assert model.actuator_ctrllimited[i]
    assert model.sensor("ft_force").type[0] == mujoco.mjtSensor.mjSENS_FORCE
    assert model.sensor("ft_torque").type[0] == mujoco.mjtSensor.mjSENS_TORQUE
    ft = model.site("ft").id
    assert model.sensor("ft_force").objid[0] == ft and model.sensor("ft_torque").objid[0] == ft
    # the tool tip sphere is centred on the tool site
    tip, tool = model.geom("tool_tip"), model.site("tool")
    assert tip.bodyid[0] == tool.bodyid[0] and np.allclose(tip.pos, tool.pos)
    assert (model.dof_damping > 0).all() and (model.dof_armature > 0).all()


@pytest.mark.parametrize("name", sorted(SLAVES))
def test_only_the_tool_tip_touches_a_wall(name):
    """A plane (a half-space) with contype = conaffinity = 1 above the whole arm in its zero pose:
    every geom of the arm is inside it, and only the tool tip makes contact."""
    spec = mujoco.MjSpec.from_file(str(MODELS / name))
    model0 = spec.compile()
    data0 = mujoco.MjData(model0)
    mujoco.mj_kinematics(model0, data0)
    top = max(data0.geom_xpos[i][2] + model0.geom_rbound[i] for i in range(model0.ngeom))
    wall = spec.worldbody.add_geom()
    wall.name, wall.type = "wall", mujoco.mjtGeom.mjGEOM_PLANE
    wall.size, wall.pos = [2.0, 2.0, 0.01], [0.0, 0.0, top + 0.01]
    wall.contype, wall.conaffinity = 1, 1
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    pairs = {frozenset((model.geom(c.geom1).name, model.geom(c.geom2).name)) for c in data.contact[: data.ncon]}
    assert pairs == {frozenset(("wall", "tool_tip"))}


@pytest.mark.parametrize("name", sorted(SLAVES))
def test_ft_sensor_reads_the_force_the_tool_applies(name):
    """Zero gravity, the tool tip pressed into a wall: ft_force (flange frame, turned to world)
    is minus the contact force on the tip, to within the probe's inertial force."""
    spec = mujoco.MjSpec.from_file(str(MODELS / name))
    spec.option.gravity = [0.0, 0.0, 0.0]
    model0 = spec.compile()
    data0 = mujoco.MjData(model0)
    mujoco.mj_kinematics(model0, data0)
    wall = spec.worldbody.add_geom()
    wall.type, wall.size = mujoco.mjtGeom.mjGEOM_PLANE, [2.0, 2.0, 0.01]
    wall.pos = [0.0, 0.0, data0.geom("tool_tip").xpos[2] + 0.005]
    wall.contype, wall.conaffinity = 1, 1
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert data.ncon == 1
    f6 = np.zeros(6)
    mujoco.mj_contactForce(model, data, 0, f6)
    contact = data.contact[0]
    on_tip = contact.frame.reshape(3, 3).T @ f6[:3]
    if model.geom(contact.geom1).name == "tool_tip":
        on_tip = -on_tip
    sensed = data.site("ft").xmat.reshape(3, 3) @ data.sensor("ft_force").data
    assert np.linalg.norm(on_tip) > 1.0
    assert np.linalg.norm(sensed + on_tip) < 0.05 * np.linalg.norm(on_tip)


def test_ur5e_forward_kinematics_matches_dh():
    model = load("ur5e.xml")
    data = mujoco.MjData(model)
    for q in random_configs(model):
        frames = ur5e_frames(q)
        t06 = frames[-1]
        tool_pos, tool_rot = site_pose(model, "tool", q)
        ft_pos, ft_rot = site_pose(model, "ft", q)
        assert np.abs(ft_pos - t06[:3, 3]).max() < 1e-9
        assert np.abs(ft_rot - t06[:3, :3]).max() < 1e-9
        want_tool = t06[:3, 3] + UR5E_TOOL_OFFSET_M * t06[:3, 2]
        assert np.abs(tool_pos - want_tool).max() < 1e-9
        assert np.abs(tool_rot - t06[:3, :3]).max() < 1e-9
        # every link's centre of mass where UR publishes it (in DH frame i)
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        for t, (body, com) in zip(frames, UR5E_COM_M.items()):
            want = t[:3, :3] @ np.array(com) + t[:3, 3]
            assert np.abs(data.body(body).xipos - want).max() < 1e-9, body


def test_ur5e_masses_and_limits():
    model = load("ur5e.xml")
    for body, mass in UR5E_MASSES_KG.items():
        assert model.body(body).mass[0] == pytest.approx(mass, abs=1e-12)
    moving = model.body_subtreemass[model.body("shoulder_link").id]
    assert moving == pytest.approx(sum(UR5E_MASSES_KG.values()) + 0.002, abs=1e-9)  # + the probe
    assert model.actuator_ctrlrange.tolist() == [[-t, t] for t in (150, 150, 150, 28, 28, 28)]
    two_pi = 2 * math.pi
    want = [[-two_pi, two_pi]] * 2 + [[-math.pi, math.pi]] + [[-two_pi, two_pi]] * 3
    assert np.abs(model.jnt_range - np.array(want)).max() < 1e-12
    assert model.jnt_limited.all()


def test_dxl_forward_kinematics_closed_form():
    model = load("dxl_arm.xml")
    for q in random_configs(model):
        pos, _ = site_pose(model, "tool", q)
        assert np.abs(pos - dxl_tool(q)).max() < 1e-9
        ft_pos, ft_rot = site_pose(model, "ft", q)
        # the flange frame: z along the forearm, the tool DXL_PROBE_M further along it
        assert np.abs(pos - (ft_pos + DXL_PROBE_M * ft_rot[:, 2])).max() < 1e-9


def test_dxl_torque_limits_follow_from_the_current_limit():
    """ctrlrange = (stall torque / stall current at 12 V) x Current Limit x 2.69 mA; armature =
    gear ratio^2 x rotor inertia; link masses at least the servos they carry."""
    model = load("dxl_arm.xml")
    for joint, (servo, limit_units, rotor) in DXL_CONFIG.items():
        stall_nm, stall_a, gear, _ = DXL_SERVOS[servo]
        torque_nm = stall_nm / stall_a * limit_units * GOAL_CURRENT_UNIT_A
        assert limit_units * GOAL_CURRENT_UNIT_A <= stall_a  # the limit binds, not the 12 V supply
        act = model.actuator(joint)
        assert act.ctrlrange.tolist() == pytest.approx([-torque_nm, torque_nm], abs=1e-4)
        assert model.joint(joint).armature[0] == pytest.approx(gear**2 * rotor, rel=1e-3)
    for body, mass in DXL_MASSES_KG.items():
        assert model.body(body).mass[0] == pytest.approx(mass, abs=1e-12)
    assert np.abs(model.jnt_range - np.array([[-3.14159, 3.14159], [-1.5, 1.9], [-2.4, 2.4]])).max() < 1e-12
    assert model.dof_damping.tolist() == [0.1, 0.1, 0.04]
    assert model.dof_frictionloss.tolist() == [0.15, 0.15, 0.06]
    assert model.body("turret").mass[0] >= DXL_SERVOS["XM540-W270"][3]  # carries the shoulder servo
    assert model.body("upper_arm").mass[0] >= DXL_SERVOS["XM430-W350"][3]  # carries the elbow servo
