"""MuJoCo backends: the master haptic device and the slave robot touching a wall.

`mujoco` is imported here, not at package import. Model files live in the package's `models/`
folder (found by haptic_teleop.resources; robot and scene in separate files, the scene includes
the robot by a relative path). Scene values (mass, damping, wall position, stiffness, damping)
are written into the compiled model, so one MJCF serves every scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from haptic_teleop.errors import PlantError

INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")


def models_dir() -> Path:
    """The bundled models' folder, wherever the package is installed (haptic_teleop.resources)."""
    from haptic_teleop.resources import models_dir as bundled

    return bundled()


def resolve_model(name: str) -> Path:
    p = Path(name)
    if p.is_absolute() or p.is_file():
        return p
    cand = models_dir() / p.name
    if cand.exists():
        return cand
    raise PlantError(f"model file {name!r} not found (looked in {models_dir()})")


def actuator_limited1(force: float, limit: float) -> float:
    """The force a plant's actuator applies for a command: clamped to +-limit, NaN gives 0.

    Also compiled by the engine's compiled loop (haptic_teleop/engine/compiled/axis_host.py)."""
    if not -limit <= force <= limit:
        return 0.0 if math.isnan(force) else math.copysign(limit, force)
    return force


@dataclass(frozen=True)
class SimSettings:
    """Numerical settings shared by both MuJoCo plants."""

    period_s: float = 0.001
    substeps: int = 1
    integrator: str = "implicitfast"
    solver_iterations: int = 100
    solver_tolerance: float = 1e-8


def _load(path: Path, sim: SimSettings):  # type: ignore[no-untyped-def]
    import mujoco

    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        raise PlantError(f"cannot load MuJoCo model {path}: {exc}") from None
    model.opt.timestep = sim.period_s / sim.substeps
    model.opt.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{sim.integrator.upper()}")
    model.opt.iterations = sim.solver_iterations
    model.opt.tolerance = sim.solver_tolerance
    _skip_unused_stages(model)
    return model, mujoco.MjData(model)


def _skip_unused_stages(model) -> None:  # type: ignore[no-untyped-def]
    """Turn off MuJoCo stages that cannot change anything in this model (docs/performance_python_loop.md).

    - collision detection, when no geom can collide (no contact pair, every contype and
      conaffinity 0): it finds nothing, at about 1000 instructions a step. Constraints (joint
      friction, limits) still work: only contacts are skipped.
    - constraint islands, with a single degree of freedom: there is only ever one island.
    Both keep every result bit for bit (test_skipped_stages_change_nothing).
    """
    import mujoco

    flags = mujoco.mjtDisableBit
    if model.npair == 0 and not (model.geom_contype.any() or model.geom_conaffinity.any()):
        model.opt.disableflags |= int(flags.mjDSBL_CONTACT)
    if model.nv == 1:
        model.opt.disableflags |= int(flags.mjDSBL_ISLAND)


def _bind_state(plant) -> None:  # type: ignore[no-untyped-def]
    """Per-tick handles on the plant's MjData: memoryviews on its arrays and the step function.

    A memoryview reads a Python float and writes one straight into MuJoCo's memory, several
    times cheaper than numpy's scalar indexing; `model` and `data` stay public and are the same
    objects (options set on `plant.model` after construction take effect).
    """
    plant._qpos = memoryview(plant.data.qpos)
    plant._qvel = memoryview(plant.data.qvel)
    plant._ctrl = memoryview(plant.data.ctrl)
    plant._mj_step = plant._mj.mj_step


class MujocoDevice:
    """Master haptic device: one slide joint, hand motor and device motor on it.

    The operator's arm mass moves with the handle, so it is added to the handle's mass.
    """

    axes = 1

    def __init__(
        self,
        sim: SimSettings,
        mass_kg: float,
        damping_n_s_per_m: float,
        force_limit_n: float,
        hand_mass_kg: float = 0.0,
        model: str = "master_device.xml",
        start_position_m: float = 0.0,
    ) -> None:
        import mujoco

        self._mj = mujoco
        self.model, self.data = _load(resolve_model(model), sim)
        m = self.model
        body = m.body("handle").id
        m.body_mass[body] = mass_kg + hand_mass_kg
        m.dof_damping[m.joint("master_x").dofadr[0]] = damping_n_s_per_m
        self._limit = force_limit_n
        self._substeps = sim.substeps
        self.data.qpos[0] = start_position_m
        mujoco.mj_forward(m, self.data)
        _bind_state(self)

    @property
    def force_limit_n(self) -> float:
        """The actuator's force limit (`actuator_limited1`'s `limit`), N."""
        return self._limit

    @property
    def substeps(self) -> int:
        """MuJoCo steps per period."""
        return self._substeps

    def read(self) -> tuple[list[float], list[float]]:
        return [self._qpos[0]], [self._qvel[0]]

    def step(self, actuator_force_n: list[float], external_force_n: list[float] | None = None) -> list[float]:
        f = actuator_limited1(actuator_force_n[0], self._limit)
        ctrl = self._ctrl
        ctrl[0] = external_force_n[0] if external_force_n is not None else 0.0
        ctrl[1] = f
        if self._substeps == 1:
            self._mj_step(self.model, self.data)
        else:
            for _ in range(self._substeps):
                self._mj_step(self.model, self.data)
        return [f]

    def contact_force(self) -> list[float]:
        return [0.0]

    def set_state(self, position_m: float, velocity_m_per_s: float) -> None:
        """Put the handle at a position and velocity (an imposed trajectory, core/operator.py):
        what `read` returns until the next `step`."""
        self._qpos[0] = position_m
        self._qvel[0] = velocity_m_per_s

    def inertia_kg(self) -> float:
        """The mass the joint moves (handle and hand, plus the joint's armature), kg."""
        m = self.model
        return float(m.body_mass[m.body("handle").id] + m.dof_armature[m.joint("master_x").dofadr[0]])

    def joint_damping(self) -> list[float]:
        """The simulator's damping of the joint (MjModel dof_damping, N s/m), read now: it is the
        scene's damping plus any viscous friction effect, or whatever was written into the model."""
        return [float(self.model.dof_damping[self.model.joint("master_x").dofadr[0]])]

    def close(self) -> None:
        self.data.ctrl[:] = 0.0


class MujocoWallRobot:
    """Slave robot end effector and a wall at `wall_position_m` (tip coordinate at first contact).

    Wall stiffness K (N/m) and damping B (N s/m) are realised exactly by MuJoCo's soft contact with
    constant impedance d: solref = (-k d^2, -b d) with k = K (1-d) / (d^2 m), b = B (1-d) / (d m),
    m the end effector's mass (derivation and check in docs/plants.md). The force is MuJoCo's
    constraint force on the joint, not recomputed by hand.
    """

    axes = 1

    def __init__(
        self,
        sim: SimSettings,
        mass_kg: float,
        damping_n_s_per_m: float,
        force_limit_n: float,
        wall_position_m: float,
        wall_stiffness_n_per_m: float,
        wall_damping_n_s_per_m: float,
        contact_impedance: float = 0.1,
        model: str = "wall_scene.xml",
        start_position_m: float = 0.0,
    ) -> None:
        import mujoco

        self._mj = mujoco
        self.model, self.data = _load(resolve_model(model), sim)
        m = self.model
        m.body_mass[m.body("end_effector").id] = mass_kg
        m.dof_damping[m.joint("slave_x").dofadr[0]] = damping_n_s_per_m
        tip = m.geom("tip").id
        wall = m.geom("wall").id
        m.geom_pos[wall][0] = wall_position_m + m.geom_size[tip][0] + m.geom_size[wall][0]
        d = contact_impedance
        k = wall_stiffness_n_per_m * (1.0 - d) / (d * d * mass_kg)
        b = wall_damping_n_s_per_m * (1.0 - d) / (d * mass_kg)
        pair = m.pair("tip_wall").id
        m.pair_solref[pair] = [-k * d * d, -b * d]
        m.pair_solimp[pair] = [d, d, 0.001, 0.5, 2.0]
        self._limit = force_limit_n
        self._substeps = sim.substeps
        self.data.qpos[0] = start_position_m
        mujoco.mj_forward(m, self.data)
        _bind_state(self)
        self._qfrc = memoryview(self.data.qfrc_constraint)
        self._contact = 0.0

    @property
    def force_limit_n(self) -> float:
        """The actuator's force limit (`actuator_limited1`'s `limit`), N."""
        return self._limit

    @property
    def substeps(self) -> int:
        """MuJoCo steps per period."""
        return self._substeps

    def read(self) -> tuple[list[float], list[float]]:
        return [self._qpos[0]], [self._qvel[0]]

    def step(self, actuator_force_n: list[float], external_force_n: list[float] | None = None) -> list[float]:
        f = actuator_limited1(actuator_force_n[0], self._limit)
        self._ctrl[0] = f
        n = self._substeps
        if n == 1:
            self._mj_step(self.model, self.data)
            self._contact = 0.0 + self._qfrc[0]  # 0.0 + : the same value (and zero sign) as the mean below
            return [f]
        acc = 0.0
        for _ in range(n):
            self._mj_step(self.model, self.data)
            acc += self._qfrc[0]
        self._contact = acc / n
        return [f]

    def contact_force(self) -> list[float]:
        return [self._contact]

    def set_contact_force(self, force_n: float) -> None:
        """The wall force of the last period, as measured by a loop that stepped this plant's
        MjData itself (the compiled loop): what `contact_force` returns until the next `step`."""
        self._contact = force_n

    def joint_damping(self) -> list[float]:
        """The simulator's damping of the joint (MjModel dof_damping, N s/m), read now: it is the
        scene's damping plus any viscous friction effect, or whatever was written into the model."""
        return [float(self.model.dof_damping[self.model.joint("slave_x").dofadr[0]])]

    def close(self) -> None:
        self.data.ctrl[:] = 0.0
