"""Dynamixel Protocol 2.0 framing, written from ROBOTIS' e-Manual (Protocol 2.0; CRC calculation).

Packet: FF FF FD 00 | id | length (2, little-endian) | instruction | params... | CRC (2, little-
endian). `length` counts instruction, params and CRC after byte stuffing. A status packet is the
same with instruction 0x55 and an error byte before its params.

- CRC-16: polynomial x^16 + x^15 + x^2 + 1 (0x8005), initial value 0, no reflection, over every
  byte from the first header byte to the last param (stuffed), sent low byte first.
- Byte stuffing: in the instruction..params range, each "FF FF FD" is followed by an extra FD, so
  the header never appears inside a packet; the receiver checks the CRC over the stuffed bytes
  and then removes the extra FDs.

`Parser` takes arbitrary chunks of a byte stream and yields `InstructionPacket`s and
`FramingError`s (a packet whose CRC does not match, which a servo ignores; bytes dropped while
looking for a header). Pure: no I/O, no clock.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from haptic_teleop.plants.dynamixel.tables import BROADCAST_ID, HEADER, Instruction

STATUS_INSTRUCTION = int(Instruction.STATUS)
MAX_PACKET_LENGTH = 4096
"""The largest length field the parser accepts; a bigger one is taken for noise and skipped."""


def _crc_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16 (poly 0x8005, MSB first, init `crc`) of `data`; pass a previous value to continue."""
    table = _CRC_TABLE
    for b in bytes(data):
        crc = ((crc << 8) & 0xFFFF) ^ table[((crc >> 8) ^ b) & 0xFF]
    return crc


def stuff(body: bytes | bytearray) -> bytes:
    """Insert an FD after every FF FF FD of `body` (the instruction..params range)."""
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            # only a pattern whose FD is the byte just copied (not a stuffed FD) counts
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes | bytearray) -> bytes:
    """Remove the FD stuffed after each FF FF FD of `body` (the inverse of `stuff`)."""
    out = bytearray()
    i, n = 0, len(body)
    while i < n:
        b = body[i]
        out.append(b)
        if b == 0xFD and i >= 2 and body[i - 2] == 0xFF and body[i - 1] == 0xFF and i + 1 < n and body[i + 1] == 0xFD:
            i += 2
        else:
            i += 1
    return bytes(out)


def _frame(packet_id: int, body: bytes) -> bytes:
    """Header, id, length and CRC around an already stuffed body."""
    length = len(body) + 2
    head = HEADER + bytes((packet_id, length & 0xFF, length >> 8))
    crc = crc16(head + body)
    return head + body + bytes((crc & 0xFF, crc >> 8))


def instruction_packet(packet_id: int, instruction: int, params: bytes | bytearray = b"") -> bytes:
    """An instruction packet (what a host sends), stuffed and with its CRC."""
    return _frame(packet_id, stuff(bytes((instruction,)) + bytes(params)))


def status_packet(packet_id: int, error: int, params: bytes | bytearray = b"") -> bytes:
    """A status packet: instruction 0x55, the error byte (error number | Alert bit), params."""
    return _frame(packet_id, stuff(bytes((STATUS_INSTRUCTION, error)) + bytes(params)))


@dataclass(frozen=True)
class FastSlot:
    """One servo's part of a FAST SYNC READ reply: its error byte, id and data."""

    servo_id: int
    error: int
    data: bytes


def fast_sync_read_status(slots: Sequence[FastSlot], declared: int | None = None) -> bytes:
    """The combined FAST SYNC READ reply: one status packet with id 0xFE whose body is, per servo,
    error, id, data and a CRC. Each slot's CRC is the running CRC of the packet from its first
    header byte through that slot's data, so the last slot's CRC is the packet's CRC. The body is
    not byte-stuffed (the reply is decoded by position). The length field counts the whole reply
    of `declared` servos (default: all given); with fewer slots given the packet stops short, as
    when a servo of the chain does not append its part."""
    n_data = sum(2 + len(s.data) + 2 for s in slots)
    if declared is not None and slots:
        n_data += (declared - len(slots)) * (4 + len(slots[0].data))
    length = 1 + n_data  # instruction, slots (each with its CRC; the last CRC is the packet's)
    out = bytearray(HEADER + bytes((BROADCAST_ID, length & 0xFF, length >> 8, STATUS_INSTRUCTION)))
    for s in slots:
        out += bytes((s.error, s.servo_id)) + s.data
        crc = crc16(out)
        out += bytes((crc & 0xFF, crc >> 8))
    return bytes(out)


def corrupt_crc(packet: bytes) -> bytes:
    """The same packet with its last CRC byte inverted (a reply damaged on the line)."""
    return packet[:-1] + bytes((packet[-1] ^ 0xFF,))


@dataclass(frozen=True)
class InstructionPacket:
    """A received instruction: target id, instruction byte, un-stuffed params, and how many bytes
    it took on the wire (stuffed, with header and CRC)."""

    packet_id: int
    instruction: int
    params: bytes
    wire_bytes: int


@dataclass(frozen=True)
class FramingError:
    """Bytes that made no valid packet: `kind` "crc" (a whole packet whose CRC did not match; a
    servo ignores it) or "noise" (bytes skipped while looking for a header)."""

    kind: str
    wire_bytes: int
    packet_id: int = -1


class Parser:
    """Incremental instruction-packet parser: `feed(chunk)` yields what the chunk completed."""

    __slots__ = ("_buf",)

    def __init__(self) -> None:
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes held that do not yet make a packet."""
        return len(self._buf)

    def feed(self, chunk: bytes | bytearray) -> Iterator[InstructionPacket | FramingError]:
        buf = self._buf
        buf += chunk
        while True:
            start = buf.find(HEADER)
            if start < 0:
                # keep a tail that may be the start of a header
                keep = 0
                for k in (3, 2, 1):
                    if len(buf) >= k and bytes(buf[-k:]) == HEADER[:k]:
                        keep = k
                        break
                dropped = len(buf) - keep
                if dropped:
                    del buf[:dropped]
                    yield FramingError("noise", dropped)
                return
            if start:
                del buf[:start]
                yield FramingError("noise", start)
            if len(buf) < 7:
                return
            packet_id = buf[4]
            length = buf[5] | (buf[6] << 8)
            if length < 3 or length > MAX_PACKET_LENGTH or packet_id in (0xFD, 0xFF):
                del buf[:1]
                yield FramingError("noise", 1)
                continue
            total = 7 + length
            if len(buf) < total:
                return
            packet = bytes(buf[:total])
            del buf[:total]
            crc = packet[-2] | (packet[-1] << 8)
            if crc16(packet[:-2]) != crc:
                yield FramingError("crc", total, packet_id)
                continue
            body = unstuff(packet[7:-2])
            yield InstructionPacket(packet_id, body[0], body[1:], total)


# ---------------------------------------------------------------- status parsing (for tests and tools)


@dataclass(frozen=True)
class StatusPacket:
    packet_id: int
    error: int
    params: bytes


def parse_status(packet: bytes) -> StatusPacket:
    """One whole status packet (ValueError naming what is wrong)."""
    if len(packet) < 11 or packet[:4] != HEADER:
        raise ValueError("not a status packet: too short or no header")
    length = packet[5] | (packet[6] << 8)
    if len(packet) != 7 + length:
        raise ValueError(f"status packet length field {length} does not match its {len(packet)} bytes")
    if crc16(packet[:-2]) != packet[-2] | (packet[-1] << 8):
        raise ValueError("status packet CRC does not match")
    if packet[7] != STATUS_INSTRUCTION:
        raise ValueError(f"instruction 0x{packet[7]:02x} is not STATUS (0x55)")
    body = unstuff(packet[7:-2])
    return StatusPacket(packet[4], body[1], body[2:])
