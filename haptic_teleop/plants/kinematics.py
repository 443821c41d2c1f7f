"""An arm's kinematics and gravity from its MJCF model, for backends whose state comes from real
joints (docs/identify.md, docs/arms.md).

A hardware arm (Dynamixel servos, a Universal Robots arm) reports joint positions and takes joint
torques; the point the task-space coupling acts on, its Jacobian and the torque holding the arm
against gravity come from the same MJCF model the simulation uses. MuJoCo is used here only as a
kinematics and rigid-body library: nothing is simulated, no time passes, `set_q` writes the
measured configuration and the quantities below are of that configuration.

The gravity torque is MuJoCo's bias force at zero velocity: `mj_rne` (flg_acc = 0) with qvel = 0
after `mj_kinematics`, `mj_comPos` and `mj_comVel`. At rest the Coriolis and centrifugal terms
vanish, so qfrc_bias(q, 0) = g(q), the torque the motors must add to hold the arm still (the
same as MuJoCo's `qfrc_gravcomp` with every body's gravcomp = 1, which is how `MujocoArm`
computes it: test/hardware/test_kinematics.py compares the two).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from haptic_teleop.errors import PlantError
from haptic_teleop.plants.mujoco_plant import resolve_model


class ArmKinematics:
    """One arm's kinematics from its MJCF, joints in the driver's order.

    model: a bundled model's name or a path (`resolve_model`); joints: the joint names in the
    driver's order (None: the motors' order in the model); point_site: "handle" (master) or "tool"
    (slave). Call `set_q(q_rad)` with the measured positions, then read `point()`, `jacobian()`,
    `orientation()`, `gravity_torque()` ... of that configuration. Joints of the model the driver
    does not have stay at the model's reference position (qpos0).
    """

    def __init__(self, model: str, joints: Sequence[str] | None, point_site: str) -> None:
        import mujoco

        self._mj = mujoco
        path = resolve_model(model)
        try:
            spec = mujoco.MjSpec.from_file(str(path))
        except (ValueError, RuntimeError) as exc:
            raise PlantError(f"cannot load MuJoCo model {path}: {exc}") from None
        if not any(s.name == point_site for s in spec.sites):
            raise PlantError(f"model {path} has no site {point_site!r} (the point the coupling acts on)")
        model_joints = [j.name for j in spec.joints]
        motors = [a.name for a in spec.actuators]
        names = tuple(joints) if joints is not None else tuple(a.target for a in spec.actuators)
        for name in names:
            if name not in model_joints:
                raise PlantError(f"model {path} has no joint {name!r}; its joints: {', '.join(model_joints)}")
            if name not in motors:
                raise PlantError(f"model {path} has no motor named {name!r} (one motor per joint, named after it)")
        try:
            m = spec.compile()
        except (ValueError, RuntimeError) as exc:
            raise PlantError(f"cannot compile MuJoCo model {path}: {exc}") from None
        self.model = m
        self.data = mujoco.MjData(m)
        self.path = path
        self.joints = names
        self.n = len(names)
        self.point_site = point_site
        jid = [m.joint(name).id for name in names]
        for i, name in zip(jid, names, strict=True):
            if int(m.jnt_type[i]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
                raise PlantError(f"joint {name!r} of {path} is not a hinge or slide joint")
        self._jid = np.array(jid, dtype=int)
        self._qadr = np.array([m.jnt_qposadr[i] for i in jid], dtype=int)
        self._dadr = np.array([m.jnt_dofadr[i] for i in jid], dtype=int)
        self._act = np.array([m.actuator(name).id for name in names], dtype=int)
        for k, name in enumerate(names):
            if m.actuator_gear[self._act[k], 0] != 1.0:
                raise PlantError(f"motor {name!r} of {path} has gear != 1 (torques are set directly)")
        self._site = m.site(point_site).id
        self._jacp = np.zeros((3, m.nv))
        self._jacr = np.zeros((3, m.nv))
        self._bias = np.zeros(m.nv)
        self._q = np.zeros(self.n)
        self.set_q(m.qpos0[self._qadr])

    # ------------------------------------------------------------------------------ configuration

    def set_q(self, q_rad: Sequence[float] | np.ndarray) -> None:
        """Set the joint positions (rad; m for a slide joint), driver order; zero velocity."""
        q = np.asarray(q_rad, dtype=float)
        if q.shape != (self.n,):
            raise PlantError(f"set_q got {q.size} values for {self.n} joints ({', '.join(self.joints)})")
        mj, m, d = self._mj, self.model, self.data
        d.qpos[self._qadr] = q
        d.qvel[:] = 0.0
        mj.mj_kinematics(m, d)
        mj.mj_comPos(m, d)
        self._q = q.copy()
        self._jac6: np.ndarray | None = None
        self._grav: np.ndarray | None = None

    @property
    def q_rad(self) -> np.ndarray:
        """The configuration last set (a copy)."""
        return self._q.copy()

    # ------------------------------------------------------------------------------ kinematics

    def point(self) -> np.ndarray:
        """The point site's position (m), world frame."""
        return np.array(self.data.site_xpos[self._site])

    def jacobian(self, rotational: bool = False) -> np.ndarray:
        """d(point)/dq: 3 x n (translational), or 6 x n with the rotational rows under it."""
        if self._jac6 is None:
            self._mj.mj_jacSite(self.model, self.data, self._jacp, self._jacr, self._site)
            self._jac6 = np.vstack((self._jacp[:, self._dadr], self._jacr[:, self._dadr]))
        return self._jac6.copy() if rotational else self._jac6[:3].copy()

    def point_velocity(self, qd_rad_per_s: Sequence[float] | np.ndarray) -> np.ndarray:
        """The point's linear velocity (m/s, world frame) at joint velocities qd: J qd."""
        qd = np.asarray(qd_rad_per_s, dtype=float)
        if qd.shape != (self.n,):
            raise PlantError(f"point_velocity got {qd.size} values for {self.n} joints")
        out: np.ndarray = self.jacobian() @ qd
        return out

    def orientation(self) -> np.ndarray:
        """The point site's rotation matrix (3 x 3, world frame)."""
        return np.array(self.data.site_xmat[self._site]).reshape(3, 3)

    # ------------------------------------------------------------------------------ dynamics

    def gravity_torque(self) -> np.ndarray:
        """Torque per joint (N m) holding the arm still against gravity at q: qfrc_bias at zero
        velocity (`mj_rne`, flg_acc = 0), in driver order."""
        if self._grav is None:
            mj, m, d = self._mj, self.model, self.data
            d.qvel[:] = 0.0
            mj.mj_comVel(m, d)
            mj.mj_rne(m, d, 0, self._bias)
            self._grav = np.array(self._bias[self._dadr])
        return self._grav.copy()

    def mass_matrix(self) -> np.ndarray:
        """The joint-space inertia M(q) (n x n, kg m^2), rotor armature included, driver order."""
        mj, m, d = self._mj, self.model, self.data
        mj.mj_crb(m, d)
        full = np.zeros((m.nv, m.nv))
        mj.mj_fullM(m, d, full)
        return np.array(full[np.ix_(self._dadr, self._dadr)])

    def inertial_torque(
        self, qd_rad_per_s: Sequence[float] | np.ndarray, qdd_rad_per_s2: Sequence[float] | np.ndarray
    ) -> np.ndarray:
        """M(q) qdd + C(q, qd) qd (N m, driver order): the rigid-body torque beyond gravity that
        moves the arm with velocity qd and acceleration qdd at q (joints not driven at rest)."""
        mj, m, d = self._mj, self.model, self.data
        qd = np.asarray(qd_rad_per_s, dtype=float)
        qdd = np.asarray(qdd_rad_per_s2, dtype=float)
        if qd.shape != (self.n,) or qdd.shape != (self.n,):
            raise PlantError(f"inertial_torque needs {self.n} velocities and {self.n} accelerations")
        g = self.gravity_torque()
        d.qvel[:] = 0.0
        d.qvel[self._dadr] = qd
        mj.mj_comVel(m, d)
        mj.mj_rne(m, d, 0, self._bias)
        coriolis = np.array(self._bias[self._dadr]) - g
        d.qvel[:] = 0.0
        mj.mj_comVel(m, d)
        out: np.ndarray = self.mass_matrix() @ qdd + coriolis
        return out

    # ------------------------------------------------------------------------------ limits

    def joint_range_rad(self) -> np.ndarray:
        """Each joint's MJCF range (n x 2: low, high; rad or m), +-inf for an unlimited joint."""
        m = self.model
        out = np.empty((self.n, 2))
        for k, j in enumerate(self._jid):
            if m.jnt_limited[j]:
                out[k] = m.jnt_range[j]
            else:
                out[k] = (-math.inf, math.inf)
        return out

    def torque_limit_nm(self) -> np.ndarray:
        """Each motor's torque limit (N m): the largest |value| of its ctrlrange, +inf when the
        motor's control is unlimited."""
        m = self.model
        out = np.empty(self.n)
        for k, a in enumerate(self._act):
            if m.actuator_ctrllimited[a]:
                out[k] = float(np.max(np.abs(m.actuator_ctrlrange[a])))
            else:
                out[k] = math.inf
        return out

    def damping_nm_s_per_rad(self) -> np.ndarray:
        """The model's viscous joint damping (dof_damping, N m s/rad), driver order."""
        return np.array(self.model.dof_damping[self._dadr])

    def frictionloss_nm(self) -> np.ndarray:
        """The model's dry (Coulomb) joint friction (dof_frictionloss, N m), driver order."""
        return np.array(self.model.dof_frictionloss[self._dadr])
