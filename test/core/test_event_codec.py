"""Prediction-based filtering with FEC, ARQ or no error control behind it (core/event_codec.py),
through real core.link Links (data forward, ACKs backward), tick by tick."""

from __future__ import annotations

import math

import numpy as np
import pytest

from haptic_teleop.core.event_codec import EventCodecConfig, EventDecoder, EventEncoder, build_event_codec
from haptic_teleop.core.hli_codec import HliConfig, build_hli_codec
from haptic_teleop.core.link import Link
from haptic_teleop.core.netconfig import BlackoutConfig, DelayConfig, LossConfig, NetworkEffectsConfig, build_link

PERIOD_NS = 1_000_000
TH = 0.0004  # the threshold: 0.4 mm
DELAY = 2  # ticks one way


def link(*, down: list[tuple[int, int]] | None = None, loss: float = 0.0, seed: int = 1) -> Link:
    """A link with DELAY ticks one way, down in the given [start, end) tick windows."""
    blackout = None
    if down:
        blackout = BlackoutConfig(tuple(a * 1e-3 for a, _ in down), tuple(b * 1e-3 for _, b in down))
    lc = LossConfig(model="bernoulli", probability=loss) if loss > 0 else None
    cfg = NetworkEffectsConfig(blackout=blackout, loss=lc, delay=DelayConfig(delay_s=DELAY * 1e-3))
    return build_link(cfg, seed, "forward")


def kinked(ticks: int, every: int, dim: int = 1) -> list[tuple[float, ...]]:
    """Piecewise linear: every `every` ticks the velocity turns round (1 to 2 mm/tick, alternating
    sign per axis: a change of at least 2 mm/tick, well over TH), so each kink is one event and the
    prediction is exact between kinks."""
    rng = np.random.default_rng(5)
    x = np.zeros(dim)
    v = np.zeros(dim)
    out = []
    for n in range(ticks):
        if n % every == 0:
            v = (-1.0) ** (n // every) * rng.uniform(1e-3, 2e-3, dim)
        x = x + v
        out.append(tuple(float(a) for a in x))
    return out


def run(
    enc: EventEncoder | object, dec: EventDecoder | object, fwd: Link, back: Link, x: list[tuple[float, ...]]
) -> list[tuple[float, ...] | None]:
    played: list[tuple[float, ...] | None] = []
    for n in range(len(x)):
        now = n * PERIOD_NS
        for a in back.deliver(now):
            enc.feedback(a, now)  # type: ignore[attr-defined]
        for p in enc.send(n, now, x[n]):  # type: ignore[attr-defined]
            fwd.send(p)
        for p in fwd.deliver(now):
            for a in dec.receive(p, now):  # type: ignore[attr-defined]
                back.send(a)
        played.append(dec.sample(n, now))  # type: ignore[attr-defined]
    return played


def error(played: list[tuple[float, ...] | None], x: list[tuple[float, ...]], lag: int) -> list[float]:
    """|played(n) - x(n - lag)| per tick (NaN where nothing is played yet)."""
    out = []
    for n, y in enumerate(played):
        if y is None or n < lag:
            out.append(math.nan)
        else:
            out.append(math.dist(y, x[n - lag]))
    return out


def event_ticks(fwd: Link) -> list[int]:
    return sorted({p.seq for p in fwd.log})


@pytest.mark.parametrize(
    "cfg",
    [
        EventCodecConfig(),
        EventCodecConfig(error_control="fec", fec_k=2),
        EventCodecConfig(error_control="arq", timeout_s=0.025, max_retransmissions=4),
        EventCodecConfig(error_control="arq", timeout_s=0.005, max_retransmissions=1),
    ],
)
@pytest.mark.parametrize("dim", [1, 3])
def test_lossless_equals_prediction_based_filtering(cfg: EventCodecConfig, dim: int) -> None:
    """The HLI codec with N_HLI1 = 0 is prediction-based filtering (studies/replications/codec.py); with no
    loss every error control plays exactly what it plays and sends its events at the same ticks."""
    t = np.arange(3000) * 1e-3
    x = [tuple(float(-0.05 * (1 - math.cos(2 * math.pi * s / (1.5 + 0.3 * i)))) for i in range(dim)) for s in t]
    hcfg = HliConfig(threshold_m=TH, p=0.2, r=0.8, alpha=0.99, p_allowable=0.99)
    henc, hdec = build_hli_codec(hcfg, PERIOD_NS, dim)
    assert henc.n_hli1 == 0
    ref_fwd = link()
    ref = run(henc, hdec, ref_fwd, link(), x)
    enc, dec = build_event_codec(cfg, PERIOD_NS, dim)
    fwd, back = link(), link()
    got = run(enc, dec, fwd, back, x)
    assert got == ref
    assert [p.seq for p in fwd.log] == [p.seq for p in ref_fwd.log]
    assert 20 < enc.counters["events"] < 300  # it does filter, and it does send
    assert enc.counters["retransmitted"] == 0 and enc.counters["gave_up"] == 0
    assert dec.counters["late"] == 0 and dec.counters["rebased"] == 0
    if cfg.error_control == "arq":
        assert enc.counters["acked"] == enc.counters["events"] and enc.pending == 0
        assert len(back.log) == enc.counters["events"]


@pytest.mark.parametrize("dim", [1, 3])
def test_arq_retransmission_rebases_the_receiver(dim: int) -> None:
    x = kinked(1000, 100, dim)
    cfg = EventCodecConfig(error_control="arq", timeout_s=0.025, max_retransmissions=4)
    enc0, dec0 = build_event_codec(cfg, PERIOD_NS, dim)
    f0 = link()
    run(enc0, dec0, f0, link(), x)
    assert event_ticks(f0)[2:] == list(range(100, 1000, 100))  # one event per kink (after the start-up two)
    k = 300  # lose the kink's event
    enc, dec = build_event_codec(cfg, PERIOD_NS, dim)
    fwd, back = link(down=[(k, k + 1)]), link()
    played = run(enc, dec, fwd, back, x)
    assert [p.send_time_ns // PERIOD_NS for p in fwd.log if p.seq == k] == [k, k + 25]
    assert enc.counters["retransmitted"] == 1 and enc.counters["gave_up"] == 0 and enc.pending == 0
    assert dec.counters["recovered"] == 1 and dec.counters["late"] == 1 and dec.counters["rebased"] == 1
    e = error(played, x, DELAY)
    arrives = k + 25 + DELAY  # the retransmission is received (and the receiver re-based) at this tick
    before = e[k + DELAY : arrives]  # the receiver keeps the old slope
    after = e[arrives + 1 : k + 100 + DELAY]  # until the next kink's event
    assert max(before) > 10 * TH
    assert max(after) < TH * 1e-3  # the sender's mirror exactly: the kink's new slope from k on


def test_without_the_rebase_the_error_stays() -> None:
    """The same loss without error control: the receiver keeps the old slope until the next event."""
    x = kinked(1000, 100)
    enc, dec = build_event_codec(EventCodecConfig(), PERIOD_NS, 1)
    played = run(enc, dec, link(down=[(300, 301)]), link(), x)
    e = error(played, x, DELAY)
    assert min(e[300 + DELAY + 30 : 400 + DELAY]) > 10 * TH
    assert dec.counters["rebased"] == 0


@pytest.mark.parametrize("dim", [1, 3])
def test_fec_recovers_a_lost_event_from_the_next_events_copy(dim: int) -> None:
    x = kinked(800, 50, dim)
    wait = 60  # more than the 50 ticks to the next event: the recovery is in time to be played
    cfg = EventCodecConfig(error_control="fec", fec_k=1, wait_ticks=wait)
    enc0, dec0 = build_event_codec(cfg, PERIOD_NS, dim)
    ref = run(enc0, dec0, link(), link(), x)
    enc, dec = build_event_codec(cfg, PERIOD_NS, dim)
    fwd = link(down=[(300, 301)])
    played = run(enc, dec, fwd, link(), x)
    assert [p.seq for p in fwd.log if p.fate != 0] == [300]
    assert dec.counters["recovered"] == 1 and dec.counters["late"] == 0
    assert played == ref  # the lost event played from its copy, exactly
    # and the copy is the event's: the payload of the next event carries (offset 50, x(300), x(299))
    nxt = next(p for p in fwd.log if p.seq == 350)
    assert nxt.payload[2 * dim :] == (50.0, *x[300], *x[299])
    assert nxt.size_bytes == 20 + 8 * (2 * dim + 1 + 2 * dim)


def test_fec_k_bounds_what_comes_back() -> None:
    """Two consecutive events lost: k = 2 brings both back with the third, k = 1 only the newer;
    without waiting the copies come late and the receiver re-bases on the newest."""
    x = kinked(800, 50)
    down = [(300, 301), (350, 351)]
    for k, recovered in ((1, 1), (2, 2)):
        enc, dec = build_event_codec(EventCodecConfig(error_control="fec", fec_k=k), PERIOD_NS, 1)
        run(enc, dec, link(down=down), link(), x)
        assert dec.counters["recovered"] == recovered
        assert dec.counters["late"] == recovered and dec.counters["rebased"] == 1
        assert dec.counters["stale"] == recovered - 1


@pytest.mark.parametrize(("mu", "nu"), [(25, 4), (4, 1), (10, 0)])
def test_arq_gives_up_after_nu(mu: int, nu: int) -> None:
    x = kinked(1500, 300)
    k = 600
    cfg = EventCodecConfig(error_control="arq", timeout_s=mu * 1e-3, max_retransmissions=nu)
    enc, dec = build_event_codec(cfg, PERIOD_NS, 1)
    fwd = link(down=[(k, k + nu * mu + 1)])  # every transmission of the event at k is lost
    played = run(enc, dec, fwd, link(), x)
    # retransmitted every mu, though no other event is sent meanwhile (the timeouts run every tick)
    assert [p.send_time_ns // PERIOD_NS for p in fwd.log if p.seq == k] == [k + i * mu for i in range(nu + 1)]
    assert enc.counters["retransmitted"] == nu and enc.counters["gave_up"] == 1 and enc.pending == 0
    assert dec.counters["rebased"] == 0 and dec.counters["recovered"] == 0
    e = error(played, x, DELAY)
    assert min(e[k + DELAY + 30 : 900 + DELAY]) > 10 * TH  # nothing came: the old slope until the next event


def test_arq_lost_ack_costs_a_duplicate() -> None:
    x = kinked(600, 100)
    cfg = EventCodecConfig(error_control="arq", timeout_s=0.025, max_retransmissions=4)
    enc, dec = build_event_codec(cfg, PERIOD_NS, 1)
    # the ACK of the event at 200 leaves the receiver at 202
    back = link(down=[(202, 203)])
    run(enc, dec, link(), back, x)
    assert enc.counters["retransmitted"] == 1 and enc.counters["gave_up"] == 0 and enc.pending == 0
    assert dec.counters["duplicates"] == 1 and dec.counters["rebased"] == 0


def test_random_loss_keeps_counts_consistent() -> None:
    x = kinked(4000, 37, 2)
    cfg = EventCodecConfig(error_control="arq", timeout_s=0.004, max_retransmissions=1)
    enc, dec = build_event_codec(cfg, PERIOD_NS, 2)
    fwd, back = link(loss=0.3, seed=3), link(loss=0.3, seed=4)
    run(enc, dec, fwd, back, x)
    c = enc.counters
    assert c["sent"] == c["events"] + c["retransmitted"] == len(fwd.log)
    assert c["retransmitted"] <= c["events"]  # nu = 1
    assert dec.counters["received"] == sum(1 for p in fwd.log if p.fate == 0)
    assert dec.counters["rebased"] > 0


def test_bad_config_and_payload() -> None:
    with pytest.raises(ValueError, match="error_control"):
        EventCodecConfig(error_control="parity")
    with pytest.raises(ValueError, match="fec_k"):
        EventCodecConfig(error_control="fec", fec_k=0)
    enc, dec = build_event_codec(EventCodecConfig(), PERIOD_NS, 2)
    with pytest.raises(ValueError, match="sample has 1 values"):
        enc.send(0, 0, (1.0,))
    p = enc.send(0, 0, (1.0, 2.0))[0]
    p.payload = p.payload[:3]
    with pytest.raises(ValueError, match="payload of 3 values"):
        dec.receive(p, 0)
