"""ArmKinematics (plants/kinematics.py) against the simulated arm (plants/arm.py::MujocoArm) on the
bundled models: the same point, Jacobian, orientation and gravity torque at random configurations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from haptic_teleop.errors import PlantError
from haptic_teleop.plants.arm import MujocoArm
from haptic_teleop.plants.kinematics import ArmKinematics
from haptic_teleop.plants.mujoco_plant import SimSettings

CASES = [("dxl_arm.xml", "tool"), ("ur5e.xml", "tool"), ("touch.xml", "handle")]


def _random_q(kin: ArmKinematics, rng: np.random.Generator) -> np.ndarray:
    rng_ = kin.joint_range_rad()
    lo = np.where(np.isfinite(rng_[:, 0]), rng_[:, 0], -math.pi)
    hi = np.where(np.isfinite(rng_[:, 1]), rng_[:, 1], math.pi)
    return rng.uniform(lo, hi)


@pytest.mark.parametrize(("model", "site"), CASES)
def test_matches_the_simulated_arm(model: str, site: str) -> None:
    """At 20 random configurations (and random velocities for the point velocity) the kinematic
    model gives MujocoArm's point, point velocity, Jacobians, orientation and gravity torque
    (MujocoArm's is MuJoCo's qfrc_gravcomp, a different computation from the bias force)."""
    kin = ArmKinematics(model, None, site)
    rng = np.random.default_rng(7)
    for _ in range(20):
        q = _random_q(kin, rng)
        qd = rng.normal(0.0, 1.0, kin.n)
        arm = MujocoArm(SimSettings(), model, site, start_q_rad=q, gravity_compensation=True)
        arm.data.qvel[arm.constants().dof_adr] = qd
        arm.read()
        kin.set_q(q)
        x, v = arm.point()
        np.testing.assert_allclose(kin.point(), x, atol=1e-12)
        np.testing.assert_allclose(kin.point_velocity(qd), v, atol=1e-12)
        np.testing.assert_allclose(kin.jacobian(), arm.jacobian(), atol=1e-12)
        np.testing.assert_allclose(kin.jacobian(rotational=True), arm.jacobian(rotational=True), atol=1e-12)
        np.testing.assert_allclose(kin.orientation(), arm.orientation(), atol=1e-12)
        g = arm.gravity_torque()
        assert np.abs(g).max() > 1e-3  # the arm has weight to hold at this configuration
        np.testing.assert_allclose(kin.gravity_torque(), g, rtol=1e-9, atol=1e-9 * np.abs(g).max())


def test_gravity_holds_the_arm() -> None:
    """The gravity torque applied as the motor torques of an arm simulated *without* gravity
    compensation holds it still (a check independent of MuJoCo's gravcomp)."""
    kin = ArmKinematics("dxl_arm.xml", ["base_yaw", "shoulder", "elbow"], "tool")
    q0 = np.array([0.3, 0.4, -0.8])
    arm = MujocoArm(SimSettings(), "dxl_arm.xml", "tool", start_q_rad=q0, gravity_compensation=False)
    arm.model.dof_frictionloss[:] = 0.0  # dry friction would hide a small gravity error
    for _ in range(500):
        q, _ = arm.read()
        kin.set_q(q)
        arm.step(kin.gravity_torque())
    q, _ = arm.read()
    np.testing.assert_allclose(q, q0, atol=1e-6)


def test_joint_order_is_the_drivers() -> None:
    """Joints given in another order: every per-joint result follows that order."""
    a = ArmKinematics("dxl_arm.xml", ["base_yaw", "shoulder", "elbow"], "tool")
    b = ArmKinematics("dxl_arm.xml", ["elbow", "base_yaw", "shoulder"], "tool")
    perm = [2, 0, 1]
    q = np.array([0.2, 0.5, -0.7])
    a.set_q(q)
    b.set_q(q[perm])
    np.testing.assert_allclose(b.point(), a.point(), atol=1e-12)
    np.testing.assert_allclose(b.jacobian(), a.jacobian()[:, perm], atol=1e-12)
    np.testing.assert_allclose(b.gravity_torque(), a.gravity_torque()[perm], atol=1e-12)
    np.testing.assert_allclose(b.joint_range_rad(), a.joint_range_rad()[perm])
    np.testing.assert_allclose(b.torque_limit_nm(), a.torque_limit_nm()[perm])
    np.testing.assert_allclose(b.mass_matrix(), a.mass_matrix()[np.ix_(perm, perm)], atol=1e-12)


def test_limits_from_the_model() -> None:
    """Ranges and torque limits are the MJCF's (dxl_arm.xml: the XM540/XM430 current limits)."""
    kin = ArmKinematics("dxl_arm.xml", None, "tool")
    np.testing.assert_allclose(kin.joint_range_rad(), [[-3.14159, 3.14159], [-1.5, 1.9], [-2.4, 2.4]])
    np.testing.assert_allclose(kin.torque_limit_nm(), [7.7765, 7.7765, 3.0689])
    np.testing.assert_allclose(kin.damping_nm_s_per_rad(), [0.1, 0.1, 0.04])
    np.testing.assert_allclose(kin.frictionloss_nm(), [0.15, 0.15, 0.06])


def test_inertial_torque_is_the_simulated_acceleration() -> None:
    """M qdd + C qd from the kinematic model equals the torque that gives the simulator's own
    acceleration (gravity, friction and damping off): MuJoCo's forward dynamics inverted."""
    import mujoco

    kin = ArmKinematics("dxl_arm.xml", None, "tool")
    m = kin.model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(3)
    m2 = mujoco.MjModel.from_xml_path(str(kin.path))
    m2.opt.gravity[:] = 0.0
    m2.dof_damping[:] = 0.0
    m2.dof_frictionloss[:] = 0.0
    m2.jnt_limited[:] = 0
    d = mujoco.MjData(m2)
    for _ in range(10):
        q = _random_q(kin, rng)
        qd = rng.normal(0.0, 2.0, kin.n)
        tau = rng.normal(0.0, 1.0, kin.n)
        d.qpos[:] = q
        d.qvel[:] = qd
        d.ctrl[:] = tau
        mujoco.mj_forward(m2, d)
        kin.set_q(q)
        np.testing.assert_allclose(kin.inertial_torque(qd, d.qacc), tau, atol=1e-9)


def test_bad_names() -> None:
    with pytest.raises(PlantError, match="no joint 'wrist'"):
        ArmKinematics("dxl_arm.xml", ["base_yaw", "wrist"], "tool")
    with pytest.raises(PlantError, match="no site 'tool'"):
        ArmKinematics("touch.xml", None, "tool")  # a master device: a handle, no tool
    with pytest.raises(PlantError, match="not found"):
        ArmKinematics("no_such_arm.xml", None, "tool")
    kin = ArmKinematics("dxl_arm.xml", None, "tool")
    with pytest.raises(PlantError, match="2 values for 3 joints"):
        kin.set_q([0.0, 0.0])
