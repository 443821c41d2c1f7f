"""ARQ baseline (core/arq.py): data forward and ACKs backward, each over its own real
core.link.Link, tick by tick."""

from __future__ import annotations

import numpy as np
import pytest

from haptic_teleop.core.arq import SEED_000_EXPERIMENT, ArqConfig, ArqDecoder, ArqEncoder, build_arq
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


def test_never_more_than_nu_retransmissions_then_gives_up() -> None:
    mu, nu = 25, 4
    cfg = ArqConfig(timeout_s=mu * 1e-3, max_retransmissions=nu)
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
