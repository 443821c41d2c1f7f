"""Bags carry their integrity: CRCs detect a flipped byte, damage gets one clear line, `bag recover`
rebuilds a cut bag from exactly its complete chunks, `bag info` reports it all."""

import io
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from haptic_teleop.engine.lockstep import COL, COLUMNS
from haptic_teleop.errors import BagError
from haptic_teleop.record.layouts import PACKET_FIELDS
from haptic_teleop.record.reader import BagReader
from haptic_teleop.record.recorder import RunRecorder
from haptic_teleop.record.tools import recover

MAGIC = b"\x89MCAP0\r\n"


def _write(bag: Path, ticks: int = 3000, compression: str = "none") -> Path:
    rows = np.zeros((ticks, len(COLUMNS)))
    t = np.arange(ticks, dtype=np.float64)
    for j in range(len(COLUMNS)):
        rows[:, j] = np.sin(t * 1e-2 + j)
    rows[:, COL["fwd_rx_seq"]] = np.where(t >= 20, t - 20, -1)
    rows[:, COL["bwd_rx_seq"]] = np.where(t >= 30, t - 30, -1)
    rec = RunRecorder(bag, "scene: {}\n", 1_000_000, True, True, len(COLUMNS), parallel=False, compression=compression)
    for a in range(0, ticks, 1000):
        rec.append(rows[a : a + 1000])
        pk = np.zeros((1000, len(PACKET_FIELDS)))
        pk[:, 0] = np.arange(a, a + 1000)
        rec.append_packets("forward", pk)
    return rec.close({"ticks": ticks})


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory) -> Path:
    return _write(tmp_path_factory.mktemp("good") / "bag")


def _mcap(bag: Path) -> Path:
    (p,) = bag.glob("*.mcap")
    return p


def _copy(bag: Path, dst: Path) -> Path:
    shutil.copytree(bag, dst)
    return dst


def _mcap_stream_ok(path: Path) -> Exception | None:
    """mcap's stream reader with CRC validation over the whole file (chunks and data section)."""
    from mcap.stream_reader import StreamReader

    try:
        with open(path, "rb") as f:
            for _ in StreamReader(f, validate_crcs=True).records:
                pass
    except Exception as exc:  # noqa: BLE001 - which error mcap raises is its business
        return exc
    return None


def _mcap_seek_ok(path: Path) -> Exception | None:
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            reader = make_reader(f, validate_crcs=True)
            for _ in reader.iter_messages():
                pass
    except Exception as exc:  # noqa: BLE001
        return exc
    return None


def _read_all(bag: Path) -> None:
    with BagReader(bag) as r:
        for topic in r.topics:
            if topic.endswith("packets"):
                r.packets(topic)
            elif topic.startswith("/haptic_teleop"):
                list(r._raw(topic))  # a recovered bag may lack the run facts
            else:
                r.read(topic)


def _chunk_offsets(path: Path) -> list[tuple[int, int]]:
    """(offset, length) of each chunk record, from mcap's own reading of the summary."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [(c.chunk_start_offset, c.chunk_length) for c in make_reader(f).get_summary().chunk_indexes]


def test_a_flipped_byte_in_a_chunk_is_detected(tmp_path, good_bag):
    assert _mcap_seek_ok(_mcap(good_bag)) is None and _mcap_stream_ok(_mcap(good_bag)) is None
    bag = _copy(good_bag, tmp_path / "bag")
    chunks = _chunk_offsets(_mcap(bag))
    off, length = chunks[1]
    data = bytearray(_mcap(bag).read_bytes())
    data[off + length // 2] ^= 0x01  # inside a message of the second chunk
    _mcap(bag).write_bytes(bytes(data))
    assert "crc" in str(_mcap_seek_ok(_mcap(bag))).lower()
    assert "crc" in str(_mcap_stream_ok(_mcap(bag))).lower()
    n = len(chunks)
    with pytest.raises(BagError, match=rf"chunk 2 of {n} \(byte {off}\) is damaged \(CRC mismatch\).*bag recover"):
        _read_all(bag)
    out = recover(bag)
    assert out.chunks == n - 1 and len(out.damaged) == 1
    _read_all(bag)  # what is left reads


def test_a_flipped_byte_in_the_summary_or_data_section_is_detected(tmp_path, good_bag):
    """Summary: BagReader refuses it (CRC mismatch); mcap's Python reader (1.6) does not check the
    summary CRC. Data section outside chunks (a schema): mcap's stream reader and `bag info` see it."""
    from mcap.records import SummaryOffset
    from mcap.stream_reader import StreamReader

    bag = _copy(good_bag, tmp_path / "s")
    with open(_mcap(bag), "rb") as f:
        offsets = [r for r in StreamReader(f).records if isinstance(r, SummaryOffset)]
    stats_at = next(o.group_start for o in offsets if o.group_opcode == 0x0B)
    data = bytearray(_mcap(bag).read_bytes())
    data[stats_at + 9 + 5] ^= 0x01  # a high byte of the message count: still parses
    _mcap(bag).write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"has a damaged summary section \(CRC mismatch\): `haptic-teleop bag recover"):
        BagReader(bag)
    assert recover(bag).chunks == len(_chunk_offsets(_mcap(good_bag)))
    _read_all(bag)

    bag = _copy(good_bag, tmp_path / "d")
    data = bytearray(_mcap(bag).read_bytes())
    data[60] ^= 0x01  # inside the first schema record (data section, outside any chunk)
    _mcap(bag).write_bytes(bytes(data))
    assert "DataEnd" in str(_mcap_stream_ok(_mcap(bag)))
    text, sound = __import__("haptic_teleop.record.tools", fromlist=["info"]).info(bag)
    assert not sound and "the data section's CRC does not match" in text


def test_damage_is_named_in_one_line(tmp_path, good_bag):
    killed = _copy(good_bag, tmp_path / "killed")
    (killed / "metadata.yaml").unlink()
    n = len(_chunk_offsets(_mcap(killed)))
    with pytest.raises(BagError) as e:
        BagReader(killed)
    assert str(e.value) == (
        f"{killed}/ has no metadata.yaml (the run was killed before the bag was closed?): "
        f"`haptic-teleop bag recover {killed}` rebuilds it from its {n} complete chunks, 3.000 s of messages"
    )
    cut = _copy(good_bag, tmp_path / "cut")
    data = _mcap(cut).read_bytes()
    off, _ = _chunk_offsets(_mcap(cut))[2]
    _mcap(cut).write_bytes(data[: off + 100])
    with pytest.raises(BagError, match=r"is truncated .*rebuilds it from its 2 complete chunks, \d\.\d+ s of messages"):
        BagReader(cut)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BagError, match="not a rosbag2 directory"):
        BagReader(empty)
    assert "\n" not in str(e.value)


def _messages_of_chunk(data: bytes, off: int, length: int, topics: dict[int, str]) -> list[tuple[str, int, bytes]]:
    """The messages of one chunk record, parsed by mcap's stream reader."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    recs = StreamReader(io.BytesIO(MAGIC + data[off : off + length]), skip_magic=False).records
    out = []
    try:
        for r in recs:
            if isinstance(r, Message):
                out.append((topics[r.channel_id], r.log_time, bytes(r.data)))
    except Exception:  # noqa: BLE001 - the end of this one-chunk stream (no footer)
        pass
    return out


class _Source:
    def __init__(self, data, chunks, per_chunk):
        self.data, self.chunks, self.per_chunk = data, chunks, per_chunk

    def __repr__(self) -> str:
        return f"<bag of {len(self.data)} bytes>"


@pytest.fixture(scope="module")
def cut_source(tmp_path_factory):
    from mcap.reader import make_reader

    bag = _write(tmp_path_factory.mktemp("src") / "bag", ticks=2500)
    path = _mcap(bag)
    data = path.read_bytes()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    topics = {c.id: c.topic for c in summary.channels.values()}
    chunks = [(c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes]
    per_chunk = [_messages_of_chunk(data, o, n, topics) for o, n in chunks]
    return _Source(data, chunks, per_chunk)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.floats(0.0, 1.0))
def test_recover_keeps_exactly_the_complete_chunks(tmp_path_factory, cut_source, where):
    """A bag cut at any byte: recover fails with BagError only (a cut inside the header), else the
    recovered bag reads (ours, rosbags, mcap validating) and holds exactly the complete chunks' messages."""
    from mcap.reader import make_reader
    from rosbags.rosbag2 import Reader

    data, chunks, per_chunk = cut_source.data, cut_source.chunks, cut_source.per_chunk
    cut = int(where * len(data))
    work = tmp_path_factory.mktemp("cut") / "bag"
    work.mkdir()
    (work / "bag.mcap").write_bytes(data[:cut])
    try:
        out = recover(work)
    except BagError:
        assert cut < 8 + 9 + 30, cut  # only a file cut inside its magic or header is hopeless
        return
    complete = [i for i, (o, n) in enumerate(chunks) if o + n <= cut]
    expected = sorted(m for i in complete for m in per_chunk[i])
    assert out.chunks == len(complete)
    with open(work / "bag.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        got = sorted((ch.topic, m.log_time, bytes(m.data)) for _, ch, m in reader.iter_messages())
    assert got == expected
    with Reader(work) as r:  # rosbags opens it through metadata.yaml
        assert r.message_count == len(expected)
    with BagReader(work) as r:
        n = len(r.read("/master/joint_states").log_ns) if r.has("/master/joint_states") else 0
    assert n == sum(1 for m in expected if m[0] == "/master/joint_states")


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "haptic_teleop.cli", *args], capture_output=True, text=True, timeout=300
    )


def test_bag_cli(tmp_path, good_bag):
    ok = _cli("bag", "info", str(good_bag))
    assert ok.returncode == 0, ok.stderr
    assert "Integrity:         ok (4 chunk CRCs, data section CRC, summary CRC)" in ok.stdout
    assert "Topic: /master/joint_states | Type: sensor_msgs/msg/JointState | Count: 3000 |" in ok.stdout
    assert "QoS: best_effort, keep_last 1, volatile" in ok.stdout
    cut = _copy(good_bag, tmp_path / "cut")
    (cut / "metadata.yaml").unlink()
    data = _mcap(cut).read_bytes()
    _mcap(cut).write_bytes(data[: len(data) // 2])
    bad = _cli("bag", "info", str(cut))
    assert bad.returncode == 1 and "DAMAGED" in bad.stdout and "bag recover" in bad.stdout
    rec = _cli("bag", "recover", str(cut))
    assert rec.returncode == 0, rec.stderr
    assert "recovered 1 chunks" in rec.stdout and "dropped the" in rec.stdout
    assert _cli("bag", "info", str(cut)).returncode == 0
    again = _cli("bag", "recover", str(cut))
    assert "nothing to recover" in again.stdout
    # A bag written without CRCs (rosbags' writer): nothing to check, said so.
    from rosbags.rosbag2 import StoragePlugin, Writer

    from haptic_teleop.record.layouts import typestore

    ts = typestore()
    with Writer(tmp_path / "other", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/a", "std_msgs/msg/String", typestore=ts)
        w.write(c, 5, bytes(ts.serialize_cdr(ts.types["std_msgs/msg/String"](data="x"), "std_msgs/msg/String")))
    other = _cli("bag", "info", str(tmp_path / "other"))
    assert other.returncode == 0 and "Integrity:         ok (structure only: the file carries no CRCs)" in other.stdout
    for args in (("info", str(tmp_path / "nope")), ("recover", str(tmp_path))):
        r = _cli("bag", *args)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr


def test_compressed_bags_recover(tmp_path):
    for comp in ("zstd", "lz4"):
        bag = _write(tmp_path / comp / "bag", ticks=6000, compression=comp)
        data = _mcap(bag).read_bytes()
        (bag / "metadata.yaml").unlink()
        _mcap(bag).write_bytes(data[: int(len(data) * 0.7)])
        out = recover(bag)
        assert out.chunks >= 1
        with BagReader(bag) as r:
            assert len(r.read("/master/joint_states").log_ns) > 0
        struct.calcsize("<Q")


def test_a_killed_runs_bag_analyses_after_recover(tmp_path):
    """The data path end to end: a real run's bag cut where a kill would leave it (no summary
    section, no metadata.yaml, run facts never written), `bag recover`, then `analyze`: the
    summary holds the recovered ticks and says the run was interrupted."""
    import json

    from haptic_teleop.cli.main import main

    run = tmp_path / "run"
    assert main(["run", "wall_contact", "--set", "scene.duration_s=3", "--out", str(run), "--no-plots", "--quiet"]) == 0
    cut = _copy(run / "bag", tmp_path / "cut")
    path = _mcap(cut)
    path.write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])
    (cut / "metadata.yaml").unlink()
    assert _cli("analyze", str(cut), "--no-plots").returncode == 2  # names the damage and the fix
    assert _cli("bag", "recover", str(cut)).returncode == 0
    r = _cli("analyze", str(cut), "--out", str(tmp_path / "an"), "--no-plots")
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "an" / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert 0 < summary["ticks"] < 3000
