"""The MuJoCo arm plant (plants/arm.py) on small 3-link test models (test/models/)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from haptic_teleop.errors import PlantError
from haptic_teleop.plants.arm import MujocoArm, WallSpec
from haptic_teleop.plants.mujoco_plant import SimSettings

MODELS = Path(__file__).parent / "models"
SLAVE = str(MODELS / "arm3_slave.xml")
MASTER = str(MODELS / "arm3_master.xml")
START = [0.0, 0.0, 0.0]  # tool at (0.2, 0, -0.14)


def _press(arm: MujocoArm, force: np.ndarray, ticks: int = 5000, damping: float = 2.0) -> None:
    for _ in range(ticks):
        _, qd = arm.read()
        arm.step(arm.jacobian().T @ force - damping * qd)


@pytest.mark.parametrize("stiffness", [1e3, 1e4, 3e4])
@pytest.mark.parametrize("normal", [(-1.0, 0.0, 0.0), (-0.6, 0.0, 0.8)])
def test_wall_static_stiffness(stiffness: float, normal: tuple[float, float, float]) -> None:
    """Pressing the tool into the wall with a steady force F along -normal: the penetration is
    F / K (within 1 %) and the contact force is F back along the normal."""
    n = np.array(normal)
    point = np.array([0.2, 0.0, -0.14]) - 0.01 * n  # 1 cm from the start, along -normal
    arm = MujocoArm(
        SimSettings(), SLAVE, "tool", start_q_rad=START, wall=WallSpec(tuple(point), normal, stiffness, 30.0)
    )
    f = 5.0
    _press(arm, -f * n)
    arm.read()
    pen = arm.contact_penetration_m()
    force, torque = arm.contact_wrench()
    assert pen > 0.0
    assert f / pen == pytest.approx(stiffness, rel=0.01)
    np.testing.assert_allclose(force, f * n, atol=0.01 * f)
    np.testing.assert_allclose(torque, 0.0, atol=1e-9)  # frictionless point contact at the tool point


def test_split_step_equals_mj_step() -> None:
    """read (mj_step1) + step (mj_step2) gives the same states as MuJoCo's own mj_step, bit for bit."""
    arm = MujocoArm(SimSettings(), SLAVE, "tool", start_q_rad=[0.1, 0.2, -0.3], gravity_compensation=False)
    m = arm.model
    d = mujoco.MjData(m)
    d.qpos[:] = arm.data.qpos
    tau = np.array([0.3, -0.2, 0.1])
    for _ in range(200):
        arm.read()
        arm.step(tau)
        d.ctrl[:] = tau
        mujoco.mj_step(m, d)
    q, qd = arm.read()
    assert q.tobytes() == d.qpos.tobytes() and qd.tobytes() == d.qvel.tobytes()


def test_gravity_compensation_holds_the_arm() -> None:
    held = MujocoArm(SimSettings(), SLAVE, "tool", start_q_rad=[0.0, 0.3, 0.5])
    free = MujocoArm(SimSettings(), SLAVE, "tool", start_q_rad=[0.0, 0.3, 0.5], gravity_compensation=False)
    for arm in (held, free):
        for _ in range(500):
            arm.read()
            arm.step(np.zeros(3))
    assert np.abs(held.read()[0] - [0.0, 0.3, 0.5]).max() < 1e-9
    assert np.abs(free.read()[0] - [0.0, 0.3, 0.5]).max() > 0.05
    assert np.abs(held.gravity_torque()).max() > 0.1  # the compensation was there, gravity only
    assert np.all(free.gravity_torque() == 0.0)


def test_torque_clipped_with_gravity_and_nan_is_zero() -> None:
    arm = MujocoArm(SimSettings(), SLAVE, "tool", start_q_rad=[0.0, 0.3, 0.5])
    arm.read()
    g = arm.gravity_torque()
    applied = arm.step([100.0, -100.0, float("nan")])
    np.testing.assert_allclose(applied[:2] + g[:2], [4.0, -4.0])  # ctrlrange of the model
    assert applied[2] == 0.0
    np.testing.assert_array_equal(arm.data.ctrl, applied)


def test_torque_limit_and_damping_overrides() -> None:
    arm = MujocoArm(SimSettings(), SLAVE, "tool", damping_nm_s_per_rad=[1.0, 2.0, 3.0], torque_limit_nm=[1.0, 1.0, 1.0])
    np.testing.assert_array_equal(arm.damping_nm_s_per_rad, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(arm.model.dof_damping, [1.0, 2.0, 3.0])
    arm.read()
    g = arm.gravity_torque()
    applied = arm.step([5.0, 5.0, 5.0])
    np.testing.assert_allclose(applied + g, 1.0)


def test_hand_force_moves_the_handle_along_it() -> None:
    arm = MujocoArm(SimSettings(), MASTER, "handle", start_q_rad=[0.0, 0.0, 0.0], hand_mass_kg=0.3)
    x0 = arm.point()[0]
    for _ in range(100):
        arm.read()
        arm.step(np.zeros(3), hand_force_n=[0.0, 1.0, 0.0])
    dx = arm.point()[0] - x0
    assert dx[1] > 1e-3 and abs(dx[0]) < 0.2 * dx[1]


def test_unknown_joint_lists_the_model_joints() -> None:
    with pytest.raises(PlantError, match="no joint 'wrist'; its joints: base_yaw, shoulder, elbow"):
        MujocoArm(SimSettings(), SLAVE, "tool", joints=["base_yaw", "wrist"])


def test_tool_starting_inside_the_wall_is_refused() -> None:
    with pytest.raises(PlantError, match="inside the wall"):
        MujocoArm(SimSettings(), SLAVE, "tool", start_q_rad=START, wall=WallSpec((0.15, 0, 0), (-1, 0, 0), 1e4, 10.0))


def test_wall_normal_must_be_unit() -> None:
    with pytest.raises(ValueError, match="unit"):
        WallSpec((0, 0, 0), (2.0, 0, 0), 1e4, 10.0)
    with pytest.raises(ValueError, match="nonzero"):
        WallSpec((0, 0, 0), (0.0, 0, 0), 1e4, 10.0)
