"""The joints the emulated servos drive: the project's MuJoCo arm, or one inertia per joint.

Both take joint torques (N m, held over a step) and advance by their own time step; both expose
`joints`, `time_s`, `state()` and `step(torque_nm)`.

- "mujoco": `plants.arm.MujocoArm` built from the model (default `dxl_arm.xml`) without gravity
  compensation (the host compensates gravity, as on the real arm), with the TRUE friction set on
  the model (viscous `dof_damping`, Coulomb `dof_frictionloss` with the stiff sticking constraint
  `plants._with_effects` uses), an optional wall, and an optional operator hand: a 3-D
  spring-damper at the `handle` site (or `tool`) toward the project's push profile
  (`core.operator.Operator.intended_along`).
- "inertia": per joint I qdd = tau - b qd - c sign(qd), integrated semi-implicitly: the viscous
  term implicitly, then Coulomb friction as an impulse bounded by c dt that sticks the joint when
  it can stop it (so a joint held by less than c stays at rest).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from haptic_teleop.core.operator import Operator, OperatorParams, hand1
from haptic_teleop.emulators.dynamixel.config import HandConfig, PhysicsConfig

TORQUE_CEILING_NM = 1000.0
"""The arm plant's own torque clip, set far above any servo: the servo's Current Limit binds."""


class InertiaPhysics:
    def __init__(self, cfg: PhysicsConfig) -> None:
        self.joints = tuple(j.name for j in cfg.joints)
        self.dt_s = cfg.dt_s
        self.time_s = 0.0
        self._inertia = [j.inertia_kg_m2 for j in cfg.joints]
        self._viscous = [j.viscous_nm_s_per_rad for j in cfg.joints]
        self._coulomb = [j.coulomb_nm for j in cfg.joints]
        self._q = [float(j.start_q_rad) for j in cfg.joints]
        self._qd = [0.0] * len(self.joints)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self._q), np.array(self._qd)

    def step(self, torque_nm: np.ndarray) -> None:
        # plain floats: a few joints, and numpy's per-call cost would dominate
        h = self.dt_s
        for i in range(len(self._q)):
            inertia = self._inertia[i]
            m = inertia + h * self._viscous[i]  # the viscous term implicitly
            v_free = (inertia * self._qd[i] + h * float(torque_nm[i])) / m
            limit = h * self._coulomb[i]
            # Coulomb friction: the impulse that would stop the joint this step, if within c h
            if abs(m * v_free) <= limit:
                v = 0.0
            else:
                v = v_free - math.copysign(limit / m, v_free)
            self._qd[i] = v
            self._q[i] += h * v
        self.time_s += h


class MujocoPhysics:
    def __init__(self, cfg: PhysicsConfig) -> None:
        from haptic_teleop.plants.arm import MujocoArm, WallSpec, inspect_model
        from haptic_teleop.plants.mujoco_plant import SimSettings

        info = inspect_model(cfg.model)
        site = "handle" if "handle" in info.sites else "tool"
        wall = None
        if cfg.wall is not None:
            w = cfg.wall
            wall = WallSpec(
                (w.point_m[0], w.point_m[1], w.point_m[2]),
                (w.normal[0], w.normal[1], w.normal[2]),
                w.stiffness_n_per_m,
                w.damping_n_s_per_m,
                w.contact_impedance,
            )
        n = len(info.motors)
        self.arm: Any = MujocoArm(
            SimSettings(period_s=cfg.dt_s, substeps=1),
            cfg.model,
            site,
            start_q_rad=cfg.start_q_rad,
            damping_nm_s_per_rad=cfg.damping_nm_s_per_rad,
            torque_limit_nm=[TORQUE_CEILING_NM] * n,
            gravity_compensation=False,
            wall=wall,
        )
        self.joints: tuple[str, ...] = tuple(self.arm.joints)
        self.site = site
        self.dt_s = cfg.dt_s
        self.time_s = 0.0
        model = self.arm.model
        dof = self.arm.constants().dof_adr
        if cfg.frictionloss_nm is not None:
            if len(cfg.frictionloss_nm) != len(self.joints):
                raise ValueError(
                    f"physics.frictionloss_nm has {len(cfg.frictionloss_nm)} values for joints {self.joints}"
                )
            model.dof_frictionloss[dof] = cfg.frictionloss_nm
        # MuJoCo's dry friction is a soft constraint; as plants._with_effects does, a time constant
        # of two steps and an impedance of 0.9999 make a joint held below its friction stay put.
        for d in dof:
            if model.dof_frictionloss[d] > 0.0:
                model.dof_solref[d] = (2.0 * model.opt.timestep, 1.0)
                model.dof_solimp[d] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
        self._hand: Operator | None = None
        self._hand_cfg: HandConfig | None = cfg.hand
        if cfg.hand is not None:
            h = cfg.hand
            self._hand = Operator(
                OperatorParams(
                    profile="push",
                    start_s=h.start_s,
                    speed_m_per_s=h.speed_m_per_s,
                    distance_m=h.distance_m,
                    stiffness_n_per_m=h.stiffness_n_per_m,
                    damping_n_s_per_m=h.damping_n_s_per_m,
                )
            )
            x0, _ = self.arm.point()
            self._origin = tuple(float(c) for c in (h.origin_m if h.origin_m is not None else x0))

    @property
    def damping_nm_s_per_rad(self) -> np.ndarray:
        return np.asarray(self.arm.damping_nm_s_per_rad)

    @property
    def frictionloss_nm(self) -> np.ndarray:
        return np.array(self.arm.model.dof_frictionloss[self.arm.constants().dof_adr])

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        q, qd = self.arm.read()
        return np.array(q, dtype=float), np.array(qd, dtype=float)

    def hand_force_n(self) -> np.ndarray | None:
        if self._hand is None or self._hand_cfg is None:
            return None
        x, v = self.arm.point()
        xd, vd = self._hand.intended_along(self.time_s, self._origin, self._hand_cfg.direction)
        k, b = self._hand_cfg.stiffness_n_per_m, self._hand_cfg.damping_n_s_per_m
        return np.array([hand1(k, b, xd[i], vd[i], float(x[i]), float(v[i])) for i in range(3)])

    def step(self, torque_nm: np.ndarray) -> None:
        f = self.hand_force_n()
        self.arm.step(torque_nm, None if f is None else f)
        self.time_s += self.dt_s


Physics = InertiaPhysics | MujocoPhysics


def build_physics(cfg: PhysicsConfig) -> Physics:
    return InertiaPhysics(cfg) if cfg.kind == "inertia" else MujocoPhysics(cfg)
