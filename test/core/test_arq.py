"""ARQ baseline (core/arq.py): data forward and ACKs backward, each over its own real
core.link.Link, tick by tick."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from haptic_teleop.core.arq import (
    ACK_WINDOW,
    SEED_000_EXPERIMENT,
    ArqConfig,
    ArqDecoder,
    ArqEncoder,
    build_arq,
    cumulative_seqs,
)
from haptic_teleop.core.link import DELIVERED, Link
from haptic_teleop.core.netconfig import (
    BlackoutConfig,
    DelayConfig,
    LinkTraces,
    LossConfig,
    NetworkEffectsConfig,
    build_link,
)

PERIOD_NS = 1_000_000
MS = 1_000_000


def link(
    delay_ms: float, *, blackout_ms: tuple[float, float] | None = None, lost: list[int] | None = None, seed: int = 1
) -> Link:
    traces = LinkTraces()
    loss = None
    if lost is not None:
        pattern = np.zeros(max(lost) + 1, dtype=bool)
        pattern[lost] = True
        loss = LossConfig(model="trace", file="pattern.csv", repeat=False)
        traces = LinkTraces(loss=pattern)
    blackout = None if blackout_ms is None else BlackoutConfig((blackout_ms[0] * 1e-3,), (blackout_ms[1] * 1e-3,))
    cfg = NetworkEffectsConfig(blackout=blackout, loss=loss, delay=DelayConfig(delay_s=delay_ms * 1e-3))
    return build_link(cfg, seed, "forward", traces=traces)


def signal(ticks: int, dim: int = 2) -> list[tuple[float, ...]]:
    rng = np.random.default_rng(9)
    return [tuple(float(v) for v in rng.integers(-512, 512, dim) / 64.0) for _ in range(ticks)]


def run(
    cfg: ArqConfig, fwd: Link, back: Link, samples: list[tuple[float, ...]], tail: int = 300
) -> tuple[ArqEncoder, ArqDecoder, list[tuple[float, ...] | None]]:
    enc, dec = build_arq(cfg, PERIOD_NS)
    played = []
    for n in range(len(samples) + tail):
        now = n * PERIOD_NS
        for a in back.deliver(now):
            enc.feedback(a, now)
        if n < len(samples):
            for p in enc.send(n, now, samples[n]):
                fwd.send(p)
        for p in fwd.deliver(now):
            for a in dec.receive(p, now):
                back.send(a)
        for a in dec.acks(n, now):  # the cumulative ACK (ack_every_ticks > 1), as CodecChannel.step
            back.send(a)
        played.append(dec.sample(n, now))
    return enc, dec, played


def transmissions(fwd: Link, seq: int) -> list[int]:
    return [p.send_time_ns // MS for p in fwd.log if p.seq == seq]


@pytest.mark.parametrize("cfg", SEED_000_EXPERIMENT)
def test_lossless_link_sends_nothing_extra(cfg: ArqConfig) -> None:
    ticks = 200
    fwd, back = link(1.0), link(1.0)  # round trip 2 ms, under both experiment timeouts
    x = signal(ticks)
    enc, dec, played = run(cfg, fwd, back, x)
    c = enc.counters
    assert c["sent"] == c["samples"] == ticks and c["retransmitted"] == 0 and c["gave_up"] == 0
    assert c["acked"] == ticks and enc.pending == 0
    assert dec.counters["acks_sent"] == ticks and dec.counters["duplicates"] == 0
    assert all(p.size_bytes == 20 + 8 * 3 for p in fwd.log)  # sample (2) + attempt (1)
    assert all(p.size_bytes == 20 + 8 * 1 for p in back.log)  # the ACK
    assert played[1 : ticks + 1] == x  # one tick of delay, every sample


def test_retransmits_exactly_after_the_timeout() -> None:
    cfg = ArqConfig(timeout_s=0.025, max_retransmissions=4)
    fwd, back = link(2.0, lost=[10]), link(2.0)  # the original of sample 10 is lost
    x = signal(100)
    enc, dec, _ = run(cfg, fwd, back, x)
    assert transmissions(fwd, 10) == [10, 35]
    assert enc.counters["retransmitted"] == 1 and enc.counters["gave_up"] == 0 and enc.pending == 0
    assert dec.counters["recovered"] == 1
    assert dec.counters["recovered_late"] == 1  # played the newest meanwhile (wait_ticks 0)
    assert dec.rec.get(10) == x[10]


@pytest.mark.parametrize("k", [1, 4])
def test_never_more_than_nu_retransmissions_then_gives_up(k: int) -> None:
    mu, nu = 25, 4
    cfg = ArqConfig(timeout_s=mu * 1e-3, max_retransmissions=nu, ack_every_ticks=k)
    start, end = 10, 111  # every packet sent in [10, 111) ms is lost
    fwd, back = link(2.0, blackout_ms=(start, end)), link(2.0)
    x = signal(200)
    enc, dec, _ = run(cfg, fwd, back, x)
    # Sample s goes out at s, s + mu, ... s + nu mu until a copy leaves outside the blackout.
    expected_retx = 0
    expected_gave_up = 0
    for s in range(200):
        times = [s + j * mu for j in range(nu + 1)]
        first_ok = next((j for j, t in enumerate(times) if not start <= t < end), None)
        want = times if first_ok is None else times[: first_ok + 1]
        assert transmissions(fwd, s) == want, s
        expected_retx += len(want) - 1
        expected_gave_up += first_ok is None
    assert expected_gave_up == 1  # sample 10: 10, 35, 60, 85, 110 all in the blackout
    assert enc.counters["retransmitted"] == expected_retx
    assert enc.counters["gave_up"] == expected_gave_up
    assert enc.pending == 0
    assert not dec.rec.has(10)


def test_gives_up_after_one_retransmission_with_the_short_timeout() -> None:
    cfg = SEED_000_EXPERIMENT[1]  # 4 ms, 1 retransmission
    fwd, back = link(1.0, blackout_ms=(20, 25)), link(1.0)
    enc, _, _ = run(cfg, fwd, back, signal(60))
    assert transmissions(fwd, 20) == [20, 24]  # both lost: given up
    assert transmissions(fwd, 21) == [21, 25]  # the retransmission gets through
    assert enc.counters["gave_up"] == 1  # sample 20 (21..24 come back at 25..28)
    assert enc.counters["retransmitted"] == 5


def test_lost_ack_causes_one_harmless_duplicate() -> None:
    cfg = ArqConfig(timeout_s=0.025, max_retransmissions=4)
    fwd, back = link(2.0), link(2.0, lost=[5])  # the ACK of sample 5 is lost
    x = signal(80)
    enc, dec, played = run(cfg, fwd, back, x)
    assert not any(p.fate == DELIVERED for p in back.log if p.seq == 5 and p.send_time_ns == 7 * MS)
    assert transmissions(fwd, 5) == [5, 30]
    assert enc.counters["retransmitted"] == 1 and enc.pending == 0
    assert dec.counters["duplicates"] == 1
    assert played[2:82] == x  # the duplicate changed nothing


def test_waiting_plays_retransmissions_in_time() -> None:
    cfg = ArqConfig(timeout_s=0.004, max_retransmissions=1, wait_ticks=4)
    fwd, back = link(1.0, lost=[10, 30]), link(1.0)
    x = signal(60)
    _, dec, played = run(cfg, fwd, back, x)
    assert dec.counters["recovered"] == 2 and dec.counters["recovered_late"] == 0
    assert played[5:65] == x  # 1 tick of delay + 4 of waiting: every sample, none predicted


def test_bad_config_names_the_field() -> None:
    with pytest.raises(ValueError, match="timeout_s"):
        ArqConfig(timeout_s=0.0)
    with pytest.raises(ValueError, match="max_retransmissions"):
        ArqConfig(max_retransmissions=-1)


# Cumulative selective ACKs (ack_every_ticks k > 1)


def acks_sent(back: Link) -> list[tuple[int, tuple[float, ...], bool]]:
    """(send tick, payload, delivered) of every ACK the decoder sent, lost ones included."""
    return [(p.send_time_ns // MS, p.payload, p.fate == DELIVERED) for p in back.log]


def test_cumulative_acks_one_every_k_ticks_name_everything_received() -> None:
    k = 4
    cfg = ArqConfig(timeout_s=0.025, max_retransmissions=4, ack_every_ticks=k)
    fwd, back = link(2.0), link(2.0)
    ticks = 200
    x = signal(ticks)
    enc, dec, played = run(cfg, fwd, back, x)
    sent = acks_sent(back)
    times = [t for t, _, _ in sent]
    assert times == list(range(2, ticks + 3, k))  # the first arrival's tick, then every k ticks (the last: 202)
    assert dec.counters["acks_sent"] == len(sent) == ticks // k + 1
    assert all(p.size_bytes == 20 + 8 * 2 for p in back.log)  # (newest, bitmap): nothing below the window
    assert cumulative_seqs(sent[1][1]) == list(range(4, -1, -1))  # ACK at tick 6: 4, and 3 .. 0 by the bitmap
    c = enc.counters
    assert c["acked"] == ticks and c["retransmitted"] == 0 and c["acks_stale"] == 0 and enc.pending == 0
    assert played[2 : ticks + 2] == x


@pytest.mark.parametrize("lost", [[3], [2, 3, 4]])
def test_a_lost_ack_is_covered_by_the_next_cumulative_one(lost: list[int]) -> None:
    cfg = ArqConfig(timeout_s=0.025, max_retransmissions=4, ack_every_ticks=4)
    fwd, back = link(2.0), link(2.0, lost=lost)
    ticks = 100
    enc, dec, _ = run(cfg, fwd, back, signal(ticks))
    sent = acks_sent(back)
    after = len(lost) + lost[0]
    assert [d for _, _, d in sent[lost[0] : after + 1]] == [False] * len(lost) + [True]
    named_lost = {s for _, pl, _ in sent[lost[0] : after] for s in cumulative_seqs(pl)}
    assert named_lost <= set(cumulative_seqs(sent[after][1]))  # the next ACK repeats them
    c = enc.counters
    assert c["retransmitted"] == 0 and c["acked"] == ticks and enc.pending == 0  # nothing resent
    assert dec.counters["duplicates"] == 0


def test_a_retransmission_below_the_window_is_named_and_acknowledged() -> None:
    mu = 100  # the retransmission of sample 10 arrives with newest seq 110: 100 > ACK_WINDOW below
    cfg = ArqConfig(timeout_s=mu * 1e-3, max_retransmissions=4, ack_every_ticks=4)
    fwd, back = link(2.0, lost=[10]), link(2.0)
    enc, dec, _ = run(cfg, fwd, back, signal(200))
    assert transmissions(fwd, 10) == [10, 110]  # once: its ACK names it
    naming = [(t, pl) for t, pl, _ in acks_sent(back) if 10 in cumulative_seqs(pl)]
    assert len(naming) == 1 and len(naming[0][1]) == 3 and naming[0][1][2] == 10.0
    assert int(naming[0][1][0]) - 10 > ACK_WINDOW
    assert back.log[[t for t, _, _ in acks_sent(back)].index(naming[0][0])].size_bytes == 20 + 8 * 3
    assert enc.counters["retransmitted"] == 1 and enc.counters["gave_up"] == 0 and enc.pending == 0
    assert dec.counters["recovered"] == 1


@pytest.mark.parametrize("mu_ms", [30, 51, 80])
def test_every_data_packet_is_named_by_the_next_ack(mu_ms: int) -> None:
    # 20 % of the data packets and 20 % of the ACKs lost: each ACK names every data packet that
    # arrived since the ACK before it (mu 51 ms: retransmissions arrive at the window's edge and
    # leave it before the ACK), and the sender never retransmits a sample an ACK that reached it
    # named before the timeout.
    k = 5
    cfg = ArqConfig(timeout_s=mu_ms * 1e-3, max_retransmissions=3, ack_every_ticks=k)
    rng = np.random.default_rng(mu_ms)
    ticks = 400
    fwd = link(2.0, lost=sorted(rng.choice(900, 180, replace=False).tolist()))
    back = link(2.0, lost=sorted(rng.choice(150, 30, replace=False).tolist()))
    enc, _dec, _ = run(cfg, fwd, back, signal(ticks))
    sent = acks_sent(back)
    assert all(b[0] - a[0] >= k for a, b in itertools.pairwise(sent))
    prev = -1
    below = 0
    for t, pl, _ in sent:
        got = {p.seq for p in fwd.log if p.fate == DELIVERED and prev < p.arrival_time_ns // MS <= t}
        assert got and got <= set(cumulative_seqs(pl)), t
        below += len(pl) - 2
        prev = t
    assert below > 0 if mu_ms > ACK_WINDOW else True
    assert all(p.size_bytes == 20 + 8 * len(p.payload) for p in back.log)
    # a retransmission only for a sample no delivered ACK named before its timeout
    acked_at: dict[int, int] = {}
    for p in back.log:
        if p.fate == DELIVERED:
            for s in cumulative_seqs(p.payload):
                acked_at.setdefault(s, p.arrival_time_ns // MS)
    for p in fwd.log:
        if p.send_time_ns // MS != p.seq:  # a retransmission
            assert acked_at.get(p.seq, 10**9) >= p.send_time_ns // MS, p.seq
    c = enc.counters
    assert c["retransmitted"] > 0 and c["samples"] == ticks
    # (pending: the last samples, whose last ACK was lost: no data arrives after it to ACK again)
    assert c["acked"] + c["gave_up"] + enc.pending == ticks


def test_ack_every_ticks_bounds() -> None:
    with pytest.raises(ValueError, match="ack_every_ticks"):
        ArqConfig(ack_every_ticks=0)
    with pytest.raises(ValueError, match="ack_every_ticks"):
        ArqConfig(ack_every_ticks=ACK_WINDOW // 2 + 1)


def test_the_compiled_loops_compose_cores_cumulative_acks() -> None:
    # the ARQ kernel's receiver ACK state is core/arq.py's ack_mark and ack_due, compiled: no copy
    from haptic_teleop.core import arq
    from haptic_teleop.engine.compiled import codec_arq

    for name in ("ack_mark", "ack_due"):
        assert getattr(codec_arq, name).py_func.__code__ is getattr(arq, name).__code__, name
    assert "ack_mark" in codec_arq.arq_block.py_func.__code__.co_names
    assert "ack_due" in codec_arq.arq_cumulative_ack.py_func.__code__.co_names
    assert "ack_mark" in arq.ArqDecoder.receive.__code__.co_names
    assert "ack_due" in arq.ArqDecoder.acks.__code__.co_names
