"""The jittered and reordering delay decided a window at once (`Delay.apply_all`,
`Link.schedule_all`) gives what `Delay.apply` gives packet by packet, bit for bit, from the same
random numbers: uncorrelated and netem-correlated jitter of each table shape, netem reordering
(uncorrelated and netem-correlated, gaps of 1 and 3), with and without `keep_order`, behind a loss
and a constant delay, in windows of uneven sizes, with the plain run (`delay_run`) and the compiled
one (engine/compiled/link_runs.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from windowed import MS, N, in_windows, one_by_one, send_times

from haptic_teleop.core.delay import ConstantDelay, Delay, PiecewiseDelay, SinusoidDelay, profile_run
from haptic_teleop.core.link import DELIVERED, Link
from haptic_teleop.core.loss import BernoulliLoss
from haptic_teleop.core.netconfig import NetworkEffectsConfig
from haptic_teleop.core.uniform import NetemCorrelatedUniform, UniformSource, effect_rng
from haptic_teleop.scene.traces import build_scene_link
from haptic_teleop.typedconfig import build


def jitter_link(seed: int, distribution: str, correlation: float, keep_order: bool, jitter_s: float = 0.004) -> Link:
    """A loss, a constant delay (moves the time a packet reaches the jitter), then the jitter: 2 ms
    of delay against 4 ms of jitter, so packets overtake one another and some delays clamp at 0."""
    return Link(
        [
            BernoulliLoss(0.2, effect_rng(seed, "forward", "loss")),
            ConstantDelay(0.0015),
            Delay(
                0.002,
                jitter_s=jitter_s,
                distribution=distribution,
                rng=effect_rng(seed, "forward", "delay") if jitter_s > 0.0 else None,
                correlation=correlation,
                keep_order=keep_order,
            ),
        ]
    )


@pytest.mark.parametrize("keep_order", [False, True])
@pytest.mark.parametrize("correlation", [0.0, 0.25])
@pytest.mark.parametrize("distribution", ["normal", "uniform", "pareto"])
def test_windows_equal_send_bit_for_bit(distribution, correlation, keep_order, runs):
    seed = 11
    send = send_times(seed)
    ref = jitter_link(seed, distribution, correlation, keep_order)
    arrival_ref, fate_ref = one_by_one(ref, send)
    link = jitter_link(seed, distribution, correlation, keep_order)
    arrival, fate = in_windows(link, send, runs)
    assert np.array_equal(fate, fate_ref)
    assert np.array_equal(arrival, arrival_ref)
    assert (link.sent, link.lost) == (ref.sent, ref.lost) and 0 < link.lost < N
    delivered = arrival[fate == DELIVERED]
    in_order = bool(np.all(np.diff(delivered) >= 0))
    assert in_order == keep_order  # the jitter reorders, unless kept in order
    assert np.count_nonzero(arrival == send + int(0.0015 * 1e9)) > 0  # some delays clamped at 0
    # The same state after: the correlated stream's last number, the last delivered arrival, and
    # the next number drawn (`take` leaves the source where `next` calls would have).
    d_ref, d = ref.effects[2], link.effects[2]
    assert d._last_arrival == d_ref._last_arrival
    for _ in range(5000):
        assert d._ju() == d_ref._ju()


@pytest.mark.parametrize("keep_order", [False, True])
def test_a_delay_without_jitter_is_decided_in_windows(keep_order, runs):
    send = send_times(3)
    ref = jitter_link(3, "normal", 0.0, keep_order, jitter_s=0.0)
    arrival_ref, fate_ref = one_by_one(ref, send)
    link = jitter_link(3, "normal", 0.0, keep_order, jitter_s=0.0)
    arrival, fate = in_windows(link, send, runs)
    assert np.array_equal(fate, fate_ref) and np.array_equal(arrival, arrival_ref)
    assert np.array_equal(arrival, send + 3_500_000)


def test_take_gives_the_numbers_next_gives():
    """`UniformSource.take` between `next` calls, inside a block, across blocks, and for none, hands
    out the same stream as `next` alone; so does a NetemCorrelatedUniform's inner source after its
    constructor drew its first number."""
    ref, src = UniformSource(np.random.default_rng(4)), UniformSource(np.random.default_rng(4))
    got: list[float] = []
    for step in (3, 0, 5, 4000, 1, 10_000, 0, 2, 4096, 7):
        got += src.take(step).tolist() if step != 2 else [src.next(), src.next()]
        got.append(src.next())
    assert got == [ref.next() for _ in range(len(got))]
    a = NetemCorrelatedUniform(np.random.default_rng(9), 0.25)
    b = NetemCorrelatedUniform(np.random.default_rng(9), 0.25)
    fresh_a, fresh_b = a._fresh.__self__, b._fresh.__self__
    assert fresh_a.take(5000).tolist() == [fresh_b.next() for _ in range(5000)]
    assert a.next() == b.next()


def reorder_link(seed: int, gap: int, correlation: float, jitter: bool, keep_order: bool) -> Link:
    """A loss, a constant delay, then a delay (2 ms, with 4 ms of netem-correlated jitter or none)
    that reorders: 1 in 10 packets, after `gap` - 1 kept ones, skips it."""
    return Link(
        [
            BernoulliLoss(0.2, effect_rng(seed, "forward", "loss")),
            ConstantDelay(0.0015),
            Delay(
                0.002,
                jitter_s=0.004 if jitter else 0.0,
                rng=effect_rng(seed, "forward", "delay") if jitter else None,
                correlation=0.25,
                keep_order=keep_order,
                reorder_probability=0.1,
                reorder_correlation=correlation,
                reorder_gap_packets=gap,
                reorder_rng=effect_rng(seed, "forward", "reorder"),
            ),
        ]
    )


@pytest.mark.parametrize("keep_order", [False, True], ids=["any_order", "keep_order"])
@pytest.mark.parametrize("jitter", [False, True], ids=["no_jitter", "jitter"])
@pytest.mark.parametrize("correlation", [0.0, 0.25])
@pytest.mark.parametrize("gap", [1, 3])
def test_reordering_in_windows_equals_send(gap, correlation, jitter, keep_order, runs):
    """netem reordering: a packet that skips the delay keeps the time it reached it (not held behind
    the others, even with `keep_order`) and counts as reordered if delivered; the counter, both
    streams and the last delivered arrival go on where they were."""
    seed = 21
    send = send_times(seed)
    ref = reorder_link(seed, gap, correlation, jitter, keep_order)
    arrival_ref, fate_ref = one_by_one(ref, send)
    link = reorder_link(seed, gap, correlation, jitter, keep_order)
    arrival, fate = in_windows(link, send, runs)
    assert np.array_equal(fate, fate_ref)
    assert np.array_equal(arrival, arrival_ref)
    assert (link.sent, link.lost, link.effects[0].dropped) == (ref.sent, ref.lost, ref.effects[0].dropped)
    d, d_ref = link.effects[2], ref.effects[2]
    assert d.reordered == d_ref.reordered > 0
    assert (d._counter, d._last_arrival) == (d_ref._counter, d_ref._last_arrival)
    got = fate == DELIVERED
    skipped = arrival[got] == send[got] + 1_500_000  # reached the delay then, left then
    if not jitter:  # (a jittered delay may clamp at 0 too)
        assert np.count_nonzero(skipped) == d.reordered
    assert not np.all(np.diff(arrival[got]) >= 0)  # reordered, even with keep_order
    for draw, draw_ref in ((d._ru, d_ref._ru), (d._ju, d_ref._ju)):
        if draw is not None:
            if type(draw.__self__) is NetemCorrelatedUniform:
                assert draw.__self__._last == draw_ref.__self__._last
            for _ in range(5000):
                assert draw() == draw_ref()


@pytest.mark.parametrize("keep_order", [False, True], ids=["any_order", "keep_order"])
def test_a_skipped_packet_holds_nothing_behind_it(keep_order, runs):
    """Packets reach the reordering delay out of order (a jitter before it): a skipped one leaves
    when it came, and a later packet is held (`keep_order`) only behind the last one delayed."""
    seed = 8

    def link() -> Link:
        return Link(
            [
                Delay(0.0, jitter_s=0.004, rng=effect_rng(seed, "forward", "jitter"), distribution="uniform"),
                Delay(
                    0.002, keep_order=keep_order, reorder_probability=0.3,
                    reorder_rng=effect_rng(seed, "forward", "reorder"),
                ),
            ]
        )  # fmt: skip

    send = send_times(seed)
    ref, windowed = link(), link()
    arrival_ref, fate_ref = one_by_one(ref, send)
    arrival, fate = in_windows(windowed, send, runs)
    assert np.array_equal(fate, fate_ref) and np.array_equal(arrival, arrival_ref)
    d, d_ref = windowed.effects[1], ref.effects[1]
    assert (d.reordered, d._counter, d._last_arrival) == (d_ref.reordered, d_ref._counter, d_ref._last_arrival)
    assert d.reordered > 0


def test_what_apply_all_cannot_decide_is_not_vectorized():
    """A time-varying delay given as a plain function, copula-correlated jitter or reordering, and
    jitter and reordering drawn from one generator: packet by packet only."""
    rng = np.random.default_rng
    shared = rng(10)
    cases = [
        Delay(0.01, profile=lambda t: 0.0),
        Delay(0.01, jitter_s=0.002, rng=rng(1), profile=lambda t: 1e6),
        Delay(
            0.01, reorder_probability=0.1, reorder_correlation=0.25, reorder_rng=rng(4),
            correlation_model="gaussian_copula",
        ),
        Delay(0.01, jitter_s=0.002, rng=rng(5), correlation=0.25, correlation_model="gaussian_copula"),
        Delay(0.01, jitter_s=0.002, rng=shared, reorder_probability=0.1, reorder_rng=shared),
    ]  # fmt: skip
    for d in cases:
        assert not d.vectorized
        with pytest.raises(ValueError, match="no vectorized form"):
            d.apply_all(np.zeros(3, dtype=np.int64), np.zeros(3, dtype=np.int64), np.zeros(3, dtype=np.int64))
        link = Link([BernoulliLoss(0.1, rng(6)), d])
        assert not link.vectorized
        with pytest.raises(ValueError, match="cannot decide a run at once"):
            link.schedule_all(np.arange(3, dtype=np.int64))
    # what is: no jitter, uncorrelated, netem-correlated, and copula with no correlation (plain uniforms)
    for d in (
        Delay(0.01),
        Delay(0.01, jitter_s=0.002, rng=rng(7), keep_order=True),
        Delay(0.01, jitter_s=0.002, rng=rng(8), correlation=0.5),
        Delay(0.01, jitter_s=0.002, rng=rng(9), correlation_model="gaussian_copula"),
        Delay(0.01, reorder_probability=0.1, reorder_rng=rng(11)),
        Delay(0.01, jitter_s=0.002, rng=rng(12), reorder_probability=0.1, reorder_correlation=0.5, reorder_rng=rng(13)),
        Delay(0.01, reorder_probability=0.1, reorder_rng=rng(14), correlation_model="gaussian_copula"),
        Delay(0.01, profile=PiecewiseDelay([0.0, 1.0], [0.0, 0.01])),
        Delay(0.01, jitter_s=0.002, rng=rng(15), profile=SinusoidDelay(0.0, 0.02, 0.5)),
    ):
        assert d.vectorized and Link([d]).vectorized


def scene_link(effects: dict, seed: int) -> Link:
    return build_scene_link(build(NetworkEffectsConfig, effects), seed, "forward")


LOSS = {
    "bernoulli": {"probability": 0.3},
    "gilbert_elliott": {"model": "gilbert_elliott", "p": 0.05, "r": 0.25, "one_minus_h": 0.7, "one_minus_k": 0.01},
}


@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    delay_ms=st.sampled_from([0.0, 1.0, 50.0]),
    jitter=st.sampled_from([("normal", 0.0), ("uniform", 0.25), ("pareto", 0.5), ("paretonormal", 0.25)]),
    keep_order=st.booleans(),
    loss=st.sampled_from(sorted(LOSS)),
    blackout=st.booleans(),
    reorder=st.sampled_from([None, (0.1, 1, 0.0), (0.2, 3, 0.25)]),
)
def test_a_scene_link_with_jitter_is_decided_in_windows(seed, delay_ms, jitter, keep_order, loss, blackout, reorder):
    """As the scene builds it (`build_link`: each effect's own stream), a link with jitter (and
    reordering) behind a blackout and a loss model: `schedule_all` in windows decides what `send`
    decides."""
    distribution, correlation = jitter
    delay = {"delay_s": delay_ms / 1000, "jitter_s": 0.003, "distribution": distribution}
    effects: dict = {"delay": {**delay, "correlation": correlation, "keep_order": keep_order}, "loss": LOSS[loss]}
    if reorder is not None and delay_ms > 0.0:  # (reorder needs a delay)
        p, gap, rho = reorder
        effects["reorder"] = {"probability": p, "gap_packets": gap, "correlation": rho}
    if blackout:
        effects["blackout"] = {"starts_s": [0.5, 2.0], "ends_s": [0.7, 2.001]}
    send = np.arange(N, dtype=np.int64) * MS
    arrival_ref, fate_ref = one_by_one(scene_link(effects, seed), send)
    arrival, fate = in_windows(scene_link(effects, seed), send, None)
    assert np.array_equal(fate, fate_ref) and np.array_equal(arrival, arrival_ref)


def test_a_scene_link_with_copula_jitter_or_reordering_is_refused():
    jitter = {"delay_s": 0.01, "jitter_s": 0.002}
    copula = {"correlation_model": "gaussian_copula"}
    for effects in (
        {"delay": jitter, "reorder": {"probability": 0.1, "correlation": 0.25}, **copula},
        {"delay": {**jitter, "correlation": 0.25}, **copula},
    ):
        link = scene_link(effects, 1)
        assert not link.vectorized
        with pytest.raises(ValueError, match="cannot decide a run at once"):
            link.schedule_all(np.arange(3, dtype=np.int64))
    assert scene_link({"delay": {**jitter, "correlation": 0.25}}, 1).vectorized  # netem's model
    assert scene_link({"delay": jitter, "reorder": {"probability": 0.1, "correlation": 0.25}}, 1).vectorized


PROFILES = {
    "ramp": lambda: PiecewiseDelay([0.5, 2.0, 3.0], [0.0, 0.03, 0.005]),
    "steps": lambda: PiecewiseDelay([0.5, 2.0, 3.0], [0.0, 0.03, 0.005], interpolation="step"),
    "sinusoid": lambda: SinusoidDelay(0.0, 0.02, 0.7, phase_s=0.1),
}


@pytest.mark.parametrize("reorder", [False, True], ids=["no_reorder", "reorder"])
@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_a_time_varying_delay_is_decided_in_windows(profile, reorder, runs):
    """A schedule (a trace is one too) or a sinusoid on top of jitter (and reordering): the same
    arrivals in windows as packet by packet; the profile's values from `profile_run`, the function
    the profile's own call runs."""

    def link() -> Link:
        return Link(
            [
                BernoulliLoss(0.1, effect_rng(4, "forward", "loss")),
                Delay(
                    0.002, jitter_s=0.001, rng=effect_rng(4, "forward", "delay"), profile=PROFILES[profile](),
                    reorder_probability=0.05 if reorder else 0.0,
                    reorder_rng=effect_rng(4, "forward", "reorder") if reorder else None,
                ),
            ]
        )  # fmt: skip

    send = send_times(4)
    arrival_ref, fate_ref = one_by_one(link(), send)
    arrival, fate = in_windows(link(), send, runs)
    assert np.array_equal(fate, fate_ref) and np.array_equal(arrival, arrival_ref)
    got = fate == DELIVERED
    assert np.ptp(arrival[got] - send[got]) > 15 * MS  # the profile moved the delay
    p = PROFILES[profile]()
    out = np.empty(len(send))
    (runs or {}).get("profile_run", profile_run)(*p.profile_args(), send, out)
    assert out.tolist() == [p(int(t)) for t in send]
