"""The joint-level seam between real actuators and the arm plants (docs/hardware.md).

A `JointDriver` is one chain of actuators spoken to through its vendor SDK (Dynamixel servos on one
bus through `dynamixel_sdk`; a Universal Robots arm through `ur_rtde` in direct torque mode). It
knows nothing of kinematics, energy bounds or scenes: it turns joint torques into the device's
command units and the device's state into SI joint values, once per tick, and it owns the
device's own safety (watchdogs, error registers, torque off). The arm plants built on it take
their kinematics from the same MJCF model the simulation uses.

Every SDK is imported inside the driver's module, so this file imports without any of them.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from types import ModuleType
from typing import ClassVar, Protocol

import numpy as np

from haptic_teleop.errors import PlantError


class HardwareError(PlantError):
    """A device failed, replied outside its protocol, or refused to start; the message names the
    device (port or host, servo id or joint), what happened and what to do. Raised only after the
    driver has tried to turn its torque off."""


class MissingSDKError(HardwareError):
    """A hardware backend's SDK is not installed: something the user fixes with pip (exit 2)."""

    exit_code = 2


# module -> the PyPI requirement that provides it (setup.py's `hardware` extra has the same bounds)
SDKS = {
    "dynamixel_sdk": "dynamixel-sdk>=3.8.4",
    "rtde_receive": "ur-rtde>=1.6.5",
    "rtde_control": "ur-rtde>=1.6.5",
}


def import_sdk(module: str) -> ModuleType:
    """Import a backend's SDK module, or say in one line which package to install."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingSDKError(
            f"the hardware backend needs the Python module {module!r}, which is not installed: "
            f"pip install '{SDKS[module]}' (or install haptic_teleop with its 'hardware' extra)"
        ) from None


@dataclass(frozen=True)
class JointSample:
    """One read of the chain: joint positions (rad), velocities (rad/s) and the torque the motors
    report (N m, from their current), in the driver's joint order, and the host's monotonic time
    (s) at which the read completed.

    `measured`: `tau_nm` is what the device reports its motors apply (a Dynamixel's Present
    Current, a UR's `actual_current_as_torque`). False where the device gives no such report (a UR
    commanded in task space, a UR read before its first report arrived): `tau_nm` is then the
    torque last commanded, kept so the sample is complete, and the flag says so (docs/hardware_plant.md,
    "Applied, not commanded")."""

    q_rad: np.ndarray
    qd_rad_per_s: np.ndarray
    tau_nm: np.ndarray
    t_s: float
    measured: bool = True


class JointDriver(Protocol):
    """A chain of torque-controlled joints.

    Order of calls: `start()` once (connect, check, configure; torque enabled with a zero command;
    the first sample), then per tick `read()` and `write(tau)`, and `stop()` on every exit path
    (idempotent, never raises, safe to call from a signal handler's aftermath or `atexit`).
    """

    joints: tuple[str, ...]
    torque_limit_nm: np.ndarray  # per joint: the largest torque the device will apply (N m)

    def start(self) -> JointSample: ...

    def read(self) -> JointSample: ...

    def write(self, tau_nm: np.ndarray) -> np.ndarray:
        """Command these joint torques until the next write; returns them as the device will apply
        them if it obeys (after its quantisation and clip): the command. What the motors did apply
        over the hold is the next read's `tau_nm` (when `measured`), which the ledger books."""
        ...

    def stop(self) -> None: ...


# --------------------------------------------------------------------------------------------
# A side's `hardware` section: what every real backend's config class has in common. Each backend
# keeps its own class beside its driver (plants/dynamixel/config.py, plants/ur/config.py), named
# in the registry (plants/base.py); `<side>.backend` picks which one reads the section.

DEVICE_CLOCKS = ("real", "lockstep")


@dataclass(frozen=True)
class Problem:
    """What a side's hardware section gets wrong for its scene: the key (from the side: `hardware.port`,
    `joints`), the value and what is allowed; the scene loader names the file and side."""

    key: str
    value: object
    allowed: str


@dataclass(frozen=True)
class HardwareConfig:
    """The start-up checks and the clock every real side has (docs/hardware.md); a backend's
    config class adds its device's keys, and names those a real side cannot do without."""

    required: ClassVar[tuple[str, ...]] = ()

    device_clock: str = field(
        default="real",
        metadata={
            "choices": DEVICE_CLOCKS,
            "help": "real: a tick's motion took the wall time between reads (the ledger is stretched for late "
            "ticks); lockstep: the device advances one period per command (the bus emulator, --emulate)",
        },
    )
    max_hold_s: float | None = field(
        default=None,
        metadata={
            "gt": 0.0,
            "max": 1.0,
            "help": "the longest hold of a torque the energy bound budgets on a real clock (default: 3 "
            "periods; a lockstep device: one); a longer hold stops the side (docs/eba.md)",
        },
    )
    start_tolerance_rad: float = field(
        default=0.05, metadata={"gt": 0.0, "max": 3.2, "help": "start pose check: farther from start_q_rad is refused"}
    )
    ramp_in_s: float = field(
        default=0.5, metadata={"min": 0.0, "max": 60.0, "help": "torque ramps from zero over this time at start"}
    )

    def problem(self, role: str, joints: tuple[str, ...], emulate: bool) -> Problem | None:
        """What this section gets wrong for a side `role` ("master" or "slave") on this backend with
        these joints, or None. `emulate`: the device's address is filled in later (`--emulate`)."""
        return None

    def absent(self) -> Problem | None:
        """The device is not there at all (a serial port that does not exist), or None: checked
        before a run writes anything, so a wrong address costs neither time nor an output folder."""
        return None


@dataclass(frozen=True)
class ArmDriver:
    """A real side's driver as the arm plant takes it: the `JointDriver`, whether the device's own
    controller compensates gravity (then the plant adds none), where the contact wrench comes from
    (None: the contact estimate from the joint torques), and where the device is (for messages)."""

    driver: JointDriver
    gravity_by_device: bool
    wrench: Callable[[], np.ndarray] | None
    where: str
