"""Protocol 2.0 framing and the servo's rules, without a process (emulators/dynamixel/protocol.py,
servo.py, bus.py). The expected bytes are the e-Manual's own examples (Protocol 2.0, Instruction
Details), not this code's output."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.emulators.dynamixel import protocol as p
from haptic_teleop.emulators.dynamixel.bus import Bus
from haptic_teleop.emulators.dynamixel.config import BusConfig
from haptic_teleop.errors import ConfigError
from haptic_teleop.plants.dynamixel import tables as t

# (packet, from the e-Manual's examples)
MANUAL_PACKETS = [
    "ff ff fd 00 01 03 00 01 19 4e",  # PING id 1
    "ff ff fd 00 fe 03 00 01 31 42",  # PING broadcast
    "ff ff fd 00 01 07 00 55 00 06 04 26 65 5d",  # its status: model 1030, firmware 38
    "ff ff fd 00 01 07 00 02 84 00 04 00 1d 15",  # READ Present Position
    "ff ff fd 00 01 08 00 55 00 a6 00 00 00 8c c0",  # its status: 166
    "ff ff fd 00 01 09 00 03 74 00 00 02 00 00 ca 89",  # WRITE 512 to Goal Position
    "ff ff fd 00 fe 09 00 82 84 00 04 00 01 02 ce fa",  # SYNC READ ids 1, 2
    "ff ff fd 00 01 03 00 08 2f 4e",  # REBOOT
]


@pytest.mark.parametrize("hexed", MANUAL_PACKETS)
def test_crc_matches_the_manual(hexed):
    pkt = bytes.fromhex(hexed)
    assert p.crc16(pkt[:-2]) == pkt[-2] | (pkt[-1] << 8)


def test_composers_give_the_manual_bytes():
    assert p.instruction_packet(1, t.Instruction.PING).hex(" ") == MANUAL_PACKETS[0]
    assert p.status_packet(1, 0, bytes([0x06, 0x04, 0x26])).hex(" ") == MANUAL_PACKETS[2]
    params = bytes([0x84, 0, 4, 0, 1, 2])
    assert p.instruction_packet(0xFE, t.Instruction.SYNC_READ, params).hex(" ") == MANUAL_PACKETS[6]
    st_ = p.parse_status(bytes.fromhex(MANUAL_PACKETS[4]))
    assert (st_.packet_id, st_.error, st_.params) == (1, 0, bytes([0xA6, 0, 0, 0]))


def test_stuffing_example():
    assert p.stuff(bytes.fromhex("ffff fd")) == bytes.fromhex("ffff fdfd")
    assert p.stuff(bytes.fromhex("ffff fdfd")) == bytes.fromhex("ffff fdfd fd")
    assert p.unstuff(bytes.fromhex("ffff fdfd")) == bytes.fromhex("ffff fd")


hdr_rich = st.lists(st.sampled_from([0xFF, 0xFD, 0x00, 0x55, 0xFE]) | st.integers(0, 255), max_size=64).map(bytes)


@given(hdr_rich)
def test_stuffing_round_trip_and_no_header_inside(body):
    s = p.stuff(body)
    assert p.unstuff(s) == body
    for i in range(len(s) - 3):
        if s[i : i + 3] == b"\xff\xff\xfd":
            assert s[i + 3] == 0xFD  # never a header (FF FF FD 00) inside a body


packets = st.tuples(st.integers(0, 0xFC) | st.just(0xFE), st.sampled_from(list(t.Instruction)), hdr_rich).map(
    lambda a: (a[0], int(a[1]), a[2])
)


@settings(max_examples=200)
@given(st.lists(packets, min_size=1, max_size=6), st.data())
def test_parser_on_random_splits(items, data):
    stream = b"".join(p.instruction_packet(i, ins, prm) for i, ins, prm in items)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    parser = p.Parser()
    got = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)]):
        got.extend(parser.feed(stream[a:b]))
    assert [(g.packet_id, g.instruction, g.params) for g in got] == items
    assert sum(g.wire_bytes for g in got) == len(stream) and parser.pending == 0


def test_bad_crc_is_reported_and_the_next_packet_still_parses():
    good = p.instruction_packet(2, t.Instruction.PING)
    bad = p.corrupt_crc(p.instruction_packet(1, t.Instruction.PING))
    out = list(p.Parser().feed(b"\x00\x13" + bad + good))
    assert [type(o).__name__ for o in out] == ["FramingError", "FramingError", "InstructionPacket"]
    assert out[0].kind == "noise" and out[1].kind == "crc" and out[2].packet_id == 2


def _bus(**servo):
    cfg = BusConfig.from_dict(
        {
            "time": {"mode": "lockstep"},
            "physics": {"kind": "inertia", "joints": [{"name": "j", "inertia_kg_m2": 0.01}]},
            "servos": [{"id": 1, "model": "XM430-W350", "joint": "j", **servo}],
        }
    )
    return Bus(cfg)


def _status(bus, ins, params=b"", pid=1):
    replies = bus.handle(p.Parser().feed(p.instruction_packet(pid, ins, params)).__next__(), 0.0)
    return [p.parse_status(r.data) for r in replies]


def test_servo_write_rules():
    bus = _bus(registers={"operating_mode": 0})
    w = t.Instruction.WRITE
    (r,) = _status(bus, w, bytes([t.ADDR_TORQUE_ENABLE, 0, 1]))
    assert r.error == 0
    (r,) = _status(bus, w, bytes([t.ADDR_CURRENT_LIMIT, 0, 10, 0]))
    assert r.error == t.StatusError.ACCESS  # EEPROM with torque on
    (r,) = _status(bus, w, bytes([t.ADDR_GOAL_CURRENT, 0]) + (1194).to_bytes(2, "little"))
    assert r.error == t.StatusError.DATA_RANGE  # beyond Current Limit 1193
    (r,) = _status(bus, w, bytes([t.ADDR_GOAL_CURRENT, 0, 5]))
    assert r.error == t.StatusError.DATA_LENGTH  # one byte of a two-byte field
    (r,) = _status(bus, w, bytes([t.ADDR_PRESENT_POSITION, 0, 0, 0, 0, 0]))
    assert r.error == t.StatusError.ACCESS  # read-only
    (r,) = _status(bus, w, bytes([66, 0, 1]))
    assert r.error == t.StatusError.ACCESS  # a gap of the table
    (r,) = _status(bus, t.Instruction.READ, bytes([t.ADDR_GOAL_CURRENT, 0, 2, 0]))
    assert r.error == 0 and r.params == b"\x00\x00"  # the refused writes changed nothing


def test_fast_sync_read_layout_is_what_the_reader_walks():
    slots = [p.FastSlot(1, 0, b"\x01\x02"), p.FastSlot(2, 0x80, b"\x03\x04")]
    pkt = p.fast_sync_read_status(slots)
    length = pkt[5] | (pkt[6] << 8)
    assert pkt[4] == 0xFE and len(pkt) == 7 + length and pkt[7] == 0x55
    body = pkt[8:]
    assert body[0:4] == b"\x00\x01\x01\x02" and body[6:10] == b"\x80\x02\x03\x04"
    assert p.crc16(pkt[:-2]) == pkt[-2] | (pkt[-1] << 8)  # the last slot's CRC is the packet's
    assert p.crc16(pkt[:12]) == pkt[12] | (pkt[13] << 8)  # the first slot's CRC: the running CRC
    short = p.fast_sync_read_status(slots[:1], declared=2)
    assert short[5] | (short[6] << 8) == length and len(short) < len(pkt)  # stops short


def test_config_errors_name_the_key():
    base = {"physics": {"kind": "inertia", "joints": [{"name": "j", "inertia_kg_m2": 0.01}]}}
    for servos, key in [
        ([{"id": 1, "model": "XM999", "joint": "j"}], "servos[0].model"),
        ([{"id": 1, "model": "XM430-W350", "joint": "k"}], "servos[0].joint"),
        ([{"id": 1, "model": "XM430-W350", "joint": "j", "registers": {"goal_current": 1}}], "goal_current"),
        ([{"id": 1, "model": "XM430-W350", "joint": "j", "registers": {"return_delay_time": 300}}], "return_delay"),
        ([{"id": 1, "model": "XM430-W350", "joint": "j"}, {"id": 1, "model": "XM430-W350", "joint": "j"}], "[1].id"),
    ]:
        with pytest.raises(ConfigError, match=key.replace("[", r"\[").replace("]", r"\]")):
            BusConfig.from_dict({**base, "servos": servos})
    with pytest.raises(ConfigError, match="baud_bps"):
        BusConfig.from_dict({**base, "baud_bps": 250000, "servos": [{"id": 1, "model": "XM430-W350", "joint": "j"}]})
    cfg = BusConfig.from_dict({**base, "servos": [{"id": 3, "model": "XM430-W350", "joint": "j", "sign": -1}]})
    assert BusConfig.from_json(cfg.to_json()) == cfg


def test_the_documented_example_config_builds():
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "dynamixel.md").read_text()
    example = re.search(r"```json\n(.*?)```", text, re.S)
    assert example is not None
    bus = Bus(BusConfig.from_json(example.group(1)))
    assert bus.physics.joints == ("base_yaw", "shoulder", "elbow") and [s.id for s in bus.servos] == [1, 2, 3]


def test_a_fault_scheduled_by_emulator_time_fires_when_lockstep_time_reaches_it():
    cfg = BusConfig.from_dict(
        {
            "time": {"mode": "lockstep", "lockstep_dt_s": 0.01},
            "physics": {"kind": "inertia", "joints": [{"name": "j", "inertia_kg_m2": 0.01}]},
            "servos": [{"id": 1, "model": "XM430-W350", "joint": "j", "registers": {"operating_mode": 0}}],
            "faults": [{"servo_id": 1, "kind": "hardware_error", "bits": 4, "at_time_s": 0.05}],
        }
    )
    bus = Bus(cfg)
    write_goal = bytes([t.ADDR_GOAL_CURRENT, 0, 1, 0])
    errors = [_status(bus, t.Instruction.WRITE, write_goal)[0].error for _ in range(8)]
    # five writes take lockstep time to 0.05 s; the sixth instruction finds the fault due
    assert errors == [0] * 5 + [t.ALERT_BIT] * 3
    assert bus.servos[0].get("hardware_error_status") == 4 and bus.time_s == pytest.approx(0.08)
