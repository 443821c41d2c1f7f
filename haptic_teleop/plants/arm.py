"""MuJoCo arms: a master device or a slave arm of any number of revolute joints (docs/arms.md).

A model follows the names the project's MJCF keep: one motor per joint, named after the joint,
whose `ctrlrange` is the joint's torque limit (N m); a site `handle` (master) or `tool` (slave) at
the point the task-space coupling acts on. The plant adds to the compiled model, through
`mujoco.MjSpec` before compiling:

- gravity compensation: every body's `gravcomp` = 1 and every joint's `actgravcomp`, so MuJoCo
  computes the gravity torques (gravity only, no Coriolis terms) in `qfrc_gravcomp` and routes
  them through the actuators (`qfrc_actuator`); the plant keeps `ctrl + qfrc_gravcomp` within
  each motor's torque limit, so gravity compensation spends the same limited torque a real
  motor has. `ctrl`, the torque beyond gravity compensation, is the port's torque the energy
  bound accounts for (gravity with its exact compensation is a conservative pair);
- a slave's wall: a plane through `point_m` with unit `normal` pointing into free space, a
  frictionless explicit contact pair with a small sphere at the tool point, contact parameters
  set for a static stiffness K (N/m) and damping B (N s/m) (`wall_solref`);
- a master's operator hand: the hand's mass as a point mass at the handle (it moves rigidly with
  the handle), and the hand force applied at the handle as joint torques J^T f (`qfrc_applied`),
  plus the force holding the hand's own weight (the operator carries it, not the device motors).

State is read with MuJoCo's split step: `read()` runs `mj_step1` (kinematics, Jacobians,
gravity torques and collisions of the current state), `step()` sets the torques and runs
`mj_step2` (actuation, constraint forces, integration). So the state, the Jacobian and the
gravity torques a tick reads belong to the same instant, with no `mj_forward` on top of the step
(the same two C functions a compiled loop would call). Further substeps of a period use `mj_step`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from haptic_teleop.core.taskspace import jacobian_times, jacobian_transpose
from haptic_teleop.errors import PlantError
from haptic_teleop.plants.mujoco_plant import SimSettings, resolve_model

TOOL_RADIUS_M = 0.002  # the contact sphere added at the tool point of a model without a "tool_tip"


@dataclass(frozen=True)
class WallSpec:
    """A plane wall: a point on its surface, its unit normal (into free space), K, B and MuJoCo's
    constant contact impedance d (as the one-axis wall, docs/plants.md)."""

    point_m: tuple[float, float, float]
    normal: tuple[float, float, float]
    stiffness_n_per_m: float
    damping_n_s_per_m: float
    contact_impedance: float = 0.1

    def __post_init__(self) -> None:
        n = math.sqrt(sum(c * c for c in self.normal))
        if not n > 0.0 or not math.isfinite(n):
            raise ValueError(f"wall normal must be a nonzero finite vector, got {self.normal}")
        if abs(n - 1.0) > 1e-9:
            raise ValueError(f"wall normal must be a unit vector, got {self.normal} (length {n})")


def wall_solref(stiffness: float, damping: float, impedance: float, inv_weight: float) -> tuple[float, float]:
    """solref (-s0, -s1) giving a contact row of approximate inverse inertia `inv_weight` (MuJoCo's
    efc_diagApprox, 1/kg) the static stiffness K and the damping B (docs/arms.md, "The wall").

    In MuJoCo's soft contact the regulariser is R = (1 - d)/d * diagApprox and the reference
    acceleration -b v - k d r with k = s0 / d^2, b = s1 / d. At rest R f = -k d r, so
    K = s0 / ((1 - d) diagApprox); the damping term B = s1 / ((1 - d) diagApprox) in the same way
    (exact for the one-axis plant, where diagApprox = 1/m: docs/plants.md)."""
    s = (1.0 - impedance) * inv_weight
    return -stiffness * s, -damping * s


def _quat_z_to(normal: Sequence[float]) -> list[float]:
    """Unit quaternion (w, x, y, z) turning the z axis onto `normal` (a unit vector)."""
    z = np.array([0.0, 0.0, 1.0])
    n = np.asarray(normal, dtype=float)
    c = float(z @ n)
    if c < -1.0 + 1e-12:
        return [0.0, 1.0, 0.0, 0.0]
    axis = np.cross(z, n)
    q = np.array([1.0 + c, *axis])
    return list(q / np.linalg.norm(q))


@dataclass(frozen=True)
class ArmConstants:
    """What a `MujocoArm` resolves in its model once and uses every tick (copies:
    `MujocoArm.constants`); the compiled arm loop (engine/compiled/arm_host.py) takes them from here.

    site_id: the handle/tool site; substeps: MuJoCo steps per period; gravity_compensation: whether
    the motors carry `qfrc_gravcomp`; wall_geoms: (wall, tool tip) geom ids of the contact pair, None
    without a wall; qpos_adr, dof_adr, actuator_ids: per joint, in the plant's joint order;
    hand_support_n: the force (world frame) holding the operator's hand up, added to the hand force.
    """

    site_id: int
    substeps: int
    gravity_compensation: bool
    wall_geoms: tuple[int, int] | None
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    actuator_ids: np.ndarray
    hand_support_n: np.ndarray


class MujocoArm:
    """One arm (master device or slave) in MuJoCo, joints in the order of `joints`.

    `point_site` is "handle" (master) or "tool" (slave). Per tick: `read()` -> (q, qd), then
    `point()`, `jacobian()`, `gravity_torque()` of the same state; `step(tau)` -> the torques applied
    (beyond gravity compensation); `contact_wrench()` the environment's force and torque on the tool
    over the last period, in the world (task) frame.
    """

    def __init__(
        self,
        sim: SimSettings,
        model: str,
        point_site: str,
        joints: Sequence[str] | None = None,
        start_q_rad: Sequence[float] | None = None,
        damping_nm_s_per_rad: Sequence[float] | None = None,
        torque_limit_nm: Sequence[float] | None = None,
        gravity_compensation: bool = True,
        wall: WallSpec | None = None,
        hand_mass_kg: float = 0.0,
    ) -> None:
        import mujoco

        self._mj = mujoco
        path = resolve_model(model)
        try:
            spec = mujoco.MjSpec.from_file(str(path))
        except (ValueError, RuntimeError) as exc:
            raise PlantError(f"cannot load MuJoCo model {path}: {exc}") from None
        site = _find(spec.sites, point_site)
        if site is None:
            raise PlantError(f"model {path} has no site {point_site!r} (the point the coupling acts on)")
        model_joints = [j.name for j in spec.joints]
        names = tuple(joints) if joints is not None else tuple(a.target for a in spec.actuators)
        for name in names:
            if name not in model_joints:
                raise PlantError(f"model {path} has no joint {name!r}; its joints: {', '.join(model_joints)}")
            if _find(spec.actuators, name) is None:
                raise PlantError(f"model {path} has no motor named {name!r} (one motor per joint, named after it)")
        if gravity_compensation:
            for b in spec.bodies:
                if b.name != "world":
                    b.gravcomp = 1.0
            for j in spec.joints:
                j.actgravcomp = 1
        if hand_mass_kg > 0.0:
            # The operator's hand moves with the handle; its weight is the operator's to carry
            # (added to the hand force in `step`), not the device motors'.
            site.parent.add_body(
                name="operator_hand", pos=list(site.pos), mass=hand_mass_kg, inertia=[1e-9, 1e-9, 1e-9], gravcomp=0.0
            )
        self.tool_radius_m = 0.0
        if wall is not None:
            # The tool's contact sphere: the model's own "tool_tip" (centred on the tool site), else one added.
            tip = _find(spec.geoms, "tool_tip")
            if tip is None:
                tip = site.parent.add_geom(
                    name="tool_tip",
                    type=mujoco.mjtGeom.mjGEOM_SPHERE,
                    size=[TOOL_RADIUS_M, 0.0, 0.0],
                    pos=list(site.pos),
                    mass=0.0,
                )
            elif tip.type != mujoco.mjtGeom.mjGEOM_SPHERE:
                raise PlantError(f"geom 'tool_tip' of {path} must be a sphere centred on the tool site")
            tip.contype, tip.conaffinity = 0, 0  # only the explicit pair below touches the wall
            self.tool_radius_m = float(tip.size[0])
            n = np.asarray(wall.normal, dtype=float)
            # The plane sits one sphere radius behind the wall surface: the tool *point* meets the
            # surface when the sphere meets the plane.
            pos = np.asarray(wall.point_m, dtype=float) - self.tool_radius_m * n
            spec.worldbody.add_geom(
                name="wall",
                type=mujoco.mjtGeom.mjGEOM_PLANE,
                size=[0.0, 0.0, 0.01],
                pos=list(pos),
                quat=_quat_z_to(n),
                contype=0,
                conaffinity=0,
            )
            d = wall.contact_impedance
            spec.add_pair(
                name="tool_wall", geomname1="wall", geomname2="tool_tip", condim=1, solimp=[d, d, 0.001, 0.5, 2.0]
            )
        try:
            m = spec.compile()
        except (ValueError, RuntimeError) as exc:
            raise PlantError(f"cannot compile MuJoCo model {path}: {exc}") from None
        m.opt.timestep = sim.period_s / sim.substeps
        m.opt.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{sim.integrator.upper()}")
        m.opt.iterations = sim.solver_iterations
        m.opt.tolerance = sim.solver_tolerance
        self.model = m
        self.data = mujoco.MjData(m)
        self.joints = names
        self.n = len(names)
        jid = [m.joint(name).id for name in names]
        for i, name in zip(jid, names, strict=True):
            if int(m.jnt_type[i]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
                raise PlantError(f"joint {name!r} of {path} is not a hinge or slide joint")
        self._qadr = np.array([m.jnt_qposadr[i] for i in jid])
        self._dadr = np.array([m.jnt_dofadr[i] for i in jid])
        self._act = np.array([m.actuator(name).id for name in names])
        lo = m.actuator_ctrlrange[self._act, 0].copy()
        hi = m.actuator_ctrlrange[self._act, 1].copy()
        for k, name in enumerate(names):
            if not m.actuator_ctrllimited[self._act[k]]:
                lo[k], hi[k] = -math.inf, math.inf
            if m.actuator_gear[self._act[k], 0] != 1.0:
                raise PlantError(f"motor {name!r} of {path} has gear != 1 (torques are set directly)")
        if torque_limit_nm is not None:
            if len(torque_limit_nm) != self.n:
                raise PlantError(f"torque_limit_nm has {len(torque_limit_nm)} values for {self.n} joints")
            lo = -np.asarray(torque_limit_nm, dtype=float)
            hi = np.asarray(torque_limit_nm, dtype=float)
        if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            raise PlantError(f"every motor of {path} needs a torque limit (ctrlrange, N m)")
        self.torque_lo, self.torque_hi = lo, hi
        # The plant clips (ctrl + gravity within the limit); MuJoCo's own clamp would not see gravity.
        m.actuator_ctrllimited[self._act] = 0
        if damping_nm_s_per_rad is not None:
            if len(damping_nm_s_per_rad) != self.n:
                raise PlantError(f"damping_nm_s_per_rad has {len(damping_nm_s_per_rad)} values for {self.n} joints")
            m.dof_damping[self._dadr] = damping_nm_s_per_rad
        self._hand_support = -hand_mass_kg * np.array(m.opt.gravity)  # the operator holds their hand up
        self._site = m.site(point_site).id
        self._body = int(m.site_bodyid[self._site])
        self._gravity = gravity_compensation
        self._substeps = sim.substeps
        self._jacp = np.zeros((3, m.nv))
        self._jacr = np.zeros((3, m.nv))
        self._applied = np.zeros(self.n)
        self._wrench = np.zeros(6)
        if start_q_rad is not None:
            if len(start_q_rad) != self.n:
                raise PlantError(f"start_q_rad has {len(start_q_rad)} values for {self.n} joints")
            self.data.qpos[self._qadr] = start_q_rad
        mujoco.mj_forward(m, self.data)
        self._pair_geoms: tuple[int, int] | None = None
        self.wall = wall
        if wall is not None:
            g_wall, g_tip = m.geom("wall").id, m.geom("tool_tip").id
            self._pair_geoms = (g_wall, g_tip)
            # diagApprox of a frictionless contact row: the two bodies' translational inverse
            # weights at the model's reference configuration (the world's is 0).
            self.contact_inv_weight_per_kg = float(m.body_invweight0[m.geom_bodyid[g_tip], 0])
            pair = m.pair("tool_wall").id
            m.pair_solref[pair] = wall_solref(
                wall.stiffness_n_per_m, wall.damping_n_s_per_m, wall.contact_impedance, self.contact_inv_weight_per_kg
            )
            if self.contact_penetration_m() > 0.0:
                raise PlantError(
                    f"the tool starts {self.contact_penetration_m() * 1e3:.3g} mm inside the wall; "
                    "allowed: a start configuration with the tool in free space"
                )
        self._jac3: np.ndarray | None = None
        self._jac6: np.ndarray | None = None
        self._fresh = False

    # ---------------------------------------------------------------------------------- state

    @property
    def damping_nm_s_per_rad(self) -> np.ndarray:
        """Each joint's physical damping, from the compiled model (what the simulator applies)."""
        return np.array(self.model.dof_damping[self._dadr])

    def joint_damping(self) -> list[float]:
        """The Plant protocol's name for `damping_nm_s_per_rad` (N m s/rad per joint)."""
        return [float(b) for b in self.damping_nm_s_per_rad]

    def constants(self) -> ArmConstants:
        """The model's indices and the plant's constants, as the tick uses them."""
        return ArmConstants(
            site_id=self._site,
            substeps=self._substeps,
            gravity_compensation=self._gravity,
            wall_geoms=self._pair_geoms,
            qpos_adr=self._qadr.copy(),
            dof_adr=self._dadr.copy(),
            actuator_ids=self._act.copy(),
            hand_support_n=self._hand_support.copy(),
        )

    def stepped_externally(self, wrench: np.ndarray) -> None:
        """Its MjData was stepped by other code (the compiled arm loop runs mj_step1 and mj_step2 on
        it): the next `read` runs mj_step1 again, and `wrench` (force, then torque about the tool
        point: 6 values) is the wall's wrench over the last period (`contact_wrench`)."""
        self._wrench = np.array(wrench, dtype=float)
        self._fresh = False

    def _step1(self) -> None:
        if not self._fresh:
            self._mj.mj_step1(self.model, self.data)
            self._fresh = True
            self._jac3 = self._jac6 = None  # this state's Jacobians: computed once, when first asked

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions (rad) and velocities (rad/s) at the start of the tick (copies)."""
        self._step1()
        d = self.data
        return d.qpos[self._qadr], d.qvel[self._dadr]

    def point(self) -> tuple[np.ndarray, np.ndarray]:
        """The handle/tool point's position (m) and velocity (m/s), world frame, this tick."""
        self._step1()
        jac = self.jacobian()
        v = np.zeros(3)
        jacobian_times(v, jac, self.data.qvel[self._dadr])  # summed in order: the compiled loop's bits
        return np.array(self.data.site_xpos[self._site]), v

    def jacobian(self, rotational: bool = False) -> np.ndarray:
        """d(point)/dq, 3 x n (6 x n with the rotational rows under it), this tick."""
        self._step1()
        if self._jac6 is None:
            self._mj.mj_jacSite(self.model, self.data, self._jacp, self._jacr, self._site)
            self._jac6 = np.vstack((self._jacp[:, self._dadr], self._jacr[:, self._dadr]))
            self._jac3 = np.ascontiguousarray(self._jac6[:3])
        # copies: a caller may scale its Jacobian in place
        return self._jac6.copy() if rotational else self._jac3.copy()  # type: ignore[union-attr]

    def orientation(self) -> np.ndarray:
        """The point site's rotation matrix (3 x 3, world frame), this tick."""
        self._step1()
        return np.array(self.data.site_xmat[self._site]).reshape(3, 3)

    def angular_velocity(self) -> np.ndarray:
        """The point site's angular velocity (rad/s, world frame), this tick."""
        return self.jacobian(rotational=True)[3:] @ self.data.qvel[self._dadr]

    def gravity_torque(self) -> np.ndarray:
        """Torque per joint the actuators add to hold the arm against gravity (gravity only), this tick."""
        self._step1()
        if not self._gravity:
            return np.zeros(self.n)
        return np.array(self.data.qfrc_gravcomp[self._dadr])

    def torque_room(self) -> tuple[np.ndarray, np.ndarray]:
        """The range of port torque (beyond gravity compensation) each motor has left, this tick."""
        g = self.gravity_torque()
        return self.torque_lo - g, self.torque_hi - g

    def contact_penetration_m(self) -> float:
        """How far the tool point is behind the wall surface (m; negative in free space)."""
        if self.wall is None:
            return -math.inf
        x = self.data.site_xpos[self._site]
        return float(np.dot(np.asarray(self.wall.point_m) - x, self.wall.normal))

    def wall_omega_rad_per_s(self) -> float:
        """The contact's natural frequency at the current configuration (0 without a wall).

        With A = n^T J M^-1 J^T n the tool's inverse inertia along the normal and w the row's
        diagApprox, the contact's spring acts on the acceleration as
        omega^2 = A K (1 - d) w / (A d + (1 - d) w) (docs/arms.md); omega h <= sqrt(2) keeps the
        simulated wall passive (docs/robustness.md)."""
        if self.wall is None:
            return 0.0
        mj, m, d = self._mj, self.model, self.data
        mj.mj_forward(m, d)
        jacp = np.zeros((3, m.nv))
        mj.mj_jacSite(m, d, jacp, None, self._site)
        jn = jacp.T @ np.asarray(self.wall.normal)
        x = np.zeros(m.nv)
        mj.mj_solveM(m, d, x.reshape(1, -1), jn.reshape(1, -1))
        a = float(jn @ x)
        w = self.contact_inv_weight_per_kg
        imp = self.wall.contact_impedance
        return math.sqrt(a * self.wall.stiffness_n_per_m * (1.0 - imp) * w / (a * imp + (1.0 - imp) * w))

    # ---------------------------------------------------------------------------------- step

    def step(self, torque_nm: Sequence[float] | np.ndarray, hand_force_n: Sequence[float] | None = None) -> np.ndarray:
        """Hold the port torques (beyond gravity compensation) for one period; returns them as applied.

        Each joint's total (torque + gravity compensation) is clipped at its motor's limit and a
        NaN torque becomes 0. `hand_force_n`: a 3-D force (world frame) at the point site, applied
        as J^T f (the master's operator hand)."""
        self._step1()
        mj, m, d = self._mj, self.model, self.data
        lo, hi = self.torque_room()
        tau = np.asarray(torque_nm, dtype=float)
        tau = np.minimum(np.maximum(np.where(np.isnan(tau), 0.0, tau), lo), hi)  # NaN -> 0, then the clip
        d.ctrl[self._act] = tau
        if hand_force_n is not None:
            f = np.asarray(hand_force_n, dtype=float) + self._hand_support
            tau_hand = np.zeros(self.n)
            jacobian_transpose(tau_hand, self.jacobian(), f)  # J^T f summed in order (the compiled loop's bits)
            d.qfrc_applied[self._dadr] = tau_hand
        mj.mj_step2(m, d)
        self._fresh = False
        wrench = self._contact()
        for _ in range(self._substeps - 1):
            mj.mj_step(m, d)
            wrench += self._contact()
        self._wrench = wrench / self._substeps
        self._applied = tau
        return tau

    def _contact(self) -> np.ndarray:
        """Force and torque (about the tool point) of the wall on the tool in the step just made."""
        out = np.zeros(6)
        pg = self._pair_geoms
        if pg is None:
            return out
        d = self.data
        f6 = np.zeros(6)
        x = d.site_xpos[self._site]
        for i in range(d.ncon):
            c = d.contact[i]
            if (c.geom1, c.geom2) != pg or c.efc_address < 0:
                continue
            self._mj.mj_contactForce(self.model, d, i, f6)
            frame = c.frame.reshape(3, 3)
            f = np.zeros(3)  # frame.T @ f6[:3], summed in order (the compiled loop's bits)
            # on geom2 (the tool), from geom1 (the wall): the normal points wall -> tool
            jacobian_transpose(f, frame, f6)
            out[:3] += f
            out[3:] += np.cross(c.pos - x, f)
        return out

    def contact_wrench(self) -> tuple[np.ndarray, np.ndarray]:
        """The wall's force (N) and torque about the tool point (N m) on the tool, world frame,
        averaged over the last period's MuJoCo steps (zero without a wall)."""
        return self._wrench[:3].copy(), self._wrench[3:].copy()

    def close(self) -> None:
        self.data.ctrl[:] = 0.0
        self.data.qfrc_applied[:] = 0.0


@dataclass(frozen=True)
class ModelInfo:
    """What a scene checks of an MJCF before anything is built: its joints, motors and sites."""

    joints: tuple[str, ...]
    motors: tuple[str, ...]
    sites: tuple[str, ...]


def inspect_model(model: str) -> ModelInfo:
    """The names in a model file (a path or a bundled model's name); PlantError if it cannot be read."""
    import mujoco

    path = resolve_model(model)
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except (ValueError, RuntimeError) as exc:
        raise PlantError(f"cannot load MuJoCo model {path}: {exc}") from None
    return ModelInfo(
        tuple(j.name for j in spec.joints), tuple(a.name for a in spec.actuators), tuple(s.name for s in spec.sites)
    )


def _find(items, name: str):  # type: ignore[no-untyped-def]
    for it in items:
        if it.name == name:
            return it
    return None
