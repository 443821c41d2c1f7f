"""RTDE wire format, protocol version 2 (docs/ur_protocols.md, "RTDE"; Universal Robots, "Real-Time Data
Exchange (RTDE) Guide"): package framing, the variable table a controller serves, and the
packing of data packages. No sockets of its own (`read_package` reads from the caller's), no
clock. Both sides of the wire use it: the UR emulator (emulators/ur/server.py) and the driver's
own output reader (plants/ur/rtde_outputs.py); it lives with the driver because plants may not
import emulators (docs/architecture.md, "Layers").

Every package: uint16 size (header included, big-endian), uint8 type, payload. Types:
'V' REQUEST_PROTOCOL_VERSION (u16 version -> u8 accepted), 'v' GET_URCONTROL_VERSION
(-> 4 x u32 major, minor, bugfix, build), 'M' TEXT_MESSAGE (u8 length, message, u8 length,
source, u8 warning level), 'O' CONTROL_PACKAGE_SETUP_OUTPUTS (f64 frequency + comma-separated
names -> u8 recipe id + comma-separated types), 'I' CONTROL_PACKAGE_SETUP_INPUTS (names ->
u8 recipe id + types), 'S' CONTROL_PACKAGE_START and 'P' CONTROL_PACKAGE_PAUSE (-> u8 accepted),
'U' DATA_PACKAGE (u8 recipe id + the recipe's values, big-endian, in recipe order).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

HEADER = struct.Struct(">HB")
NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"

# RTDE type name -> struct format of one value (big-endian applied by the caller).
TYPE_FORMATS: dict[str, str] = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}

# Text message warning levels (RTDE guide, TEXT_MESSAGE).
EXCEPTION_MESSAGE, ERROR_MESSAGE, WARNING_MESSAGE, INFO_MESSAGE = 0, 1, 2, 3


def _outputs() -> dict[str, str]:
    v6 = "VECTOR6D"
    table = {
        "timestamp": "DOUBLE",
        "target_q": v6,
        "target_qd": v6,
        "target_qdd": v6,
        "target_current": v6,
        "target_moment": v6,
        "actual_q": v6,
        "actual_qd": v6,
        "actual_current": v6,
        "actual_current_window": v6,
        "joint_control_output": v6,
        "actual_TCP_pose": v6,
        "actual_TCP_speed": v6,
        "actual_TCP_force": v6,
        "target_TCP_pose": v6,
        "target_TCP_speed": v6,
        "actual_digital_input_bits": "UINT64",
        "joint_temperatures": v6,
        "actual_execution_time": "DOUBLE",
        "robot_mode": "INT32",
        "joint_mode": "VECTOR6INT32",
        "safety_mode": "INT32",
        "safety_status": "INT32",
        "actual_tool_accelerometer": "VECTOR3D",
        "speed_scaling": "DOUBLE",
        "target_speed_fraction": "DOUBLE",
        "actual_momentum": "DOUBLE",
        "actual_main_voltage": "DOUBLE",
        "actual_robot_voltage": "DOUBLE",
        "actual_robot_current": "DOUBLE",
        "actual_joint_voltage": v6,
        "actual_digital_output_bits": "UINT64",
        "runtime_state": "UINT32",
        "elbow_position": "VECTOR3D",
        "elbow_velocity": "VECTOR3D",
        "robot_status_bits": "UINT32",
        "safety_status_bits": "UINT32",
        "analog_io_types": "UINT32",
        "standard_analog_input0": "DOUBLE",
        "standard_analog_input1": "DOUBLE",
        "standard_analog_output0": "DOUBLE",
        "standard_analog_output1": "DOUBLE",
        "io_current": "DOUBLE",
        "tool_mode": "UINT32",
        "tool_analog_input_types": "UINT32",
        "tool_analog_input0": "DOUBLE",
        "tool_analog_input1": "DOUBLE",
        "tool_output_voltage": "INT32",
        "tool_output_current": "DOUBLE",
        "tool_temperature": "DOUBLE",
        "tcp_force_scalar": "DOUBLE",
        "output_bit_registers0_to_31": "UINT32",
        "output_bit_registers32_to_63": "UINT32",
        "input_bit_registers0_to_31": "UINT32",
        "input_bit_registers32_to_63": "UINT32",
        "payload": "DOUBLE",
        "payload_cog": "VECTOR3D",
        "payload_inertia": v6,
        "script_control_line": "UINT32",
        "ft_raw_wrench": v6,
        "actual_current_as_torque": v6,
        "tool_digital_output_bits": "UINT8",  # not in every version; harmless to serve
    }
    for i in range(48):
        table[f"output_int_register_{i}"] = "INT32"
        table[f"output_double_register_{i}"] = "DOUBLE"
        table[f"input_int_register_{i}"] = "INT32"
        table[f"input_double_register_{i}"] = "DOUBLE"
    for i in range(64, 128):
        table[f"output_bit_register_{i}"] = "BOOL"
        table[f"input_bit_register_{i}"] = "BOOL"
    return table


def _inputs() -> dict[str, str]:
    table = {
        "speed_slider_mask": "UINT32",
        "speed_slider_fraction": "DOUBLE",
        "standard_digital_output_mask": "UINT8",
        "standard_digital_output": "UINT8",
        "configurable_digital_output_mask": "UINT8",
        "configurable_digital_output": "UINT8",
        "tool_digital_output_mask": "UINT8",
        "tool_digital_output": "UINT8",
        "standard_analog_output_mask": "UINT8",
        "standard_analog_output_type": "UINT8",
        "standard_analog_output_0": "DOUBLE",
        "standard_analog_output_1": "DOUBLE",
        "input_bit_registers0_to_31": "UINT32",
        "input_bit_registers32_to_63": "UINT32",
        "external_force_torque": "VECTOR6D",
    }
    for i in range(48):
        table[f"input_int_register_{i}"] = "INT32"
        table[f"input_double_register_{i}"] = "DOUBLE"
    for i in range(64, 128):
        table[f"input_bit_register_{i}"] = "BOOL"
    return table


OUTPUT_TYPES: Mapping[str, str] = _outputs()
INPUT_TYPES: Mapping[str, str] = _inputs()


def frame(kind: int, payload: bytes = b"") -> bytes:
    """One package: header (size incl. header, type) and payload."""
    return HEADER.pack(HEADER.size + len(payload), kind) + payload


class Receiver(Protocol):
    def recv(self, n: int, /) -> bytes: ...


def read_exact(sock: Receiver, n: int) -> bytes:
    """`n` bytes from a stream socket; ConnectionError when the peer closes it first."""
    buf = b""
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("the peer closed the RTDE connection")
        buf += chunk
    return buf


def read_package(sock: Receiver) -> tuple[int, bytes]:
    """The next package from a stream socket: (type, payload)."""
    size, kind = HEADER.unpack(read_exact(sock, HEADER.size))
    return kind, read_exact(sock, size - HEADER.size) if size > HEADER.size else b""


def text_message(message: str, source: str = "emulator", level: int = INFO_MESSAGE) -> bytes:
    m = message.encode()[:255]
    s = source.encode()[:255]
    return frame(TEXT_MESSAGE, bytes([len(m)]) + m + bytes([len(s)]) + s + bytes([level]))


@dataclass(frozen=True)
class Recipe:
    """A set-up recipe: its id, variable names and RTDE types; `struct` packs or unpacks the values
    that follow the recipe id in a data package."""

    recipe_id: int
    names: tuple[str, ...]
    types: tuple[str, ...]

    @property
    def struct(self) -> struct.Struct:
        return struct.Struct(">" + "".join(TYPE_FORMATS[t] for t in self.types))

    def pack(self, values: Mapping[str, object]) -> bytes:
        """A DATA_PACKAGE of this recipe with `values[name]` (vectors as sequences)."""
        flat: list[object] = []
        for name, typ in zip(self.names, self.types, strict=True):
            v = values[name]
            if typ.startswith("VECTOR"):
                flat.extend(v)  # type: ignore[call-overload,arg-type]
            else:
                flat.append(v)
        return frame(DATA_PACKAGE, bytes([self.recipe_id]) + self.struct.pack(*flat))

    def unpack(self, body: bytes) -> dict[str, object]:
        """The values of a DATA_PACKAGE body (recipe id already removed), by name."""
        flat = self.struct.unpack(body)
        out: dict[str, object] = {}
        k = 0
        for name, typ in zip(self.names, self.types, strict=True):
            n = int(TYPE_FORMATS[typ][0]) if TYPE_FORMATS[typ][0].isdigit() else 1
            out[name] = flat[k] if n == 1 else tuple(flat[k : k + n])
            k += n
        return out


def resolve_names(names: Sequence[str], table: Mapping[str, str]) -> list[str]:
    """Each name's type, or NOT_FOUND (the controller's answer for a name it does not know)."""
    return [table.get(n, NOT_FOUND) for n in names]
