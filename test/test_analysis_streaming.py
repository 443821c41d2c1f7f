"""summary.json in bounded memory: the streaming analysis (`analysis.stream.summarize_bag`) gives
the whole-array numbers (`metrics.compute_summary(load_signals(bag))`) on real runs, and what it
allocates does not grow with the run's length."""

import math
import tracemalloc

import numpy as np
import pytest

from haptic_teleop.analysis import stream
from haptic_teleop.analysis.metrics import compute_summary, load_signals
from haptic_teleop.analysis.stream import ExactQuantiles, summarize_bag
from haptic_teleop.cli.main import main

SCENES = {
    "wall_contact": [],
    "bursty_loss": [],
    "jitter": [],
    "varying_delay": [],
    "blackout": [],
    # duplicate copies, corruption, an adaptive buffer: the other branches of the packet pass
    "duplicates": [
        "--set", "network.forward.effects.duplicate={probability: 0.05}",
        "--set", "network.forward.effects.delay={delay_s: 0.02, jitter_s: 0.004}",
        "--set", "network.forward.buffer.policy=adaptive",
        "--set", "network.backward.effects.corrupt={probability: 0.05}",
    ],
}  # fmt: skip


def _run(tmp_path_factory, name, extra, duration_s=3.0):
    out = tmp_path_factory.mktemp("stream") / name
    scene = "wall_contact" if name == "duplicates" else name
    args = ["run", scene, "--set", f"scene.duration_s={duration_s:g}", *extra, "--out", str(out), "--quiet"]
    assert main([*args, "--no-plots"]) == 0
    return out / "bag"


def _same(ref, got):
    assert set(got) == set(ref)
    for k, a in ref.items():
        b = got[k]
        if isinstance(a, float) and math.isnan(a):
            assert isinstance(b, float) and math.isnan(b), k
        elif isinstance(a, float):
            assert b == pytest.approx(a, rel=1e-12, abs=1e-300), k
        else:
            assert b == a, k


@pytest.mark.parametrize("name", list(SCENES))
def test_streaming_summary_is_the_whole_array_summary(tmp_path_factory, name):
    bag = _run(tmp_path_factory, name, SCENES[name])
    ref = compute_summary(load_signals(bag))
    got = stream._summarize(bag)  # not summarize_bag: no fallback to the whole-array path
    _same(ref, got)
    if name == "duplicates":
        assert got["duplicates_forward"] > 0 and got["reorder_count_forward"] > 0
    if name == "bursty_loss":
        assert got["loss_burst_mean_forward_packets"] > 1.0


def test_streaming_crosses_chunks(tmp_path_factory):
    """The runs above span several chunks, so state is carried between blocks."""
    from haptic_teleop.record.reader import BagReader

    bag = _run(tmp_path_factory, "jitter", [])
    with BagReader(bag) as r:
        assert sum(1 for _ in r.blocks("/master/joint_states")) >= 3
        assert sum(1 for _ in r.packet_blocks("/forward/packets")) >= 2


def _blocks(v, k):
    return lambda: (v[i : i + k] for i in range(0, v.size, k))


def test_exact_percentile_interpolates_bit_for_bit_as_numpy():
    """Many small samples: numpy's interpolation (from the upper value when the weight is at
    least 0.5) differs from a + (b - a) g in the last bit for some of them."""
    rng = np.random.default_rng(11)
    for _ in range(300):
        v = rng.normal(0.05, 0.01, int(rng.integers(2, 50)))
        q = ExactQuantiles()
        q.add(v)
        qs = (50, 90, 99, 99.9)
        assert q.percentiles(_blocks(v, 7), qs) == [float(np.percentile(v, p)) for p in qs]


@pytest.mark.parametrize(("small", "top"), [(0, 0), (1 << 18, 0), (0, 1 << 14), (0, 40)])
@pytest.mark.parametrize("seed", range(6))
def test_exact_quantiles_match_numpy(seed, small, top, monkeypatch):
    """Through the histogram passes (small 0), the one pass for few values, and the kept largest
    values (top: all of them, or 40: the 100th percentile and, for small samples, the others)."""
    monkeypatch.setattr(stream, "SMALL", small)
    monkeypatch.setattr(stream, "TOP", top)
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 5000))
    kind = seed % 3
    if kind == 0:
        v = rng.normal(0.05, 0.01, n)
    elif kind == 1:  # heavy ties and a far outlier: most values in one histogram bin
        v = np.round(rng.normal(0.05, 0.001, n), 4)
        v[0] = 3.0
    else:  # grid values, as delays of a tick grid are
        v = rng.integers(0, 40, n) * 1e-3
    q = ExactQuantiles()
    for b in _blocks(v, 97)():
        q.add(b)
    src = _blocks(v, 97)
    assert q.percentiles(src, (0, 50, 99, 99.9, 100)) == [float(np.percentile(v, p)) for p in (0, 50, 99, 99.9, 100)]
    assert q.median(src) == float(np.median(v))
    assert q.mean() == pytest.approx(float(np.mean(v)), rel=1e-13)


def test_exact_quantiles_merge_many_distinct_values_in_one_bin(monkeypatch):
    monkeypatch.setattr(stream, "_MERGE_AT", 50)
    monkeypatch.setattr(stream, "SMALL", 0)
    monkeypatch.setattr(stream, "TOP", 0)
    v = np.concatenate([np.repeat(np.linspace(0.0, 1e-9, 1001), 3), [1.0]])  # each value 3 times
    q = ExactQuantiles()
    q.add(v)
    assert q.percentiles(lambda: iter([v[:1000], v[1000:]]), (50, 99)) == [
        float(np.percentile(v, 50)),
        float(np.percentile(v, 99)),
    ]


def _peak_kb(bag):
    tracemalloc.start()
    try:
        summarize_bag(bag)
        return tracemalloc.get_traced_memory()[1] / 1024
    finally:
        tracemalloc.stop()


def test_summary_memory_does_not_grow_with_the_run(tmp_path_factory):
    """tracemalloc peak of the streaming analysis: a 16 s run (16 chunks of each stream) allocates
    about what a 4 s one does; the whole-array path would allocate 4x."""
    short = _run(tmp_path_factory, "jitter", [], 4.0)
    long = _run(tmp_path_factory, "jitter", [], 16.0)
    a, b = _peak_kb(short), _peak_kb(long)
    assert b < 1.25 * a + 512, (a, b)


def _split(blocks, rng):
    """The same rows in random smaller blocks (many block boundaries)."""
    for b in blocks:
        cuts = np.sort(rng.integers(0, len(b), max(1, len(b) // 5)))
        yield from (p for p in np.split(b, cuts) if len(p))


def test_streaming_summary_in_tiny_blocks(tmp_path_factory, monkeypatch):
    """Every block boundary a chance for carried state to go wrong: blocks of a few rows."""
    from haptic_teleop.record.reader import BagReader, TopicData

    rng = np.random.default_rng(3)
    blocks, packet_blocks = BagReader.blocks, BagReader.packet_blocks

    def small_blocks(self, topic):
        for d in blocks(self, topic):
            cuts = np.sort(rng.integers(0, d.log_ns.size, max(1, d.log_ns.size // 7)))
            for a, b in zip([0, *cuts], [*cuts, d.log_ns.size], strict=True):
                if b > a:
                    st = None if d.stamp_ns is None else d.stamp_ns[a:b]
                    yield TopicData(d.log_ns[a:b], st, d.values[a:b], d.fields)

    monkeypatch.setattr(BagReader, "blocks", small_blocks)
    monkeypatch.setattr(BagReader, "packet_blocks", lambda self, topic: _split(packet_blocks(self, topic), rng))
    monkeypatch.setattr(stream, "SMALL", 0)  # the histogram passes for the quantiles, not the one-pass sort
    monkeypatch.setattr(stream, "TOP", 0)
    for name in ("bursty_loss", "jitter", "duplicates"):
        bag = _run(tmp_path_factory, name, SCENES[name])
        _same(compute_summary(load_signals(bag)), stream._summarize(bag))


def test_packet_pass_on_synthetic_records_with_ties_and_bursts():
    """Loss bursts, reorders (arrival ties broken by seq), counts and first arrivals of records
    with many ties and duplicate copies, fed in random blocks, against the whole-array functions."""
    from haptic_teleop.analysis import metrics

    rng = np.random.default_rng(7)
    n = 3000
    seq = np.arange(n, dtype=float)
    send = seq * 1e-3
    arrival = np.round(send + rng.integers(0, 30, n) * 1e-3, 3)  # on a ms grid: ties
    fate = np.where(rng.random(n) < 0.2, 1.0, 0.0)
    fate[(fate == 0) & (rng.random(n) < 0.1)] = 4.0
    arrival[fate == 1.0] = np.nan
    rows = np.column_stack([seq, send, arrival, fate, np.zeros(n), np.full(n, 40.0)])
    dup = rows[rng.random(n) < 0.1].copy()
    dup[:, 4] = 1.0
    dup[:, 2] = dup[:, 2] + 0.004
    rows = np.concatenate([rows, dup])
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    d = stream._Direction(duration_s=2.5, overhead=0.0)
    for b in _split([rows], rng):
        d.rows(b)
    assert d.reordered == metrics._reordered(rows) > 0
    assert d.lost / d.runs == metrics._loss_bursts(rows) > 1.0
    assert (d.sent, d.lost, d.late) == metrics._packet_counts(rows)
    assert d.dups == dup.shape[0]


def test_high_percentiles_from_the_kept_largest_values(monkeypatch):
    """A high percentile of many values comes from the largest ones kept while adding: no pass."""
    monkeypatch.setattr(stream, "TOP", 40)
    v = np.random.default_rng(2).normal(0.05, 0.01, 5000)
    q = ExactQuantiles()
    for b in _blocks(v, 97)():
        q.add(b)

    def no_pass():
        raise AssertionError("a pass over the values was made")

    assert q.percentiles(no_pass, (99.9, 100)) == [float(np.percentile(v, 99.9)), float(np.max(v))]


# `analyze BAG` in a process where MuJoCo and numba cannot be imported: what it compares the run
# with (a contact scene's undisturbed reference run) must come from the bag.
BLOCKED = "import sys; sys.modules.update(mujoco=None, numba=None, llvmlite=None); "


def test_analyze_reads_the_bag_alone_without_mujoco_or_numba(tmp_path):
    import json
    import subprocess
    import sys

    out = tmp_path / "run"
    args = ["run", "seed_contact", "--set", "scene.duration_s=2.0", "--out", str(out), "--quiet", "--no-plots"]
    assert main(args) == 0
    recorded = json.loads((out / "summary.json").read_text())
    assert recorded["force_rms_error_vs_reference_n"] > 0.0  # the scene compares with its reference
    code = BLOCKED + "from haptic_teleop.cli.main import main; sys.exit(main(sys.argv[1:]))"
    again = tmp_path / "again"
    proc = subprocess.run(
        [sys.executable, "-c", code, "analyze", str(out / "bag"), "--out", str(again), "--quiet"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((again / "summary.json").read_text())
    for key in ("force_rms_error_vs_reference_n", "force_drop_measured_n", "force_slope_measured_n_per_s"):
        assert summary[key] == recorded[key], key
    assert (again / "plots").is_dir() and list((again / "plots").glob("*.png"))
    # and the blocked imports really are blocked there
    probe = subprocess.run([sys.executable, "-c", BLOCKED + "import mujoco"], capture_output=True, text=True)
    assert probe.returncode != 0 and "import of mujoco halted" in probe.stderr
