"""Bags: what is written reads back, through this package's reader, rosbags' and mcap's validating reader;
in process and with the writer process the same calls give the same bytes."""

import filecmp
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.errors import BagError
from haptic_teleop.record.layouts import PACKET_FIELDS, FixedLayout, make_joint_state, topic_specs, typestore
from haptic_teleop.record.reader import BagReader
from haptic_teleop.record.recorder import RunRecorder, write_run
from haptic_teleop.record.streams import BLOCK_TICKS
from haptic_teleop.scene.load import find_scene, load_scene


@pytest.fixture(scope="module")
def short_run():
    scene = load_scene(
        find_scene("wall_contact"), overrides=["scene.duration_s=2.5", "network.forward.effects.loss.probability=0.05"]
    )
    return Engine(scene).run(handle_sigint=False)


@pytest.fixture(scope="module")
def clean_run():
    """No loss: after the first delay every tick releases a sample both ways (the bulk writer's usual block)."""
    return Engine(load_scene(find_scene("wall_contact"), overrides=["scene.duration_s=2.5"])).run(handle_sigint=False)


def _same_tree(a: Path, b: Path) -> bool:
    fa = sorted(p.name for p in a.iterdir())
    fb = sorted(p.name for p in b.iterdir())
    if [n.replace(a.name, "") for n in fa] != [n.replace(b.name, "") for n in fb]:
        return False
    return all(filecmp.cmp(a / x, b / y, shallow=False) for x, y in zip(fa, fb, strict=True))


def _all_messages_rosbags(bag: Path) -> list[tuple[str, int, bytes]]:
    with Reader(bag) as r:
        return [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]


def _all_messages_mcap(bag: Path) -> list[tuple[str, int, bytes]]:
    """Every message through mcap's reader with CRC validation (chunks, data section, summary)."""
    from mcap.reader import make_reader

    (path,) = bag.glob("*.mcap")
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        out = [(ch.topic, m.log_time, bytes(m.data)) for _, ch, m in reader.iter_messages(log_time_order=False)]
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == len(out)
    return out


@pytest.mark.parametrize("compression", ["none", "zstd", "lz4"])
def test_other_readers_read_every_message(tmp_path, short_run, compression):
    """rosbags' Reader and mcap's validating reader read every message of our bags, equal to what
    BagReader decodes; parallel and in process give the same bytes; compression changes the file,
    not the messages."""
    from haptic_teleop.engine.lockstep import COL

    (tmp_path / "b").mkdir()
    inproc = write_run(short_run, tmp_path / "bag", {"k": 1}, compression=compression)
    par = write_run(short_run, tmp_path / "b" / "bag", {"k": 1}, parallel=True, compression=compression)
    assert _same_tree(inproc, par)
    ros = _all_messages_rosbags(inproc)
    mc = _all_messages_mcap(inproc)
    assert sorted(ros, key=lambda m: (m[0], m[1])) == sorted(mc, key=lambda m: (m[0], m[1]))
    ts = typestore()
    master = [m for m in ros if m[0] == "/master/joint_states"]
    assert len(master) == short_run.ticks
    for topic, t, raw in master[:: max(1, len(master) // 50)]:
        msg = ts.deserialize_cdr(raw, "sensor_msgs/msg/JointState")
        assert msg.position[0] == short_run.data[t // short_run.period_ns, COL["m_x_m"]]
    # BagReader (through the message indexes) decodes the same messages the others read in full.
    with BagReader(inproc) as r:
        for topic in ("/master/joint_states", "/backward/received", "/slave/eba"):
            theirs = [m for m in ros if m[0] == topic]
            d = r.read(topic)
            assert d.log_ns.tolist() == [m[1] for m in theirs]
            spec = topic_specs()[topic]
            assert np.array_equal(d.values, spec.layout.decode(np.array([list(m[2]) for m in theirs], np.uint8))[0])
    from mcap.reader import make_reader

    with open(next(inproc.glob("*.mcap")), "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert {c.compression for c in chunks} == {"" if compression == "none" else compression}
    assert all((c.compressed_size < c.uncompressed_size) == (compression != "none") for c in chunks)


def test_roundtrip_every_topic(tmp_path, short_run):
    from haptic_teleop.engine.lockstep import COL

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
    log = run.forward_log  # the link's packets, or their records (bag rows) from the compiled loop
    if isinstance(log, np.ndarray):
        return int(np.count_nonzero((log[:, 3] == 1) & (log[:, 4] == 0)))
    return sum(1 for p in log if p.fate == 1 and not p.duplicate)


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


def test_reader_reads_sqlite3_bags_of_other_tools(tmp_path):
    """A rosbag2 bag in sqlite3 storage (another tool's) is read through rosbags' Reader."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = typestore()
    make = make_joint_state("master_x", ("position", "velocity", "effort"))
    with Writer(tmp_path / "db", version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        c = w.add_connection("/master/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        for i in range(4):
            raw = ts.serialize_cdr(make([i, -i, 2 * i], 0, i * 1000), "sensor_msgs/msg/JointState")
            w.write(c, i * 1000, bytes(raw))
    assert list((tmp_path / "db").glob("*.db3"))
    with BagReader(tmp_path / "db") as r:
        d = r.read("/master/joint_states")
    assert d.values[:, 2].tolist() == [0, 2, 4, 6] and d.log_ns.tolist() == [0, 1000, 2000, 3000]


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
    from haptic_teleop.core.link import Packet
    from haptic_teleop.record.layouts import PACKET_FIELDS
    from haptic_teleop.record.layouts import packet_rows as _packet_rows

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


def _record(run, bag_dir: Path, eba: bool, packets: bool, parallel: bool = False, logs=None) -> Path:
    """Record a finished run through RunRecorder as the engine does (blocks, then finish)."""
    from haptic_teleop.engine.lockstep import COLUMNS

    rec = RunRecorder(bag_dir, run.scene.to_yaml(), run.period_ns, eba, packets, len(COLUMNS), parallel=parallel)
    for stop in range(BLOCK_TICKS, run.ticks, BLOCK_TICKS):
        rec.block(run.data, stop)
    fwd, bwd = logs if logs is not None else (run.forward_log, run.backward_log)
    return rec.finish(run.data, run.ticks, fwd, bwd, {"k": 1})


@pytest.mark.parametrize(("eba", "packets"), [(True, True), (False, False), (True, False)])
def test_every_topic_set_and_block_shape_reads_back(tmp_path, clean_run, short_run, eba, packets):
    """Every block shape (ticks releasing nothing, one or both directions, a lossy link) and topic
    set: in process and parallel give the same bytes, and rosbags reads the same messages."""
    for name, run in (("clean", clean_run), ("lossy", short_run)):
        dirs = {}
        for mode in ("inproc", "parallel"):
            (tmp_path / name / mode).mkdir(parents=True)
            dirs[mode] = _record(run, tmp_path / name / mode / "bag", eba, packets, parallel=mode == "parallel")
        assert _same_tree(dirs["inproc"], dirs["parallel"]), name
        ros = _all_messages_rosbags(dirs["inproc"])
        assert sorted(ros) == sorted(_all_messages_mcap(dirs["inproc"]))
        with BagReader(dirs["inproc"]) as r:
            assert r.has("/master/eba") == eba and r.has("/forward/packets") == packets
            rx = r.read("/backward/received")
        assert len(rx.log_ns) == int(np.count_nonzero(run.column("bwd_rx_seq") >= 0))
        assert sum(1 for m in ros if m[0] == "/backward/received") == len(rx.log_ns)


def test_finish_takes_packet_records_as_arrays(tmp_path, short_run):
    """finish() takes each packet log as a link's Packet list or as ready records (a float64
    array in _packet_rows' format, used as is): the same bag either way; a wrong array is refused."""
    from haptic_teleop.core.link import Packet
    from haptic_teleop.record.layouts import packet_rows as _packet_rows

    rng = np.random.default_rng(11)
    logs = []
    for direction in range(2):
        log = []
        for i in range(2300 + direction):
            send = i * 1_000_000
            p = Packet(i, send, (0.0,), 120, arrival_time_ns=send + int(rng.integers(10**7, 10**8)))
            p.fate = int(rng.integers(0, 5))
            p.duplicate = bool(rng.integers(0, 2))
            log.append(p)
        logs.append(log)
    arrays = tuple(_packet_rows(log) for log in logs)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    from_lists = _record(short_run, tmp_path / "a" / "bag", True, True, logs=logs)
    from_arrays = _record(short_run, tmp_path / "b" / "bag", True, True, logs=arrays)
    assert _same_tree(from_lists, from_arrays)
    with BagReader(from_arrays) as r:
        assert np.array_equal(r.packets("/backward/packets"), arrays[1], equal_nan=True)
    assert _packet_rows(arrays[0]) is arrays[0]  # used as is, no copy
    for bad in (arrays[0][:, :5], arrays[0].astype(np.float32), arrays[0].ravel()):
        with pytest.raises(BagError, match="packet records must be a float64 array"):
            _packet_rows(bad)
    # A wrong log still leaves a closed, readable bag (in process and with the writer process).
    for parallel in (False, True):
        (tmp_path / f"bad{parallel}").mkdir()
        with pytest.raises(BagError, match="packet records must be a float64 array"):
            _record(
                short_run,
                tmp_path / f"bad{parallel}" / "bag",
                True,
                True,
                parallel,
                (arrays[0], arrays[1][:, :2]),
            )
        with BagReader(tmp_path / f"bad{parallel}" / "bag") as r:
            assert len(r.read("/master/joint_states").log_ns) == short_run.ticks
            assert r.packets("/forward/packets").shape == (0, len(PACKET_FIELDS))


def test_packet_batches_equal_rosbags_serialization():
    from haptic_teleop.record.layouts import multiarray_bytes as _multiarray_bytes
    from haptic_teleop.record.layouts import packet_batch_bytes as _packet_batch_bytes

    rng = np.random.default_rng(2)
    for n in (1, 2, 7, 999, 1000):
        rows = rng.normal(size=(n, len(PACKET_FIELDS)))
        rows[::3, 2] = np.nan
        assert _packet_batch_bytes(rows) == _multiarray_bytes(rows)
        assert _packet_batch_bytes(rows[::-1]) == _multiarray_bytes(np.ascontiguousarray(rows[::-1]))


def _ruamel_dump(data) -> str:
    from io import StringIO

    from ruamel.yaml import YAML

    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    out = StringIO()
    yaml.dump(data, out)
    return out.getvalue()


def test_metadata_text_equals_ruamel_on_a_real_bag(tmp_path, short_run):
    """A run's metadata.yaml, read back and written again by ruamel: the same text (the emitter
    writes what ruamel would), and _yaml_block writes it itself (no fallback)."""
    from ruamel.yaml import YAML

    from haptic_teleop.record.metadata import yaml_block as _yaml_block

    bag = write_run(short_run, tmp_path / "bag", {})
    text = (bag / "metadata.yaml").read_text()
    data = YAML(typ="safe").load(text)
    assert _yaml_block(data) == text
    inner = data["rosbag2_bagfile_information"]
    assert _yaml_block(inner) == _ruamel_dump(inner)


def _random_yaml_data(rng, depth: int = 0):
    words = ["a", "x_y", "/haptic_teleop/scene", "std_msgs/msg/String", "bag.mcap", "RIHS01_" + "ab12" * 16, ""]
    # Words that do not look plain: ruamel is asked once (written plain or quoted; quoted means fallback).
    odd = ["2026-11-22.mcap", "2026-11-22", "yes", "-x", "a b", "0x1F", "é", "a:b", "@x", "null", "~"]

    def scalar():
        k = int(rng.integers(0, 10))
        if k == 0:
            return int(rng.integers(-(10**12), 2**63 - 1))
        if k == 1:
            return [None, True, False][int(rng.integers(0, 3))]
        if k <= 5:
            n = int(rng.integers(1, 95))
            return "".join(rng.choice(list("abcdefghijklmnopqrstuvwxyz_/."), size=n).tolist()).lstrip("./") or "z"
        if k <= 8:
            return words[int(rng.integers(0, len(words)))]
        return odd[int(rng.integers(0, len(odd)))]

    def key():
        n = int(rng.integers(1, 40))
        return "k" + "".join(rng.choice(list("abcdefghijklmnopqrstuvwxyz_"), size=n).tolist())

    def node(d):
        k = int(rng.integers(0, 5 if d < 4 else 2))
        if k <= 1:
            return scalar()
        if k == 2:
            return {key(): node(d + 1) for _ in range(int(rng.integers(0, 4)))}
        if k == 3:
            return [node(d + 1) for _ in range(int(rng.integers(0, 4)))]
        return {key(): [node(d + 1) for _ in range(int(rng.integers(0, 3)))] for _ in range(int(rng.integers(1, 3)))}

    return {key(): node(depth) for _ in range(int(rng.integers(1, 6)))}


def test_yaml_block_equals_ruamel_on_generated_data():
    """Whenever _yaml_block writes a document it is ruamel's text, byte for byte (keys sorted,
    indentation, long values moved to their own line, quoting of empty strings); where it declines
    (None) the writer uses ruamel. Most generated documents are written by _yaml_block itself."""
    from haptic_teleop.record.metadata import yaml_block as _yaml_block

    rng = np.random.default_rng(7)
    written = wrapped = 0
    for _ in range(400):
        data = _random_yaml_data(rng)
        text = _yaml_block(data)
        if text is not None:
            written += 1
            wrapped += ": \n" in text
            assert text == _ruamel_dump(data), data
    assert written > 150 and wrapped > 50, (written, wrapped)
    shared = {"a": 1}
    assert _yaml_block({"x": shared, "y": shared}) is None  # ruamel writes an anchor and an alias
    assert _yaml_block({"x": 1.5}) is None  # floats are not in the subset
    assert _yaml_block({"x": [[1]]}) is None


def test_offered_qos_in_metadata_and_channels(tmp_path):
    """metadata.yaml carries each topic's offered QoS profiles as rosbag2 v9 writes them (defaults:
    1 kHz streams best effort, keep last 1, volatile; the scene reliable, transient local), the
    MCAP channels the same as YAML; a profile given per topic replaces the default; rosbags parses both."""
    from ruamel.yaml import YAML

    from haptic_teleop.engine.lockstep import COLUMNS

    qos = {"/slave/contact_wrench": [{"reliability": "reliable", "depth": 5}]}
    rec = RunRecorder(tmp_path / "bag", "", 1_000_000, False, False, len(COLUMNS), parallel=False, qos=qos)
    rec.append(np.zeros((3, len(COLUMNS))))
    rec.close({})
    info = YAML(typ="safe").load((tmp_path / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    topics = {t["topic_metadata"]["name"]: t["topic_metadata"] for t in info["topics_with_message_count"]}
    master = topics["/master/joint_states"]["offered_qos_profiles"]
    assert [(p["reliability"], p["history"], p["depth"], p["durability"]) for p in master] == [
        ("best_effort", "keep_last", 1, "volatile")
    ]
    scene = topics["/haptic_teleop/scene"]["offered_qos_profiles"][0]
    assert (scene["reliability"], scene["durability"]) == ("reliable", "transient_local")
    wrench = topics["/slave/contact_wrench"]["offered_qos_profiles"][0]
    assert (wrench["reliability"], wrench["depth"], wrench["durability"]) == ("reliable", 5, "volatile")
    with Reader(tmp_path / "bag") as r:
        conns = {c.topic: c for c in r.connections}
    assert conns["/master/joint_states"].ext.offered_qos_profiles[0].reliability.name == "BEST_EFFORT"
    assert conns["/haptic_teleop/scene"].ext.offered_qos_profiles[0].durability.name == "TRANSIENT_LOCAL"
    with pytest.raises(BagError, match="offered QoS of /x: QoS reliability 'sometimes' is not one of"):
        RunRecorder(tmp_path / "b2", "", 1, False, False, len(COLUMNS), qos={"/x": [{"reliability": "sometimes"}]})


STRING_TYPE = "std_msgs/msg/String"


def test_chunk_closes_only_past_one_mebibyte(tmp_path):
    """A chunk is closed after the message that takes it past 1 MiB: a chunk that ends exactly at
    1 MiB stays open. Whether messages come in one call or several, the file is the same."""
    from mcap.reader import make_reader

    from haptic_teleop.record.layouts import STRING
    from haptic_teleop.record.layouts import string_bytes as _string_bytes
    from haptic_teleop.record.mcap import BagSink as _BagSink
    from haptic_teleop.record.streams import Stream as _Stream

    def stream(lengths, t0):
        blobs = [_string_bytes("x" * n) for n in lengths]
        return _Stream("/a", STRING, np.arange(t0, t0 + len(blobs)), blobs=blobs)

    trees = []
    lengths = [300_000, 300_000, 300_000]
    used = sum(31 + len(_string_bytes("x" * n)) for n in lengths)
    last = 2**20 - used - 31 - len(_string_bytes(""))  # this message ends the chunk at exactly 1 MiB
    assert used + 31 + len(_string_bytes("x" * last)) == 2**20
    lengths += [last, 10, 500_000, 600_000, 20]
    for mode in ("one_call", "calls"):
        (tmp_path / mode).mkdir()
        sink = _BagSink(tmp_path / mode / "bag", [("/a", STRING), ("/b", STRING)])
        if mode == "calls":  # the first call ends exactly at 1 MiB
            sink.write([stream(lengths[:4], 0)])
            sink.write([stream(lengths[4:], 4)])
        else:
            sink.write([stream(lengths, 0)])
        sink.write([_Stream("/b", STRING, np.array([3]), blobs=[_string_bytes("b")])])
        sink.close()
        trees.append(tmp_path / mode / "bag")
    assert _same_tree(trees[0], trees[1])
    with open(trees[0] / "bag.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        sizes = [ci.uncompressed_size for ci in reader.get_summary().chunk_indexes]
        assert [len(m.data) for _, ch, m in reader.iter_messages() if ch.topic == "/a"] == [
            len(_string_bytes("x" * n)) for n in lengths
        ]
    # chunk 1: 3 x 300 kB + the message ending at 1 MiB + the 10-byte one that takes it past
    assert sizes[0] == 2**20 + 31 + len(_string_bytes("x" * 10))
    assert len(sizes) == 3


def test_only_rosbags_public_api_is_used():
    """The recording layer uses rosbags only through its public API (the typestore, and the Reader
    for other storage): no private attribute or module of its writer. A rosbags release can then
    change its internals without changing what we write."""
    import ast

    import haptic_teleop.record as record

    allowed = {("rosbags.typesys", "Stores"), ("rosbags.typesys", "get_typestore"), ("rosbags.rosbag2", "Reader")}
    found = set()
    for path in Path(record.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("rosbags"):
                found |= {(node.module, a.name) for a in node.names}
            elif isinstance(node, ast.Import):
                assert not any(a.name.startswith("rosbags") for a in node.names), path
    assert found and found <= allowed, found - allowed
