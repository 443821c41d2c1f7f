"""A `JointDriver` on a simulated arm (docs/identify.md): the MuJoCo arm of plants/arm.py without
its own gravity compensation, so the host compensates gravity from the model as it must on
hardware, and one MuJoCo period per `write` (lockstep: simulated time, as fast as it runs).

The simulator's friction is the truth an identification recovers: viscous `dof_damping`
(N m s/rad) and dry `dof_frictionloss` (N m), the model's own unless given. MuJoCo's dry friction
is a soft constraint; as the one-axis plants' friction effect (plants/__init__.py), a time
constant of two steps and an impedance of 0.9999 make it stick and slide like Coulomb friction.
Bodies the MJCF marks `gravcomp` (the Touch's, whose motors balance them) are made to weigh again:
on hardware the host's gravity torque holds the whole arm.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from haptic_teleop.errors import PlantError
from haptic_teleop.plants.arm import MujocoArm
from haptic_teleop.plants.hardware import JointSample
from haptic_teleop.plants.mujoco_plant import SimSettings


class MujocoJointDriver:
    """A simulated chain of torque-controlled joints (the `JointDriver` protocol), lockstep.

    model: a bundled model's name or a path; joints: driver order (None: the model's motors);
    point_site: "handle" or "tool" (the arm plant needs one); damping_nm_s_per_rad and
    frictionloss_nm: per joint, the simulator's true friction (None: the model's);
    torque_limit_nm: per joint (None: the model's ctrlrange); velocity_noise_rad_per_s: white noise
    (standard deviation) on the reported velocity, drawn from `rng`; velocity_resolution_rad_per_s
    and position_resolution_rad: the reported values' quantization (0: none). `t_s` of a sample is
    simulated time.
    """

    lockstep = True  # simulated time: the loop need not pace itself

    def __init__(
        self,
        model: str,
        point_site: str,
        joints: Sequence[str] | None = None,
        start_q_rad: Sequence[float] | None = None,
        damping_nm_s_per_rad: Sequence[float] | None = None,
        frictionloss_nm: Sequence[float] | None = None,
        torque_limit_nm: Sequence[float] | None = None,
        sim: SimSettings | None = None,
        velocity_noise_rad_per_s: float = 0.0,
        velocity_resolution_rad_per_s: float = 0.0,
        position_resolution_rad: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.sim = sim if sim is not None else SimSettings()
        self.model_name = model
        self.point_site = point_site
        self.arm = MujocoArm(
            self.sim,
            model,
            point_site,
            joints=joints,
            start_q_rad=start_q_rad,
            damping_nm_s_per_rad=damping_nm_s_per_rad,
            torque_limit_nm=torque_limit_nm,
            gravity_compensation=False,
        )
        m = self.arm.model
        m.body_gravcomp[:] = 0.0
        dadr = self.arm.constants().dof_adr
        if frictionloss_nm is not None:
            if len(frictionloss_nm) != self.arm.n:
                raise PlantError(f"frictionloss_nm has {len(frictionloss_nm)} values for {self.arm.n} joints")
            m.dof_frictionloss[dadr] = frictionloss_nm
        m.dof_solref[:] = (2.0 * m.opt.timestep, 1.0)
        m.dof_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
        self._dadr = dadr
        self.joints: tuple[str, ...] = tuple(self.arm.joints)
        self.torque_limit_nm = np.minimum(-self.arm.torque_lo, self.arm.torque_hi)
        for name, v in (
            ("velocity_noise_rad_per_s", velocity_noise_rad_per_s),
            ("velocity_resolution_rad_per_s", velocity_resolution_rad_per_s),
            ("position_resolution_rad", position_resolution_rad),
        ):
            if not (v >= 0.0 and np.isfinite(v)):
                raise PlantError(f"{name} must be finite and >= 0, got {v}")
        self.velocity_noise_rad_per_s = velocity_noise_rad_per_s
        self.velocity_resolution_rad_per_s = velocity_resolution_rad_per_s
        self.position_resolution_rad = position_resolution_rad
        self._rng = rng if rng is not None else np.random.default_rng(0)
        self._tau = np.zeros(self.arm.n)
        self._ticks = 0
        self._started = False
        self.stopped = False

    @property
    def true_damping_nm_s_per_rad(self) -> np.ndarray:
        """The simulator's viscous friction per joint (driver order)."""
        return np.array(self.arm.model.dof_damping[self._dadr])

    @property
    def true_coulomb_nm(self) -> np.ndarray:
        """The simulator's dry friction per joint (driver order)."""
        return np.array(self.arm.model.dof_frictionloss[self._dadr])

    def _sample(self) -> JointSample:
        """The state as a device reports it: the velocity with white noise, then both quantized
        to the sensor's resolution (as a servo's encoder and velocity registers)."""
        q, qd = self.arm.read()
        q, qd = np.array(q), np.array(qd)
        if self.velocity_noise_rad_per_s > 0.0:
            qd = qd + self._rng.normal(0.0, self.velocity_noise_rad_per_s, qd.size)
        if self.velocity_resolution_rad_per_s > 0.0:
            qd = np.round(qd / self.velocity_resolution_rad_per_s) * self.velocity_resolution_rad_per_s
        if self.position_resolution_rad > 0.0:
            q = np.round(q / self.position_resolution_rad) * self.position_resolution_rad
        return JointSample(q, qd, self._tau.copy(), self._ticks * self.sim.period_s)

    def start(self) -> JointSample:
        if self.stopped:
            raise PlantError("the simulated joint driver was stopped; allowed: a new driver")
        self._started = True
        self._tau[:] = 0.0
        return self._sample()

    def read(self) -> JointSample:
        if not self._started or self.stopped:
            raise PlantError("read() before start() or after stop()")
        return self._sample()

    def write(self, tau_nm: np.ndarray) -> np.ndarray:
        if not self._started or self.stopped:
            raise PlantError("write() before start() or after stop()")
        applied = self.arm.step(np.asarray(tau_nm, dtype=float))
        self._tau = np.array(applied)
        self._ticks += 1
        return self._tau.copy()

    def stop(self) -> None:
        self._tau[:] = 0.0
        self.arm.close()
        self.stopped = True
