"""The streaming recorder: append / append_packets / flush / close, bounded memory, and a writer
process that never outlives its parent."""

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from haptic_teleop.engine.lockstep import COL, COLUMNS
from haptic_teleop.errors import BagError
from haptic_teleop.record.layouts import PACKET_FIELDS
from haptic_teleop.record.reader import BagReader
from haptic_teleop.record.recorder import RunRecorder
from haptic_teleop.record.streams import BLOCK_TICKS

PERIOD_NS = 1_000_000
DELAY_TICKS = 50


def _rows(a: int, b: int, delay: int = DELAY_TICKS) -> np.ndarray:
    """Tick rows [a, b): values that encode their tick, samples released `delay` ticks after sending."""
    t = np.arange(a, b, dtype=np.float64)
    rows = np.zeros((b - a, len(COLUMNS)))
    for j in range(len(COLUMNS)):
        rows[:, j] = t * 1e-3 + j
    seq = t - delay
    rows[:, COL["fwd_rx_seq"]] = np.where(seq >= 0, seq, -1)
    rows[:, COL["bwd_rx_seq"]] = np.where((seq >= 0) & (t % 3 != 0), seq, -1)  # not every tick releases
    return rows


def _packets(seqs: np.ndarray) -> np.ndarray:
    rows = np.zeros((seqs.size, len(PACKET_FIELDS)))
    rows[:, 0] = seqs
    rows[:, 1] = seqs * 1e-3
    rows[:, 2] = np.where(seqs % 7 == 0, np.nan, seqs * 1e-3 + 0.05)
    rows[:, 3] = np.where(seqs % 7 == 0, 1, 0)
    rows[:, 5] = 120
    return rows


def _record(bag: Path, parallel: bool, pieces: list[int], flush_at: int | None = None) -> Path:
    """Append ticks in pieces of the given sizes, packets in shuffled batches between them."""
    rng = np.random.default_rng(3)
    bag.parent.mkdir(parents=True, exist_ok=True)
    rec = RunRecorder(bag, "scene: {}\n", PERIOD_NS, True, True, len(COLUMNS), parallel=parallel)
    a = 0
    for i, k in enumerate(pieces):
        rec.append(_rows(a, a + k))
        seqs = np.arange(a, a + k, dtype=np.float64)
        rng.shuffle(seqs)
        rec.append_packets("forward", _packets(seqs))
        rec.append_packets("backward", _packets(seqs[: k // 2]))
        a += k
        if flush_at == i:
            rec.flush()
    return rec.close({"ticks": a})


PIECES = [1, 999, 2500, 17, 4000, 1483]


def test_streaming_api_reads_back_and_is_deterministic(tmp_path):
    """Uneven pieces, packets in any seq order: every tick and packet reads back (packets sorted
    by seq); in process and with the writer process, the same calls give the same bytes."""
    a = _record(tmp_path / "a" / "bag", parallel=False, pieces=PIECES)
    b = _record(tmp_path / "b" / "bag", parallel=True, pieces=PIECES)
    assert (a / "bag.mcap").read_bytes() == (b / "bag.mcap").read_bytes()
    assert (a / "metadata.yaml").read_text() == (b / "metadata.yaml").read_text()
    n = sum(PIECES)
    expect = _rows(0, n)
    with BagReader(b) as r:
        m = r.read("/master/joint_states")
        assert np.array_equal(m.values[:, 0], expect[:, COL["m_x_m"]])
        rx = r.read("/backward/received")
        released = expect[:, COL["bwd_rx_seq"]] >= 0
        assert len(rx.log_ns) == int(released.sum())
        src = expect[released, COL["bwd_rx_seq"]].astype(int)
        assert np.array_equal(rx.values[:, 2], expect[src, COL["s_contact_n"]])
        assert np.array_equal(rx.stamp_ns, src * PERIOD_NS)
        fwd = r.packets("/forward/packets")
        assert np.array_equal(fwd[:, 0], np.arange(n))
        assert np.array_equal(fwd, _packets(np.arange(n, dtype=np.float64)), equal_nan=True)
        assert r.packets("/backward/packets").shape[0] == sum(k // 2 for k in PIECES)


@pytest.mark.parametrize("parallel", [False, True], ids=["in-process", "writer-process"])
def test_a_run_stopped_before_its_first_tick_still_holds_its_scene(tmp_path, parallel):
    bag = _record(tmp_path / "bag", parallel, [])
    with BagReader(bag) as r:
        assert r.string("/haptic_teleop/scene") == "scene: {}\n"
        assert r.string("/haptic_teleop/run_info") == '{"ticks": 0}'


def test_memory_is_bounded_whatever_the_run_length(tmp_path):
    """The recorder keeps the sent columns of the last few blocks only (a playout buffer releases in
    order): after 100 blocks its history is as small as after 5; rows appended are copied."""
    rec = RunRecorder(tmp_path / "bag", "", PERIOD_NS, False, False, len(COLUMNS), parallel=False)
    sizes = []
    for i in range(100):
        rows = _rows(i * BLOCK_TICKS, (i + 1) * BLOCK_TICKS)
        rec.append(rows)
        rows[:] = np.nan  # the caller reuses its buffer
        sizes.append(rec._streams.history.buf.nbytes)
    rec.close({})
    assert sizes[-1] == sizes[4] <= 4 * BLOCK_TICKS * 5 * 8
    with BagReader(tmp_path / "bag") as r:
        rx = r.read("/forward/received")
        assert not np.isnan(rx.values).any()
        assert len(rx.log_ns) == 100 * BLOCK_TICKS - DELAY_TICKS


def test_flush_puts_everything_in_complete_chunks(tmp_path):
    """After flush, a copy of the unfinished file (what a kill would leave) holds every message
    appended so far, read by mcap's stream reader."""
    from mcap.stream_reader import StreamReader

    rec = RunRecorder(tmp_path / "bag", "", PERIOD_NS, True, True, len(COLUMNS), parallel=True)
    rec.append(_rows(0, 1500))
    rec.append_packets("forward", _packets(np.arange(1500.0)))
    rec.flush()
    snapshot = (tmp_path / "bag" / "bag.mcap").read_bytes()
    rec.append(_rows(1500, 2000))
    rec.close({})
    assert not (tmp_path / "bag" / "metadata.yaml").read_text() == ""
    from mcap.exceptions import EndOfFile
    from mcap.records import Channel, Message

    channels = {}
    counts: dict[str, int] = {}
    with open(tmp_path / "cut.mcap", "wb") as f:
        f.write(snapshot)
    with open(tmp_path / "cut.mcap", "rb") as f, contextlib.suppress(EndOfFile):
        for record in StreamReader(f, skip_magic=False).records:
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                topic = channels[record.channel_id]
                counts[topic] = counts.get(topic, 0) + 1
    assert counts["/master/joint_states"] == 1500
    assert counts["/forward/packets"] == 2  # 1500 records in batches of up to 1000


def test_bad_calls_are_refused(tmp_path):
    rec = RunRecorder(tmp_path / "bag", "", PERIOD_NS, True, True, len(COLUMNS), parallel=False)
    with pytest.raises(BagError, match="tick rows must be a float64 array"):
        rec.append(np.zeros((3, 4)))
    with pytest.raises(BagError, match="packet direction must be"):
        rec.append_packets("sideways", _packets(np.arange(3.0)))
    with pytest.raises(BagError, match="compression 'gzip' is not one of none, zstd, lz4"):
        RunRecorder(tmp_path / "b2", "", PERIOD_NS, True, True, len(COLUMNS), compression="gzip")
    rec.close({})
    with pytest.raises(BagError, match="recorder is closed"):
        rec.append(_rows(0, 1))
    # An unwritable output path fails when the recorder is made, before anything runs.
    (tmp_path / "a_file").write_text("x")
    for parallel in (False, True):
        with pytest.raises(BagError, match=r"a_file/bag: cannot create the bag \(Not a directory\)"):
            RunRecorder(tmp_path / "a_file" / "bag", "", PERIOD_NS, True, True, len(COLUMNS), parallel=parallel)


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        with open(task / "children") as f:
            out += [int(x) for x in f.read().split()]
    return out


def _alive(pid: int) -> bool:
    """Running (not a zombie waiting for its new parent to reap it)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


RUN = (sys.executable, "-m", "haptic_teleop.cli", "run", "wall_contact")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_writer_closes_the_bag_and_exits_when_the_run_is_killed(tmp_path):
    """SIGKILL of `haptic-teleop run` mid-run: its bag-writer child notices, closes the bag
    (summary, metadata.yaml) and exits; the bag reads back with the ticks written so far."""
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [*RUN, "--out", str(out), "--no-plots", "--set", "scene.duration_s=3600"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    bag = out / "bag"
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            mcap = bag / "bag.mcap"
            if mcap.exists() and mcap.stat().st_size > 3 * 2**20:
                break
            assert proc.poll() is None, "the run ended before it could be killed"
            time.sleep(0.1)
        else:
            pytest.fail("the run wrote no chunks in 300 s")
        children = _children(proc.pid)
        assert children, "no writer process"
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 120
        while any(_alive(c) for c in children) and time.monotonic() < deadline:
            time.sleep(0.2)
        left = [c for c in children if _alive(c)]
        for c in left:
            os.kill(c, signal.SIGKILL)
        assert not left, "the bag writer outlived the killed run"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert (bag / "metadata.yaml").exists()
    with BagReader(bag) as r:
        ticks = len(r.read("/master/joint_states").log_ns)
        info = r.string("/haptic_teleop/run_info")
    assert ticks >= 1000
    assert '"recorder_parent_died": true' in info
    shutil.rmtree(out)
