"""The runs compiled (engine/compiled/link_runs.py) decide what core/loss.py's and core/delay.py's
plain functions decide, from the same draws (the compiled loop's vectorized schedule uses them)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.core import loss

link_runs = pytest.importorskip("haptic_teleop.engine.compiled.link_runs")

probability = st.floats(0.0, 1.0)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(0, 3000), bad=st.booleans(), p=probability, r=probability)
def test_compiled_gilbert_run_is_the_plain_one(seed, n, bad, p, r):
    draws = np.random.default_rng(seed).random(2 * n)
    plain, compiled = np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.bool_)
    end_plain = loss.gilbert_run(bad, draws, p, r, 0.7, 0.01, plain)
    end_compiled = link_runs.RUNS["gilbert_run"](bad, draws, p, r, 0.7, 0.01, compiled)
    assert bool(end_compiled) == end_plain
    assert np.array_equal(plain, compiled)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(0, 3000), state=st.sampled_from([1, 2, 3, 4]), p=probability)
def test_compiled_four_state_run_is_the_plain_one(seed, n, state, p):
    draws = np.random.default_rng(seed).random(n)
    args = (p * 0.5, 0.3, 0.2, 0.1, p * 0.4)
    plain, compiled = np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.bool_)
    end_plain = loss.four_state_run(state, draws, *args, plain)
    end_compiled = link_runs.RUNS["four_state_run"](state, draws, *args, compiled)
    assert int(end_compiled) == end_plain
    assert np.array_equal(plain, compiled)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(0, 3000), rho=st.sampled_from([0.0, 0.25, 0.9]), p=probability)
def test_compiled_bernoulli_run_is_the_plain_one(seed, n, rho, p):
    """netem-correlated Bernoulli loss's run (rho 0: the fresh numbers as they are)."""
    fresh = np.random.default_rng(seed).random(n)
    plain, compiled = np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.bool_)
    end_plain = loss.bernoulli_run(fresh, rho, 0.5, p, plain)
    end_compiled = link_runs.RUNS["bernoulli_run"](fresh, rho, 0.5, p, compiled)
    assert float(end_compiled) == end_plain
    assert np.array_equal(plain, compiled)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    n=st.integers(0, 3000),
    length=st.integers(1, 4000),
    n0=st.integers(0, 10_000),
    repeat=st.booleans(),
)
def test_compiled_trace_run_is_the_plain_one(seed, n, length, n0, repeat):
    """The replayed pattern's run, from any position, past the pattern's end or not."""
    pattern = (np.random.default_rng(seed).random(length) < 0.3).astype(np.float64)
    plain, compiled = np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.bool_)
    end_plain = loss.trace_run(pattern, n0, repeat, plain)
    end_compiled = link_runs.RUNS["trace_run"](pattern, n0, repeat, compiled)
    assert int(end_compiled) == end_plain == n0 + n
    assert np.array_equal(plain, compiled)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    n=st.integers(0, 3000),
    rho=st.sampled_from([0.0, 0.25, 0.9]),
    distribution=st.sampled_from(["uniform", "normal", "pareto", "paretonormal", None]),
    keep_order=st.booleans(),
    base_ms=st.sampled_from([0.0, 0.5, 20.0]),
    reorder=st.sampled_from([None, (0.1, 1, 0.0, 0), (0.3, 3, 0.25, 1), (1.0, 5, 0.9, 4)]),
)
def test_compiled_delay_run_is_the_plain_one(seed, n, rho, distribution, keep_order, base_ms, reorder):
    """The jittered and reordering delay's run (core/delay.py `delay_run`; None: no jitter, or no
    reordering: no numbers) compiled gives the plain one's arrivals and end state, bit for bit."""
    from haptic_teleop.core.delay import delay_run
    from haptic_teleop.core.uniform import jitter_table

    rng = np.random.default_rng(seed)
    arrivals = np.cumsum(rng.integers(0, 3_000_000, n)).astype(np.int64)
    delivered = rng.random(n) < 0.8
    fresh = np.zeros(0) if distribution is None else rng.random(n)
    table = np.array(() if distribution in ("uniform", None) else jitter_table(distribution), dtype=np.float64)
    args = (rho, 0.5, table, len(table), base_ms * 1e6, 0.0 if distribution is None else 4e6, keep_order, -(1 << 62))
    p, gap, r_rho, counter = reorder if reorder is not None else (0.0, 1, 0.0, 0)
    r_fresh = np.zeros(0) if reorder is None else rng.random(n)
    r_args = (r_fresh, r_rho, 0.5, p, gap, counter)
    plain, compiled = arrivals.copy(), arrivals.copy()
    extra = np.zeros(0) if seed % 2 else rng.random(n) * 2e7  # a time-varying part, or none
    end_plain = delay_run(plain, delivered, fresh, *args, *r_args, extra)
    end_compiled = link_runs.RUNS["delay_run"](compiled, delivered, fresh, *args, *r_args, extra)
    kinds = (float, int, float, int, int)
    assert tuple(k(v) for k, v in zip(kinds, end_compiled, strict=True)) == end_plain
    assert np.array_equal(plain, compiled)
    if reorder is not None and n > 100:
        assert end_plain[4] > 0  # some delivered packets skipped the delay


def test_a_gilbert_elliott_link_is_decided_in_windows_with_the_compiled_run():
    """The schedule's path: `Link.schedule_all` with the compiled runs, window by window, equals
    `send` packet by packet (bursty_loss's chain)."""
    from haptic_teleop.core.link import Packet
    from haptic_teleop.core.loss import GilbertElliottLoss

    def link():
        from haptic_teleop.core.delay import ConstantDelay
        from haptic_teleop.core.link import Link

        ge = GilbertElliottLoss(0.01, 0.25, 0.7, 0.001, np.random.default_rng(5))
        return Link([ConstantDelay(0.02), ge])

    n = 20_000
    one = link()
    for i in range(n):
        one.send(Packet(i, i * 1_000_000, (), 64))
    windowed = link()
    assert windowed.vectorized
    fates = [
        windowed.schedule_all(np.arange(a, b, dtype=np.int64) * 1_000_000, link_runs.RUNS)[1]
        for a, b in ((0, 1), (1, 10_000), (10_000, n))
    ]
    assert np.concatenate(fates).tolist() == [p.fate for p in one.log]
    assert windowed.lost == one.lost > 0
