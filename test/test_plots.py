"""Plots of a run and of a sweep: each figure carries the series the bag holds, readable and bounded.

A real run (engine, network, playout buffers, MuJoCo, rosbag2) writes the bag the figures are
built from; the figures are inspected before saving (artists, offsets, labels, limits).
"""

import dataclasses
import math

import numpy as np
import pytest
from matplotlib.collections import PathCollection

from haptic_teleop.analysis.decimate import (
    DEFAULT_COLUMNS,
    SCATTER_COLUMNS,
    SCATTER_ROWS,
    minmax_envelope,
    thin_events,
    thin_points,
)
from haptic_teleop.analysis.metrics import load_signals
from haptic_teleop.analysis.plots import FIGURES, energy_figure, energy_margins, network_figure
from haptic_teleop.analysis.stream import summarize_bag
from haptic_teleop.analysis.timeline import buffer_exits, buffer_occupancy, loss_causes, skip_times
from haptic_teleop.cli.main import main
from haptic_teleop.studies.batch.aggregate import aggregate
from haptic_teleop.studies.batch.figure import key_label, metric_unit, sweep_figure, wrap_key
from haptic_teleop.studies.batch.plan import Param

SCENE = [
    "--set", "scene.duration_s=1.0",
    "--set", "network.forward.effects.blackout={starts_s: [0.3], ends_s: [0.4]}",
    "--set", "network.forward.effects.loss={model: bernoulli, probability: 0.05}",
    "--set", "network.forward.effects.delay={delay_s: 0.02, jitter_s: 0.004}",
    "--set", "network.forward.buffer.policy=adaptive",
    "--set", "network.backward.effects.corrupt={probability: 0.05}",
    "--set", "network.backward.effects.delay={delay_s: 0.01}",
]  # fmt: skip


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("plots") / "run"
    assert main(["run", "wall_contact", *SCENE, "--out", str(out), "--quiet"]) == 0
    return out, load_signals(out / "bag")


def _collections(ax):
    return {c.get_label(): c for c in ax.collections if isinstance(c, PathCollection)}


def _lines(ax):
    return {ln.get_label(): ln for ln in ax.get_lines()}


def _panels(fig, direction):
    """(delay, events, occupancy) axes of one direction of the network figure."""
    k = 0 if direction == "forward" else 1
    return fig.axes[3 * k : 3 * k + 3]


def test_run_writes_every_plot_and_analyze_the_same(run, tmp_path):
    out, _ = run
    for name in ("forces.png", "positions.png", "energy.png", "network.png"):
        assert (out / "plots" / name).stat().st_size > 10_000, name
    assert main(["analyze", str(out / "bag"), "--out", str(tmp_path / "again")]) == 0
    assert sorted(p.name for p in (tmp_path / "again" / "plots").iterdir()) == sorted(FIGURES)


def test_loss_markers_sit_exactly_on_the_lost_packets_by_cause(run):
    _, sig = run
    fig = network_figure(sig)
    fwd, bwd = sig.forward_packets, sig.backward_packets
    orig = fwd[fwd[:, 4] == 0]
    lost = orig[orig[:, 3] == 1]
    in_window = (lost[:, 1] >= 0.3 - 1e-12) & (lost[:, 1] < 0.4 - 1e-12)
    assert in_window.sum() == 100 and (~in_window).sum() > 10  # the blackout, and the loss model outside it
    lanes = _collections(_panels(fig, "forward")[1])
    blackout = lanes[f"lost: blackout ({in_window.sum()})"]
    random = lanes[f"lost: random loss (bernoulli) ({(~in_window).sum()})"]
    np.testing.assert_array_equal(blackout.get_offsets()[:, 0], lost[in_window, 1])
    np.testing.assert_array_equal(random.get_offsets()[:, 0], lost[~in_window, 1])
    # Backward: corruption only, at the send times of the corrupted packets.
    lanes_b = _collections(_panels(fig, "backward")[1])
    corrupt = bwd[(bwd[:, 3] == 3) & (bwd[:, 4] == 0)]
    assert corrupt.shape[0] > 10
    assert [k for k in lanes_b if k.startswith("lost:")] == [f"lost: corruption ({corrupt.shape[0]})"]
    np.testing.assert_array_equal(lanes_b[f"lost: corruption ({corrupt.shape[0]})"].get_offsets()[:, 0], corrupt[:, 1])
    # The blackout window is shaded on the forward panels only.
    assert any(p.get_label() == "blackout window" for p in _panels(fig, "forward")[0].patches)
    assert not _panels(fig, "backward")[0].patches


def test_loss_causes_split_network_losses_by_blackout_window():
    rows = np.array(
        [
            # seq, send, arrival, fate, duplicate, size
            [0, 0.10, np.nan, 1, 0, 72],  # loss model
            [1, 0.30, np.nan, 1, 0, 72],  # blackout: start inclusive
            [2, 0.35, np.nan, 1, 0, 72],  # blackout
            [3, 0.40, np.nan, 1, 0, 72],  # end exclusive: loss model
            [4, 0.50, np.nan, 2, 0, 72],  # queue
            [4, 0.50, np.nan, 1, 1, 72],  # a lost copy: not counted
            [5, 0.60, 0.62, 4, 0, 72],  # late: not a loss
        ]
    )
    effects = {"blackout": {"starts_s": [0.3], "ends_s": [0.4]}, "loss": {"model": "gilbert_elliott"}}
    got = loss_causes(rows, effects)
    assert list(got) == ["blackout", "burst loss (gilbert_elliott)", "queue overflow (rate limit)"]
    np.testing.assert_array_equal(got["blackout"], [0.30, 0.35])
    np.testing.assert_array_equal(got["burst loss (gilbert_elliott)"], [0.10, 0.40])
    np.testing.assert_array_equal(got["queue overflow (rate limit)"], [0.50])
    assert list(loss_causes(rows[:1], {})) == ["network"]


def test_buffer_occupancy_hand_computed():
    t = np.arange(11) * 0.001  # ticks, period 1 ms
    played = np.array([0, 2, 4])  # released: seq 0 at 3 ms, seq 2 at 5 ms, seq 4 at 9 ms
    release = t[[3, 5, 9]]
    rows = np.array(
        [
            # seq, send, arrival, fate, duplicate, size
            [0, 0.000, 0.0015, 0, 0, 72],  # held from 1.5 ms, played at 3 ms
            [1, 0.001, 0.0035, 4, 0, 72],  # late: skipped at 5 ms, when seq 2 is released
            [2, 0.002, 0.0039, 0, 0, 72],  # played at 5 ms
            [3, 0.003, 0.0059, 4, 0, 72],  # late: skipped at 9 ms, when seq 4 is released
            [4, 0.004, 0.0069, 0, 0, 72],  # played at 9 ms
            [5, 0.005, np.nan, 1, 0, 72],  # lost: never held
            [6, 0.006, 0.0079, 0, 0, 72],  # still held at the end
            [6, 0.006, 0.0085, 0, 1, 72],  # its duplicate copy: dropped on arrival, never held
            [7, 0.007, 0.0500, 0, 0, 72],  # in flight at the end: never held
        ]
    )
    occ = buffer_occupancy(rows, played, release, t)
    #                 t(ms): 0  1  2  3  4  5  6  7  8  9 10
    np.testing.assert_array_equal(occ, [0, 0, 1, 0, 2, 0, 1, 2, 3, 1, 1])
    np.testing.assert_array_equal(skip_times(rows, played, release), t[[5, 9]])
    # A packet older than a sample already released leaves on arrival.
    np.testing.assert_array_equal(buffer_exits(np.array([1]), np.array([0.006]), played, release), [0.006])


def test_network_panels_show_the_bag_delays_releases_skips_and_occupancy(run):
    _, sig = run
    fig = network_figure(sig)
    for direction in ("forward", "backward"):
        rows = sig.forward_packets if direction == "forward" else sig.backward_packets
        played = sig.forward_played_seq if direction == "forward" else sig.backward_played_seq
        release = sig.forward_release_s if direction == "forward" else sig.backward_release_s
        a_delay, a_events, a_occ = _panels(fig, direction)
        assert a_delay.get_ylabel().startswith("one-way delay (ms)")
        # Delivered packets: one dot each at (send time, (arrival - send) in ms).
        ok = (rows[:, 3] == 0) & (rows[:, 4] == 0) & (rows[:, 2] <= sig.t_s[-1])
        dots = next(c for k, c in _collections(a_delay).items() if k.startswith("delivered"))
        np.testing.assert_allclose(dots.get_offsets()[:, 0], rows[ok, 1])
        np.testing.assert_allclose(dots.get_offsets()[:, 1], (rows[ok, 2] - rows[ok, 1]) * 1e3)
        lanes = _collections(a_events)
        np.testing.assert_array_equal(lanes[f"released ({release.size})"].get_offsets()[:, 0], release)
        skips = skip_times(rows, played, release)
        np.testing.assert_array_equal(lanes[f"skipped, late ({skips.size})"].get_offsets()[:, 0], skips)
        (line,) = a_occ.get_lines()
        np.testing.assert_array_equal(line.get_xdata(), sig.t_s)
        np.testing.assert_array_equal(line.get_ydata(), buffer_occupancy(rows, played, release, sig.t_s))
        assert a_occ.get_ylabel() == "buffer\n(packets)"
    fwd_skips = skip_times(sig.forward_packets, sig.forward_played_seq, sig.forward_release_s)
    assert fwd_skips.size > 0  # jitter + adaptive buffer: some late packets, so the lane is exercised
    assert np.max(_panels(fig, "forward")[2].get_lines()[0].get_ydata()) >= 2  # the adaptive buffer holds packets
    assert fig.axes[-1].get_xlabel() == "time (s)"
    assert all(ax.get_shared_x_axes().joined(ax, fig.axes[0]) for ax in fig.axes)


def test_delay_axis_clips_a_few_extreme_delays_and_marks_them(run):
    _, sig = run
    rows = sig.forward_packets.copy()
    i = int(np.flatnonzero((rows[:, 3] == 0) & (rows[:, 2] < 0.5))[0])
    rows[i, 2] = rows[i, 1] + 5.0  # one packet 5 s late: an unclipped axis would squash the rest
    fig = network_figure(dataclasses.replace(sig, forward_packets=rows))
    a_delay = _panels(fig, "forward")[0]
    _, top = a_delay.get_ylim()
    assert top < 100.0  # ms: the 20 +- 4 ms delays fill the axis
    marks = next(c for k, c in _collections(a_delay).items() if k.startswith("above the axis: 1 "))
    np.testing.assert_array_equal(marks.get_offsets(), [[rows[i, 1], top]])


def test_energy_reservoir_is_drawn_distinctly_and_both_ranges_are_in_view(run):
    _, sig = run
    fig = energy_figure(sig)
    margins = energy_margins(sig)
    for k, (side, res) in enumerate((("master", sig.master_reservoir_j), ("slave", sig.slave_reservoir_j))):
        ax, dax = fig.axes[2 * 0 + k], fig.axes[2 + k]
        lines = _lines(ax)
        band = lines["controller reservoir (wide band)"]
        thin = lines["energy margin from plant signals"]
        np.testing.assert_array_equal(band.get_ydata(), res)
        np.testing.assert_array_equal(thin.get_ydata(), margins[side])
        assert band.get_linewidth() >= 4 * thin.get_linewidth()
        assert band.get_color() != thin.get_color() and band.get_zorder() < thin.get_zorder()
        lo, hi = ax.get_ylim()
        both = np.concatenate([res, margins[side]])
        assert lo <= both.min() and hi >= both.max()
        assert hi - lo <= 1.5 * (both.max() - both.min()) + 1e-6  # the curves fill the axis (no forced 0)
        i = int(np.argmin(margins[side]))
        mark = next(ln for lbl, ln in lines.items() if lbl.startswith("margin minimum"))
        assert (mark.get_xdata()[0], mark.get_ydata()[0]) == (sig.t_s[i], margins[side][i])
        (diff,) = dax.get_lines()
        np.testing.assert_array_equal(diff.get_ydata(), res - margins[side])
        # the check holds (round-off): said in words, on a +-1 nJ axis where the line is flat
        (said,) = dax.texts
        assert said.get_text().startswith("equal to round-off")
        assert dax.get_ylim() == pytest.approx((-1e-9, 1e-9))
    # a ledger that disagrees with the plant is said to
    broken = dataclasses.replace(sig, slave_reservoir_j=sig.slave_reservoir_j + 1e-3)
    (said,) = energy_figure(broken).axes[3].texts
    assert said.get_text().startswith("NOT equal: up to 0.001 J apart")


def test_long_runs_are_decimated_to_the_plot_width(run):
    _, sig = run
    n = 300_000  # ticks; the short run's signals and packets repeated
    reps = -(-n // sig.t_s.size)
    T = sig.period_s

    def long(a):
        return np.tile(a, reps)[:n] if a is not None else None

    rows = []
    for r in range(reps):
        block = sig.forward_packets.copy()
        block[:, 0] += r * sig.t_s.size
        block[:, 1:3] += r * sig.t_s.size * T
        rows.append(block)
    packets = np.concatenate(rows)
    rel = np.concatenate([sig.forward_release_s + r * sig.t_s.size * T for r in range(reps)])
    seq = np.concatenate([sig.forward_played_seq + r * sig.t_s.size for r in range(reps)])
    big = dataclasses.replace(
        sig,
        t_s=np.arange(n) * T,
        **{f: long(getattr(sig, f)) for f in (
            "operator_x_m", "operator_force_n", "master_x_m", "master_v_m_per_s", "master_force_n",
            "slave_x_m", "slave_force_n", "contact_n", "master_reservoir_j", "slave_reservoir_j")},
        forward_packets=packets,
        backward_packets=packets,
        forward_release_s=rel,
        backward_release_s=rel,
        forward_played_seq=seq,
        backward_played_seq=seq,
        forward_delays_s=np.tile(sig.forward_delays_s, reps),
        backward_delays_s=np.tile(sig.forward_delays_s, reps),
    )  # fmt: skip
    assert packets.shape[0] > 250_000
    for name, build in FIGURES.items():
        fig = build(big)
        for ax in fig.axes:
            for ln in ax.get_lines():
                assert len(ln.get_xdata()) <= 2 * DEFAULT_COLUMNS + 4, (name, ln.get_label())
            for c in ax.collections:
                bound = max(SCATTER_COLUMNS * SCATTER_ROWS, DEFAULT_COLUMNS)
                assert len(c.get_offsets()) <= bound, (name, c.get_label())


def test_decimation_keeps_every_column_extreme():
    rng = np.random.default_rng(0)
    t = np.arange(1_000_003) * 1e-3
    y = rng.normal(size=t.size)
    y[123_456] = 50.0
    y[777_777] = -50.0
    td, yd = minmax_envelope(t, y, columns=1000)
    assert td.size <= 2 * 1000 + 4 and np.all(np.diff(td) > 0)
    assert yd.max() == 50.0 and yd.min() == -50.0 and td[0] == t[0] and td[-1] == t[-1]
    k = -(-t.size // 1000)
    for col in (0, 17, 500, 999):
        seg = y[col * k : (col + 1) * k]
        inside = (td >= t[col * k]) & (td <= t[min((col + 1) * k, t.size) - 1])
        assert yd[inside].max() == seg.max() and yd[inside].min() == seg.min()
    small = np.arange(10.0)
    assert minmax_envelope(small, small, columns=5)[0] is small
    x = rng.uniform(0, 10, size=200_000)
    idx = thin_points(x, rng.uniform(0, 1, size=x.size), (0, 10), (0, 1), columns=100, rows=10, max_points=1000)
    assert 900 <= idx.size <= 1000 and np.all(np.diff(idx) > 0)
    ev = thin_events(np.sort(x), (0, 10), columns=100, max_points=1000)
    assert ev.size == 100


def test_sweep_labels_are_readable():
    keys = ("network.forward.effects.delay.jitter_s", "network.backward.effects.delay.jitter_s")
    assert key_label(keys) == "network.{forward,backward}.effects.delay.jitter_s"
    assert key_label(("scene.seed",)) == "scene.seed"
    wrapped = wrap_key("network.{forward,backward}.buffer.allowed_force_error_n", 30)
    assert wrapped.count("\n") >= 1 and max(len(x) for x in wrapped.split("\n")) <= 31
    assert metric_unit("buffering_delay_forward_mean_s", [0.02]) == ("ms", 1e3, "buffering_delay_forward_mean")
    assert metric_unit("late_loss_rate_forward", [0.1])[:2] == ("%", 100.0)
    assert metric_unit("force_rms_error_n", [1.0])[0] == "N"
    assert metric_unit("wire_bits_per_s_forward", [1e5])[:2] == ("kbit/s", 1e-3)
    assert metric_unit("wire_bits_per_s_forward", [1.1e6])[:2] == ("Mbit/s", 1e-6)


def _sweep_rows(params, metric_values):
    rows = []
    for combo, seed, v in metric_values:
        rows.append({"run": "x", "combo": combo, "seed": seed, "summary": {"late_loss_rate_forward": v,
                     "buffering_delay_forward_mean_s": v / 10}})  # fmt: skip
    return rows, aggregate(params, rows, ["late_loss_rate_forward", "buffering_delay_forward_mean_s"])


def test_sweep_two_parameters_one_numeric_is_one_series_per_value():
    policy = Param(("network.forward.buffer.policy", "network.backward.buffer.policy"), ("none", "fixed"))
    jitter = Param(("network.forward.effects.delay.jitter_s", "network.backward.effects.delay.jitter_s"),
                   ("0.002", "0.005", "0.01"))  # fmt: skip
    vals = [((p, j), s, 0.1 * (i + 1) + 0.01 * s) for i, (p, j) in enumerate(
        [(p, j) for p in policy.values for j in jitter.values]) for s in (1, 2)]  # fmt: skip
    rows, agg = _sweep_rows([policy, jitter], vals)
    metrics = ["late_loss_rate_forward", "buffering_delay_forward_mean_s"]
    fig = sweep_figure([policy.keys, jitter.keys], [policy.values, jitter.values], rows, agg, metrics)
    top, bottom = fig.axes
    legend = top.get_legend()
    assert legend.get_title().get_text().replace("\n", "") == "network.{forward,backward}.buffer.policy"
    assert [t.get_text() for t in legend.get_texts()] == ["runs", "none", "fixed"]
    assert bottom.get_xlabel() == "network.{forward,backward}.effects.delay.jitter_s"
    assert [t.get_text() for t in bottom.get_xticklabels()] == ["0.002", "0.005", "0.01"]
    assert top.get_ylabel() == "late loss rate forward\n(%)"
    assert bottom.get_ylabel().replace("\n", " ") == "buffering delay forward mean (ms)"
    # The "fixed" series: x the jitter values, y the mean over seeds in % (seeds 1, 2: +0.01, +0.02).
    line = next(c for c in top.containers if c.get_label() == "fixed").lines[0]
    np.testing.assert_allclose(np.asarray(line.get_xdata(), dtype=float), [0.002, 0.005, 0.01])
    np.testing.assert_allclose(np.asarray(line.get_ydata(), dtype=float), [100 * (0.1 * i + 0.015) for i in (4, 5, 6)])


def test_sweep_many_categorical_values_turn_their_tick_labels():
    policy = Param(("network.forward.buffer.policy",), tuple(f"policy_{i}" for i in range(14)))
    rows, agg = _sweep_rows([policy], [((v,), 1, 0.1) for v in policy.values])
    fig = sweep_figure([policy.keys], [policy.values], rows, agg, ["late_loss_rate_forward"])
    (ax,) = fig.axes
    labels = ax.get_xticklabels()
    assert [t.get_text() for t in labels] == list(policy.values)
    assert all(t.get_rotation() == 45 for t in labels)
    few = Param(("a.b",), ("x", "y"))
    rows, agg = _sweep_rows([few, few], [(("x", "y"), 1, 0.1)])
    fig = sweep_figure([("a.b",), ("c.d",)], [("x",), ("y",)], rows, agg, ["late_loss_rate_forward"])
    (ax,) = fig.axes
    assert [t.get_text() for t in ax.get_xticklabels()] == ["x\ny"]
    assert ax.get_xlabel() == "a.b\nc.d"
    assert math.isclose(ax.get_lines()[0].get_ydata()[0], 10.0)


def _same_plot_data(a, b, path="data"):
    """Every field of two PlotData equal, arrays exactly (NaN equal to NaN)."""
    if dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            _same_plot_data(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            _same_plot_data(a[k], b[k], f"{path}[{k}]")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same_plot_data(x, y, f"{path}[{i}]")
    elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        np.testing.assert_array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float), err_msg=path)
    elif isinstance(a, float) and math.isnan(a):
        assert isinstance(b, float) and math.isnan(b), path
    else:
        assert a == b, path


def test_streamed_plot_data_is_the_whole_array_reduction(run):
    """What `run` draws (streamed from the bag) is what the whole signals reduce to."""
    from haptic_teleop.analysis import bag_plotdata, plotdata

    out, sig = run
    ref = plotdata.from_signals(sig)
    _same_plot_data(ref, bag_plotdata._from_bag(out / "bag"))
    # as `run` calls it: the lag from summary.json
    lag_s = summarize_bag(out / "bag")["force_alignment_lag_s"]
    _same_plot_data(ref, bag_plotdata._from_bag(out / "bag", lag_s))


def test_streamed_plot_data_of_a_decimated_run(tmp_path):
    """A run long enough that every series is decimated (> 2 x 2400 ticks) and the scatter and
    event lanes are thinned (> 20000 packets, releases)."""
    from haptic_teleop.analysis import bag_plotdata, plotdata

    out = tmp_path / "long"
    assert main(["run", "jitter", "--set", "scene.duration_s=21", "--out", str(out), "--quiet", "--no-plots"]) == 0
    sig = load_signals(out / "bag")
    ref = plotdata.from_signals(sig)
    assert ref.contact[0].size < sig.t_s.size and ref.network["forward"].groups[0][2] > 20_000
    _same_plot_data(ref, bag_plotdata._from_bag(out / "bag"))


@pytest.mark.parametrize("seed", range(4))
def test_accumulators_match_the_whole_array_decimation(seed):
    from haptic_teleop.analysis.plotdata import Envelope, Events, Thin

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 60_000))
    t = np.arange(n) * 1e-3
    y = np.round(rng.normal(size=n), 2)  # ties: the first minimum and maximum must be kept
    cuts = np.sort(rng.integers(0, n, 7))
    env, thin, ev = Envelope(n, 300), Thin((0.0, n * 1e-3), (-3.0, 3.0), max_points=5000), Events((0.0, n * 1e-3))
    for a, b in zip([0, *cuts], [*cuts, n], strict=True):
        env.add(t[a:b], y[a:b])
        thin.add(t[a:b], y[a:b])
        ev.add(t[a:b])
    for got, want in zip(env.result(), minmax_envelope(t, y, 300), strict=True):
        np.testing.assert_array_equal(got, want)
    idx = thin_points(t, y, (0.0, n * 1e-3), (-3.0, 3.0), max_points=5000)
    for got, want in zip(thin.result(), (t[idx], y[idx]), strict=True):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(ev.result(), thin_events(t, (0.0, n * 1e-3)))


def test_plot_data_memory_does_not_grow_with_the_run(tmp_path):
    """tracemalloc peak of the streamed reduction: a 16 s run allocates about what a 4 s one does."""
    import tracemalloc

    from haptic_teleop.analysis.bag_plotdata import from_bag

    peaks = []
    for d in (4, 16):
        out = tmp_path / f"r{d}"
        args = ["run", "jitter", "--set", f"scene.duration_s={d}", "--out", str(out), "--quiet", "--no-plots"]
        assert main(args) == 0
        tracemalloc.start()
        try:
            from_bag(out / "bag")
            peaks.append(tracemalloc.get_traced_memory()[1] / 1024)
        finally:
            tracemalloc.stop()
    assert peaks[1] < 1.25 * peaks[0] + 512, peaks


def test_streamed_plot_data_in_tiny_blocks(run, monkeypatch):
    """The bag read in blocks of a few rows: state carried across every block boundary."""
    from haptic_teleop.analysis import bag_plotdata, plotdata
    from haptic_teleop.record.reader import BagReader, TopicData

    rng = np.random.default_rng(5)
    blocks, packet_blocks = BagReader.blocks, BagReader.packet_blocks

    def cut(n):
        c = np.sort(rng.integers(0, n, max(1, n // 7)))
        return [(a, b) for a, b in zip([0, *c], [*c, n], strict=True) if b > a]

    def small_blocks(self, topic):
        for d in blocks(self, topic):
            for a, b in cut(d.log_ns.size):
                st = None if d.stamp_ns is None else d.stamp_ns[a:b]
                yield TopicData(d.log_ns[a:b], st, d.values[a:b], d.fields)

    def small_packets(self, topic):
        for rows in packet_blocks(self, topic):
            yield from (rows[a:b] for a, b in cut(len(rows)))

    monkeypatch.setattr(BagReader, "blocks", small_blocks)
    monkeypatch.setattr(BagReader, "packet_blocks", small_packets)
    out, sig = run
    _same_plot_data(plotdata.from_signals(sig), bag_plotdata._from_bag(out / "bag"))
