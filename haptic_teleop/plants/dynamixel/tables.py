"""Dynamixel X-series facts as data: control tables, units, register codes, protocol codes.

Every number here is from ROBOTIS' e-Manual (the servo pages of the XM430-W350 and XM540-W270,
the Protocol 2.0 page); docs/dynamixel_facts.md lists each with its section. Nothing
here imports an SDK: the host driver and the bus emulator read the same tables.

Conventions
- A control-table field is little-endian, `size` bytes at `address`; signed fields are two's
  complement (Homing Offset, Goal/Present Current, Velocity, Position, Bus Watchdog's -1).
- `low`/`high` are the range a WRITE is checked against when it is fixed; fields whose range
  depends on another field (Goal Current: +-Current Limit(38), Goal Velocity: +-Velocity
  Limit(44), Goal Position: Min/Max Position Limit) say so in `range_from` and have no fixed range.
- The SI conversions round to the nearest register unit (ties to even, Python's `round`) and then
  clip to the register's range where one is given; the inverse conversions are exact products.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Literal

# ---------------------------------------------------------------- units (e-Manual control table)

CURRENT_UNIT_A = 2.69e-3
"""Goal/Present Current(102/126) and Current Limit(38): about 2.69 mA per unit."""
VELOCITY_UNIT_RPM = 0.229
"""Goal/Present Velocity(104/128), Velocity Limit(44): 0.229 rev/min per unit."""
VELOCITY_UNIT_RAD_PER_S = VELOCITY_UNIT_RPM * 2.0 * math.pi / 60.0
POSITION_TICKS_PER_REV = 4096
"""Present/Goal Position(132/116), Homing Offset(20): 4096 pulses per revolution (12-bit encoder)."""
POSITION_UNIT_RAD = 2.0 * math.pi / POSITION_TICKS_PER_REV
POSITION_CENTER_TICKS = 2048
"""The middle of one turn (0..4095): where the emulator puts a joint's zero."""
RETURN_DELAY_UNIT_S = 2e-6
"""Return Delay Time(9): 2 us per unit, 0..254 (default 250 = 500 us)."""
BUS_WATCHDOG_UNIT_S = 0.020
"""Bus Watchdog(98): 20 ms per unit, 1..127 arms it, 0 disarms and clears, -1 reads as tripped."""
VOLTAGE_UNIT_V = 0.1
"""Present Input Voltage(144), Min/Max Voltage Limit(34/32): 0.1 V per unit."""
TEMPERATURE_UNIT_C = 1.0
"""Present Temperature(146): 1 degree C per unit."""
REALTIME_TICK_UNIT_S = 0.001
"""Realtime Tick(120): 1 ms per unit, wraps at 32767."""
REALTIME_TICK_WRAP = 32768

# ---------------------------------------------------------------- protocol codes (Protocol 2.0)

HEADER = b"\xff\xff\xfd\x00"
"""Header 0xFF 0xFF 0xFD and the Reserved byte 0x00 that starts every packet."""
BROADCAST_ID = 0xFE
MAX_ID = 0xFC  # 0..252 address a servo; 0xFD and 0xFF are never ids


class Instruction(IntEnum):
    """Instruction byte of an instruction packet (0x55 marks a status packet)."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93


class StatusError(IntEnum):
    """Error number (bits 0..6) of a status packet's error field."""

    NONE = 0x00
    RESULT_FAIL = 0x01
    INSTRUCTION = 0x02
    CRC = 0x03
    DATA_RANGE = 0x04
    DATA_LENGTH = 0x05
    DATA_LIMIT = 0x06
    ACCESS = 0x07


# A status packet's bytes (Protocol 2.0, e-Manual "Status Packet"): header FF FF FD, reserved 00,
# id, length (2 bytes: instruction + error + parameters + CRC), instruction 0x55, error, then the
# parameters and the CRC. A status of N parameter bytes has length N + 4.
STATUS_ID = 4
STATUS_LENGTH = 5
STATUS_ERROR = 8
STATUS_PARAMS = 9
PING_STATUS_PARAMS = 3
"""A PING's status parameters: Model Number (2 bytes) and Firmware Version (1 byte)."""

ALERT_BIT = 0x80
"""Bit 7 of a status packet's error field: the device has a hardware error (read Hardware Error
Status(70) for which); set in every status packet until the error is cleared by REBOOT."""

STATUS_ERROR_TEXT = {
    StatusError.RESULT_FAIL: "result fail: the servo failed to process the instruction",
    StatusError.INSTRUCTION: "instruction error: an undefined instruction, or ACTION without REG_WRITE",
    StatusError.CRC: "CRC error: the instruction packet's CRC did not match",
    StatusError.DATA_RANGE: "data range error: the value is outside the field's minimum/maximum",
    StatusError.DATA_LENGTH: "data length error: fewer bytes written than the field's size",
    StatusError.DATA_LIMIT: "data limit error: the value is outside the field's limit",
    StatusError.ACCESS: (
        "access error: a read-only or undefined address written, or an EEPROM field written with torque on"
    ),
}

FAST_SYNC_READ_MIN_FIRMWARE = 45
"""X-series firmware from which FAST SYNC READ (0x8A) is answered (e-Manual, Protocol 2.0, Fast
Sync Read: "X series firmware v45 or above"; see docs/dynamixel_facts.md for how this was checked)."""

BUS_WATCHDOG_MIN_FIRMWARE = 38
"""Bus Watchdog(98) and Drive Mode(10) exist from firmware v38 (e-Manual, XM430-W350, Bus Watchdog)."""

BAUD_RATES_BPS: dict[int, int] = {
    0: 9_600,
    1: 57_600,
    2: 115_200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}
"""Baud Rate(8) register code -> bits per second (X430/X540; default code 1 = 57600)."""


def baud_code(baud_bps: int) -> int:
    """The Baud Rate(8) code of a rate; ValueError naming the allowed rates if there is none."""
    for code, bps in BAUD_RATES_BPS.items():
        if bps == baud_bps:
            return code
    raise ValueError(f"baud {baud_bps} bps has no Baud Rate(8) code; allowed: {sorted(BAUD_RATES_BPS.values())}")


# ---------------------------------------------------------------- hardware error status (70)


@dataclass(frozen=True)
class HardwareErrorBit:
    bit: int
    name: str
    meaning: str
    action: str


HARDWARE_ERROR_BITS: tuple[HardwareErrorBit, ...] = (
    HardwareErrorBit(
        0,
        "input voltage error",
        "the supply voltage is outside Min/Max Voltage Limit(34/32)",
        "check the power supply (12 V nominal for XM servos) and its cable; then REBOOT the servo",
    ),
    HardwareErrorBit(
        2,
        "overheating error",
        "the internal temperature exceeds Temperature Limit(31)",
        "turn the load down and let the servo cool; check Present Temperature(146); then REBOOT it",
    ),
    HardwareErrorBit(
        3,
        "motor encoder error",
        "the motor encoder malfunctions",
        "power-cycle the servo; if it persists the servo needs repair (ROBOTIS service)",
    ),
    HardwareErrorBit(
        4,
        "electrical shock error",
        "an electrical shock on the circuit, or too little power to run the motor",
        "check the supply can deliver the current and the wiring for shorts; then REBOOT the servo",
    ),
    HardwareErrorBit(
        5,
        "overload error",
        "a persistent load above the servo's maximum output",
        "reduce the load or the commanded current (Goal Current, Current Limit); then REBOOT the servo",
    ),
)
"""Bits of Hardware Error Status(70) and of the Shutdown(63) mask (bits 1, 6, 7 unused)."""

HARDWARE_ERROR_MASK = sum(1 << b.bit for b in HARDWARE_ERROR_BITS)


def decode_hardware_error(status: int) -> tuple[HardwareErrorBit, ...]:
    """The bits set in a Hardware Error Status(70) value, in bit order."""
    return tuple(b for b in HARDWARE_ERROR_BITS if status & (1 << b.bit))


def describe_hardware_error(status: int) -> str:
    """One human sentence per set bit ('overload error (a persistent load ...): reduce ...'), '; '
    joined; unknown bits are named as such."""
    parts = [f"{b.name} ({b.meaning}): {b.action}" for b in decode_hardware_error(status)]
    unknown = status & ~HARDWARE_ERROR_MASK & 0xFF
    if unknown:
        parts.append(f"unknown hardware error bits 0x{unknown:02x}")
    return "; ".join(parts) if parts else "no hardware error"


# ---------------------------------------------------------------- control table

Area = Literal["EEPROM", "RAM"]
Access = Literal["R", "RW"]


@dataclass(frozen=True)
class Field:
    """One control-table item. `default` is the factory value (None: set by the servo at run time);
    `low`/`high` the fixed write range (None: no fixed range, see `range_from`)."""

    name: str
    address: int
    size: int
    signed: bool
    area: Area
    access: Access
    default: int | None = None
    low: int | None = None
    high: int | None = None
    range_from: str = ""

    @property
    def end(self) -> int:
        return self.address + self.size

    def encode(self, value: int) -> bytes:
        """The field's bytes for `value` (ValueError when it does not fit the size)."""
        return int_to_bytes(value, self.size, self.signed)

    def decode(self, data: bytes | bytearray) -> int:
        return int_from_bytes(data, self.signed)


def int_to_bytes(value: int, size: int, signed: bool) -> bytes:
    """Little-endian, two's complement when signed; ValueError when `value` does not fit."""
    try:
        return int(value).to_bytes(size, "little", signed=signed)
    except OverflowError:
        raise ValueError(f"{value} does not fit {size} byte(s) {'signed' if signed else 'unsigned'}") from None


def int_from_bytes(data: bytes | bytearray, signed: bool) -> int:
    return int.from_bytes(bytes(data), "little", signed=signed)


@dataclass(frozen=True)
class ServoModel:
    """One servo model: its PING model number, its control table, its torque constant."""

    name: str
    model_number: int
    fields: tuple[Field, ...]
    torque_constant_nm_per_a: float
    """Stall torque / stall current at 12 V (docs/models.md); a scene may identify its own."""
    stall_torque_nm: float
    stall_current_a: float
    gear_ratio: float
    table_size: int = 148
    """Bytes from address 0 through Present Temperature(146) (Backup Ready at 147 on the X540);
    the indirect-address area above is not described here."""

    def field(self, name: str) -> Field:
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(f"{self.name} has no control-table field {name!r}; fields: {[f.name for f in self.fields]}")

    def field_at(self, address: int) -> Field | None:
        """The field covering `address`, or None in a gap of the table."""
        for f in self.fields:
            if f.address <= address < f.end:
                return f
        return None

    def default_table(self) -> bytearray:
        """The control table at power-on: every field with a default holds it, the rest 0."""
        table = bytearray(self.table_size)
        for f in self.fields:
            if f.default is not None:
                table[f.address : f.end] = f.encode(f.default)
        return table

    @property
    def current_limit_max(self) -> int:
        high = self.field("current_limit").high
        assert high is not None
        return high


def _x_series_fields(
    model_number: int,
    current_limit: int,
    velocity_limit_default: int,
    max_voltage_default: int,
    min_voltage_default: int,
    voltage_range: tuple[int, int],
) -> tuple[Field, ...]:
    """The XM430/XM540 control table (e-Manual, Control Table of EEPROM Area / RAM Area).
    Indirect addresses (168..) and External Port fields of the X540 are left out."""
    e: Area = "EEPROM"
    r: Area = "RAM"
    vlo, vhi = voltage_range
    return (
        Field("model_number", 0, 2, False, e, "R", model_number),
        Field("model_information", 2, 4, False, e, "R", 0),
        Field("firmware_version", 6, 1, False, e, "R"),
        Field("id", 7, 1, False, e, "RW", 1, 0, 252),
        Field("baud_rate", 8, 1, False, e, "RW", 1, 0, 7),
        Field("return_delay_time", 9, 1, False, e, "RW", 250, 0, 254),
        Field("drive_mode", 10, 1, False, e, "RW", 0, 0, 5),
        Field("operating_mode", 11, 1, False, e, "RW", 3, 0, 16),
        Field("secondary_id", 12, 1, False, e, "RW", 255, 0, 255),
        Field("protocol_type", 13, 1, False, e, "RW", 2, 1, 2),
        Field("homing_offset", 20, 4, True, e, "RW", 0, -1_044_479, 1_044_479),
        Field("moving_threshold", 24, 4, False, e, "RW", 10, 0, 1023),
        Field("temperature_limit", 31, 1, False, e, "RW", 80, 0, 100),
        Field("max_voltage_limit", 32, 2, False, e, "RW", max_voltage_default, vlo, vhi),
        Field("min_voltage_limit", 34, 2, False, e, "RW", min_voltage_default, vlo, vhi),
        Field("pwm_limit", 36, 2, False, e, "RW", 885, 0, 885),
        Field("current_limit", 38, 2, False, e, "RW", current_limit, 0, current_limit),
        Field("acceleration_limit", 40, 4, False, e, "RW", 32767, 0, 32767),
        Field("velocity_limit", 44, 4, False, e, "RW", velocity_limit_default, 0, 1023),
        Field("max_position_limit", 48, 4, False, e, "RW", 4095, 0, 4095),
        Field("min_position_limit", 52, 4, False, e, "RW", 0, 0, 4095),
        Field("shutdown", 63, 1, False, e, "RW", 52, 0, 255),
        Field("torque_enable", 64, 1, False, r, "RW", 0, 0, 1),
        Field("led", 65, 1, False, r, "RW", 0, 0, 1),
        Field("status_return_level", 68, 1, False, r, "RW", 2, 0, 2),
        Field("registered_instruction", 69, 1, False, r, "R", 0),
        Field("hardware_error_status", 70, 1, False, r, "R", 0),
        Field("velocity_i_gain", 76, 2, False, r, "RW", 1920, 0, 16383),
        Field("velocity_p_gain", 78, 2, False, r, "RW", 100, 0, 16383),
        Field("position_d_gain", 80, 2, False, r, "RW", 0, 0, 16383),
        Field("position_i_gain", 82, 2, False, r, "RW", 0, 0, 16383),
        Field("position_p_gain", 84, 2, False, r, "RW", 800, 0, 16383),
        Field("feedforward_2nd_gain", 88, 2, False, r, "RW", 0, 0, 16383),
        Field("feedforward_1st_gain", 90, 2, False, r, "RW", 0, 0, 16383),
        Field("bus_watchdog", 98, 1, True, r, "RW", 0, 0, 127),
        Field("goal_pwm", 100, 2, True, r, "RW", 0, range_from="pwm_limit"),
        Field("goal_current", 102, 2, True, r, "RW", 0, range_from="current_limit"),
        Field("goal_velocity", 104, 4, True, r, "RW", 0, range_from="velocity_limit"),
        Field("profile_acceleration", 108, 4, False, r, "RW", 0, 0, 32767),
        Field("profile_velocity", 112, 4, False, r, "RW", 0, 0, 32767),
        Field("goal_position", 116, 4, True, r, "RW", 0, range_from="position_limits"),
        Field("realtime_tick", 120, 2, False, r, "R", 0),
        Field("moving", 122, 1, False, r, "R", 0),
        Field("moving_status", 123, 1, False, r, "R", 0),
        Field("present_pwm", 124, 2, True, r, "R", 0),
        Field("present_current", 126, 2, True, r, "R", 0),
        Field("present_velocity", 128, 4, True, r, "R", 0),
        Field("present_position", 132, 4, True, r, "R", 0),
        Field("velocity_trajectory", 136, 4, True, r, "R", 0),
        Field("position_trajectory", 140, 4, True, r, "R", 0),
        Field("present_input_voltage", 144, 2, False, r, "R", 120),
        Field("present_temperature", 146, 1, False, r, "R", 30),
    )


XM430_W350 = ServoModel(
    name="XM430-W350",
    model_number=1020,
    fields=_x_series_fields(1020, 1193, 350, 160, 95, (95, 160)),
    torque_constant_nm_per_a=1.783,  # 4.1 N m / 2.3 A at 12 V
    stall_torque_nm=4.1,
    stall_current_a=2.3,
    gear_ratio=353.5,
)

XM540_W270 = ServoModel(
    name="XM540-W270",
    model_number=1120,
    fields=_x_series_fields(1120, 2047, 128, 160, 95, (95, 160)),
    torque_constant_nm_per_a=2.409,  # 10.6 N m / 4.4 A at 12 V (the e-Manual lists 2.409 N m/A)
    stall_torque_nm=10.6,
    stall_current_a=4.4,
    gear_ratio=272.5,
)

MODELS: dict[str, ServoModel] = {m.name: m for m in (XM430_W350, XM540_W270)}
"""Servo models by name ('XM430-W350', 'XM540-W270')."""
MODELS_BY_NUMBER: dict[int, ServoModel] = {m.model_number: m for m in MODELS.values()}
"""Servo models by the model number PING answers."""


def model(name: str) -> ServoModel:
    """The model of this name; ValueError naming the known models."""
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown Dynamixel model {name!r}; known: {sorted(MODELS)}") from None


# Addresses the driver and emulator use by name (identical on every model here).
ADDR_MODEL_NUMBER = 0
ADDR_FIRMWARE_VERSION = 6
ADDR_ID = 7
ADDR_BAUD_RATE = 8
ADDR_RETURN_DELAY_TIME = 9
ADDR_DRIVE_MODE = 10
ADDR_OPERATING_MODE = 11
ADDR_HOMING_OFFSET = 20
ADDR_CURRENT_LIMIT = 38
ADDR_VELOCITY_LIMIT = 44
ADDR_MAX_POSITION_LIMIT = 48
ADDR_MIN_POSITION_LIMIT = 52
ADDR_SHUTDOWN = 63
ADDR_TORQUE_ENABLE = 64
ADDR_LED = 65
ADDR_STATUS_RETURN_LEVEL = 68
ADDR_REGISTERED_INSTRUCTION = 69
ADDR_HARDWARE_ERROR_STATUS = 70
ADDR_BUS_WATCHDOG = 98
ADDR_GOAL_PWM = 100
ADDR_GOAL_CURRENT = 102
ADDR_GOAL_VELOCITY = 104
ADDR_GOAL_POSITION = 116
ADDR_REALTIME_TICK = 120
ADDR_MOVING = 122
ADDR_PRESENT_CURRENT = 126
ADDR_PRESENT_VELOCITY = 128
ADDR_PRESENT_POSITION = 132
ADDR_PRESENT_INPUT_VOLTAGE = 144
ADDR_PRESENT_TEMPERATURE = 146

OPERATING_MODE_CURRENT = 0
OPERATING_MODE_VELOCITY = 1
OPERATING_MODE_POSITION = 3
OPERATING_MODE_EXTENDED_POSITION = 4
OPERATING_MODE_CURRENT_BASED_POSITION = 5
OPERATING_MODE_PWM = 16

STATE_BLOCK_ADDRESS = ADDR_PRESENT_CURRENT
STATE_BLOCK_SIZE = 10
"""Present Current(126, 2) + Present Velocity(128, 4) + Present Position(132, 4): one contiguous
block, what one group sync read per tick reads."""

# ---------------------------------------------------------------- SI <-> register units


def current_units_to_amps(units: int) -> float:
    return units * CURRENT_UNIT_A


def amps_to_current_units(current_a: float, limit_units: int | None = None) -> int:
    """Nearest register unit, clipped to +-limit_units when given."""
    u = round(current_a / CURRENT_UNIT_A)
    if limit_units is not None:
        u = max(-limit_units, min(limit_units, u))
    return u


def torque_nm_to_current_units(torque_nm: float, k_t_nm_per_a: float, limit_units: int | None = None) -> int:
    """Goal Current units for a joint torque: round(tau / (k_t x 2.69 mA)), clipped to
    +-limit_units (the servo's Current Limit(38)) when given."""
    if k_t_nm_per_a <= 0.0:
        raise ValueError(f"torque constant {k_t_nm_per_a} N m/A must be > 0")
    return amps_to_current_units(torque_nm / k_t_nm_per_a, limit_units)


def current_units_to_torque_nm(units: int, k_t_nm_per_a: float) -> float:
    """Joint torque of a current register value: units x 2.69 mA x k_t."""
    return units * CURRENT_UNIT_A * k_t_nm_per_a


def rad_to_position_ticks(angle_rad: float) -> int:
    """Nearest encoder tick of an angle (4096 per turn), no offset: 2 pi -> 4096."""
    return round(angle_rad / POSITION_UNIT_RAD)


def position_ticks_to_rad(ticks: int) -> float:
    return ticks * POSITION_UNIT_RAD


def rad_per_s_to_velocity_units(velocity_rad_per_s: float, limit_units: int | None = None) -> int:
    """Nearest velocity unit (0.229 rev/min), clipped to +-limit_units when given."""
    u = round(velocity_rad_per_s / VELOCITY_UNIT_RAD_PER_S)
    if limit_units is not None:
        u = max(-limit_units, min(limit_units, u))
    return u


def velocity_units_to_rad_per_s(units: int) -> float:
    return units * VELOCITY_UNIT_RAD_PER_S


def wire_time_s(n_bytes: int, baud_bps: int) -> float:
    """Time `n_bytes` take on the bus: 10 bits a byte (start, 8 data, stop; no parity)."""
    return n_bytes * 10.0 / baud_bps
