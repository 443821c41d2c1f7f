"""Things that move: one `Plant` protocol over simulators and hardware.

Backends are chosen by name from `BACKENDS`; their SDKs (mujoco, dynamixel_sdk, rtde) are imported
inside the backend module, so this package imports without them.
"""

from __future__ import annotations

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

    def close(self) -> None:
        """Release the device (torque off on hardware)."""
        ...
