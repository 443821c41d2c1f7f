"""Bags: what is written reads back; bulk and parallel writing give the same bytes as rosbags' API."""

import filecmp
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from haptic_teleop.bag import BagReader, FixedLayout, make_joint_state, topic_specs, typestore, write_run
from haptic_teleop.engine import Engine
from haptic_teleop.errors import BagError
from haptic_teleop.scene import find_scene, load_scene


@pytest.fixture(scope="module")
def short_run():
    scene = load_scene(
        find_scene("wall_contact"), overrides=["scene.duration_s=2.5", "network.forward.effects.loss.probability=0.05"]
    )
    return Engine(scene).run(handle_sigint=False)


def _same_tree(a: Path, b: Path) -> bool:
    fa = sorted(p.name for p in a.iterdir())
    fb = sorted(p.name for p in b.iterdir())
    if [n.replace(a.name, "") for n in fa] != [n.replace(b.name, "") for n in fb]:
        return False
    return all(filecmp.cmp(a / x, b / y, shallow=False) for x, y in zip(fa, fb, strict=True))


def test_bulk_and_parallel_writes_equal_the_plain_api(tmp_path, short_run):
    """The fast paths must produce exactly what rosbags' message-by-message writer produces."""
    plain = write_run(short_run, tmp_path / "bag", {"k": 1}, bulk=False)
    bulk_dir = tmp_path / "b" / "bag"
    bulk_dir.parent.mkdir()
    write_run(short_run, bulk_dir, {"k": 1}, bulk=True)
    par_dir = tmp_path / "c" / "bag"
    par_dir.parent.mkdir()
    write_run(short_run, par_dir, {"k": 1}, bulk=True, parallel=True)
    assert filecmp.cmp(plain / "bag.mcap", bulk_dir / "bag.mcap", shallow=False)
    assert filecmp.cmp(plain / "bag.mcap", par_dir / "bag.mcap", shallow=False)
    assert (plain / "metadata.yaml").read_text() == (bulk_dir / "metadata.yaml").read_text()


def test_roundtrip_every_topic(tmp_path, short_run):
    from haptic_teleop.engine import COL

    bag = write_run(short_run, tmp_path / "bag", {"ticks": short_run.ticks})
    n = short_run.ticks
    d = short_run.data[:n]
    with BagReader(bag) as r:
        m = r.read("/master/joint_states")
        assert np.array_equal(m.values[:, 0], d[:, COL["m_x_m"]])
        assert np.array_equal(m.values[:, 2], d[:, COL["m_force_n"]])
        assert np.array_equal(m.stamp_ns, np.arange(n) * short_run.period_ns)
        c = r.read("/slave/contact_wrench")
        assert np.array_equal(c.values[:, 0], d[:, COL["s_contact_n"]])
        e = r.read("/slave/eba")
        assert np.array_equal(e.values[:, 0], d[:, COL["s_energy_j"]])
        rx = r.read("/forward/received")
        seq = d[:, COL["fwd_rx_seq"]]
        assert len(rx.log_ns) == int(np.count_nonzero(seq >= 0))
        # The received sample carries the send stamp and the values that were sent at that tick.
        src = (rx.stamp_ns // short_run.period_ns).astype(int)
        assert np.array_equal(rx.values[:, 0], d[src, COL["m_x_m"]])
        assert np.all(rx.log_ns - rx.stamp_ns >= 50_000_000)
        pk = r.packets("/forward/packets")
        assert pk.shape[0] == len(short_run.forward_log)
        assert int(np.count_nonzero(pk[:, 3] == 1)) == short_run_lost(short_run)
    # Every message deserializes with rosbags' own reader as a standard type.
    ts = typestore()
    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, _, raw in reader.messages():
            ts.deserialize_cdr(raw, conn.msgtype)
    assert types["/master/joint_states"] == "sensor_msgs/msg/JointState"
    assert types["/slave/contact_wrench"] == "geometry_msgs/msg/WrenchStamped"


def short_run_lost(run) -> int:
    return sum(1 for p in run.forward_log if p.fate == 1 and not p.duplicate)


def test_fixed_layout_matches_full_serialization():
    ts = typestore()
    lay = FixedLayout("sensor_msgs/msg/JointState", make_joint_state("j", ("position", "velocity")), 2)
    vals = np.array([[1.5, -2.25], [3.0, 4.0]])
    stamps = np.array([1_500_000_001, 7], dtype=np.int64)
    rows = lay.encode(vals, stamps)
    for i in range(2):
        msg = ts.deserialize_cdr(rows[i].tobytes(), "sensor_msgs/msg/JointState")
        assert list(msg.position) == [vals[i, 0]]
        assert list(msg.velocity) == [vals[i, 1]]
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stamps[i]
    back, st = lay.decode(rows)
    assert np.array_equal(back, vals) and np.array_equal(st, stamps)


def test_reader_falls_back_for_other_layouts(tmp_path):
    """A bag from another tool (different joint name length) is decoded message by message."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = typestore()
    make = make_joint_state("a_much_longer_joint_name", ("position", "velocity", "effort"))
    with Writer(tmp_path / "other", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/master/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        for i in range(5):
            w.write(
                c, i * 1000, bytes(ts.serialize_cdr(make([i, 2 * i, 3 * i], 0, i * 1000), "sensor_msgs/msg/JointState"))
            )
    assert topic_specs()["/master/joint_states"].layout.size != len(
        ts.serialize_cdr(make([0, 0, 0], 0, 0), "sensor_msgs/msg/JointState")
    )
    with BagReader(tmp_path / "other") as r:
        d = r.read("/master/joint_states")
    assert d.values[:, 1].tolist() == [0, 2, 4, 6, 8]
    assert d.stamp_ns.tolist() == [0, 1000, 2000, 3000, 4000]


def test_bag_errors(tmp_path, short_run):
    with pytest.raises(BagError, match="no such bag"):
        BagReader(tmp_path / "missing")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "metadata.yaml").write_text("not: a bag\n")
    with pytest.raises(BagError, match="not a readable rosbag2"):
        BagReader(tmp_path / "junk")
    bag = write_run(short_run, tmp_path / "bag", {})
    with BagReader(bag) as r, pytest.raises(BagError, match="topic /nope is missing"):
        r.string("/nope")
    with pytest.raises(BagError, match="exists already"):
        write_run(short_run, tmp_path / "bag", {})


def test_packet_rows_equal_packet_by_packet_conversion():
    """The vectorised packet records equal converting each packet on its own (the previous code),
    for every fate: arrival NaN unless delivered or late, duplicates flagged, times in seconds."""
    from haptic_teleop.bag import PACKET_FIELDS, _packet_rows
    from haptic_teleop.core.network import Packet

    rng = np.random.default_rng(5)
    log = []
    for i in range(500):
        send = int(rng.integers(0, 10**11))  # up to 100 s: rounding of ns -> s matters
        p = Packet(i, send, (0.0,), int(rng.integers(50, 200)), arrival_time_ns=send + int(rng.integers(0, 10**9)))
        p.fate = int(rng.integers(0, 5))
        p.duplicate = bool(rng.integers(0, 2))
        log.append(p)
    expected = np.empty((len(log), len(PACKET_FIELDS)))
    for i, p in enumerate(log):
        expected[i] = (
            p.seq,
            p.send_time_ns * 1e-9,
            p.arrival_time_ns * 1e-9 if p.fate in {0, 4} else np.nan,
            p.fate,
            1.0 if p.duplicate else 0.0,
            p.size_bytes,
        )
    rows = _packet_rows(log)
    assert rows.shape == expected.shape
    assert np.array_equal(rows, expected, equal_nan=True)
    assert {int(f) for f in rows[:, 3]} == {0, 1, 2, 3, 4}
    assert _packet_rows([]).shape == (0, len(PACKET_FIELDS))


def test_bulk_message_index_spans_chunks(tmp_path, short_run):
    """The bulk writer keeps the per-chunk message index itself; a bag of several chunks reads
    back every message of every topic in order (rosbags reads through that index)."""
    bag = write_run(short_run, tmp_path / "bag", {})
    with Reader(bag) as r:
        counts = {c.topic: 0 for c in r.connections}
        last = {}
        for conn, t, _ in r.messages():
            counts[conn.topic] += 1
            assert t >= last.get(conn.topic, 0)
            last[conn.topic] = t
        size = (bag / "bag.mcap").stat().st_size
    assert size > 3 * 2**20  # more than three chunks of 1 MiB
    assert counts["/master/joint_states"] == short_run.ticks
    assert counts["/forward/received"] == int(np.count_nonzero(short_run.column("fwd_rx_seq") >= 0))
