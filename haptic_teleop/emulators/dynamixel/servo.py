"""One emulated X-series servo: its control table and the rules a real one applies to it.

Pure: no I/O, no clock (times are passed in). The bus (`bus.py`) routes instructions here and
turns the answers into status packets; the physics reads `applied_current_units()` and writes
back the joint state through `set_present()`.

Rules (e-Manual, the servo's control table and Protocol 2.0 "Error"):
- a write touching a read-only or undefined address, or an EEPROM field while Torque Enable(64)
  is 1, is refused with the access error; one covering part of a field with the data length
  error; a value outside the field's range with the data range error. A refused write changes
  nothing (all fields of one packet, or none).
- Goal Current(102) is within +-Current Limit(38); the motor never draws more than the limit.
- Operating Mode(11): a write that switches it (to a value other than the present one) resets
  Goal PWM(100) to PWM Limit(36), Goal Current(102) to Current Limit(38), and Profile
  Acceleration(108) and Profile Velocity(112) to 0 (XM430-W350 page, "Operating Mode(11)", the
  NOTE "Switching Operating Mode will reset ..."). A host that then turns the torque on without
  writing Goal Current gets full current. Writing the present mode again is no switch. A packet
  that switches the mode cannot carry a limit or a reset field: from 11 it covers the gap 14..19
  and is refused. Were it accepted, the packet's value would stand, as the field lies after 11 and
  a write applies in address order. The gains, which the NOTE resets "properly to the selected
  Operating Mode" without giving values, are not reset.
- Hardware Error Status(70): a bit also set in Shutdown(63) turns the torque off; while any bit
  is set every status packet carries the Alert bit (0x80). Only REBOOT clears it.
- Bus Watchdog(98) = 1..127 with the torque on: no instruction for this servo within value x
  20 ms stops it (goal treated as 0), 98 reads -1 and writes of a Goal field answer the data range
  error until 98 is written 0.
- REBOOT: RAM back to its power-on values (torque off, errors cleared, watchdog 0), EEPROM kept.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable

from haptic_teleop.emulators.dynamixel.config import ServoConfig
from haptic_teleop.plants.dynamixel import tables as t

GOAL_FIELDS = ("goal_pwm", "goal_current", "goal_velocity", "goal_position")
MODE_SWITCH_RESETS = (
    ("goal_pwm", "pwm_limit"),
    ("goal_current", "current_limit"),
    ("profile_acceleration", None),
    ("profile_velocity", None),
)
"""What switching Operating Mode(11) resets: (field, the limit it goes to; None: to 0)."""
INT32 = 2**31 - 1


class Servo:
    """The state of one servo. `notes` receives one line per thing the emulator does not emulate."""

    def __init__(self, cfg: ServoConfig, baud_bps: int, notes: Callable[[str], None] | None = None) -> None:
        self.cfg = cfg
        self.model = cfg.servo_model
        self.k_t_nm_per_a = cfg.k_t_nm_per_a
        self._notes = notes or (lambda _line: None)
        self._fields = {f.name: f for f in self.model.fields}
        # per field: its struct (little-endian, signed or not) and address, for fast get/set
        self._layout = {
            f.name: (
                struct.Struct(
                    "<" + {1: "b", 2: "h", 4: "i"}[f.size] if f.signed else "<" + {1: "B", 2: "H", 4: "I"}[f.size]
                ),
                f.address,
            )
            for f in self.model.fields
        }
        self._field_at = [self.model.field_at(a) for a in range(self.model.table_size)]
        table = self.model.default_table()
        self._put(table, "id", cfg.id)
        self._put(table, "baud_rate", t.baud_code(baud_bps))
        self._put(table, "firmware_version", cfg.firmware_version)
        for name, value in cfg.registers:
            self._put(table, name, value)
        self.table = table
        self._ram_at_power_on = bytes(table[self._fields["torque_enable"].address :])
        self.bus_baud_bps = baud_bps
        self.vanished = False
        self.drop_replies = 0
        self.corrupt_replies = 0
        self.slow_replies = 0
        self.slow_extra_s = 0.0
        self.last_heard_s = 0.0
        self.watchdog_trips = 0
        self.watchdog_timer_restart = False

    # ------------------------------------------------------------------------ registers

    def _put(self, table: bytearray, name: str, value: int) -> None:
        f = self._fields[name]
        table[f.address : f.end] = f.encode(value)

    def get(self, name: str) -> int:
        fmt, address = self._layout[name]
        value: int = fmt.unpack_from(self.table, address)[0]
        return value

    def set(self, name: str, value: int) -> None:
        """Set a field directly (the servo's own doing: present values, errors), no rules."""
        fmt, address = self._layout[name]
        fmt.pack_into(self.table, address, value)

    @property
    def id(self) -> int:
        return self.table[t.ADDR_ID]

    @property
    def listening(self) -> bool:
        """Hears the bus: not vanished, and its Baud Rate(8) matches the bus's."""
        return not self.vanished and t.BAUD_RATES_BPS.get(self.table[t.ADDR_BAUD_RATE]) == self.bus_baud_bps

    @property
    def return_delay_s(self) -> float:
        return self.get("return_delay_time") * t.RETURN_DELAY_UNIT_S

    @property
    def status_return_level(self) -> int:
        return self.get("status_return_level")

    @property
    def torque_on(self) -> bool:
        return self.get("torque_enable") == 1

    @property
    def watchdog_tripped(self) -> bool:
        return self.get("bus_watchdog") == -1

    def error_byte(self, error: int) -> int:
        """The status packet's error field: the error number, with the Alert bit while a hardware
        error is set."""
        return error | (t.ALERT_BIT if self.get("hardware_error_status") else 0)

    # ------------------------------------------------------------------------ instructions

    def read(self, address: int, length: int) -> tuple[int, bytes]:
        """(error number, data) of a READ; undefined bytes inside the table read as 0."""
        if length < 1:
            return t.StatusError.DATA_LENGTH, b""
        if address < 0 or address + length > len(self.table):
            return t.StatusError.ACCESS, b""
        return t.StatusError.NONE, bytes(self.table[address : address + length])

    def write(self, address: int, data: bytes) -> int:
        """Apply a WRITE with the servo's rules; returns the error number (0: written)."""
        end = address + len(data)
        if not data:
            return t.StatusError.DATA_LENGTH
        if address < 0 or end > len(self.table):
            return t.StatusError.ACCESS
        touched = []
        a = address
        while a < end:
            f = self._field_at[a]
            if f is None:
                return t.StatusError.ACCESS
            touched.append(f)
            a = f.end
        if touched[0].address < address or touched[-1].end > end:
            return t.StatusError.DATA_LENGTH
        for f in touched:
            if f.access != "RW" or (f.area == "EEPROM" and self.torque_on):
                return t.StatusError.ACCESS
        values = {f.name: f.decode(data[f.address - address : f.end - address]) for f in touched}
        for name, v in values.items():
            err = self._check_range(name, v, values)
            if err:
                return err
        if values.get("torque_enable") == 1 and not self.torque_on:
            if self.get("hardware_error_status"):
                return t.StatusError.RESULT_FAIL  # only REBOOT turns the torque on after a shutdown
            mode = values.get("operating_mode", self.get("operating_mode"))
            if mode != t.OPERATING_MODE_CURRENT:
                self._notes(
                    f"servo {self.id}: Torque Enable refused (Result Fail): operating mode {mode} is not emulated; "
                    f"only current control (Operating Mode(11) = {t.OPERATING_MODE_CURRENT})"
                )
                return t.StatusError.RESULT_FAIL
        switched = "operating_mode" in values and values["operating_mode"] != self.get("operating_mode")
        self.table[address:end] = data
        if switched:  # after the checks: a refused write switches nothing, so resets nothing
            for name, limit in MODE_SWITCH_RESETS:
                if name not in values:
                    self.set(name, self.get(limit) if limit else 0)
        if "torque_enable" in values and values["torque_enable"] == 1:
            self.watchdog_timer_restart = True
        return t.StatusError.NONE

    def _check_range(self, name: str, v: int, values: dict[str, int]) -> int:
        f = self._fields[name]
        if name in GOAL_FIELDS and self.watchdog_tripped:
            return t.StatusError.DATA_RANGE
        if f.low is not None and f.high is not None:
            return t.StatusError.NONE if f.low <= v <= f.high else t.StatusError.DATA_RANGE
        limit_of = {"goal_current": "current_limit", "goal_velocity": "velocity_limit", "goal_pwm": "pwm_limit"}
        if name in limit_of:
            lim = values.get(limit_of[name], self.get(limit_of[name]))
            return t.StatusError.NONE if -lim <= v <= lim else t.StatusError.DATA_RANGE
        if name == "goal_position":
            mode = self.get("operating_mode")
            if mode == t.OPERATING_MODE_POSITION:
                lo, hi = self.get("min_position_limit"), self.get("max_position_limit")
                return t.StatusError.NONE if lo <= v <= hi else t.StatusError.DATA_RANGE
        return t.StatusError.NONE

    def reboot(self) -> None:
        """RAM back to its power-on values (torque off, errors and watchdog cleared)."""
        start = self._fields["torque_enable"].address
        self.table[start:] = self._ram_at_power_on

    def set_hardware_error(self, bits: int) -> None:
        """A hardware fault: its bits in Hardware Error Status(70); Shutdown(63) bits turn torque off."""
        self.set("hardware_error_status", self.get("hardware_error_status") | bits)
        if bits & self.get("shutdown"):
            self.set("torque_enable", 0)

    # ------------------------------------------------------------------------ watchdog

    def heard(self, now_s: float) -> None:
        """An instruction for this servo arrived at `now_s` (wall time)."""
        self.last_heard_s = now_s

    def check_watchdog(self, now_s: float) -> bool:
        """Trip the Bus Watchdog if armed, torque on and silent too long; True if it tripped now."""
        if self.watchdog_timer_restart:
            self.watchdog_timer_restart = False
            self.last_heard_s = now_s
        w = self.get("bus_watchdog")
        if w <= 0 or not self.torque_on or self.vanished:
            return False
        if now_s - self.last_heard_s > w * t.BUS_WATCHDOG_UNIT_S:
            self.set("bus_watchdog", -1)
            self.watchdog_trips += 1
            return True
        return False

    # ------------------------------------------------------------------------ physics side

    @property
    def direction(self) -> int:
        """+1/-1 from the joint to the servo's frame: the configured sign, reversed by Drive Mode bit 0."""
        return self.cfg.sign * (-1 if self.get("drive_mode") & 1 else 1)

    def applied_current_units(self) -> int:
        """The current the motor draws (servo frame): Goal Current within the Current Limit when
        the torque is on, in current control, not stopped by the watchdog; else 0."""
        if self.vanished or not self.torque_on or self.watchdog_tripped:
            return 0
        if self.get("operating_mode") != t.OPERATING_MODE_CURRENT:
            return 0
        lim = self.get("current_limit")
        return max(-lim, min(lim, self.get("goal_current")))

    def joint_torque_nm(self) -> float:
        """The torque this servo puts on its joint (joint frame, N m), with its TRUE k_t."""
        return self.direction * t.current_units_to_torque_nm(self.applied_current_units(), self.k_t_nm_per_a)

    def set_present(self, q_rad: float, qd_rad_per_s: float, time_s: float) -> None:
        """Present Position/Velocity/Current, Moving and Realtime Tick from the joint state."""
        s = self.direction
        ticks = t.POSITION_CENTER_TICKS + s * (q_rad - self.cfg.offset_rad) / t.POSITION_UNIT_RAD
        ticks += self.get("homing_offset")
        pos = max(-INT32, min(INT32, round(ticks))) if math.isfinite(ticks) else 0
        vel = round(s * qd_rad_per_s / t.VELOCITY_UNIT_RAD_PER_S) if math.isfinite(qd_rad_per_s) else 0
        vel = max(-INT32, min(INT32, vel))
        _PRESENT.pack_into(self.table, t.ADDR_PRESENT_CURRENT, self.applied_current_units(), vel, pos)
        self.table[t.ADDR_MOVING] = 1 if abs(vel) > self.get("moving_threshold") else 0
        _TICK.pack_into(self.table, t.ADDR_REALTIME_TICK, int(time_s / t.REALTIME_TICK_UNIT_S) % t.REALTIME_TICK_WRAP)


_PRESENT = struct.Struct("<hii")  # Present Current(126), Velocity(128), Position(132): contiguous
_TICK = struct.Struct("<H")
