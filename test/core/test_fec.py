"""FEC baseline (core/fec.py) driven tick by tick through real core.link.Link objects with
constructed loss traces (the n-th packet lost when pattern[n] is set)."""

from __future__ import annotations

import numpy as np
import pytest

from haptic_teleop.core.fec import FecConfig, FecDecoder, build_fec
from haptic_teleop.core.link import DELIVERED, Link
from haptic_teleop.core.netconfig import DelayConfig, LinkTraces, LossConfig, NetworkEffectsConfig, build_link

PERIOD_NS = 1_000_000
DELAY = 2  # ticks


def trace_link(lost: list[int], ticks: int, delay_ticks: int = DELAY) -> Link:
    pattern = np.zeros(ticks, dtype=bool)
    pattern[lost] = True
    cfg = NetworkEffectsConfig(
        loss=LossConfig(model="trace", file="pattern.csv"), delay=DelayConfig(delay_s=delay_ticks * 1e-3)
    )
    return build_link(cfg, 1, "forward", traces=LinkTraces(loss=pattern))


def signal(ticks: int, dim: int = 3, seed: int = 5) -> list[tuple[float, ...]]:
    """Random values on a 1/64 grid: sums and differences are exact, and no predictor guesses them."""
    rng = np.random.default_rng(seed)
    return [tuple(float(v) for v in rng.integers(-512, 512, dim) / 64.0) for _ in range(ticks)]


def run(
    cfg: FecConfig, link: Link, samples: list[tuple[float, ...]]
) -> tuple[FecDecoder, list[tuple[float, ...] | None]]:
    enc, dec = build_fec(cfg, PERIOD_NS)
    played = []
    for n in range(len(samples) + 3 * cfg.k + DELAY):
        now = n * PERIOD_NS
        if n < len(samples):
            for p in enc.send(n, now, samples[n]):
                link.send(p)
        for p in link.deliver(now):
            assert dec.receive(p, now) == []
        played.append(dec.sample(n, now))
    return dec, played


def test_repetition_recovers_every_burst_up_to_k_exactly() -> None:
    k, ticks = 3, 80
    lost = [10, 20, 21, 30, 31, 32, 50, 52, 54]  # bursts of 1, 2, 3 = k, and scattered singles
    x = signal(ticks)
    link = trace_link(lost, ticks)
    dec, played = run(FecConfig(scheme="repetition", k=k, wait_ticks=k), link, x)
    assert link.lost == len(lost)
    assert dec.counters["recovered"] == len(lost)
    assert dec.counters["recovered_late"] == 0
    assert {p.seq for p in dec.recovered_log} == set(lost)
    for p in dec.recovered_log:
        assert p.payload == x[p.seq]
    # Waiting k ticks, every tick plays the true sample: the loss is invisible.
    for n in range(DELAY + k, ticks):
        assert played[n] == x[n - DELAY - k], n


def test_repetition_does_not_recover_a_burst_of_k_plus_one() -> None:
    k, ticks = 3, 60
    lost = [20, 21, 22, 23]
    x = signal(ticks)
    dec, played = run(FecConfig(scheme="repetition", k=k, wait_ticks=k), trace_link(lost, ticks), x)
    assert {p.seq for p in dec.recovered_log} == {21, 22, 23}
    assert not dec.rec.has(20)
    assert played[20 + DELAY + k] != x[20]  # predicted, and the values are random


def test_without_waiting_recoveries_are_late_and_kept_for_the_record() -> None:
    k, ticks = 2, 50
    lost = [10, 11, 30]
    x = signal(ticks)
    dec, played = run(FecConfig(scheme="repetition", k=k, wait_ticks=0), trace_link(lost, ticks), x)
    assert dec.counters["recovered"] == 3
    assert dec.counters["recovered_late"] == 3
    assert played[30 + DELAY] != x[30]  # played a prediction at the lost sample's slot
    assert played[31 + DELAY] == x[31]  # then the newest again, no added latency


def test_parity_recovers_one_loss_per_window_with_the_next_packet() -> None:
    k, ticks = 4, 80
    lost = [10, 20, 25, 40, 60]  # at least k apart: one unknown per window
    x = signal(ticks)
    dec, played = run(FecConfig(scheme="parity", k=k, wait_ticks=1), trace_link(lost, ticks), x)
    assert {p.seq for p in dec.recovered_log} == set(lost)
    for p in dec.recovered_log:
        assert p.payload == x[p.seq]  # exact: the values add exactly on their 1/64 grid
    assert dec.counters["recovered_late"] == 0  # one tick of waiting is enough for isolated losses
    for n in range(DELAY + 1, ticks):
        assert played[n] == x[n - DELAY - 1], n


def test_parity_recovers_a_burst_up_to_k_after_k_more_packets_not_longer() -> None:
    k, ticks = 3, 80
    x = signal(ticks)
    dec, played = run(FecConfig(scheme="parity", k=k, wait_ticks=2 * k - 1), trace_link([20, 21, 22], ticks), x)
    assert {p.seq for p in dec.recovered_log} == {20, 21, 22}
    assert all(p.payload == x[p.seq] for p in dec.recovered_log)
    for n in range(DELAY + 2 * k - 1, ticks):
        assert played[n] == x[n - DELAY - 2 * k + 1], n
    # A burst of k + 1: only its last k samples come back.
    dec, _ = run(FecConfig(scheme="parity", k=k), trace_link([20, 21, 22, 23], ticks), x)
    assert {p.seq for p in dec.recovered_log} == {21, 22, 23}
    # Every other packet lost: each window's older unknowns were recovered already, so every loss
    # comes back with the next packet, in order.
    lost = list(range(20, 40, 2))
    dec, _ = run(FecConfig(scheme="parity", k=4, wait_ticks=1), trace_link(lost, ticks), x)
    assert [p.seq for p in dec.recovered_log] == lost
    assert dec.counters["recovered_late"] == 0
    assert all(p.payload == x[p.seq] for p in dec.recovered_log)


def test_repetition_recovers_exactly_what_its_rule_says_under_gilbert_loss() -> None:
    k, ticks = 2, 3000
    cfg = NetworkEffectsConfig(loss=LossConfig(model="gilbert", p=0.05, r=0.5), delay=DelayConfig(delay_s=0.002))
    link = build_link(cfg, 3, "forward")
    x = signal(ticks, dim=1)
    dec, _ = run(FecConfig(scheme="repetition", k=k), link, x)
    got = [p.fate == DELIVERED for p in link.log]
    lost = [m for m in range(ticks) if not got[m]]
    expected = {m for m in lost if any(got[j] for j in range(m + 1, min(m + k, ticks - 1) + 1))}
    assert len(lost) > 100 and len(expected) < len(lost)  # bursts longer than k occurred
    assert {p.seq for p in dec.recovered_log} == expected


@pytest.mark.parametrize(("scheme", "k", "floats"), [("repetition", 1, 6), ("repetition", 4, 15), ("parity", 4, 6)])
def test_payload_layout_and_size_seen_on_the_wire(scheme: str, k: int, floats: int) -> None:
    link = trace_link([], 20)
    x = signal(20)
    run(FecConfig(scheme=scheme, k=k), link, x)
    assert len(link.log) == 20
    for p in link.log:
        assert len(p.payload) == floats
        assert p.size_bytes == 20 + 8 * floats  # std_msgs/Float64MultiArray
        assert p.payload[:3] == x[p.seq]  # the sample first
        if scheme == "repetition" and p.seq >= k:
            assert p.payload[3:] == tuple(v for j in range(1, k + 1) for v in x[p.seq - j])
        if scheme == "parity" and p.seq >= k:
            assert p.payload[3:] == tuple(sum(x[p.seq - j][i] for j in range(1, k + 1)) for i in range(3))


def test_bad_config_names_the_field() -> None:
    with pytest.raises(ValueError, match="k must be in"):
        FecConfig(k=0)
    with pytest.raises(ValueError, match="scheme must be one of"):
        FecConfig(scheme="reed_solomon")


@pytest.mark.parametrize("jitter_s", [0.0, 0.002])
def test_parity_recovers_exactly_what_its_rule_says_under_gilbert_loss(jitter_s: float) -> None:
    """With jitter packets overtake one another: a late packet can complete a later one's window."""
    k, ticks = 3, 3000
    delay = DelayConfig(delay_s=0.004, jitter_s=jitter_s, distribution="uniform")
    cfg = NetworkEffectsConfig(loss=LossConfig(model="gilbert", p=0.05, r=0.4), delay=delay)
    link = build_link(cfg, 4, "forward")
    x = signal(ticks, dim=2)
    dec, _ = run(FecConfig(scheme="parity", k=k), link, x)
    got = [p.fate == DELIVERED for p in link.log]
    # The rule, applied until nothing changes: a received packet p solves its window
    # [p - k, p - 1] when exactly one sample there is unknown.
    known = list(got)
    changed = True
    while changed:
        changed = False
        for p in range(ticks):
            window = range(max(0, p - k), p)
            unknown = [m for m in window if not known[m]]
            if got[p] and len(unknown) == 1:
                known[unknown[0]] = changed = True
    expected = {m for m in range(ticks) if known[m] and not got[m]}
    assert len(expected) > 100 and len(expected) < ticks - sum(got)  # some losses are beyond its reach
    recovered = {p.seq: p.payload for p in dec.recovered_log}
    # (With jitter a delayed original can be beaten by its recovery: recovered, not lost.)
    assert {m for m in recovered if not got[m]} == expected
    assert all(v == x[m] for m, v in recovered.items())


@pytest.mark.parametrize("scheme", ["repetition", "parity"])
def test_a_stream_starting_late_or_skipping_ticks_carries_what_the_sender_had(scheme: str) -> None:
    """A live sender's seqs are its tick stamps: the stream starts at any seq (redundancy before it
    is its first sample, a parity window is clipped there) and an overrun skips ticks (each skipped
    tick holds the sample sent before it)."""
    k, n0 = 3, 1000
    enc, _ = build_fec(FecConfig(scheme=scheme, k=k), PERIOD_NS)
    x = signal(10, dim=2)
    sent = [0, 1, 2, 5, 6, 7]  # ticks n0 + 3 and n0 + 4 skipped
    had = {n0 + s: x[s] for s in sent} | {n0 + 3: x[2], n0 + 4: x[2]}  # the sender's sample at each tick
    for s in sent:
        n = n0 + s
        (p,) = enc.send(n, n * PERIOD_NS, x[s])
        assert p.payload[:2] == x[s]
        older = [had[max(n0, n - j)] for j in range(1, k + 1)]
        if scheme == "repetition":
            assert p.payload[2:] == tuple(v for o in older for v in o)
        else:
            window = [had[m] for m in range(max(n0, n - k), n)]
            assert p.payload[2:] == tuple(sum(o[i] for o in window) for i in range(2))


def test_the_compiled_loops_compose_cores_fec() -> None:
    # the FEC kernel's encoder and decoder steps are core/fec.py's functions, compiled: no copy
    from haptic_teleop.core import fec
    from haptic_teleop.engine.compiled import codec_fec

    for name in ("fec_sent", "fec_payload", "fec_receive"):
        assert getattr(codec_fec, name).py_func.__code__ is getattr(fec, name).__code__, name
    # and the tick calls them
    names = codec_fec.fec_tick.py_func.__code__.co_names
    assert {"fec_sent", "fec_payload", "fec_receive", "rec_sample"} <= set(names)
