"""The `Plant` protocol every backend implements, and the registry of backends by name.

A backend is a pair of classes, the operator's device (master) and the robot with its
environment (slave). Its SDK (mujoco, dynamixel_sdk, rtde) is imported only when a class of it is
asked for (`backend_class`), so this module and `haptic_teleop.plants` import without any SDK.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Protocol


class Plant(Protocol):
    """A device with `axes` linear axes, stepped one control period at a time.

    `read()` returns the state at the start of the tick; `step(force)` holds the actuator force
    for one period and returns the force actually applied (after the plant's own limits), which is
    what the energy accounting must use.
    """

    axes: int

    def read(self) -> tuple[list[float], list[float]]:
        """Position (m) and velocity (m/s) per axis."""
        ...

    def step(self, actuator_force_n: list[float], external_force_n: list[float] | None = None) -> list[float]:
        """Advance one period; returns the actuator force applied."""
        ...

    def contact_force(self) -> list[float]:
        """Environment force on the device over the last period, per axis (N); zero if none."""
        ...

    def joint_damping(self) -> list[float]:
        """The physical damping of each port's joint as the device really has it (SI: N s/m for a
        slide joint, N m s/rad for a hinge); in simulation the compiled model's `dof_damping`."""
        ...

    def close(self) -> None:
        """Release the device (torque off on hardware)."""
        ...


@dataclass(frozen=True)
class Backend:
    """Where a backend's classes live: `module` is imported only when a class is asked for."""

    module: str
    master: str  # class name of the operator's device
    slave: str  # class name of the robot and its environment


ROLES = ("master", "slave")

# name -> backend. Adding hardware: a module under haptic_teleop/plants/ with the two classes.
BACKENDS: dict[str, Backend] = {
    "mujoco": Backend("haptic_teleop.plants.mujoco_plant", master="MujocoDevice", slave="MujocoWallRobot"),
}


def backend_class(name: str, role: str) -> type:
    """The class that builds the `role` ("master" or "slave") plant of backend `name`."""
    if name not in BACKENDS:
        raise ValueError(f"unknown plant backend {name!r}; allowed: {', '.join(sorted(BACKENDS))}")
    if role not in ROLES:
        raise ValueError(f"unknown plant role {role!r}; allowed: {', '.join(ROLES)}")
    b = BACKENDS[name]
    cls: type = getattr(importlib.import_module(b.module), getattr(b, role))
    return cls
