"""Opening a Dynamixel bus's serial port through `dynamixel_sdk`: what the driver does at start
(`open_port`) and what `run` checks before it builds anything (`probe_port`), with one error each
saying what to do (docs/dynamixel_driver.md)."""

from __future__ import annotations

import errno
import os
from typing import Any

from haptic_teleop.plants.dynamixel.chain import SDK_BAUD_RATES_BPS
from haptic_teleop.plants.hardware import HardwareError, import_sdk


def open_port(sdk: Any, port: str, baud_bps: int) -> Any:
    """The SDK's PortHandler on `port`, open at `baud_bps`; a port that does not exist, may not be opened or is no
    serial port is a HardwareError saying what to do (`probe_port` runs it before a run builds
    anything)."""
    handler = sdk.PortHandler(port)
    try:
        handler.openPort()
        ok = handler.setBaudRate(baud_bps)
    except OSError as exc:
        code = exc.errno
        if code is None and exc.args and isinstance(exc.args[0], int):
            code = exc.args[0]
        if code == errno.ENOENT or not os.path.exists(port):
            raise HardwareError(
                f"{port} does not exist: is the USB adapter (U2D2) plugged in? `ls /dev/ttyUSB* "
                f"/dev/serial/by-id/` lists the serial ports; set the chain's port to one of them"
            ) from None
        if code in (errno.EACCES, errno.EPERM):
            raise HardwareError(
                f"{port}: permission denied: add yourself to the dialout group (`sudo usermod -aG dialout "
                f"$USER`, then log out and in) or install the udev rule of docs/dynamixel_driver.md"
            ) from None
        raise HardwareError(
            f"{port} cannot be opened ({exc}): is it the adapter's serial port? Close any other program using "
            f"it (Dynamixel Wizard, another haptic-teleop), or unplug and replug the adapter"
        ) from None
    if not ok:
        handler.closePort()
        raise HardwareError(f"{port}: the SDK refused {baud_bps} bps; allowed: {SDK_BAUD_RATES_BPS}")
    return handler


def probe_port(port: str, baud_bps: int) -> None:
    """Open and close `port` as the driver will (`open_port`): raises its HardwareError, or the
    SDK's MissingSDKError, at once, before a run builds its engine or writes an output."""
    open_port(import_sdk("dynamixel_sdk"), port, baud_bps).closePort()
