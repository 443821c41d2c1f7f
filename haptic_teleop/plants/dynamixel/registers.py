"""One byte of each servo's control table read through the SDK on a port no driver holds: how a
check after a run (and the tests) see what the servos really hold (Torque Enable(64), Bus
Watchdog(98)). The SDK is imported when called."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from haptic_teleop.plants.hardware import HardwareError, import_sdk


def read_byte_each(port_name: str, ids: Sequence[int], address: int, baud_bps: int, tries: int = 50) -> list[int]:
    """One byte of each servo's control table (e.g. Torque Enable(64), Bus Watchdog(98)), read
    through the SDK on a port no driver holds, a dropped reply retried up to `tries` times: how a
    check after a run (and the tests) see what the servos really hold."""
    sdk: Any = import_sdk("dynamixel_sdk")
    port = sdk.PortHandler(port_name)
    if not (port.openPort() and port.setBaudRate(baud_bps)):
        raise HardwareError(f"{port_name}: cannot open the port at {baud_bps} bps")
    packet = sdk.PacketHandler(2.0)
    values: list[int] = []
    try:
        for servo in ids:
            for _ in range(tries):
                value, result, _ = packet.read1ByteTxRx(port, servo, address)
                if result == sdk.COMM_SUCCESS:
                    values.append(int(value))
                    break
            else:
                raise HardwareError(
                    f"servo {servo} on {port_name} did not answer a READ of address {address} in {tries} tries"
                )
    finally:
        port.closePort()
    return values
