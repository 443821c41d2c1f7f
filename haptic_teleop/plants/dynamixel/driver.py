"""A chain of Dynamixel X-series servos in current control, spoken to through `dynamixel_sdk`
(Protocol 2.0), as a `JointDriver` (plants/hardware.py). docs/dynamixel_driver.md has the details.

Per tick the driver puts two packets on the bus: one GROUP SYNC READ (or FAST SYNC READ) of the
10-byte block Present Current(126) + Present Velocity(128) + Present Position(132) of every servo,
and one GROUP SYNC WRITE of Goal Current(102) (no reply). Units come from `tables.py`.

Joint convention: `q_rad = sign x (servo angle - zero_offset_rad)`, the servo angle being Present
Position x 2 pi / 4096 (so `zero_offset_rad` is the servo's own angle at the joint's zero; 2048
ticks = pi is the middle of a turn); velocity and torque take the same sign. The torque is
Present Current x 2.69 mA x the joint's torque constant (N m/A, the datasheet's stall torque /
stall current unless the configuration gives an identified one).

Safety: the Bus Watchdog(98) is armed, so a servo stops when no instruction reaches it for
`bus_watchdog_s` (the host died or hung); `stop()` (idempotent, never raises) writes Goal Current 0
and Torque Enable 0 to every servo, twice; it runs from `with driver:`, `atexit` and every error
this module raises. `torque_off_on_exit(...)` (used by `with driver:`) turns a SIGTERM into an
exception while inside, so the `finally` that stops the servos runs.

The SDK is imported in `start()` only, so this module imports without it.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import re
import select
import signal
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

import numpy as np

from haptic_teleop.interrupt import Interrupted
from haptic_teleop.plants.dynamixel import tables as T
from haptic_teleop.plants.dynamixel.chain import (
    FAST_PART,
    READ_BLOCK,
    DynamixelChainConfig,
)
from haptic_teleop.plants.dynamixel.port import open_port
from haptic_teleop.plants.hardware import HardwareError, JointDriver, JointSample, import_sdk

_STATE = struct.Struct("<hii")  # Present Current (int16), Present Velocity (int32), Present Position (int32)

START_TRIES = 3
"""Tries of each start-up transaction (ping, read, write) before a servo counts as silent: a
reply can miss the SDK's packet timeout once on a busy host."""

SETTLE_S = 0.3
"""After reads failed, how long the driver lets late replies pass before it pings a silent servo
again to tell a vanished servo from a slow or noisy line."""

LATE_S = 0.1
"""Before a start-up transaction is tried again, how long the driver lets the unanswered request's
reply (if it is only late) arrive, to drop it with everything else on the line: the next request's
answer is then its own."""

START_TIMEOUT_S = 0.1
"""How long a start-up (or diagnosis) transaction waits for its reply: longer than the SDK's own
(about 34 ms), which a busy host's emulator missed three times in a row in one CI run; it only
costs time when a servo does not answer."""

APPLIED_REL = 0.2
"""A servo applies what it was told when its Present Current is within `applied_tolerance_units`
plus this fraction of the Goal Current (a current loop settles within a tick, with sensor noise
of a few units; the e-Manual gives no figure: docs/dynamixel_driver.md, "Applied, not commanded")."""

_NO_ERROR = 0x7F  # a status's error number bits (bit 7 is the Alert bit)

_warned_not_usb: set[str] = set()


@dataclass(frozen=True)
class DynamixelSample(JointSample):
    """A `JointSample` with `stale`: 0 for a fresh read, else how many reads in a row failed (the
    values and `t_s` are then those of the last good read)."""

    stale: int = 0


class DynamixelDriver:
    """`JointDriver` over one Dynamixel bus. Use as `with DynamixelDriver(cfg) as drv: drv.start(); ...`
    (torque off on leaving the block, also on SIGTERM and Ctrl-C), or call `stop()` yourself."""

    def __init__(self, config: DynamixelChainConfig) -> None:
        self.config = config
        js = config.joints
        self.joints: tuple[str, ...] = tuple(j.name for j in js)
        self._ids = [j.id for j in js]
        self._sign = np.array([float(j.sign) for j in js])
        self._offset = np.array([j.zero_offset_rad for j in js])
        self._kt = np.array([j.k_t_nm_per_a for j in js])
        self._limit = [j.current_limit_units for j in js]
        self._limit_arr = np.array(self._limit, dtype=float)
        self._nm_per_unit = self._kt * T.CURRENT_UNIT_A  # joint torque per current unit, before the sign
        self.torque_limit_nm: np.ndarray = self._nm_per_unit * np.array(self._limit, dtype=float)
        self.fast_sync_read_used = False
        self.stale = 0  # reads in a row that failed (0: the last sample is fresh)
        self.stale_reads = 0  # failed reads since start
        self.reads = 0
        self.late_replies = 0  # status packets that answered an earlier request, skipped
        self.late_bytes = 0  # bytes on the line before a request (late replies), dropped
        self.corrupt_replies = 0
        self._run_late = 0  # late_replies when the current run of failed reads began
        self._run_corrupt = 0
        self._goal_units = np.zeros(len(js), dtype=np.int64)  # the Goal Current last written
        self._mismatch = np.zeros(len(js), dtype=np.int64)  # fresh reads in a row not applying it
        self._last_fail = ""
        self._last_fail_index: int | None = None
        self._sample: DynamixelSample | None = None
        self._raw_prev: np.ndarray | None = None
        self._wrap = np.zeros(len(js))
        self._last_comm_s = 0.0
        self._sdk: Any = None
        self._port: Any = None
        self._ph: Any = None
        self._gsw_current: Any = None
        self._gsw_torque: Any = None
        self._gsr: Any = None
        self._started = False
        self._stopped = False
        self._guard: contextlib.ExitStack | None = None

    # ------------------------------------------------------------------ naming

    def _servo(self, k: int) -> str:
        return f"servo {self._ids[k]} ({self.joints[k]}) on {self.config.port}"

    def _fail(self, message: str) -> HardwareError:
        """Torque off (best effort), then the error to raise."""
        self.stop()
        return HardwareError(message)

    # ------------------------------------------------------------------ start

    def start(self) -> DynamixelSample:
        """Open the port, check the adapter and every servo, configure current control, torque on
        with zero current; returns the first sample. Raises HardwareError (torque off first)."""
        if self._started:
            raise HardwareError(f"{self.config.port}: start() called twice; make a new DynamixelDriver")
        self._started = True
        sdk: Any = import_sdk("dynamixel_sdk")

        self._sdk = sdk
        cfg = self.config
        self._open_port()
        atexit.register(self.stop)
        self._check_latency_timer()
        firmware: list[int] = []
        for k, joint in enumerate(cfg.joints):
            for attempt in range(START_TRIES):
                if attempt:
                    self._settle()
                number, result, _ = self._ping(k)
                if result == sdk.COMM_SUCCESS:
                    break
            if result != sdk.COMM_SUCCESS:
                raise self._fail(
                    f"servo {joint.id} ({joint.name}) does not answer on {cfg.port} at {cfg.baud_bps} bps "
                    f"({self._result_text(result)}): check that it is powered (its LED blinks at power-on), "
                    f"that its ID(7) is {joint.id} and its Baud Rate(8) is {cfg.baud_bps} bps (scan the bus with "
                    f"Dynamixel Wizard), and the cables from the adapter along the chain"
                )
            want = joint.servo_model
            if number != want.model_number:
                found = T.MODELS_BY_NUMBER.get(number)
                what = f"a {found.name}" if found else "an unknown model"
                raise self._fail(
                    f"{self._servo(k)} is {what} (model number {number}), but the configuration says "
                    f"{want.name} (model number {want.model_number}): fix the joint's model, or its id if "
                    f"two servos were swapped"
                )
            firmware.append(self._read(k, T.ADDR_FIRMWARE_VERSION, 1, "read Firmware Version(6)"))
            status = self._read(k, T.ADDR_HARDWARE_ERROR_STATUS, 1, "read Hardware Error Status(70)")
            if status:
                raise self._fail(self._hardware_error_text(k, status))
            if firmware[k] < T.BUS_WATCHDOG_MIN_FIRMWARE:
                raise self._fail(
                    f"{self._servo(k)} runs firmware v{firmware[k]}, which has no Bus Watchdog(98) (v"
                    f"{T.BUS_WATCHDOG_MIN_FIRMWARE}+): update its firmware with Dynamixel Wizard"
                )
        fast_ok = all(f >= T.FAST_SYNC_READ_MIN_FIRMWARE for f in firmware)
        if cfg.fast_sync_read and not fast_ok:
            old = [k for k, f in enumerate(firmware) if f < T.FAST_SYNC_READ_MIN_FIRMWARE]
            raise self._fail(
                f"fast_sync_read is on but {self._servo(old[0])} runs firmware v{firmware[old[0]]} "
                f"(FAST SYNC READ needs v{T.FAST_SYNC_READ_MIN_FIRMWARE}+): update it with Dynamixel Wizard, "
                f"or leave fast_sync_read unset (auto) or false"
            )
        self.fast_sync_read_used = fast_ok if cfg.fast_sync_read is None else cfg.fast_sync_read
        for k in range(len(self._ids)):
            self._write(k, T.ADDR_TORQUE_ENABLE, 1, 0, "Torque Enable(64) = 0")
            self._write(k, T.ADDR_OPERATING_MODE, 1, T.OPERATING_MODE_CURRENT, "Operating Mode(11) = 0 (current)")
            self._write(k, T.ADDR_CURRENT_LIMIT, 2, self._limit[k], f"Current Limit(38) = {self._limit[k]}")
            self._write(k, T.ADDR_RETURN_DELAY_TIME, 1, cfg.return_delay_units, "Return Delay Time(9)")
            self._write(k, T.ADDR_BUS_WATCHDOG, 1, 0, "Bus Watchdog(98) = 0 (clears a tripped watchdog)")
            self._write(k, T.ADDR_GOAL_CURRENT, 2, 0, "Goal Current(102) = 0")
            self._write(k, T.ADDR_BUS_WATCHDOG, 1, cfg.bus_watchdog_units, "Bus Watchdog(98) armed")
        port, ph = self._port, self._ph
        self._gsw_current = sdk.GroupSyncWrite(port, ph, T.ADDR_GOAL_CURRENT, 2)
        self._gsw_torque = sdk.GroupSyncWrite(port, ph, T.ADDR_TORQUE_ENABLE, 1)
        self._gsr = sdk.GroupSyncRead(port, ph, T.STATE_BLOCK_ADDRESS, READ_BLOCK)
        for i in self._ids:
            self._gsw_current.addParam(i, [0, 0])
            self._gsw_torque.addParam(i, [0])
            self._gsr.addParam(i)
        for k in range(len(self._ids)):
            self._write(k, T.ADDR_TORQUE_ENABLE, 1, 1, "Torque Enable(64) = 1")
        self._last_comm_s = time.monotonic()
        for _ in range(cfg.max_consecutive_comm_errors):
            sample = self.read()
            if not sample.stale:
                return sample
        raise AssertionError("unreachable: read() raises after max_consecutive_comm_errors failures")

    def _open_port(self) -> None:
        self._ph = self._sdk.PacketHandler(2.0)
        self._port = open_port(self._sdk, self.config.port, self.config.baud_bps)

    def _check_latency_timer(self) -> None:
        cfg = self.config
        names = (os.path.basename(cfg.port), os.path.basename(os.path.realpath(cfg.port)))
        usb = next((n for n in names if re.fullmatch(r"ttyUSB\d+", n)), None)
        if usb is None:
            pty = os.path.realpath(cfg.port).startswith("/dev/pts/")  # an emulator's bus: nothing to say
            if cfg.port not in _warned_not_usb and not pty:
                _warned_not_usb.add(cfg.port)
                print(
                    f"haptic-teleop: {cfg.port} is not a USB serial adapter (ttyUSBn): "
                    f"the USB latency timer check does not apply",
                    file=sys.stderr,
                )
            return
        path = Path(cfg.sysfs_root) / usb / "latency_timer"
        try:
            value = int(path.read_text().strip())
        except (OSError, ValueError) as exc:
            print(f"haptic-teleop: {cfg.port}: cannot read {path} ({exc}): latency timer not checked", file=sys.stderr)
            return
        if value > cfg.latency_timer_ms_max:
            raise self._fail(
                f"{cfg.port}: the USB latency timer is {value} ms ({path}), above {cfg.latency_timer_ms_max} ms: "
                f"every read would wait up to {value} ms for the adapter; set it to 1 ms: "
                f"`echo 1 | sudo tee {Path(cfg.sysfs_root) / usb / 'latency_timer'}` (until the adapter is "
                f"unplugged; the udev rule in docs/dynamixel_driver.md sets it for good)"
            )

    # ------------------------------------------------------------------ single register access (start-up)

    def _result_text(self, result: int) -> str:
        return str(self._ph.getTxRxResult(result)).replace("[TxRxResult] ", "").rstrip("!").lower()

    def _status_fault(self, k: int, error: int, what: str) -> HardwareError:
        if error & T.ALERT_BIT:
            return self._hardware_fault(k)
        text = T.STATUS_ERROR_TEXT.get(T.StatusError(error & 0x7F)) if error & 0x7F <= 7 else None
        return self._fail(f"{self._servo(k)} refused to {what}: {text or f'status error 0x{error:02x}'}")

    # ------------------------------------------------------------------ one request, one answer

    def _status(self, k: int, params: int) -> tuple[list[int], int, int]:
        """The status packet of servo k answering the request just put on the bus, with `params`
        parameter bytes: (parameters, result, error byte). A status of another servo, or of this
        servo with another length, answers an earlier request that came late: it is counted
        (`late_replies`) and skipped, never taken as this request's answer (the SDK's own receive
        matches the id only). The request's packet timeout bounds the wait."""
        ph, port, sdk = self._ph, self._port, self._sdk
        want = self._ids[k]
        while True:
            rx, result = ph.rxPacket(port, False)
            if result != sdk.COMM_SUCCESS:
                if result == sdk.COMM_RX_CORRUPT:
                    self.corrupt_replies += 1
                return [], result, 0
            length = rx[T.STATUS_LENGTH] | rx[T.STATUS_LENGTH + 1] << 8
            error = rx[T.STATUS_ERROR]
            if rx[T.STATUS_ID] == want and (length == params + 4 or (length == 4 and error & _NO_ERROR)):
                return list(rx[T.STATUS_PARAMS : T.STATUS_PARAMS + params]), result, error
            self.late_replies += 1

    def _drop_input(self) -> None:
        """Drop what is on the line (late replies), counted in `late_bytes`."""
        port = self._port
        with contextlib.suppress(AttributeError, OSError, ValueError):
            self.late_bytes += int(port.ser.in_waiting)
        port.clearPort()

    def _settle(self) -> None:
        """After a request went unanswered: let its reply arrive if it is only late, then drop it."""
        time.sleep(LATE_S)
        self._drop_input()

    def _ping(self, k: int) -> tuple[int, int, int]:
        """PING servo k: (model number, result, error byte), its own answer only (`_status`)."""
        ph, port, sdk = self._ph, self._port, self._sdk
        tx = [0] * 10  # the instruction packet's bytes, as the SDK's ping builds them (header added by txPacket)
        tx[T.STATUS_ID] = self._ids[k]
        tx[T.STATUS_LENGTH] = 3
        tx[T.STATUS_LENGTH + 2] = int(T.Instruction.PING)
        port.is_using = False
        result = ph.txPacket(port, tx)
        if result != sdk.COMM_SUCCESS:
            return 0, result, 0
        port.setPacketTimeoutMillis(START_TIMEOUT_S * 1000.0)
        data, result, error = self._status(k, T.PING_STATUS_PARAMS)
        if result != sdk.COMM_SUCCESS or len(data) < 2:
            return 0, result, error
        return data[0] | data[1] << 8, result, error

    def _try_read(self, k: int, address: int, size: int) -> tuple[list[int], int, int]:
        """A READ of servo k, tried START_TRIES times (late replies let pass between): (data,
        result, error byte) of the last try."""
        ph, port, sdk = self._ph, self._port, self._sdk
        data: list[int] = []
        result, error = sdk.COMM_TX_FAIL, 0
        for attempt in range(START_TRIES):
            if attempt:
                self._settle()
            port.is_using = False
            result = ph.readTx(port, self._ids[k], address, size)
            data, error = [], 0
            if result == sdk.COMM_SUCCESS:
                port.setPacketTimeoutMillis(START_TIMEOUT_S * 1000.0)
                data, result, error = self._status(k, size)
            if result == sdk.COMM_SUCCESS:
                break
        return data, result, error

    def _read(self, k: int, address: int, size: int, what: str) -> int:
        sdk = self._sdk
        data, result, error = self._try_read(k, address, size)
        if result != sdk.COMM_SUCCESS:
            raise self._fail(
                f"{self._servo(k)} did not answer to {what} ({self._result_text(result)}) at "
                f"{self.config.baud_bps} bps: check its power and cable"
            )
        if error & _NO_ERROR:
            raise self._status_fault(k, error, what)
        return T.int_from_bytes(bytes(data[:size]), False)

    def _write(self, k: int, address: int, size: int, value: int, what: str) -> None:
        ph, port, sdk = self._ph, self._port, self._sdk
        data = list(T.int_to_bytes(value, size, value < 0))
        for attempt in range(START_TRIES):
            if attempt:
                self._settle()
            port.is_using = False
            result = ph.writeTxOnly(port, self._ids[k], address, size, data)
            error = 0
            if result == sdk.COMM_SUCCESS:
                port.setPacketTimeoutMillis(START_TIMEOUT_S * 1000.0)
                _, result, error = self._status(k, 0)
            if result == sdk.COMM_SUCCESS:
                break
        if result != sdk.COMM_SUCCESS:
            raise self._fail(
                f"{self._servo(k)} did not answer to the write {what} ({self._result_text(result)}) at "
                f"{self.config.baud_bps} bps: check its power and cable"
            )
        if error:
            raise self._status_fault(k, error, f"write {what}")

    def _hardware_error_text(self, k: int, status: int) -> str:
        return (
            f"{self._servo(k)} reports a hardware error (Hardware Error Status(70) = 0x{status:02x}): "
            f"{T.describe_hardware_error(status)}. The servo holds the error (and its torque off) until it "
            f"is rebooted: REBOOT it with Dynamixel Wizard or power-cycle the chain, then start again"
        )

    def _hardware_fault(self, k: int) -> HardwareError:
        """The Alert bit came back: read which hardware error (70), torque off, the error."""
        self._port.is_using = False
        result = self._ph.readTx(self._port, self._ids[k], T.ADDR_HARDWARE_ERROR_STATUS, 1)
        data: list[int] = []
        if result == self._sdk.COMM_SUCCESS:
            data, result, _ = self._status(k, 1)
        if result != self._sdk.COMM_SUCCESS or not data:
            return self._fail(
                f"{self._servo(k)} signals a hardware error (Alert bit) but its Hardware Error Status(70) could "
                f"not be read ({self._result_text(result)}): power-cycle the chain and read it with Dynamixel Wizard"
            )
        return self._fail(self._hardware_error_text(k, int(data[0])))

    # ------------------------------------------------------------------ per tick

    def read(self) -> DynamixelSample:
        """One (fast) sync read of every servo's current, velocity and position, in SI units."""
        if self._stopped or self._gsr is None:
            raise self._not_running("read")
        now = time.monotonic()
        if self._last_comm_s and now - self._last_comm_s > self.config.bus_watchdog_units * T.BUS_WATCHDOG_UNIT_S:
            self._check_watchdog(now - self._last_comm_s)
        if self.stale == 0:  # a run of failed reads may begin: what went wrong in it is counted from here
            self._run_late, self._run_corrupt = self.late_replies + self.late_bytes, self.corrupt_replies
        blocks = self._sync_read_fast() if self.fast_sync_read_used else self._sync_read()
        self._last_comm_s = time.monotonic()
        if blocks is None:
            self.stale += 1
            self.stale_reads += 1
            if self.stale >= self.config.max_consecutive_comm_errors:
                raise self._comm_fault()
            assert self._sample is not None, "a failed first read"
            s = self._sample
            return DynamixelSample(s.q_rad, s.qd_rad_per_s, s.tau_nm, s.t_s, stale=self.stale)
        self.stale = 0
        self.reads += 1
        state = np.array([_STATE.unpack_from(b) for b in blocks], dtype=float)  # current, velocity, position
        raw = state[:, 2]
        if self._raw_prev is not None:  # unwrap the 32-bit multi-turn count if it ever rolls over
            d = raw - self._raw_prev
            self._wrap -= np.where(d > 2**31, 2.0**32, 0.0) - np.where(d < -(2**31), 2.0**32, 0.0)
        self._raw_prev = raw
        ticks = raw + self._wrap
        vel = state[:, 1]
        cur = state[:, 0]
        self._check_applied(cur)
        sign = self._sign
        sample = DynamixelSample(
            q_rad=sign * (ticks * T.POSITION_UNIT_RAD - self._offset),
            qd_rad_per_s=sign * vel * T.VELOCITY_UNIT_RAD_PER_S,
            tau_nm=sign * cur * self._nm_per_unit,
            t_s=self._last_comm_s,
        )
        self._sample = sample
        return sample

    def _check_applied(self, present_units: np.ndarray) -> None:
        """Each servo's Present Current against the Goal Current last written: a servo that stays
        off it for `applied_mismatch_reads` fresh reads is not applying what it is told, and what
        the host would record as applied is not: find why, torque off, one error naming it."""
        cfg = self.config
        goal = self._goal_units
        off = np.abs(present_units - goal) > cfg.applied_tolerance_units + APPLIED_REL * np.abs(goal)
        self._mismatch = np.where(off, self._mismatch + 1, 0)
        worst = int(np.argmax(self._mismatch))
        if self._mismatch[worst] >= cfg.applied_mismatch_reads:
            raise self._applied_fault(worst, int(present_units[worst]), int(goal[worst]))

    def _applied_fault(self, k: int, present: int, goal: int) -> HardwareError:
        """Why servo k does not apply its Goal Current: its Bus Watchdog, Torque Enable, Hardware
        Error Status and Operating Mode, read back; the error to raise (torque off first)."""
        n = int(self._mismatch[k])
        seen = (
            f"{self._servo(k)} is not applying the commanded torque: Present Current {present} units against "
            f"Goal Current {goal} units for {n} reads in a row"
        )
        self._port.is_using = False
        watchdog = self._read(k, T.ADDR_BUS_WATCHDOG, 1, "read Bus Watchdog(98)")
        if watchdog == 0xFF:  # -1: tripped
            why = (
                f"its Bus Watchdog(98) tripped (no instruction reached it within "
                f"{self.config.bus_watchdog_units * 20} ms: a busy or stalled host), so it ignores Goal Current; "
                f"keep the loop reading and writing every "
                f"tick, give it a core of its own, or raise bus_watchdog_s"
            )
        elif self._read(k, T.ADDR_TORQUE_ENABLE, 1, "read Torque Enable(64)") == 0:
            why = (
                "its Torque Enable(64) is 0: something turned its torque off (another program on the bus, "
                "a reboot, a power dip); find it before starting again"
            )
        elif status := self._read(k, T.ADDR_HARDWARE_ERROR_STATUS, 1, "read Hardware Error Status(70)"):
            return self._fail(f"{seen}: {self._hardware_error_text(k, status)}")
        elif (mode := self._read(k, T.ADDR_OPERATING_MODE, 1, "read Operating Mode(11)")) != T.OPERATING_MODE_CURRENT:
            why = f"its Operating Mode(11) is {mode}, not current control (0): another program changed it"
        else:
            why = (
                "it answers and reports no fault: the motor cannot draw that current (supply voltage too low "
                "for the speed, a PWM Limit(36) below 885, a mechanical block); check the supply and the load, "
                "or raise applied_tolerance_units if the current loop is noisier than that"
            )
        return self._fail(f"{seen}: {why}; torque is off")

    def _not_running(self, what: str) -> HardwareError:
        state = "stopped (torque off)" if self._stopped else "not started"
        return HardwareError(f"{self.config.port}: {what}() on a driver that is {state}; start a new DynamixelDriver")

    def _miss(self, index: int | None, why: str) -> None:
        """A failed read: why, and which servo's reply was missing (the first of a run of failures
        is kept: a late reply delays the servos after it in the next reads)."""
        self._last_fail = why
        if self.stale == 0:
            self._last_fail_index = index

    def _send_read(self, send: Callable[[], int], what: str, reply_bytes: int) -> None:
        """Put a read instruction on the bus (what is on the line before it, late replies, counted
        and dropped) and wait until its `reply_bytes` can have arrived."""
        self._drop_input()
        result = send()
        if result != self._sdk.COMM_SUCCESS:
            raise self._fail(
                f"{self.config.port}: could not send the {what} ({self._result_text(result)}): "
                "was the adapter unplugged?"
            )
        if self.config.read_timeout_s is not None:
            self._port.setPacketTimeoutMillis(self.config.read_timeout_s * 1000.0)
        self._wait_for_bytes(reply_bytes)

    def _sync_read(self) -> list[bytes] | None:
        sdk = self._sdk
        self._send_read(self._gsr.txPacket, "sync read", (11 + READ_BLOCK) * len(self._ids))
        blocks: list[bytes] = []
        for k in range(len(self._ids)):
            data, result, error = self._status(k, READ_BLOCK)
            if result != sdk.COMM_SUCCESS:
                self._miss(k, self._result_text(result))
                return None
            if error:
                if error & T.ALERT_BIT:
                    raise self._hardware_fault(k)
                self._miss(k, f"status error 0x{error:02x}")
                return None
            blocks.append(bytes(data))
        return None if self._more_came() else blocks

    def _more_came(self) -> bool:
        """Bytes on the line after every reply was taken: a late reply came in this read's window,
        so one of the replies taken may be it (same servo, same length) and not this read's own
        answer. The read is not used (stale); the next request drops those bytes."""
        try:
            extra = int(self._port.ser.in_waiting)
        except (AttributeError, OSError, ValueError):
            return False
        if extra:
            self.late_replies += 1
            self._miss(None, f"{extra} bytes came after the replies (a late reply)")
        return extra > 0

    def _sync_read_fast(self) -> list[bytes] | None:
        sdk, ph, port = self._sdk, self._ph, self._port
        n = len(self._ids)
        self._send_read(self._gsr.fastSyncReadTxPacket, "fast sync read", 8 + FAST_PART * n)
        data, result, _ = ph.fastSyncReadRx(port, T.BROADCAST_ID, FAST_PART * n)
        if result != sdk.COMM_SUCCESS:
            self.corrupt_replies += result == sdk.COMM_RX_CORRUPT
            self._miss(None, self._result_text(result))
            return None
        if len(data) < FAST_PART * n:
            self._miss(None, f"a fast sync read reply of {len(data)} bytes, expected {FAST_PART * n}")
            return None
        blocks: list[bytes] = []
        alert: int | None = None
        for k, i in enumerate(self._ids):
            part = data[k * FAST_PART : (k + 1) * FAST_PART]
            if part[1] != i:
                self._miss(k, f"the fast sync read reply has id {part[1]} where servo {i} belongs")
                return None
            if part[0] & T.ALERT_BIT and alert is None:
                alert = k
            elif part[0] & 0x7F:
                self._miss(k, f"status error 0x{part[0]:02x}")
                return None
            blocks.append(bytes(part[2 : 2 + READ_BLOCK]))
        if alert is not None:
            raise self._hardware_fault(alert)
        return None if self._more_came() else blocks

    def _wait_for_bytes(self, n_bytes: int) -> None:
        """Sleep in select() until the replies' bytes are in the input buffer, or the read's
        timeout passed. The SDK then parses them without its busy poll (it reads with timeout 0 in
        a loop), which would take a CPU from the emulator or the rest of the host."""
        port = self._port
        ser = port.ser
        try:
            fd = ser.fileno()
        except (AttributeError, OSError, ValueError):
            return
        per_byte_s = 10.0 / self.config.baud_bps
        deadline = time.monotonic() + port.packet_timeout / 1000.0 - port.getTimeSinceStart() / 1000.0
        while True:
            have = ser.in_waiting
            if have >= n_bytes:
                return
            left = deadline - time.monotonic()
            if left <= 0:
                return
            if have:  # part of the replies came: sleep for the rest's wire time
                time.sleep(min(left, max(50e-6, (n_bytes - have) * per_byte_s)))
            else:
                select.select([fd], [], [], left)

    def _comm_fault(self) -> HardwareError:
        """Too many reads in a row failed: find which servo stopped answering (ping each), then the error."""
        cfg, sdk = self.config, self._sdk
        n_bad = self.stale
        self._port.is_using = False
        with contextlib.suppress(Exception):  # Goal Current 0 at once: the diagnosis takes a while
            for i in self._ids:
                self._gsw_current.changeParam(i, [0, 0])
            self._gsw_current.txPacket()
            self._port.is_using = False
        self._settle()  # replies that are only late arrive now, and count as late
        silent = list(range(len(self._ids)))
        for settle_s in (0.0, SETTLE_S):  # a second round after late replies have left the line
            time.sleep(settle_s)
            still = []
            self._drop_input()
            for k in silent:
                _, result, _ = self._ping(k)
                if result != sdk.COMM_SUCCESS:
                    still.append(k)
            silent = still
            if not silent:
                break
        if silent:
            k = silent[0]
            more = (
                f" (also silent: {', '.join(f'servo {self._ids[j]} ({self.joints[j]})' for j in silent[1:])})"
                if len(silent) > 1
                else ""
            )
            return self._fail(
                f"{self._servo(k)} stopped answering: {n_bad} reads in a row failed ({self._last_fail}) at "
                f"{cfg.baud_bps} bps and it does not answer a ping{more}; check its power supply, the cable into "
                f"it and the connectors along the chain; torque is off"
            )
        who = f"{self._servo(self._last_fail_index)}" if self._last_fail_index is not None else cfg.port
        late = self.late_replies + self.late_bytes - self._run_late
        corrupt = self.corrupt_replies - self._run_corrupt
        if late and not corrupt:
            why = (
                "the replies come late (answers to earlier requests arrived after their read gave up): a busy host "
                "or adapter; check the USB latency timer, Return Delay Time(9), give the loop a core of its own, or "
                "raise read_timeout_s"
            )
        elif corrupt:
            why = (
                f"the replies come corrupted ({corrupt} with a bad CRC or cut short): check the cable and its "
                f"length, the supply (noise), the connectors, or lower the baud rate"
            )
        else:
            why = (
                "the replies go missing: check the cable and its length, the supply (noise), Return Delay "
                "Time(9), the USB latency timer, or lower the baud rate"
            )
        return self._fail(
            f"{who}: {n_bad} reads in a row failed ({self._last_fail}) at {cfg.baud_bps} bps although every servo "
            f"answers a ping: {why}; torque is off"
        )

    def _check_watchdog(self, gap_s: float) -> None:
        """The host was silent longer than the Bus Watchdog: did it trip?"""
        self._port.is_using = False
        for k in range(len(self._ids)):
            data, result, _ = self._try_read(k, T.ADDR_BUS_WATCHDOG, 1)
            # 0xFF (-1): tripped; a servo that does not answer is left to the reads to name
            if result == self._sdk.COMM_SUCCESS and data[:1] == [0xFF]:
                raise self._fail(
                    f"{self._servo(k)}: its Bus Watchdog(98) tripped (the host sent nothing for "
                    f"{gap_s * 1000:.0f} ms, the watchdog is {self.config.bus_watchdog_units * 20} ms) and it "
                    f"stopped: keep the loop reading and writing every tick (nothing slow between start() and "
                    f"the loop), or raise bus_watchdog_s; torque is off"
                )

    def write(self, tau_nm: np.ndarray) -> np.ndarray:
        """Goal Current for these joint torques (nearest unit, clipped to Current Limit, NaN -> 0)
        in one sync write; returns the torques the servos will apply."""
        if self._stopped or self._gsw_current is None:
            raise self._not_running("write")
        tau = np.asarray(tau_nm, dtype=float)
        n = len(self._ids)
        if tau.shape != (n,):
            raise ValueError(f"write() takes {n} torques ({', '.join(self.joints)}), got shape {tau.shape}")
        lim = self._limit_arr
        wanted = tau * self._sign / self._nm_per_unit
        wanted[np.isnan(wanted)] = 0.0
        units_arr = np.clip(np.rint(wanted), -lim, lim)  # +-inf -> the limit
        gsw = self._gsw_current
        for i, u in zip(self._ids, units_arr.astype(np.int64).tolist(), strict=True):
            gsw.changeParam(i, [u & 0xFF, (u >> 8) & 0xFF])
        result = gsw.txPacket()
        if result != self._sdk.COMM_SUCCESS:
            raise self._fail(
                f"{self.config.port}: could not send Goal Current ({self._result_text(result)}): "
                f"was the adapter unplugged?"
            )
        self._last_comm_s = time.monotonic()
        self._goal_units = units_arr.astype(np.int64)
        applied: np.ndarray = self._sign * units_arr * self._nm_per_unit
        return applied

    # ------------------------------------------------------------------ stop

    def stop(self) -> None:
        """Goal Current 0 and Torque Enable 0 to every servo (twice), close the port. Idempotent,
        never raises."""
        if self._stopped:
            return
        self._stopped = True
        with contextlib.suppress(Exception):
            atexit.unregister(self.stop)
        port = self._port
        if port is None or not getattr(port, "is_open", False):
            return
        port.is_using = False  # a signal may have landed inside a transaction
        for _ in range(2):
            with contextlib.suppress(Exception):
                if self._gsw_current is not None:
                    for i in self._ids:
                        self._gsw_current.changeParam(i, [0, 0])
                    self._gsw_current.txPacket()
                    port.is_using = False
            with contextlib.suppress(Exception):
                if self._gsw_torque is not None:
                    self._gsw_torque.txPacket()
                else:  # stopped during start(): a broadcast WRITE (no servo replies to it)
                    self._ph.write2ByteTxOnly(port, T.BROADCAST_ID, T.ADDR_GOAL_CURRENT, 0)
                    port.is_using = False
                    self._ph.write1ByteTxOnly(port, T.BROADCAST_ID, T.ADDR_TORQUE_ENABLE, 0)
                port.is_using = False
        with contextlib.suppress(Exception):
            port.ser.flush()  # the bytes are on the wire before the port closes
        with contextlib.suppress(Exception):
            port.closePort()

    @property
    def stopped(self) -> bool:
        return self._stopped

    def __enter__(self) -> DynamixelDriver:
        self._guard = contextlib.ExitStack()
        self._guard.enter_context(torque_off_on_exit(self))
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._guard is not None:
            self._guard.close()
            self._guard = None
        self.stop()


def _raise_interrupted(signum: int, frame: FrameType | None) -> None:
    raise Interrupted(signum)


@contextlib.contextmanager
def torque_off_on_exit(*drivers: DynamixelDriver) -> Iterator[None]:
    """Stop every driver when the block ends: normally, by an exception, by Ctrl-C or by SIGTERM.

    Python's default SIGTERM ends the process without running `finally` blocks or `atexit`; while
    inside, a SIGTERM and a SIGINT raise `interrupt.Interrupted` (a KeyboardInterrupt with
    `exit_code` 143 or 130) instead, when the process has no handler of its own (the command
    line's `interrupt.install()` has one: it raises or stops the loop, and the `finally` runs
    either way). Main thread only for the handlers; the stop runs in any thread."""
    previous: dict[signal.Signals, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            if signal.getsignal(sig) in (signal.SIG_DFL, signal.default_int_handler, None):
                previous[sig] = signal.signal(sig, _raise_interrupted)
    try:
        yield
    finally:
        for d in drivers:
            d.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _is_a_joint_driver(driver: DynamixelDriver) -> JointDriver:
    """For the type checker: DynamixelDriver satisfies the JointDriver protocol."""
    return driver
