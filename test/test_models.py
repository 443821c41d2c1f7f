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


TOUCH_L_M = 0.13335  # upper arm and forearm (published Phantom Omni kinematics)
MASTERS = {"touch.xml": (2.9, 3.6)}  # peak handle force range [N] in the nominal pose


def test_every_model_compiles():
    found = sorted(p.name for p in MODELS.glob("*.xml"))
    for want in ("touch.xml", "ur5e.xml"):
        assert want in found
    for name in found:
        model = load(name)
        assert model.nq >= 1, name


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
    assert not model.geom_contype.any() and not model.geom_conaffinity.any()


def test_ur5e_names_and_sensors():
    model = load("ur5e.xml")
    assert tuple(names(model, mujoco.mjtObj.mjOBJ_JOINT, model.njnt)) == UR5E_JOINTS
    assert tuple(names(model, mujoco.mjtObj.mjOBJ_ACTUATOR, model.nu)) == UR5E_JOINTS
    assert [model.actuator_trnid[i, 0] for i in range(6)] == list(range(6))
    assert model.sensor("ft_force").type[0] == mujoco.mjtSensor.mjSENS_FORCE
    assert model.sensor("ft_torque").type[0] == mujoco.mjtSensor.mjSENS_TORQUE
    ft = model.site("ft").id
    assert model.sensor("ft_force").objid[0] == ft and model.sensor("ft_torque").objid[0] == ft
    model.site("tool")
    # only the tool tip can touch a wall (a plane with contype = conaffinity = 1)
    colliding = [model.geom(i).name for i in range(model.ngeom) if model.geom_contype[i] or model.geom_conaffinity[i]]
    assert colliding == ["tool_tip"]
    tip = model.geom("tool_tip")
    assert tip.contype[0] & 1 and tip.conaffinity[0] & 1
    assert np.allclose(model.geom_pos[tip.id], model.site_pos[model.site("tool").id])


def test_ur5e_forward_kinematics_matches_dh():
    model = load("ur5e.xml")
    for q in random_configs(model):
        t06 = ur5e_frames(q)[-1]
        tool_pos, tool_rot = site_pose(model, "tool", q)
        ft_pos, ft_rot = site_pose(model, "ft", q)
        assert np.abs(ft_pos - t06[:3, 3]).max() < 1e-9
        assert np.abs(ft_rot - t06[:3, :3]).max() < 1e-9
        want_tool = t06[:3, 3] + UR5E_TOOL_OFFSET_M * t06[:3, 2]
        assert np.abs(tool_pos - want_tool).max() < 1e-9
        assert np.abs(tool_rot - t06[:3, :3]).max() < 1e-9


def test_touch_forward_kinematics_closed_form():
    model = load("touch.xml")
    for q in random_configs(model):
        pos, _ = site_pose(model, "handle", q)
        assert np.abs(pos - yaw_shoulder_elbow(q, TOUCH_L_M, TOUCH_L_M)).max() < 1e-9
