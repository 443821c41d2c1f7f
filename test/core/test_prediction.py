"""The "prediction only" baseline (core/prediction.py) driven through real core.link.Link objects."""

from __future__ import annotations

import numpy as np
import pytest

from haptic_teleop.core.link import Link
from haptic_teleop.core.netconfig import DelayConfig, LinkTraces, LossConfig, NetworkEffectsConfig, build_link
from haptic_teleop.core.prediction import (
    PredictionConfig,
    Reconstructor,
    build_prediction,
    float64_multiarray_size,
)

PERIOD_NS = 1_000_000


def trace_link(lost: list[int], ticks: int, delay_s: float) -> Link:
    pattern = np.zeros(ticks, dtype=bool)
    pattern[lost] = True
    cfg = NetworkEffectsConfig(loss=LossConfig(model="trace", file="pattern.csv"), delay=DelayConfig(delay_s=delay_s))
    return build_link(cfg, 1, "forward", traces=LinkTraces(loss=pattern))


def run(cfg: PredictionConfig, link: Link, samples: list[tuple[float, ...]]) -> list[tuple[float, ...] | None]:
    enc, dec = build_prediction(cfg, PERIOD_NS)
    played = []
    for n, x in enumerate(samples):
        now = n * PERIOD_NS
        for p in enc.send(n, now, x):
            link.send(p)
        for p in link.deliver(now):
            assert dec.receive(p, now) == []
        played.append(dec.sample(n, now))
    return played


def ramp(n: int) -> tuple[float, float]:
    return (0.5 * n - 3.0, -0.25 * n)  # dyadic: extrapolation is exact


def test_ramp_reproduced_exactly_over_bernoulli_gaps() -> None:
    ticks, delay = 400, 3
    cfg = NetworkEffectsConfig(
        loss=LossConfig(model="bernoulli", probability=0.3), delay=DelayConfig(delay_s=delay * 1e-3)
    )
    link = build_link(cfg, 7, "forward")
    played = run(PredictionConfig(), link, [ramp(n) for n in range(ticks)])
    assert link.lost > 60  # there were gaps to predict over
    start = delay + 12  # two samples received by then (p(first 12 all lost but one) is negligible)
    for n in range(start, ticks):
        assert played[n] == ramp(n - delay), n


def test_hold_mode_holds_the_last_sample() -> None:
    link = trace_link([10, 11, 12], 30, 0.0)
    played = run(PredictionConfig(gap="hold"), link, [ramp(n) for n in range(30)])
    assert played[10] == played[11] == played[12] == ramp(9)
    assert played[13] == ramp(13)


def test_extrapolation_stops_at_its_limit_then_holds() -> None:
    lost = list(range(10, 30))
    link = trace_link(lost, 40, 0.0)
    played = run(PredictionConfig(max_extrapolation_s=0.005), link, [ramp(n) for n in range(40)])
    for n in range(10, 15):
        assert played[n] == ramp(n)
    for n in range(15, 30):
        assert played[n] == ramp(14)  # 5 ticks past the last sample (9), then held
    assert played[30] == ramp(30)


def test_late_sample_improves_the_base_but_never_moves_playback_back() -> None:
    rec = Reconstructor("extrapolate", 50)
    rec.add(0, (0.0,), fresh=True)
    rec.add(1, (1.0,), fresh=True)
    assert rec.sample(1) == (1.0,)
    assert rec.sample(2) == (2.0,)  # predicted
    assert rec.sample(3) == (3.0,)
    rec.add(3, (10.0,), fresh=False)  # a late recovery of slot 3 (already played)
    assert rec.late == 1
    assert rec.sample(4) == (14.5,)  # extrapolated from (1, 1.0) and (3, 10.0), slot kept at 4
    rec.add(6, (6.0,), fresh=False)  # a retransmission ahead of the slot: played when its slot comes
    assert rec.sample(5) == (19.0,)
    assert rec.sample(6) == (6.0,)


def test_every_sample_sent_once_and_sized() -> None:
    enc, _ = build_prediction(PredictionConfig(), PERIOD_NS)
    packets = [p for n in range(5) for p in enc.send(n, n * PERIOD_NS, (1.0, 2.0, 3.0))]
    assert [p.seq for p in packets] == list(range(5))
    assert all(p.payload == (1.0, 2.0, 3.0) and p.size_bytes == 20 + 3 * 8 for p in packets)
    assert enc.counters["sent"] == 5


def test_size_matches_ros_serialization() -> None:
    serialization = pytest.importorskip("rclpy.serialization")
    msg = pytest.importorskip("std_msgs.msg")
    for floats in (0, 1, 2, 3, 4, 9):
        m = msg.Float64MultiArray()
        m.data = [0.5] * floats
        assert float64_multiarray_size(floats) == len(serialization.serialize_message(m))


def test_bad_config_names_the_field() -> None:
    with pytest.raises(ValueError, match="gap must be one of"):
        PredictionConfig(gap="guess")
    with pytest.raises(ValueError, match="max_extrapolation_s"):
        PredictionConfig(max_extrapolation_s=-1.0)


def test_the_compiled_loops_run_cores_reconstruction() -> None:
    # prediction's, FEC's and ARQ's kernels compose core's reconstruction: no copy of its steps
    from haptic_teleop.core import prediction as pr
    from haptic_teleop.engine.compiled import codec_arq, codec_deadband, codec_fec

    for mod, names in (
        (codec_fec, ("rec_take", "rec_choose", "rec_give", "rec_sample")),
        (codec_deadband, ("rec_take", "rec_sample")),
        (codec_arq, ("rec_take", "rec_choose", "rec_give")),
    ):
        for name in names:
            assert getattr(mod, name).py_func.__code__ is getattr(pr, name).__code__, (mod.__name__, name)
