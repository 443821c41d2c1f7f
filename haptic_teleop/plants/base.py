"""The `Plant` protocol every backend implements, and the registry of backends by name (`BACKENDS`).

A backend is what moves a side: MuJoCo's plants, or a real arm through its vendor's SDK. Its
pieces (one-axis plant classes, its hardware section's config class, its arm driver, its
emulator) are named in its registry entry and imported only when asked for, so this module and
`haptic_teleop.plants` import without any SDK.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Protocol

from haptic_teleop.plants.hardware import HardwareConfig


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
    """A backend: what moves a side, and where its pieces live. Every piece is named by its module
    (and attribute), imported only when asked for, so the registry imports no SDK.

    - `one_axis`: (module, master class, slave class) of its one-axis plants, or None;
    - `config`: "module:Class" of its `<side>.hardware` section (a `plants.hardware.HardwareConfig`),
      or None for a simulated backend, which needs none;
    - `arm_driver`: "module:function" making the real arm's `ArmDriver` from that section, the
      arm's kinematics, its torque limits and the side's period;
    - `sdk`: the Python modules its drivers import (a run is refused when one is missing);
    - `emulator`: the module of its protocol-level emulator, run as its own process;
    - `identify`: whether `haptic-teleop identify` can excite it (its gravity is the host's to add).
    """

    help: str
    one_axis: tuple[str, str, str] | None = None
    config: str | None = None
    arm_driver: str | None = None
    sdk: tuple[str, ...] = ()
    emulator: str | None = None
    identify: bool = False

    @property
    def real(self) -> bool:
        """A real device (it has a hardware section), not a simulation."""
        return self.config is not None

    def config_class(self) -> type[HardwareConfig]:
        """Its hardware section's config class."""
        assert self.config is not None
        cls: type[HardwareConfig] = _attribute(self.config)
        return cls

    def make_arm_driver(self, hw: object, kin: object, torque_limit_nm: object, period_s: float) -> object:
        """Its `ArmDriver` (plants/hardware.py) for a side's hardware section `hw`."""
        assert self.arm_driver is not None
        return _attribute(self.arm_driver)(hw, kin, torque_limit_nm, period_s)


ROLES = ("master", "slave")

# name -> backend: the one list of them. Adding a backend: its folder under plants/ (its config
# class, its driver) and one line here.
BACKENDS: dict[str, Backend] = {
    "mujoco": Backend(
        "simulated (MuJoCo)",
        one_axis=("haptic_teleop.plants.mujoco_plant", "MujocoDevice", "MujocoWallRobot"),
        identify=True,
    ),
    "dynamixel": Backend(
        "Dynamixel servos on one Protocol 2.0 bus (dynamixel_sdk)",
        config="haptic_teleop.plants.dynamixel.config:DynamixelConfig",
        arm_driver="haptic_teleop.plants.dynamixel.config:arm_driver",
        sdk=("dynamixel_sdk",),
        emulator="haptic_teleop.emulators.dynamixel",
        identify=True,
    ),
    "ur": Backend(
        "a Universal Robots arm over RTDE (ur_rtde)",
        config="haptic_teleop.plants.ur.config:URConfig",
        arm_driver="haptic_teleop.plants.ur.config:arm_driver",
        sdk=("rtde_receive", "rtde_control"),
        emulator="haptic_teleop.emulators.ur",
    ),
}


def _attribute(where: str) -> Any:
    module, _, name = where.partition(":")
    return getattr(importlib.import_module(module), name)


def backend(name: str) -> Backend:
    """The backend `name`; an unknown name is a ValueError that lists the known ones."""
    if name not in BACKENDS:
        raise ValueError(f"unknown plant backend {name!r}; allowed: {', '.join(BACKENDS)}")
    return BACKENDS[name]


def backend_class(name: str, role: str) -> type:
    """The class that builds the `role` ("master" or "slave") one-axis plant of backend `name`."""
    b = backend(name)
    if role not in ROLES:
        raise ValueError(f"unknown plant role {role!r}; allowed: {', '.join(ROLES)}")
    if b.one_axis is None:
        raise ValueError(f"plant backend {name!r} has no one-axis plants; allowed: mujoco")
    module, master, slave = b.one_axis
    cls: type = getattr(importlib.import_module(module), master if role == "master" else slave)
    return cls


def hardware_classes() -> dict[str, type[HardwareConfig]]:
    """backend name -> its hardware section's config class, for every real backend."""
    return {name: b.config_class() for name, b in BACKENDS.items() if b.real}
