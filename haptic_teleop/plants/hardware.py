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
from dataclasses import dataclass
from types import ModuleType
from typing import Protocol

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
    (s) at which the read completed."""

    q_rad: np.ndarray
    qd_rad_per_s: np.ndarray
    tau_nm: np.ndarray
    t_s: float


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
        them (after its quantisation and clip), which is what an energy ledger must book."""
        ...

    def stop(self) -> None: ...
