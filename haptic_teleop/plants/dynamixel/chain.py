"""A Dynamixel chain's configuration (one bus, its servos and how each maps to a joint) and the
bus's wire arithmetic: pure data and checks, no SDK and no I/O. The driver (driver.py) runs a
chain; `bench hardware` computes the wire-time limit from the same byte counts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from haptic_teleop.errors import ConfigError
from haptic_teleop.plants.dynamixel import tables as T

SOURCE = "dynamixel chain"

SDK_BAUD_RATES_BPS = (9_600, 57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)
"""Baud rates both a Baud Rate(8) code and `dynamixel_sdk`'s PortHandler accept (4.5 Mbps has a
code but the SDK refuses it)."""

WATCHDOG_UNITS_MAX = 127
READ_BLOCK = T.STATE_BLOCK_SIZE  # Present Current(2) + Present Velocity(4) + Present Position(4)
FAST_PART = READ_BLOCK + 4  # a FAST SYNC READ status carries error, id, data, CRC per servo


@dataclass(frozen=True)
class DynamixelJoint:
    """One servo of the chain.

    `current_limit` (register units of 2.69 mA) or `current_limit_a` (amperes; at most one of
    them) is written to Current Limit(38) and clips every command; default: the model's maximum.
    `torque_constant_nm_per_a`: default the model's (stall torque / stall current, tables.py)."""

    name: str
    id: int
    model: str
    sign: int = 1
    zero_offset_rad: float = 0.0
    torque_constant_nm_per_a: float | None = None
    current_limit: int | None = None
    current_limit_a: float | None = None

    def __post_init__(self) -> None:
        where = f"joints.{self.name}"
        if not self.name:
            raise ConfigError(SOURCE, "joints[].name", self.name, "allowed: a non-empty joint name")
        if not 0 <= self.id <= T.MAX_ID:
            raise ConfigError(SOURCE, f"{where}.id", self.id, f"allowed: a servo id 0..{T.MAX_ID}")
        if self.model not in T.MODELS:
            raise ConfigError(SOURCE, f"{where}.model", self.model, f"allowed: {', '.join(sorted(T.MODELS))}")
        if self.sign not in (1, -1):
            raise ConfigError(SOURCE, f"{where}.sign", self.sign, "allowed: +1 or -1")
        if not math.isfinite(self.zero_offset_rad):
            raise ConfigError(SOURCE, f"{where}.zero_offset_rad", self.zero_offset_rad, "allowed: a finite angle")
        kt = self.torque_constant_nm_per_a
        if kt is not None and not (math.isfinite(kt) and kt > 0):
            raise ConfigError(SOURCE, f"{where}.torque_constant_nm_per_a", kt, "allowed: a number > 0 (N m/A)")
        top = T.model(self.model).current_limit_max
        if self.current_limit is not None and self.current_limit_a is not None:
            raise ConfigError(
                SOURCE, f"{where}.current_limit", self.current_limit, "give current_limit or current_limit_a, not both"
            )
        if self.current_limit is not None and not 1 <= self.current_limit <= top:
            raise ConfigError(
                SOURCE, f"{where}.current_limit", self.current_limit, f"allowed: 1..{top} units of 2.69 mA"
            )
        if self.current_limit_a is not None and not (0 < self.current_limit_a <= top * T.CURRENT_UNIT_A):
            raise ConfigError(
                SOURCE,
                f"{where}.current_limit_a",
                self.current_limit_a,
                f"allowed: > 0 and <= {top * T.CURRENT_UNIT_A:.3f} A ({self.model})",
            )

    @property
    def servo_model(self) -> T.ServoModel:
        return T.model(self.model)

    @property
    def k_t_nm_per_a(self) -> float:
        kt = self.torque_constant_nm_per_a
        return self.servo_model.torque_constant_nm_per_a if kt is None else kt

    @property
    def current_limit_units(self) -> int:
        if self.current_limit is not None:
            return self.current_limit
        if self.current_limit_a is not None:
            # whole units at or below the limit asked for (toward safety: never above it), at least 1
            units = math.floor(self.current_limit_a / T.CURRENT_UNIT_A + 1e-9)
            return max(1, min(self.servo_model.current_limit_max, units))
        return self.servo_model.current_limit_max


@dataclass(frozen=True)
class DynamixelChainConfig:
    """One bus (one USB adapter) of servos.

    `bus_watchdog_s`: rounded up to 20 ms units, at most 127 x 20 ms. `fast_sync_read`: None (auto:
    on when every servo's firmware answers FAST SYNC READ, v45+), True (required) or False.
    `return_delay_time_s`: Return Delay Time(9), 0 recommended (the servo answers at once; the
    factory 500 us costs 0.5 ms per servo per read). `read_timeout_s`: how long a read waits for
    the status packets (None: the SDK's own, about 34 ms plus the wire time).
    `max_consecutive_comm_errors`: reads in a row that may fail (timeout, corrupt packet) before
    the driver stops with an error; a single failed read returns the last good sample marked stale.
    `applied_tolerance_units` and `applied_mismatch_reads`: a servo whose Present Current stays
    further than `applied_tolerance_units` plus a fifth of the Goal Current from the Goal Current
    the driver wrote, for `applied_mismatch_reads` fresh reads in a row, is not applying what it
    is told (a tripped Bus Watchdog, torque off, a hardware error): the driver finds which and stops.
    """

    port: str
    joints: tuple[DynamixelJoint, ...]
    baud_bps: int = 1_000_000
    bus_watchdog_s: float = 0.1
    fast_sync_read: bool | None = None
    return_delay_time_s: float = 0.0
    latency_timer_ms_max: int = 1
    sysfs_root: str = "/sys/bus/usb-serial/devices"
    read_timeout_s: float | None = None
    max_consecutive_comm_errors: int = 3
    applied_tolerance_units: int = 10
    applied_mismatch_reads: int = 20

    def __post_init__(self) -> None:
        if not self.port:
            raise ConfigError(SOURCE, "port", self.port, "allowed: a serial device path such as /dev/ttyUSB0")
        if not self.joints:
            raise ConfigError(SOURCE, "joints", self.joints, "allowed: at least one servo")
        if self.baud_bps not in SDK_BAUD_RATES_BPS:
            raise ConfigError(SOURCE, "baud_bps", self.baud_bps, f"allowed: {', '.join(map(str, SDK_BAUD_RATES_BPS))}")
        ids = [str(j.id) for j in self.joints]
        names = [j.name for j in self.joints]
        for label, values in (("id", ids), ("name", names)):
            dup = sorted({v for v in values if values.count(v) > 1})
            if dup:
                raise ConfigError(SOURCE, f"joints[].{label}", ", ".join(dup), f"each {label} once on a bus")
        top = WATCHDOG_UNITS_MAX * T.BUS_WATCHDOG_UNIT_S
        if not (0 < self.bus_watchdog_s <= top + 1e-12):
            raise ConfigError(SOURCE, "bus_watchdog_s", self.bus_watchdog_s, f"allowed: > 0 and <= {top:.2f} s")
        rdt_top = 254 * T.RETURN_DELAY_UNIT_S
        if not (0 <= self.return_delay_time_s <= rdt_top + 1e-12):
            raise ConfigError(
                SOURCE, "return_delay_time_s", self.return_delay_time_s, f"allowed: 0..{rdt_top:g} s (2 us units)"
            )
        if not 0 <= self.latency_timer_ms_max <= 255:
            raise ConfigError(SOURCE, "latency_timer_ms_max", self.latency_timer_ms_max, "allowed: 0..255 ms")
        if self.read_timeout_s is not None and not (0 < self.read_timeout_s <= 10):
            raise ConfigError(SOURCE, "read_timeout_s", self.read_timeout_s, "allowed: > 0 and <= 10 s, or None")
        if self.max_consecutive_comm_errors < 1:
            raise ConfigError(SOURCE, "max_consecutive_comm_errors", self.max_consecutive_comm_errors, "allowed: >= 1")
        if not 0 <= self.applied_tolerance_units <= 2000:
            raise ConfigError(
                SOURCE, "applied_tolerance_units", self.applied_tolerance_units, "allowed: 0..2000 units of 2.69 mA"
            )
        if self.applied_mismatch_reads < 1:
            raise ConfigError(SOURCE, "applied_mismatch_reads", self.applied_mismatch_reads, "allowed: >= 1")

    @property
    def bus_watchdog_units(self) -> int:
        """Bus Watchdog(98) value: the period rounded up to 20 ms units."""
        return max(1, min(WATCHDOG_UNITS_MAX, math.ceil(self.bus_watchdog_s / T.BUS_WATCHDOG_UNIT_S - 1e-9)))

    @property
    def return_delay_units(self) -> int:
        return round(self.return_delay_time_s / T.RETURN_DELAY_UNIT_S)


def wire_bytes_per_tick(n_servos: int, fast: bool) -> int:
    """Bytes on the bus for one tick (one sync write of Goal Current, one sync read instruction of
    the 10-byte state block, and its replies), without byte stuffing.

    - SYNC WRITE: header 4 + id 1 + length 2 + instruction 1 + address 2 + size 2 + n x (id 1 +
      data 2) + CRC 2 = 14 + 3 n;
    - SYNC READ instruction: 14 + n (one id each);
    - replies: SYNC READ: one status packet per servo, header 4 + id 1 + length 2 + instruction 1 +
      error 1 + data 10 + CRC 2 = 21 bytes each; FAST SYNC READ: one packet, header 4 + id 1 +
      length 2 + instruction 1 + n x (error 1 + id 1 + data 10 + CRC 2) = 8 + 14 n.
    """
    write = 14 + 3 * n_servos
    read_instruction = 14 + n_servos
    replies = 8 + FAST_PART * n_servos if fast else (11 + READ_BLOCK) * n_servos
    return write + read_instruction + replies


def wire_limit_hz(n_servos: int, baud_bps: int, fast: bool, return_delay_s: float = 0.0) -> float:
    """Ticks per second the bus can carry: 1 / (bytes x 10 / baud + return delays)."""
    delays = return_delay_s * (1 if fast else n_servos)
    return 1.0 / (T.wire_time_s(wire_bytes_per_tick(n_servos, fast), baud_bps) + delays)
