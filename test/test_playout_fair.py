"""Seed 000's network-adaptive buffering (`network_adaptive`) and the fair playout experiment
(docs/playout_claim.md, "The haptic-synchronization claim, tested fairly")."""

import csv
import math
from argparse import Namespace

import numpy as np
import pytest

from haptic_teleop.core.link import Packet
from haptic_teleop.core.playout_config import BufferConfig, build_buffer
from haptic_teleop.core.playout_seed import NetworkAdaptiveBuffer
from haptic_teleop.scene.load import find_scene, load_scene

MS = 1_000_000
T = MS  # 1 kHz
# Delays above the minimum: a fixed pattern spanning 0 .. 30 ms, minimum 10 ms.
PATTERN_MS = [(k * 7) % 31 for k in range(200)]


def _fed(buf, base_ms=10, offset_ns=0):
    for k, x in enumerate(PATTERN_MS):
        send = k * T
        buf.push(Packet(k, send, (0.0,), 16), send + (base_ms + x) * MS + offset_ns)
    return buf


@pytest.mark.parametrize(
    ("allow_delay_ms", "allow_loss_ms", "d0_ms", "expected_ms", "met"),
    [
        (100, 10, 5, 20, True),  # the holds bound it: max(x) - L_a = 30 - 10
        (20, 0, 10, 10, False),  # the allowable delay bounds it: D_a - d0 = 10 < 30
        (100, 40, 5, 0, True),  # every hold the window predicts is within L_a: no buffering
        (8, 10, 10, 0, False),  # D_a below d0: nothing is left for buffering
    ],
)
def test_buffering_time_is_the_analysis_rule(allow_delay_ms, allow_loss_ms, d0_ms, expected_ms, met):
    """b = min(max(0, max(x) - L_a), max(0, D_a - d0)), and the playout point is the window's least
    relative delay plus b, whatever the clock offset."""
    for offset in (0, 987 * 10**9):
        buf = NetworkAdaptiveBuffer(
            T,
            allowable_delay_ns=allow_delay_ms * MS,
            allowable_loss_time_ns=allow_loss_ms * MS,
            min_one_way_delay_ns=d0_ms * MS,
        )
        _fed(buf, offset_ns=offset)
        assert buf.buffering_ns == expected_ms * MS
        assert buf.requirement_met is met
        assert buf.target_delay_ns == (10 + expected_ms) * MS + offset


def test_network_adaptive_is_built_from_the_scene_and_plays_on_its_schedule():
    buf = build_buffer(
        BufferConfig(
            policy="network_adaptive", allowable_delay_s=0.1, allowable_loss_time_s=0.01, min_one_way_delay_s=0.005
        ),
        T,
    )
    assert isinstance(buf, NetworkAdaptiveBuffer)
    _fed(buf)
    assert buf.buffering_ns == 20 * MS
    # The schedule: sample k is played at send + 10 ms + 20 ms, not on arrival.
    k = len(PATTERN_MS)
    buf.push(Packet(k, k * T, (0.0,), 16), k * T + 11 * MS)
    released = [t for t in range(k * T, k * T + 40 * MS, T) if (p := buf.release(t)) is not None and p.seq == k]
    assert released == [k * T + 30 * MS]


def test_engine_passes_the_transparency_analysis_and_the_link_minimum():
    """The engine gives the buffer the allowable delay and loss time the transparency analysis
    predicts for the scene's E (analysis.transparency's contact model, built independently of the
    assembly's) and the link's minimum delay; the link never delivers below that minimum."""

    from haptic_teleop.analysis.transparency import contact_model
    from haptic_teleop.core.link import DELIVERED
    from haptic_teleop.core.transparency import allowable_delay, allowable_loss_time, transparent_loss_time
    from haptic_teleop.engine.lockstep import Engine

    scene = load_scene(find_scene("seed_contact_playout"), overrides=["scene.duration_s=1.0", *_NO_REORDER])
    c = scene.config
    model = contact_model(scene.config, {}, c.operator.speed_m_per_s)
    e = c.analysis.allowed_force_error_n
    d_a = allowable_delay(model, e)
    l_a = allowable_loss_time(model, e, transparent_loss_time(model, 0.0, model.master_start_force_n))
    assert model.binding and 0.05 < d_a < 1.0 and l_a == pytest.approx(e / (2 * 0.1 / 0.001 * 0.01))
    engine = Engine(scene)
    d0 = 0.02 - 0.004 * 3.668329285121323  # constant + sinusoid minimum (0) - the normal table's reach
    for buf in (engine.forward_buffer, engine.backward_buffer):
        assert isinstance(buf, NetworkAdaptiveBuffer)
        assert buf._allow_delay == round(d_a * 1e9)
        assert buf._allow_loss == round(l_a * 1e9)
        assert buf._d0 == pytest.approx(d0 * 1e9, abs=1)
    r = engine.run(handle_sigint=False)
    for log in (r.forward_log, r.backward_log):
        arrived = log[(log[:, 3] != 1) & (log[:, 4] == 0)]
        assert np.min(arrived[:, 2] - arrived[:, 1]) >= d0 - 1e-9
        assert np.any(arrived[:, 3] == DELIVERED)
    with_reorder = Engine(load_scene(find_scene("seed_contact_playout"), overrides=["scene.duration_s=0.1"]))
    assert with_reorder.backward_buffer._d0 == 0  # reordered packets skip the delay


_NO_REORDER = ["network.forward.effects.reorder=null", "network.backward.effects.reorder=null"]


def test_constant_latency_baseline_is_above_the_network_delay():
    """`fixed` with `fixed_above_delay_s` of a run's delays plays every packet of the same seed's
    network (common random numbers) after its arrival: D above every delay, nothing late."""
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.studies.replications.playout import _buffer_overrides, _delays, _run, fixed_above_delay_s
    from haptic_teleop.studies.replications.recorded import BagRuns

    short = ("scene.duration_s=1.5", "operator.duration_s=0.9", "scene.seed=2")
    none, _ = _run((*short, *_buffer_overrides({"policy": "none"})), BagRuns(), "none")
    delays = _delays(none.bwd_log)
    b = fixed_above_delay_s(delays, 0.001)
    engine = Engine(
        load_scene(
            find_scene("seed_contact_playout"),
            overrides=[*short, *_buffer_overrides({"policy": "fixed", "buffering_time_s": repr(b)})],
        )
    )
    r = engine.run(handle_sigint=False)
    assert np.allclose(_delays(r.backward_log), delays)  # the same network draws
    assert engine.backward_buffer.playout_delay_ns * 1e-9 > np.max(delays)
    assert engine.backward_buffer.late == 0


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    from haptic_teleop.studies.replications import playout

    out = tmp_path_factory.mktemp("playout") / "out"
    args = Namespace(
        out=str(out),
        seeds=3,
        policies=",".join(playout.POLICIES),
        configs="binding",
        quick=True,
        set=None,
        quiet=True,
        discard_bags=False,
    )
    assert playout.main(args) == 0
    with (out / "playout_runs.csv").open() as fh:
        runs = list(csv.DictReader(fh))
    return out, runs


def test_quick_experiment_writes_paired_tables(quick):
    out, runs = quick
    from haptic_teleop.studies.replications.playout import POLICIES

    for name in ("playout.csv", "playout_paired.csv", "playout.md", "playout.png"):
        assert (out / name).stat().st_size > 0
    seeds = {p: sorted(int(r["seed"]) for r in runs if r["policy"] == p) for p in POLICIES}
    assert all(s == [1, 2, 3] for s in seeds.values())  # every policy on the same seeds
    with (out / "playout_paired.csv").open() as fh:
        paired = {r["policy"]: r for r in csv.DictReader(fh)}
    assert set(paired) == set(POLICIES) - {"network_adaptive"}
    # The paired mean is the mean of the seed-by-seed differences.
    key = "force_rms_error_vs_reference_n"
    for p in ("adaptive", "none"):
        diff = [
            float(a[key]) - float(b[key])
            for a in runs
            if a["policy"] == p
            for b in runs
            if b["policy"] == "network_adaptive" and b["seed"] == a["seed"]
        ]
        assert float(paired[p][f"{key}_minus_seed_policy_mean"]) == pytest.approx(np.mean(diff))
    text = (out / "playout.md").read_text()
    assert "network-adaptive (seed 000)" in text and "worse on" in text


def test_every_run_of_the_experiment_is_a_bag_in_the_index(quick):
    """The quick experiment's runs (the undisturbed reference, then per seed: arrival run and
    each other policy) are bags in run order, named in bags/index.csv, and each opens."""
    from haptic_teleop.record.reader import BagReader
    from haptic_teleop.studies.replications.playout import POLICIES

    out, runs = quick
    with (out / "bags" / "index.csv").open() as fh:
        index = list(csv.DictReader(fh))
    assert len(index) == 1 + len(runs)  # 'none' is the arrival run: one bag for both
    assert index[0]["bag"] == "001_binding_undisturbed"
    assert {r["bag"] for r in index} == {d.name for d in (out / "bags").iterdir() if d.is_dir()}
    assert {f"binding_{p}_seed{s}" for p in POLICIES for s in (1, 2, 3)} == {r["bag"][4:] for r in index[1:]}
    with BagReader(out / "bags" / index[-1]["bag"]) as reader:
        assert reader.read_ticks().shape[0] == 1500


def test_policies_that_should_differ_do(quick):
    _, runs = quick

    def col(policy, key):
        return np.array([float(r[key]) for r in runs if r["policy"] == policy])

    buf = "buffering_backward_mean_ms"
    assert np.all(col("none", buf) == 0.0)
    assert np.all(col("adaptive", buf) > 10.0) and np.all(col("network_adaptive", buf) < 5.0)
    assert np.all(col("fixed_above", "late_loss_rate_backward") < 0.01) and np.all(
        col("none", "late_loss_rate_backward") > 0.3
    )
    err = "force_rms_error_vs_reference_n"
    # The seed's buffer beats the ones that buffer tens of ms on every seed.
    assert np.all(col("network_adaptive", err) < col("adaptive", err))
    assert np.all(col("network_adaptive", err) < col("fixed_above", err))
    assert all(math.isfinite(v) for v in col("percentile", err))


def test_bad_input_is_one_line(tmp_path, capsys):
    from haptic_teleop.cli.main import main
    from haptic_teleop.errors import ConfigError

    code = main(["experiment", "playout", "--policies", "none,nope", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--policies" in err
    assert not (tmp_path / "x").exists()
    # network_adaptive on a scene without a contact model and without its two keys
    with pytest.raises(ConfigError, match="allowable_delay_s and allowable_loss_time_s"):
        load_scene(
            find_scene("wall_contact"),
            overrides=["operator.profile=hold", "network.backward.buffer.policy=network_adaptive"],
        )
    ok = ["network.backward.buffer.allowable_delay_s=0.05", "network.backward.buffer.allowable_loss_time_s=0.01"]
    load_scene(
        find_scene("wall_contact"),
        overrides=["operator.profile=hold", "network.backward.buffer.policy=network_adaptive", *ok],
    )
