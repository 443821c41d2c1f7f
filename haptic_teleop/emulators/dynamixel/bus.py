"""The emulated bus: instructions to servos, status packets with their wire times, faults, physics.

Pure with respect to time: `Bus.handle(packet, end_s)` is told when the instruction's last byte
arrived (bus clock, seconds since start) and returns the status packets with the time each is
delivered to the host. The process (`__main__.py`) does the I/O and the waiting.

Timing model (docs/dynamixel.md, "Timing"): a byte takes 10 bits on the wire (start, 8 data,
stop). After an instruction's last byte the addressed servo waits its Return Delay Time(9), then
its status packet takes bytes x 10 / baud; SYNC READ and BULK READ servos answer one after another
in the order the instruction lists them, each after its own return delay from the end of the
previous reply; FAST SYNC READ is one combined packet after the first servo's return delay. Each
packet reaches the host the USB latency after its last byte.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from haptic_teleop.emulators.dynamixel import protocol as p
from haptic_teleop.emulators.dynamixel.config import BusConfig, FaultConfig
from haptic_teleop.emulators.dynamixel.physics import Physics, build_physics
from haptic_teleop.emulators.dynamixel.servo import Servo
from haptic_teleop.plants.dynamixel import tables as t

I = t.Instruction  # noqa: E741


@dataclass(frozen=True)
class Reply:
    """Bytes to put on the host's side of the line at `deliver_s` (bus clock)."""

    deliver_s: float
    data: bytes


COUNTER_KEYS = (
    "transactions",
    "bytes_in",
    "bytes_out",
    "status_packets",
    "crc_errors",
    "noise_bytes",
    "dropped_replies",
    "corrupted_replies",
    "slowed_replies",
    "watchdog_trips",
    "physics_steps",
    "faults_applied",
)


class Bus:
    def __init__(self, cfg: BusConfig, notes: Callable[[str], None] | None = None) -> None:
        self.cfg = cfg
        self.notes = notes or (lambda _line: None)
        self._noted: set[str] = set()
        self.baud_bps = cfg.baud_bps
        self.servos = [Servo(s, cfg.baud_bps, self._note) for s in cfg.servos]
        self.physics: Physics = build_physics(cfg.physics)
        joints = self.physics.joints
        for s in cfg.servos:
            if s.joint not in joints:
                raise ValueError(f"servo {s.id}: joint {s.joint!r} is not a joint of the physics; joints: {joints}")
        self._joint_index = [joints.index(s.joint) for s in cfg.servos]
        self._pending_faults = list(cfg.faults)
        self.counters: dict[str, float] = dict.fromkeys(COUNTER_KEYS, 0)
        self.counters.update(wire_time_s=0.0, return_delay_s=0.0, usb_latency_s=0.0, extra_delay_s=0.0)
        self._stale = True
        self._refresh()

    def _note(self, line: str) -> None:
        if line not in self._noted:
            self._noted.add(line)
            self.notes(line)

    # ------------------------------------------------------------------------ physics

    @property
    def time_s(self) -> float:
        """Emulator time: the physics' time (follows the wall clock in realtime mode)."""
        return self.physics.time_s

    def torques_nm(self) -> np.ndarray:
        tau = np.zeros(len(self.physics.joints))
        for s, j in zip(self.servos, self._joint_index, strict=True):
            tau[j] += s.joint_torque_nm()
        return tau

    def advance_to(self, time_s: float) -> None:
        """Step the physics, goal currents held, while a whole step fits before `time_s`."""
        dt = self.physics.dt_s
        if self.physics.time_s + dt > time_s + 1e-12:
            return
        tau = self.torques_nm()
        while self.physics.time_s + dt <= time_s + 1e-12:
            self.physics.step(tau)
            self.counters["physics_steps"] += 1
        self._stale = True

    def advance_by(self, dt_s: float) -> None:
        self.advance_to(self.physics.time_s + dt_s)

    def _refresh(self) -> None:
        """Present values from the physics, when it moved or a servo changed since the last time."""
        if not self._stale:
            return
        self._stale = False
        q, qd = self.physics.state()
        for s, j in zip(self.servos, self._joint_index, strict=True):
            s.set_present(float(q[j]), float(qd[j]), self.physics.time_s)

    def check_watchdogs(self, now_s: float) -> None:
        for s in self.servos:
            if s.check_watchdog(now_s):
                self.counters["watchdog_trips"] += 1
                self._note(f"servo {s.id}: bus watchdog tripped at {now_s:.3f} s (no instruction for it in time)")

    # ------------------------------------------------------------------------ faults

    def apply_fault(self, f: FaultConfig) -> None:
        s = self.servo(f.servo_id)
        if s is None:
            raise ValueError(f"no servo with id {f.servo_id}")
        self.counters["faults_applied"] += 1
        if f.kind == "hardware_error":
            s.set_hardware_error(f.bits)
        elif f.kind == "drop_replies":
            s.drop_replies += f.count
        elif f.kind == "corrupt_crc":
            s.corrupt_replies += f.count
        elif f.kind == "slow_replies":
            s.slow_replies += f.count
            s.slow_extra_s = f.extra_delay_s
        elif f.kind == "vanish":
            s.vanished = True
        elif f.kind == "watchdog_trip":
            s.set("bus_watchdog", -1)
            s.watchdog_trips += 1
            self.counters["watchdog_trips"] += 1
            self._note(f"servo {s.id}: bus watchdog tripped (injected)")
        elif f.kind == "torque_off":
            s.set("torque_enable", 0)
        self._stale = True

    def _due_faults(self) -> None:
        n = self.counters["transactions"]
        due = [
            f
            for f in self._pending_faults
            if (f.at_transaction is not None and n >= f.at_transaction)
            or (f.at_time_s is not None and self.time_s >= f.at_time_s)
        ]
        for f in due:
            self._pending_faults.remove(f)
            self.apply_fault(f)

    # ------------------------------------------------------------------------ instructions

    def servo(self, servo_id: int) -> Servo | None:
        for s in self.servos:
            if s.id == servo_id and s.listening:
                return s
        return None

    def framing_error(self, e: p.FramingError) -> None:
        self.counters["bytes_in"] += e.wire_bytes
        self.counters["wire_time_s"] += t.wire_time_s(e.wire_bytes, self.baud_bps)
        if e.kind == "crc":
            self.counters["crc_errors"] += 1
        else:
            self.counters["noise_bytes"] += e.wire_bytes

    def handle(self, pkt: p.InstructionPacket, end_s: float) -> list[Reply]:
        """Execute one instruction whose last byte arrived at `end_s` (bus clock)."""
        c = self.counters
        c["transactions"] += 1
        c["bytes_in"] += pkt.wire_bytes
        c["wire_time_s"] += t.wire_time_s(pkt.wire_bytes, self.baud_bps)
        self._due_faults()
        # The Bus Watchdog runs on the servos' time: the bus clock in real time, the emulator's own
        # in lockstep (which advances only with the host's writes), so a starved emulator process
        # never trips a watchdog that a servo paced by its host would not.
        heard_s = self.physics.time_s if self.cfg.time.mode == "lockstep" else end_s
        self.check_watchdogs(heard_s)
        if pkt.instruction in _READS:
            self._refresh()
        out = _Schedule(self, end_s)
        inst, pid, prm = pkt.instruction, pkt.packet_id, pkt.params
        wrote_goal_current = False
        s: Servo | None
        if inst == I.PING:
            targets = sorted((s for s in self.servos if s.listening), key=lambda s: s.id)
            for s in targets if pid == t.BROADCAST_ID else [x for x in [self.servo(pid)] if x]:
                s.heard(heard_s)
                params = s.get("model_number").to_bytes(2, "little") + bytes((s.get("firmware_version"),))
                out.status(s, 0, params)
        elif inst in (I.READ, I.WRITE, I.REBOOT) or inst not in _MULTI:
            targets = [s for s in self.servos if s.listening] if pid == t.BROADCAST_ID else []
            one = self.servo(pid)
            for s in targets or ([one] if one else []):
                s.heard(heard_s)
                wrote_goal_current |= self._single(s, inst, prm, out, broadcast=pid == t.BROADCAST_ID)
        elif inst in (I.SYNC_READ, I.FAST_SYNC_READ):
            if len(prm) >= 4:
                addr, length = _u16(prm, 0), _u16(prm, 2)
                servos = [self.servo(i) for i in prm[4:]]
                for s in servos:
                    if s is not None:
                        s.heard(heard_s)
                if inst == I.SYNC_READ:
                    for s in servos:
                        if s is not None and s.status_return_level >= 1:
                            err, data = s.read(addr, length)
                            out.status(s, err, data if not err else b"")
                        else:
                            out.silent()
                else:
                    out.fast([(s, *s.read(addr, length)) if s is not None else None for s in servos], length)
        elif inst == I.SYNC_WRITE:
            if len(prm) >= 4:
                addr, length = _u16(prm, 0), _u16(prm, 2)
                for k in range(4, len(prm) - length, length + 1):
                    s = self.servo(prm[k])
                    if s is not None:
                        s.heard(heard_s)
                        s.write(addr, bytes(prm[k + 1 : k + 1 + length]))
                        wrote_goal_current |= _touches_goal_current(addr, length)
        elif inst == I.BULK_READ:
            for k in range(0, len(prm) - 4, 5):
                s = self.servo(prm[k])
                if s is not None and s.status_return_level >= 1:
                    s.heard(heard_s)
                    err, data = s.read(_u16(prm, k + 1), _u16(prm, k + 3))
                    out.status(s, err, data if not err else b"")
                else:
                    out.silent()
        elif inst == I.BULK_WRITE:
            k = 0
            while k + 5 <= len(prm):
                addr, length = _u16(prm, k + 1), _u16(prm, k + 3)
                s = self.servo(prm[k])
                if s is not None:
                    s.heard(heard_s)
                    s.write(addr, bytes(prm[k + 5 : k + 5 + length]))
                    wrote_goal_current |= _touches_goal_current(addr, length)
                k += 5 + length
        if wrote_goal_current and self.cfg.time.mode == "lockstep":
            self.advance_by(self.cfg.time.lockstep_dt_s)
        self._stale = True  # a write may have changed what Present Current and the rest read
        return out.replies

    def _single(self, s: Servo, inst: int, prm: bytes, out: _Schedule, broadcast: bool) -> bool:
        """READ, WRITE, REBOOT or an instruction the emulator does not know, for one servo; True
        if it wrote Goal Current."""
        answer = not broadcast and s.status_return_level >= (1 if inst == I.READ else 2)
        if inst == I.READ:
            if broadcast:
                return False
            if len(prm) != 4:
                out.status(s, t.StatusError.INSTRUCTION, b"") if answer else None
                return False
            err, data = s.read(_u16(prm, 0), _u16(prm, 2))
            if answer:
                out.status(s, err, data if not err else b"")
            return False
        if inst == I.WRITE:
            if len(prm) < 3:
                if answer:
                    out.status(s, t.StatusError.DATA_LENGTH, b"")
                return False
            addr = _u16(prm, 0)
            err = s.write(addr, bytes(prm[2:]))
            if answer:
                out.status(s, err, b"")
            return not err and _touches_goal_current(addr, len(prm) - 2)
        if inst == I.REBOOT:
            if answer:
                out.status(s, 0, b"")
            s.reboot()
            return False
        self._note(f"instruction 0x{inst:02x} is not emulated: answered with the instruction error")
        if answer:
            out.status(s, t.StatusError.INSTRUCTION, b"")
        return False


_READS = (I.READ, I.SYNC_READ, I.FAST_SYNC_READ, I.BULK_READ)
_MULTI = (I.SYNC_READ, I.FAST_SYNC_READ, I.SYNC_WRITE, I.BULK_READ, I.BULK_WRITE)


def _u16(b: bytes, i: int) -> int:
    return b[i] | (b[i + 1] << 8) if i + 1 < len(b) else 0


def _touches_goal_current(address: int, length: int) -> bool:
    return address < t.ADDR_GOAL_CURRENT + 2 and address + length > t.ADDR_GOAL_CURRENT


class _Schedule:
    """Status packets of one instruction, laid out in time on the wire, with the faults applied."""

    def __init__(self, bus: Bus, end_s: float) -> None:
        self.bus = bus
        self.t_s = end_s  # when the line is free for the next reply
        self.replies: list[Reply] = []

    def _charge(self, s: Servo, return_delay: bool = True) -> tuple[float, bool, bool]:
        """(start time, drop, corrupt) of this servo's next reply; the faults counted down.
        Without `return_delay` (a later part of a FAST SYNC READ): the extra delay only."""
        c = self.bus.counters
        delay = s.return_delay_s if return_delay else 0.0
        c["return_delay_s"] += delay
        if s.slow_replies > 0:
            s.slow_replies -= 1
            delay += s.slow_extra_s
            c["extra_delay_s"] += s.slow_extra_s
            c["slowed_replies"] += 1
        drop = s.drop_replies > 0
        if drop:
            s.drop_replies -= 1
            c["dropped_replies"] += 1
        corrupt = not drop and s.corrupt_replies > 0
        if corrupt:
            s.corrupt_replies -= 1
            c["corrupted_replies"] += 1
        return self.t_s + delay, drop, corrupt

    def _send(self, start_s: float, data: bytes) -> None:
        c = self.bus.counters
        wire = t.wire_time_s(len(data), self.bus.baud_bps)
        latency = self.bus.cfg.usb_latency_s
        c["bytes_out"] += len(data)
        c["wire_time_s"] += wire
        c["usb_latency_s"] += latency
        c["status_packets"] += 1
        self.t_s = start_s + wire
        self.replies.append(Reply(self.t_s + latency, data))

    def status(self, s: Servo, error: int, params: bytes) -> None:
        start, drop, corrupt = self._charge(s)
        if drop:
            self.t_s = start
            return
        pkt = p.status_packet(s.id, s.error_byte(error), params)
        self._send(start, p.corrupt_crc(pkt) if corrupt else pkt)

    def silent(self) -> None:
        """A listed servo that does not answer: the next one answers after its own delay."""

    def fast(self, parts: list[tuple[Servo, int, bytes] | None], length: int) -> None:
        """FAST SYNC READ: one packet, begun by the first listed servo after its return delay,
        each next servo appending its part. A servo that cannot answer (absent, vanished,
        firmware older than the instruction, Status Return Level 0, or a dropped reply) ends the
        packet there, so the host receives it short; a corrupted part makes the packet's CRC
        wrong; a slowed part delays the whole packet."""
        slots: list[p.FastSlot] = []
        start = self.t_s
        corrupt = False
        for k, part in enumerate(parts):
            if part is None:
                break
            s, err, data = part
            if s.cfg.firmware_version < t.FAST_SYNC_READ_MIN_FIRMWARE or s.status_return_level < 1:
                break
            if k == 0:
                start, drop, bad = self._charge(s)
            else:
                t0 = self.t_s
                self.t_s = start
                start, drop, bad = self._charge(s, return_delay=False)
                self.t_s = t0
            if drop:
                break
            corrupt |= bad
            slots.append(p.FastSlot(s.id, s.error_byte(err), data if not err else bytes(length)))
        if not slots:
            return
        pkt = p.fast_sync_read_status(slots, len(parts))
        if corrupt and len(slots) == len(parts):
            pkt = p.corrupt_crc(pkt)
        self._send(start, pkt)
