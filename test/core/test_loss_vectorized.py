"""Loss decided a window at once (`apply_all`, `Link.schedule_all`) gives what `apply` gives packet by
packet, bit for bit: a replayed loss pattern (`TraceLoss`, `trace_run`) and netem-correlated
Bernoulli loss (`bernoulli_run` over its inner source's numbers, `UniformSource.take`), behind a
blackout and before a (jittered) delay, in windows of uneven sizes, with the plain runs and the
compiled ones (engine/compiled/link_runs.py). Copula-correlated loss has no vectorized form."""

from __future__ import annotations

import numpy as np
import pytest
from windowed import MS, N, in_windows, one_by_one, send_times

from haptic_teleop.core.delay import ConstantDelay, Delay
from haptic_teleop.core.link import DELIVERED, LOST_NETWORK, Link
from haptic_teleop.core.loss import BernoulliLoss, Blackout, TraceLoss
from haptic_teleop.core.netconfig import LinkTraces, NetworkEffectsConfig, build_link
from haptic_teleop.core.uniform import NetemCorrelatedUniform, effect_rng
from haptic_teleop.typedconfig import build

BLACKOUT = [(500 * MS, 700 * MS), (2000 * MS, 2001 * MS)]


def assert_same(link: Link, ref: Link, send: np.ndarray, runs) -> tuple[np.ndarray, np.ndarray]:
    arrival_ref, fate_ref = one_by_one(ref, send)
    arrival, fate = in_windows(link, send, runs)
    assert np.array_equal(fate, fate_ref)
    assert np.array_equal(arrival, arrival_ref)
    assert (link.sent, link.lost) == (ref.sent, ref.lost)
    for e, e_ref in zip(link.effects, ref.effects, strict=True):
        assert getattr(e, "dropped", None) == getattr(e_ref, "dropped", None)
    return arrival, fate


# --------------------------------------------------------------------------------------------
# A replayed loss pattern.


def trace_link(pattern: np.ndarray, repeat: bool) -> Link:
    return Link([Blackout(BLACKOUT), TraceLoss(pattern, repeat), ConstantDelay(0.002)])


@pytest.mark.parametrize("length", [37, N + 1000], ids=["shorter", "longer"])
@pytest.mark.parametrize("repeat", [True, False])
def test_trace_loss_in_windows_equals_send(length, repeat, runs):
    """A pattern shorter than the run (repeated, or passing every packet past its end) and one
    longer than it: the same fates, drops and position in the pattern afterwards."""
    pattern = np.random.default_rng(length).random(length) < 0.3
    send = send_times(2)
    ref, link = trace_link(pattern, repeat), trace_link(pattern, repeat)
    _, fate = assert_same(link, ref, send, runs)
    trace, trace_ref = link.effects[1], ref.effects[1]
    assert trace._n == trace_ref._n == N
    assert 0 < trace.dropped < N and link.effects[0].dropped > 0  # the blackout's packets are not the trace's
    # The pattern, where the blackout lost nothing first.
    expected = np.array([pattern[k % length] if repeat or k < length else False for k in range(N)])
    assert np.array_equal(fate != DELIVERED, expected | (fate_blackout(send)))
    # And it goes on where the windows left it, packet by packet too.
    more = send[-1] + MS * np.arange(1, 200, dtype=np.int64)
    assert np.array_equal(one_by_one(link, more)[1], one_by_one(ref, more)[1][N:])  # (link logged none before)


def fate_blackout(send: np.ndarray) -> np.ndarray:
    return np.any([(send >= a) & (send < b) for a, b in BLACKOUT], axis=0)


# --------------------------------------------------------------------------------------------
# netem-correlated Bernoulli loss.


def bernoulli_link(seed: int, correlation: float, jitter: bool) -> Link:
    effects: list = [
        Blackout(BLACKOUT),
        BernoulliLoss(0.45, effect_rng(seed, "forward", "loss"), correlation),
        ConstantDelay(0.0015),
    ]
    if jitter:
        effects.append(Delay(0.002, jitter_s=0.004, rng=effect_rng(seed, "forward", "delay"), correlation=0.25))
    return Link(effects)


@pytest.mark.parametrize("jitter", [False, True], ids=["no_jitter", "jitter"])
@pytest.mark.parametrize("correlation", [0.0, 0.25, 0.9])
def test_netem_correlated_bernoulli_in_windows_equals_send(correlation, jitter, runs):
    seed = 5
    send = send_times(seed)
    ref, link = bernoulli_link(seed, correlation, jitter), bernoulli_link(seed, correlation, jitter)
    _, fate = assert_same(link, ref, send, runs)
    loss, loss_ref = link.effects[1], ref.effects[1]
    assert 0 < loss.dropped < N
    if correlation > 0.0:
        src, src_ref = loss._u.__self__, loss_ref._u.__self__
        assert type(src) is NetemCorrelatedUniform
        assert src._last == src_ref._last
        # correlated draws lose packets in runs: a loss follows a loss more often than on average
        lost = fate[~fate_blackout(send)] == LOST_NETWORK
        after_loss = np.count_nonzero(lost[1:] & lost[:-1]) / np.count_nonzero(lost[:-1])
        assert after_loss > lost.mean() + 0.05
    # The same numbers next, from every stream.
    for _ in range(5000):
        assert loss._u() == loss_ref._u()
    if jitter:
        d, d_ref = link.effects[3], ref.effects[3]
        assert d._last_arrival == d_ref._last_arrival
        for _ in range(5000):
            assert d._ju() == d_ref._ju()


def test_a_scene_link_with_correlated_loss_and_a_trace_is_decided_in_windows(runs):
    """As `build_link` builds them (each effect on its own stream), in the scene's order."""
    for effects, traces in (
        ({"loss": {"probability": 0.1, "correlation": 0.5}, "delay": {"delay_s": 0.01, "jitter_s": 0.002}}, None),
        ({"loss": {"model": "trace", "file": "t.csv", "repeat": False}, "delay": {"delay_s": 0.01}}, "trace"),
    ):
        cfg = build(NetworkEffectsConfig, effects)
        lt = LinkTraces(loss=np.random.default_rng(3).random(2500) < 0.2) if traces else None
        send = np.arange(N, dtype=np.int64) * MS
        assert_same(build_link(cfg, 9, "forward", traces=lt), build_link(cfg, 9, "forward", traces=lt), send, runs)


def test_copula_correlated_loss_is_not_vectorized():
    rng = np.random.default_rng
    copula = BernoulliLoss(0.1, rng(1), 0.25, "gaussian_copula")
    assert not copula.vectorized
    with pytest.raises(ValueError, match="no vectorized form"):
        copula.apply_all(np.zeros(3, dtype=np.int64), np.zeros(3, dtype=np.int64), np.zeros(3, dtype=np.int64))
    link = Link([copula, ConstantDelay(0.01)])
    assert not link.vectorized
    with pytest.raises(ValueError, match="cannot decide a run at once"):
        link.schedule_all(np.arange(3, dtype=np.int64))
    # uncorrelated under the copula model (plain uniforms), netem-correlated, a trace: vectorized
    for e in (
        BernoulliLoss(0.1, rng(2), 0.0, "gaussian_copula"),
        BernoulliLoss(0.1, rng(3), 0.25),
        TraceLoss([True, False]),
    ):
        assert e.vectorized and Link([e]).vectorized
