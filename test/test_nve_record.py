"""NVE runs in the bag (record/nve_columns.py, NveStreams): the schema, the recorder in and out of
process, the reader, rosbags' reader, `bag info`, and a bag that survives Ctrl-C and kill -9."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from haptic_teleop.errors import BagError
from haptic_teleop.record.columns import ONE_DOF, SchemaError
from haptic_teleop.record.layouts import PACKET_FIELDS, typestore
from haptic_teleop.record.nve_columns import NveSchema, nve_topics
from haptic_teleop.record.reader import BagReader
from haptic_teleop.record.recorder import RunRecorder
from haptic_teleop.record.streams import BLOCK_TICKS

PERIOD_NS = 1_000_000
SCENE = "scene: {name: nve}\n"

# The groups docs/recording_nve.md ("Schema and columns") lists, written down here, not taken from the code.
SERVER = ("obj_x_m", "obj_v_m_per_s", "obj_force_n")
CLIENT_AXIS = ("hip_x_m", "hip_v_m_per_s", "obj_x_m", "obj_v_m_per_s", "force_n")
CLIENT_ONE = ("spring_n_per_m", "rtt_s", "up_rx_seq", "down_rx_seq", "up_occupancy", "down_occupancy")


def _expected_columns(clients: tuple[str, ...], axes: int) -> list[str]:
    def per_axis(group: str) -> list[str]:
        return [group] if axes == 1 else [f"{group}[{a}]" for a in "xyz"]

    out = [c for g in SERVER for c in per_axis(g)]
    for cl in clients:
        out += [c for g in CLIENT_AXIS for c in per_axis(f"{cl}.{g}")]
        out += [f"{cl}.{g}" for g in CLIENT_ONE]
    return out


def nve_rows(schema: NveSchema, a: int, b: int) -> np.ndarray:
    """Tick rows [a, b): every value names its tick and column; a client's object and round trip
    NaN before tick 50 (no packet yet); up samples released from tick 40 on (not every tick),
    down samples from tick 60 on."""
    t = np.arange(a, b, dtype=np.float64)
    rows = np.empty((b - a, schema.width))
    for j in range(schema.width):
        rows[:, j] = t + (j + 1) * 1e-4
    for c in schema.clients:
        for g in ("obj_x_m", "obj_v_m_per_s", "rtt_s"):
            rows[t < 50, schema.group(f"{c}.{g}")] = np.nan
        rows[:, schema.index(f"{c}.up_rx_seq")] = np.where((t >= 40) & (t % 5 != 0), t - 40, -1)
        rows[:, schema.index(f"{c}.down_rx_seq")] = np.where(t >= 60, t - 60, -1)
    return rows


def _packets(seqs: np.ndarray, salt: float) -> np.ndarray:
    rows = np.zeros((seqs.size, len(PACKET_FIELDS)))
    rows[:, 0] = seqs
    rows[:, 1] = seqs * 1e-3
    rows[:, 2] = np.where(seqs % 7 == 0, np.nan, seqs * 1e-3 + salt)
    rows[:, 3] = np.where(seqs % 7 == 0, 1, 0)
    rows[:, 5] = 40 + salt
    return rows


PIECES = [1, 999, 1500, 17, 1483]
BATCHES = sum(-(-k // 1000) for k in PIECES)  # packet batch messages of the first link (up to 1000 records each)


def _record(bag: Path, schema: NveSchema, parallel: bool, pieces: list[int] = PIECES) -> Path:
    """Ticks in uneven pieces; each link's packets in shuffled batches between them."""
    rng = np.random.default_rng(5)
    bag.parent.mkdir(parents=True, exist_ok=True)
    rec = RunRecorder(bag, SCENE, PERIOD_NS, False, True, schema.width, parallel=parallel, schema=schema)
    a = 0
    for k in pieces:
        rec.append(nve_rows(schema, a, a + k))
        for i, d in enumerate(schema.directions):
            seqs = np.arange(a, a + max(0, k - i), dtype=np.float64)  # links carry different counts
            rng.shuffle(seqs)
            rec.append_packets(d, _packets(seqs, 0.01 * (i + 1)))
        a += k
    return rec.close({"ticks": a})


SCHEMAS = [
    NveSchema(("client1",), 1),
    NveSchema(("client1",), 3),
    NveSchema(("client1", "client2"), 1),
    NveSchema(("left", "right_2"), 3),
]
IDS = ["1-client-1-axis", "1-client-3-axes", "2-clients-1-axis", "2-clients-3-axes"]


# -- the schema


def test_columns_are_the_designs() -> None:
    one = NveSchema(("client1",), 1)
    assert one.columns == (
        "obj_x_m", "obj_v_m_per_s", "obj_force_n",
        "client1.hip_x_m", "client1.hip_v_m_per_s", "client1.obj_x_m", "client1.obj_v_m_per_s", "client1.force_n",
        "client1.spring_n_per_m", "client1.rtt_s", "client1.up_rx_seq", "client1.down_rx_seq",
        "client1.up_occupancy", "client1.down_occupancy",
    )  # fmt: skip
    for schema in SCHEMAS:
        cols = _expected_columns(schema.clients, schema.axes)
        assert list(schema.columns) == cols
        assert schema.width == len(cols) == 3 * schema.axes + len(schema.clients) * (5 * schema.axes + 6)
        for i, c in enumerate(cols):
            assert schema.index(c) == i
        groups = list(SERVER) + [f"{c}.{g}" for c in schema.clients for g in CLIENT_AXIS + CLIENT_ONE]
        covered = [i for g in groups for i in range(schema.group(g).start, schema.group(g).stop)]
        assert covered == list(range(schema.width))  # the groups tile the row, in order
        assert NveSchema.from_facts(json.loads(json.dumps(schema.facts()))) == schema
    three = SCHEMAS[3]
    assert three.columns[three.group("right_2.force_n")] == (
        "right_2.force_n[x]",
        "right_2.force_n[y]",
        "right_2.force_n[z]",
    )
    assert three.client_group("left", "rtt_s") == slice(three.index("left.rtt_s"), three.index("left.rtt_s") + 1)
    assert three.directions == ("left/up", "left/down", "right_2/up", "right_2/down")


@pytest.mark.parametrize(
    ("clients", "axes", "words"),
    [
        (("client1",), 2, "NVE axes must be 1 or 3; got 2"),
        (("client1",), 3.0, "NVE axes must be 1 or 3; got 3.0"),
        ((), 1, "at least one client"),
        (("a", "a"), 1, "must be distinct; got a, a"),
        (("1st",), 1, r"client name '1st': letters, digits and _ only \(\[A-Za-z_\]\[A-Za-z0-9_\]\*\)"),
        (("a b",), 1, "client name 'a b'"),
        (("a/up",), 1, "client name 'a/up'"),
        (("",), 1, "client name ''"),
        ("client1", 1, "a sequence of client names; got 'client1'"),
    ],
)
def test_bad_schemas_are_named(clients: tuple[str, ...], axes: int, words: str) -> None:
    with pytest.raises(SchemaError, match=words):
        NveSchema(clients, axes)


def test_bad_facts_and_names_are_named() -> None:
    with pytest.raises(SchemaError, match="NVE schema: no 'axes' key"):
        NveSchema.from_facts({"clients": ["a"]})
    with pytest.raises(SchemaError, match="a mapping of clients and axes"):
        NveSchema.from_facts(["a"])
    with pytest.raises(SchemaError, match="clients must be a list"):
        NveSchema.from_facts({"clients": "a", "axes": 1})
    s = SCHEMAS[2]
    with pytest.raises(SchemaError, match=r"no column group 'client3.force_n'; groups: obj_x_m, .*client1, client2"):
        s.group("client3.force_n")
    with pytest.raises(SchemaError, match="no NVE client 'client3'; clients: client1, client2"):
        s.client_group("client3", "force_n")
    with pytest.raises(SchemaError, match=r"no column 'obj_x_m\[x\]'"):
        s.index("obj_x_m[x]")  # 1 axis: no [x]


def test_topics_are_the_designs() -> None:
    s = SCHEMAS[3]
    topics = {t.topic: t for t in nve_topics(s)}
    expect = ["/nve/object/joint_states"]
    for c in s.clients:
        expect += [f"/nve/{c}/{x}" for x in ("hip/joint_states", "object_pose", "object_twist", "feedback_wrench")]
        expect.append(f"/nve/{c}/coupling")
    assert list(topics) == expect
    obj = topics["/nve/object/joint_states"]
    assert obj.names == ("object_x", "object_y", "object_z")
    assert obj.columns(s) == list(range(9))
    hip = topics["/nve/right_2/hip/joint_states"]
    assert hip.names == ("right_2_hip_x", "right_2_hip_y", "right_2_hip_z")
    assert [s.columns[i] for i in hip.columns(s)] == _expected_columns(("right_2",), 3)[9:15] + [
        f"right_2.force_n[{a}]" for a in "xyz"
    ]
    assert topics["/nve/left/coupling"].names == CLIENT_ONE
    assert topics["/nve/left/feedback_wrench"].value_names(s) == ("force_x", "force_y", "force_z")
    assert s.packet_topics() == tuple(f"/nve/{c}/{d}/packets" for c in s.clients for d in ("up", "down"))


# -- recording and reading back


def _check_bag(bag: Path, schema: NveSchema, n: int) -> None:
    """Every per-tick value, stamp and packet of the bag against the rows and packets recorded."""
    rows = nve_rows(schema, 0, n)
    stamps = np.arange(n, dtype=np.int64) * PERIOD_NS
    pve = ("position", "velocity", "effort")
    with BagReader(bag) as r:
        assert r.nve_schema == schema
        assert json.loads(r.string("/haptic_teleop/run_info")) == {"ticks": n, "nve_schema": schema.facts()}
        assert r.string("/haptic_teleop/scene") == SCENE

        def group(name: str) -> np.ndarray:
            return rows[:, schema.group(name)]

        expect: dict[str, np.ndarray] = {
            "/nve/object/joint_states": np.hstack([group(g) for g in SERVER]),
        }
        for c in schema.clients:
            expect[f"/nve/{c}/hip/joint_states"] = np.hstack(
                [group(f"{c}.{g}") for g in ("hip_x_m", "hip_v_m_per_s", "force_n")]
            )
            expect[f"/nve/{c}/object_pose"] = group(f"{c}.obj_x_m")
            expect[f"/nve/{c}/object_twist"] = group(f"{c}.obj_v_m_per_s")
            expect[f"/nve/{c}/feedback_wrench"] = group(f"{c}.force_n")
            expect[f"/nve/{c}/coupling"] = np.hstack([group(f"{c}.{g}") for g in CLIENT_ONE])
        assert set(r.specs()) == set(expect)
        for topic, values in expect.items():
            d = r.read(topic)
            assert np.array_equal(d.values, values, equal_nan=True), topic
            assert np.array_equal(d.log_ns, stamps), topic
            if topic.endswith("coupling"):
                assert d.stamp_ns is None
            else:
                assert np.array_equal(d.stamp_ns, stamps), topic
            blocks = list(r.blocks(topic))  # chunk by chunk: the same
            assert np.array_equal(np.concatenate([b.values for b in blocks]), values, equal_nan=True)
        blocks = list(r.nve_blocks())  # the rows rebuilt from the topics, chunk by chunk
        assert len(blocks) > 1 and sum(len(b.log_ns) for b in blocks) == n
        whole = r.read_nve()  # the blocks joined
        assert np.array_equal(whole.values, rows, equal_nan=True)
        assert whole.fields == tuple(_expected_columns(schema.clients, schema.axes))
        assert np.array_equal(whole.log_ns, stamps) and np.array_equal(whole.stamp_ns, stamps)
        for i, direction in enumerate(schema.directions):
            k_all = [max(0, k - i) for k in PIECES]
            seqs = np.concatenate([np.arange(sum(PIECES[:p]), sum(PIECES[:p]) + k) for p, k in enumerate(k_all)])
            want = _packets(np.sort(seqs).astype(np.float64), 0.01 * (i + 1))
            got = r.packets(f"/nve/{direction}/packets")
            assert np.array_equal(got, want, equal_nan=True), direction
    # rosbags' own reader: every message is the standard type the design names, with these values.
    ts = typestore()
    axes = schema.axis_labels
    seen: dict[str, int] = {}
    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, log, raw in reader.messages():
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            topic = conn.topic
            i = seen[topic] = seen.get(topic, -1) + 1
            if topic.startswith("/haptic_teleop") or topic.endswith("/packets"):
                continue
            assert log == stamps[i]
            v = expect[topic][i]
            if topic.endswith("coupling"):
                assert [d.label for d in msg.layout.dim] == list(CLIENT_ONE)
                assert np.array_equal(msg.data, v, equal_nan=True)
                continue
            assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stamps[i]
            pad = [*v, 0.0, 0.0][:3] if len(v) == 1 else list(v)
            if topic.endswith("joint_states"):
                who = "object" if topic == "/nve/object/joint_states" else f"{topic.split('/')[2]}_hip"
                assert list(msg.name) == [f"{who}_{a}" for a in axes]
                n_ax = len(axes)
                for k, f in enumerate(pve):
                    assert np.array_equal(getattr(msg, f), v[k * n_ax : (k + 1) * n_ax], equal_nan=True)
                continue
            assert msg.header.frame_id == "world"
            if topic.endswith("object_pose"):
                p, q = msg.pose.position, msg.pose.orientation
                assert np.array_equal([p.x, p.y, p.z], pad, equal_nan=True)
                assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0)
            elif topic.endswith("object_twist"):
                lin, ang = msg.twist.linear, msg.twist.angular
                assert np.array_equal([lin.x, lin.y, lin.z], pad, equal_nan=True)
                assert (ang.x, ang.y, ang.z) == (0.0, 0.0, 0.0)
            else:
                f, tq = msg.wrench.force, msg.wrench.torque
                assert np.array_equal([f.x, f.y, f.z], pad, equal_nan=True)
                assert (tq.x, tq.y, tq.z) == (0.0, 0.0, 0.0)
    assert {t: seen[t] + 1 for t in expect} == dict.fromkeys(expect, n)
    assert types["/nve/object/joint_states"] == "sensor_msgs/msg/JointState"
    for c in schema.clients:
        assert types[f"/nve/{c}/hip/joint_states"] == "sensor_msgs/msg/JointState"
        assert types[f"/nve/{c}/object_pose"] == "geometry_msgs/msg/PoseStamped"
        assert types[f"/nve/{c}/object_twist"] == "geometry_msgs/msg/TwistStamped"
        assert types[f"/nve/{c}/feedback_wrench"] == "geometry_msgs/msg/WrenchStamped"
        assert types[f"/nve/{c}/coupling"] == "std_msgs/msg/Float64MultiArray"
        for d in ("up", "down"):
            assert types[f"/nve/{c}/{d}/packets"] == "std_msgs/msg/Float64MultiArray"
    assert types["/haptic_teleop/run_info"] == types["/haptic_teleop/scene"] == "std_msgs/msg/String"


@pytest.mark.parametrize("schema", SCHEMAS, ids=IDS)
def test_round_trip(tmp_path: Path, schema: NveSchema) -> None:
    """Synthetic rows and packets through RunRecorder, in process and with the writer process
    (the same bytes), read back by BagReader and by rosbags' reader."""
    a = _record(tmp_path / "a" / "bag", schema, parallel=False)
    b = _record(tmp_path / "b" / "bag", schema, parallel=True)
    assert (a / "bag.mcap").read_bytes() == (b / "bag.mcap").read_bytes()
    assert (a / "metadata.yaml").read_text() == (b / "metadata.yaml").read_text()
    _check_bag(b, schema, sum(PIECES))


def test_mcap_validating_reader_and_qos(tmp_path: Path) -> None:
    """mcap's validating reader reads every message (CRCs); packet batches are offered as
    teleoperation's (reliable, keep last 10), the per-tick streams best effort."""
    from mcap.reader import make_reader

    schema = SCHEMAS[3]
    bag = _record(tmp_path / "bag", schema, parallel=False)
    with open(bag / "bag.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        counts: dict[str, int] = {}
        for _, ch, _ in reader.iter_messages():
            counts[ch.topic] = counts.get(ch.topic, 0) + 1
    assert counts["/nve/right_2/feedback_wrench"] == sum(PIECES)
    assert counts["/nve/left/up/packets"] == BATCHES
    meta = (bag / "metadata.yaml").read_text()
    from ruamel.yaml import YAML

    info = YAML(typ="safe").load(meta)["rosbag2_bagfile_information"]
    qos = {
        t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"][0]
        for t in info["topics_with_message_count"]
    }
    assert (qos["/nve/left/down/packets"]["reliability"], qos["/nve/left/down/packets"]["depth"]) == ("reliable", 10)
    assert qos["/nve/left/coupling"]["reliability"] == "best_effort"


def test_bad_calls_are_refused(tmp_path: Path) -> None:
    schema = SCHEMAS[2]
    rec = RunRecorder(tmp_path / "bag", SCENE, PERIOD_NS, False, True, schema.width, parallel=False, schema=schema)
    allowed = "client1/up, client1/down, client2/up, client2/down"
    for wrong in ("forward", "client3/up", "client1/sideways", "client1"):
        with pytest.raises(
            BagError,
            match=f"NVE packet direction must be one of {allowed}; got '{wrong}'",
        ):
            rec.append_packets(wrong, _packets(np.arange(3.0), 0.1))
    with pytest.raises(BagError, match=rf"tick rows must be a float64 array of shape \(ticks, {schema.width}\)"):
        rec.append(np.zeros((3, ONE_DOF.width)))
    rec.close({"ticks": 0})
    with pytest.raises(BagError, match=f"n_columns 18 is not the NVE schema's width {schema.width}"):
        RunRecorder(tmp_path / "b2", SCENE, PERIOD_NS, False, True, 18, schema=schema)
    # With the writer process the call is refused at once (not when the writer gets to it); the bag closes.
    par = RunRecorder(tmp_path / "p", SCENE, PERIOD_NS, False, True, schema.width, parallel=True, schema=schema)
    with pytest.raises(BagError, match=f"NVE packet direction must be one of {allowed}; got 'client1/left'"):
        par.append_packets("client1/left", _packets(np.arange(3.0), 0.1))
    par.append(nve_rows(schema, 0, 5))
    par.close({"ticks": 5})
    # A teleoperation recorder refuses an NVE direction, as before.
    tele = RunRecorder(tmp_path / "t", SCENE, PERIOD_NS, False, True, ONE_DOF.width, parallel=False)
    with pytest.raises(BagError, match="packet direction must be 'forward' or 'backward'; got 'client1/up'"):
        tele.append_packets("client1/up", _packets(np.arange(3.0), 0.1))
    tele.close({})
    with BagReader(tmp_path / "t") as r:
        assert r.nve_schema is None
        assert r.schema == ONE_DOF
        with pytest.raises(BagError, match="not an NVE run's bag"):
            r.read_nve()
    with BagReader(tmp_path / "bag") as r:
        assert r.nve_schema == schema
        with pytest.raises(BagError, match=r"is an NVE run's bag .*clients client1, client2, 1 axes.*no tick schema"):
            r.schema


def test_a_run_stopped_before_its_first_tick(tmp_path: Path) -> None:
    """No tick: the scene and the run facts (with the schema) are still there; the schema comes from them."""
    schema = SCHEMAS[1]
    for parallel in (False, True):
        rec = RunRecorder(
            tmp_path / f"b{parallel}", SCENE, PERIOD_NS, False, True, schema.width, parallel=parallel, schema=schema
        )
        rec.close({"ticks": 0})
        with BagReader(tmp_path / f"b{parallel}") as r:
            assert r.string("/haptic_teleop/scene") == SCENE
            assert r.nve_schema == schema
            assert r.read("/nve/client1/object_pose").values.shape == (0, 3)


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "haptic_teleop.cli", *args],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )


def test_bag_info_names_the_nve_topics(tmp_path: Path) -> None:
    schema = SCHEMAS[3]
    bag = _record(tmp_path / "bag", schema, parallel=False)
    out = _cli("bag", "info", str(bag))
    assert out.returncode == 0, out.stderr
    n = sum(PIECES)
    assert "Run:               NVE, clients left, right_2\n" in out.stdout
    assert "Integrity:         ok (" in out.stdout
    assert f"Topic: /nve/object/joint_states | Type: sensor_msgs/msg/JointState | Count: {n} |" in out.stdout
    assert f"Topic: /nve/right_2/object_twist | Type: geometry_msgs/msg/TwistStamped | Count: {n} |" in out.stdout
    assert (
        f"Topic: /nve/left/up/packets | Type: std_msgs/msg/Float64MultiArray | Count: {BATCHES} | "
        "Serialization Format: cdr | QoS: reliable, keep_last 10, volatile"
    ) in out.stdout
    assert "Run:" not in _cli("bag", "info", str(_teleop_bag(tmp_path / "t"))).stdout


def _teleop_bag(bag: Path) -> Path:
    rec = RunRecorder(bag, SCENE, PERIOD_NS, False, True, ONE_DOF.width, parallel=False)
    rec.append(np.zeros((10, ONE_DOF.width)))
    return rec.close({})


# -- a recording killed or interrupted mid-run

KILL_SCHEMA = NveSchema(("alice", "bob"), 3)
READY_BLOCKS = 3  # the child says "ready" after handing over this many blocks
MAX_BLOCKS = 12  # then goes on slowly, and stops appending here (bounded disk use)


def child_main(bag: str, parallel: bool) -> None:
    """A recording run in its own process (run by the tests below): blocks and packets until killed."""
    schema = KILL_SCHEMA
    rec = RunRecorder(Path(bag), SCENE, PERIOD_NS, False, True, schema.width, parallel=parallel, schema=schema)
    a = 0
    try:
        while True:
            if a < MAX_BLOCKS * BLOCK_TICKS:
                rec.append(nve_rows(schema, a, a + BLOCK_TICKS))
                rec.append_packets("alice/up", _packets(np.arange(a, a + BLOCK_TICKS, dtype=np.float64), 0.01))
                a += BLOCK_TICKS
            if a == READY_BLOCKS * BLOCK_TICKS:
                if not parallel:
                    rec.flush()
                print("ready", flush=True)
            time.sleep(0.05 if a > READY_BLOCKS * BLOCK_TICKS else 0.0)
    finally:
        rec.close({"ticks": a, "interrupted": True})


def _start_child(bag: Path, parallel: bool) -> subprocess.Popen[str]:
    here = str(Path(__file__).resolve().parent)
    code = (
        f"import sys; sys.path.insert(0, {here!r}); import test_nve_record as t; t.child_main({str(bag)!r}, {parallel})"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group: a terminal's Ctrl-C reaches the group
        # SIGABRT prints every thread's stack (a child that does not end: test_ctrl_c_closes_the_nve_bag)
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), "PYTHONFAULTHANDLER": "1"},
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()  # a safety net: the child exits (EOF) if anything goes wrong
    if line.strip() != "ready":
        proc.kill()
        proc.wait()
        pytest.fail(f"the recording child did not start (said {line!r}, exit {proc.poll()})")
    return proc


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        with open(task / "children") as f:
            out += [int(x) for x in f.read().split()]
    return out


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _wait_gone(pids: list[int]) -> list[int]:
    deadline = time.monotonic() + 60  # a safety net
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [p for p in pids if _alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    return left


def _check_ticks(bag: Path, at_least: int) -> dict[str, int]:
    """Each per-tick topic holds ticks 0, 1, ... of the child's rows, values and stamps; their counts."""
    schema = KILL_SCHEMA
    counts = {}
    with BagReader(bag) as r:
        assert r.nve_schema == schema
        for topic, spec in r.specs().items():
            d = r.read(topic)
            n = len(d.log_ns)
            assert n >= at_least, topic
            rows = nve_rows(schema, 0, n)
            assert np.array_equal(d.values, rows[:, list(spec.columns)], equal_nan=True), topic
            assert np.array_equal(d.log_ns, np.arange(n) * PERIOD_NS), topic
            counts[topic] = n
        pk = r.packets("/nve/alice/up/packets")
        assert np.array_equal(pk, _packets(np.arange(pk.shape[0], dtype=np.float64), 0.01), equal_nan=True)
    return counts


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_writer_closes_the_nve_bag_when_the_run_is_killed(tmp_path: Path) -> None:
    """kill -9 of the recording process: its writer process closes the bag (run facts with the
    schema) and exits; the bag reads back with every block handed over."""
    bag = tmp_path / "bag"
    proc = _start_child(bag, parallel=True)
    writers = _children(proc.pid)
    assert writers, "no writer process"
    proc.kill()
    proc.wait()
    assert not _wait_gone(writers), "the bag writer outlived the killed run"
    assert (bag / "metadata.yaml").exists()
    counts = _check_ticks(bag, READY_BLOCKS * BLOCK_TICKS)
    assert len(set(counts.values())) == 1 and next(iter(counts.values())) % BLOCK_TICKS == 0
    with BagReader(bag) as r:
        info = json.loads(r.string("/haptic_teleop/run_info"))
    assert info["recorder_parent_died"] is True and info["nve_schema"] == KILL_SCHEMA.facts()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_ctrl_c_closes_the_nve_bag(tmp_path: Path) -> None:
    """SIGINT to the whole process group (a terminal's Ctrl-C): the writer ignores it, the run's
    `finally` closes the bag, which is complete and reads back."""
    bag = tmp_path / "bag"
    proc = _start_child(bag, parallel=True)
    writers = _children(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        proc.wait(timeout=60)  # a generous bound, not a timing
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)  # its stacks on stderr
        err = proc.communicate(timeout=30)[1]
        pytest.fail(f"the recording did not end within 60 s of Ctrl-C; its stacks:\n{err[-6000:]}")
    finally:
        if proc.poll() is None:
            proc.kill()
    assert not _wait_gone(writers)
    assert (bag / "metadata.yaml").exists()
    counts = _check_ticks(bag, READY_BLOCKS * BLOCK_TICKS)
    assert len(set(counts.values())) == 1
    with BagReader(bag) as r:
        info = json.loads(r.string("/haptic_teleop/run_info"))
    assert info["interrupted"] is True and "recorder_parent_died" not in info
    assert info["nve_schema"] == KILL_SCHEMA.facts()


def test_recover_a_killed_nve_recording(tmp_path: Path) -> None:
    """kill -9 of a recording written in process (no writer to close it): the bag is refused with
    the fix named, `bag info` says DAMAGED and names the clients, `bag recover` rebuilds it, and
    it reads back (its schema from its topics: the run facts were never written)."""
    bag = tmp_path / "bag"
    proc = _start_child(bag, parallel=False)
    proc.kill()
    proc.wait()
    assert not (bag / "metadata.yaml").exists()
    with pytest.raises(BagError, match="bag recover"):
        BagReader(bag)
    info = _cli("bag", "info", str(bag))
    assert info.returncode == 1 and "DAMAGED" in info.stdout, info.stdout + info.stderr
    assert "Run:               NVE, clients alice, bob" in info.stdout
    rec = _cli("bag", "recover", str(bag))
    assert rec.returncode == 0, rec.stderr
    assert "recovered" in rec.stdout
    assert _cli("bag", "info", str(bag)).returncode == 0
    with BagReader(bag) as r, pytest.raises(BagError, match="run_info has no messages"):
        r.string("/haptic_teleop/run_info")
    counts = _check_ticks(bag, READY_BLOCKS * BLOCK_TICKS)
    assert max(counts.values()) - min(counts.values()) <= 1  # a chunk may end inside a tick
    with BagReader(bag) as r:
        whole = r.read_nve()
    n = min(counts.values())
    assert np.array_equal(whole.values, nve_rows(KILL_SCHEMA, 0, n), equal_nan=True)


def test_a_bag_cut_inside_a_tick_recovers_and_reads(tmp_path: Path) -> None:
    """A chunk closes after the message that takes it past 1 MiB, inside a tick: a bag cut after
    such a chunk (a kill) is recovered and read back, `read_nve` giving the ticks every topic holds."""
    from haptic_teleop.record.tools import recover

    schema = SCHEMAS[3]
    bag = _record(tmp_path / "bag", schema, parallel=False)
    (bag / "metadata.yaml").unlink()
    mcap = bag / "bag.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    assert recover(bag).chunks >= 1
    with BagReader(bag) as r:
        assert r.nve_schema == schema  # from the topics: the run facts were cut off
        counts = {t: len(r.read(t).log_ns) for t in r.specs()}
        assert max(counts.values()) == min(counts.values()) + 1  # this cut fell inside a tick
        whole = r.read_nve()
    n = min(counts.values())
    assert np.array_equal(whole.values, nve_rows(schema, 0, n), equal_nan=True)
    assert np.array_equal(whole.log_ns, np.arange(n) * PERIOD_NS)
