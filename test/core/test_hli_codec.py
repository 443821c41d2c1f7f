"""The HLI codec (core/hli_codec.py): filtering under an allowed bandwidth, the rebuild of lost HLI2
events, the decoder's latency, the payload and wire size, config errors."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from haptic_teleop.core.hli import HLI1, HLI2, GilbertChannel
from haptic_teleop.core.hli_codec import (
    HliConfig,
    HliDecoder,
    HliEncoder,
    build_hli_codec,
    hli_message_bytes,
    joint_state_bytes,
)
from haptic_teleop.core.link import DEFAULT_OVERHEAD_BYTES, Packet
from haptic_teleop.record.layouts import joint_state_size

PERIOD_NS = 1_000_000  # 1 kHz
TH = 0.4e-3


def kinked_signal(
    rng: np.random.Generator, ticks: int, dim: int, min_gap: int, max_gap: int
) -> list[tuple[float, ...]]:
    """Piecewise constant velocity; at kinks min_gap..max_gap ticks apart the velocity jumps by
    0.5 to 2 mm per tick in a random direction (always >= TH_HLI: one HLI2 event per kink)."""
    x = np.zeros(dim)
    v = np.zeros(dim)
    out: list[tuple[float, ...]] = []
    next_kink = int(rng.integers(min_gap, max_gap + 1))
    for n in range(ticks):
        if n == next_kink:
            d = rng.normal(size=dim)
            v = v + d / np.linalg.norm(d) * rng.uniform(0.5e-3, 2e-3)
            next_kink += int(rng.integers(min_gap, max_gap + 1))
        x = x + v
        out.append(tuple(float(a) for a in x))
    return out


def chain_probability(ch: GilbertChannel, slots: list[int]) -> float:
    t, loss = ch.transition(), ch.loss_matrix()
    vec = ch.stationary() @ loss
    for a, b in itertools.pairwise(slots):
        vec = vec @ np.linalg.matrix_power(t, b - a) @ loss
    return float(vec.sum())


def pattern(n: int, j: int, filtering: str) -> set[int]:
    """Positions (1..n after the HLI2 event) a filtering of j may drop."""
    return set(range(1, j + 1)) if filtering == "sequential" else {2 * k - 1 for k in range(1, j + 1)}


def run(enc: HliEncoder, signal: list[tuple[float, ...]]) -> list[Packet]:
    out: list[Packet] = []
    for n, s in enumerate(signal):
        out += enc.send(n, n * PERIOD_NS, s)
    return out


def max_window_bits(packets: list[Packet], window: int) -> int:
    bits = {p.seq: 8 * (DEFAULT_OVERHEAD_BYTES + p.size_bytes) for p in packets}
    seqs = sorted(bits)
    best = 0
    for k, s in enumerate(seqs):  # windows ending at each packet: (s - window, s]
        total = sum(bits[q] for q in seqs[: k + 1] if q > s - window)
        best = max(best, total)
    return best


@pytest.mark.parametrize("filtering", ["sequential", "alternate"])
@pytest.mark.parametrize("dim", [1, 3])
def test_filtering_keeps_the_rate_under_the_allowed_bandwidth(filtering: str, dim: int) -> None:
    """Kinks >= 60 ticks apart put at most two events in a 100-tick window. The budget is chosen
    between one full event plus one filtered to j* (which must fit: the sender cannot know the
    next event is coming) and two full events (which must not fit: the limit bites). Wire bits per
    packet (1-D / 3-D): HLI2 1408 / 1920, HLI1 1568 / 2208; N_HLI1 = 11; j* = 4 (sequential) or
    6 (alternate). 1-D: the start-up (two HLI2 and 11 HLI1) 20064 bits, one event filtered to j*
    = 4 12384, two full events 37312: budget 35000 per 0.1 s (3-D: 28128 + 17376 <= 49000 <
    52416)."""
    ch_kw = {"p": 0.125, "r": 0.5}  # 20 % loss, mean burst 2 packets: N_HLI1 = 11
    allowed_bps = 350_000.0 if dim == 1 else 490_000.0
    signal = kinked_signal(np.random.default_rng(2024), 6000, dim, 60, 140)
    window = 100  # rate_window_s 0.1 at 1 kHz

    free = HliEncoder(HliConfig(**ch_kw, filtering=filtering), PERIOD_NS, dim)
    unfiltered = run(free, signal)
    budget = allowed_bps * window * PERIOD_NS * 1e-9
    assert max_window_bits(unfiltered, window) > budget  # the limit bites

    cfg = HliConfig(**ch_kw, filtering=filtering, allowed_bandwidth_bps=allowed_bps, p_allowable=1e-3)
    enc = HliEncoder(cfg, PERIOD_NS, dim)
    sent = run(enc, signal)
    assert enc.n_hli1 == 11
    assert max_window_bits(sent, window) <= budget
    assert enc.counters["over_budget"] == 0
    assert enc.counters["filtered_hli1"] > 0
    assert len(sent) == enc.counters["sent"] < len(unfiltered)
    # filtering only where the pattern allows, never more than j*, and j* is the largest j allowed
    n, j = enc.n_hli1, enc.j_max
    ch = GilbertChannel(**ch_kw)
    keep = [0, *sorted(set(range(1, n + 1)) - pattern(n, j, filtering))]
    assert chain_probability(ch, keep) <= 1e-3
    if j < (n if filtering == "sequential" else (n + 1) // 2):
        more = [0, *sorted(set(range(1, n + 1)) - pattern(n, j + 1, filtering))]
        assert chain_probability(ch, more) > 1e-3
    sent_seqs = {p.seq for p in sent}
    hli2 = [p.seq for p in unfiltered if p.payload[dim] == HLI2]
    for s in hli2:
        assert s in sent_seqs  # HLI2 events are always sent
        followers = [p.seq for p in unfiltered if p.payload[dim] == HLI1 and s < p.seq <= s + n]
        dropped = {q - s for q in followers if q not in sent_seqs}
        assert dropped <= pattern(n, j, filtering)


def test_hli0_is_always_filtered_and_nothing_else_without_a_bandwidth() -> None:
    signal = kinked_signal(np.random.default_rng(5), 3000, 2, 50, 120)
    enc = HliEncoder(HliConfig(p=0.2, r=0.8), PERIOD_NS, 2)
    sent = run(enc, signal)
    c = enc.counters
    assert c["filtered_hli1"] == 0 and c["filtered_hli0"] == c["hli0"] > 0
    assert c["sent"] == c["hli1"] + c["hli2"] == len(sent)
    assert all(p.payload[2] in (1.0, 2.0) for p in sent)


def test_payload_layout_and_wire_size() -> None:
    enc = HliEncoder(HliConfig(p=0.2, r=0.8), PERIOD_NS, 3)
    sig = [(0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1e-3, 0.0, 0.0), (2e-3, 0.0, 0.0), (3e-3, 0.0, 0.0)]
    pk = run(enc, sig)
    by_seq = {p.seq: p for p in pk}
    # the kink: HLI2 (x, class, offset, previous x)
    assert by_seq[2].payload == (1e-3, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0)
    # its 2nd follower: HLI1 (x, class, offset 2, previous x, copy of the HLI2 sample)
    assert by_seq[4].payload == (3e-3, 0.0, 0.0, 1.0, 2.0, 2e-3, 0.0, 0.0, 1e-3, 0.0, 0.0)
    assert by_seq[2].size_bytes == joint_state_size(2, 3) + 16 + 2 * 8  # one more name and its values
    assert by_seq[4].size_bytes == hli_message_bytes(3, HLI1) == joint_state_bytes(3, 4)
    assert enc.counters["wire_bits"] == sum(8 * (DEFAULT_OVERHEAD_BYTES + p.size_bytes) for p in pk)


@pytest.mark.parametrize(("floats", "names"), list(itertools.product((1, 2, 3), (1, 2, 3))))
def test_joint_state_bytes_matches_the_recorder(floats: int, names: int) -> None:
    assert joint_state_bytes(floats, names) == joint_state_size(floats, names)


def decode(
    dec: HliDecoder, packets: list[Packet], ticks: int, lost: set[int], delay: int = 0
) -> list[tuple[float, ...] | None]:
    """Deliver every packet not in `lost` `delay` ticks after its seq; sample every tick."""
    by_tick: dict[int, list[Packet]] = {}
    for p in packets:
        if p.seq not in lost:
            by_tick.setdefault(p.seq + delay, []).append(p)
    out = []
    for n in range(ticks):
        for p in by_tick.get(n, []):
            dec.receive(p, n * PERIOD_NS)
        out.append(dec.sample(n, n * PERIOD_NS))
    return out


def _kink_case(dim: int) -> tuple[list[tuple[float, ...]], int]:
    n0 = 40
    sig = []
    for k in range(120):
        a = 0.1e-3 * k if k < n0 else 0.1e-3 * (n0 - 1) + 0.9e-3 * (k - n0 + 1)
        sig.append((a,) + (0.5e-3,) * (dim - 1))
    return sig, n0


@pytest.mark.parametrize("dim", [1, 3])
@pytest.mark.parametrize("delay", [0, 3])
def test_worst_case_rebuild_from_the_last_follower(dim: int, delay: int) -> None:
    """Seed slide 48: the HLI2 event at n0 and all its followers but the N_HLI1-th are lost: the
    decoder, N_HLI1 ticks behind, plays x(n0) exactly, and the same samples as with no loss from
    n0 on."""
    sig, n0 = _kink_case(dim)
    cfg = HliConfig(p=0.2, r=0.8)
    enc, dec = build_hli_codec(cfg, PERIOD_NS, dim)
    n = enc.n_hli1
    pk = run(enc, sig)
    assert {p.seq for p in pk} >= set(range(n0, n0 + n + 1))
    assert [p.payload[dim] for p in pk if n0 <= p.seq <= n0 + n] == [2.0] + [1.0] * n
    clean = decode(HliDecoder(cfg, dim, n), pk, len(sig), set(), delay)
    lossy = decode(dec, pk, len(sig), set(range(n0, n0 + n)), delay)
    lag = n + delay
    assert lossy[n0 + lag] == sig[n0]  # exact: the follower carries the HLI2 sample
    assert dec.counters["rebuilt"] == 1
    for k in range(n0 + lag, len(sig)):
        assert lossy[k] is not None and clean[k] is not None
        assert np.allclose(lossy[k], clean[k], rtol=0, atol=1e-12), k
    # the played stream is the signal, N_HLI1 (+ the link delay) ticks late, within TH_HLI
    for k in range(lag + 2, len(sig)):
        assert np.linalg.norm(np.subtract(clean[k], sig[k - lag])) < TH  # type: ignore[arg-type]


def test_a_lost_hli2_without_followers_is_only_predicted() -> None:
    sig, n0 = _kink_case(1)
    cfg = HliConfig(p=0.2, r=0.8)
    enc, dec = build_hli_codec(cfg, PERIOD_NS, 1)
    n = enc.n_hli1
    pk = run(enc, sig)
    lossy = decode(dec, pk, len(sig), set(range(n0, n0 + n + 1)))
    assert dec.counters["rebuilt"] == 0
    played = lossy[n0 + n]
    assert played is not None and abs(played[0] - sig[n0][0]) >= TH


def test_the_decoder_runs_n_hli1_ticks_behind() -> None:
    sig, _ = _kink_case(1)
    for p, r, want in ((0.2, 0.8, 5), (0.125, 0.5, 11)):
        cfg = HliConfig(p=p, r=r)
        enc, dec = build_hli_codec(cfg, PERIOD_NS, 1)
        assert enc.n_hli1 == dec.delay_ticks == want
        out = decode(dec, run(enc, sig), len(sig), set())
        assert out[:want] == [None] * want
        assert out[want] == sig[0] and out[want + 1] == sig[1]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"p": 0.2, "r": 0.8, "threshold_m": 0.0}, "threshold_m must be > 0"),
        ({"p": 0.2, "r": 0.8, "filtering": "random"}, "filtering must be one of sequential, alternate"),
        ({"p": 0.2, "r": 0.8, "clock": "tick"}, "clock must be one of slot, packet"),
        ({"p": 0.2, "r": 0.8, "predictor": "cubic"}, "predictor must be one of linear, hold"),
        ({"p": 1.2, "r": 0.8}, "p must be in \\[0.0, 1.0\\]"),
        ({"p": 0.2, "r": 0.8, "alpha": 1e-3, "p_allowable": 1e-4}, "p_allowable .* must be >= alpha"),
        ({"p": 0.2, "r": 0.8, "allowed_bandwidth_bps": -5.0}, "allowed_bandwidth_bps must be > 0"),
        ({"p": 0.2, "r": 0.8, "alpha": float("nan")}, "alpha must be finite"),
    ],
)
def test_config_errors(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        HliConfig(**kwargs)  # type: ignore[arg-type]


def test_build_errors() -> None:
    with pytest.raises(ValueError, match="needs the Gilbert loss parameters p and r"):
        build_hli_codec(HliConfig(), PERIOD_NS, 1)
    with pytest.raises(ValueError, match="no N_HLI1 <= 200"):
        build_hli_codec(HliConfig(p=0.5, r=0.01), PERIOD_NS, 1)
    with pytest.raises(ValueError, match="period_ns must be > 0"):
        build_hli_codec(HliConfig(p=0.2, r=0.8), 0, 1)
    enc = HliEncoder(HliConfig(p=0.2, r=0.8), PERIOD_NS, 2)
    with pytest.raises(ValueError, match="sample has 3 values, the stream has 2"):
        enc.send(0, 0, (0.0, 0.0, 0.0))


@pytest.mark.parametrize("filtering", ["sequential", "alternate"])
@pytest.mark.parametrize("clock", ["slot", "packet"])
def test_an_infeasible_budget_filters_exactly_the_pattern(filtering: str, clock: str) -> None:
    """Allowed bandwidth far below one event: every event loses exactly its j* pattern positions,
    the rest is sent anyway (P_N,j* <= P_allowable wins over the rate), and the encoder counts the
    packets sent over budget."""
    signal = kinked_signal(np.random.default_rng(11), 3000, 1, 60, 140)
    cfg = HliConfig(p=0.125, r=0.5, filtering=filtering, clock=clock, allowed_bandwidth_bps=1000.0)
    enc = HliEncoder(cfg, PERIOD_NS, 1)
    sent = run(enc, signal)
    full = run(HliEncoder(HliConfig(p=0.125, r=0.5), PERIOD_NS, 1), signal)
    n, j = enc.n_hli1, enc.j_max
    # j* from the chain: slot clock with the pattern's gaps, packet clock with n - j + 1 consecutive
    ch = GilbertChannel(0.125, 0.5)

    def prob(k: int) -> float:
        keep = [0, *sorted(set(range(1, n + 1)) - pattern(n, k, filtering))]
        return chain_probability(ch, keep if clock == "slot" else list(range(len(keep))))

    top = n if filtering == "sequential" else (n + 1) // 2
    assert j == max(k for k in range(top + 1) if prob(k) <= 1e-3)
    assert j > 0
    sent_seqs = {p.seq for p in sent}
    for s in (p.seq for p in full if p.payload[1] == HLI2):
        followers = [p.seq for p in full if p.payload[1] == HLI1 and s < p.seq <= s + n]
        if len(followers) == n:
            assert {q - s for q in followers if q not in sent_seqs} == pattern(n, j, filtering)
    assert enc.counters["over_budget"] > 0


def test_the_encoder_classifies_as_the_formula_module() -> None:
    """Without a bandwidth limit the codec sends exactly the HLI1/HLI2 samples of core/hli.classify."""
    from haptic_teleop.core.hli import classify

    signal = kinked_signal(np.random.default_rng(8), 4000, 3, 20, 90)
    enc = HliEncoder(HliConfig(p=0.125, r=0.5), PERIOD_NS, 3)
    sent = {p.seq: int(p.payload[3]) for p in run(enc, signal)}
    cls = classify(signal, TH, enc.n_hli1)
    assert sent == {k: c for k, c in enumerate(cls) if c != 0}


@pytest.mark.parametrize("filtering", ["sequential", "alternate"])
def test_every_hli2_event_with_one_delivered_packet_is_played_exactly(filtering: str) -> None:
    """Over core/loss.py's Gilbert model (20 % loss, bursts of 2), with filtering: an HLI2 event
    whose packet or any follower's packet is delivered is played exactly; the events lost with all
    their sent followers are rare (P_N,j* each)."""
    from haptic_teleop.core.loss import GilbertElliottLoss

    signal = kinked_signal(np.random.default_rng(3), 20_000, 1, 20, 60)
    cfg = HliConfig(p=0.125, r=0.5, filtering=filtering, allowed_bandwidth_bps=1000.0)
    enc, dec = build_hli_codec(cfg, PERIOD_NS, 1)
    n = enc.n_hli1
    loss = GilbertElliottLoss(0.125, 0.5, 1.0, 0.0, np.random.default_rng(17))
    packets = run(enc, signal)
    for p in packets:
        loss.apply(p)
    lost = {p.seq for p in packets if p.fate != 0}
    assert 0.1 < len(lost) / len(packets) < 0.3
    played = decode(dec, packets, len(signal) + n, lost)
    events = [p.seq for p in packets if p.payload[1] == HLI2]
    carriers: dict[int, list[int]] = {s: [s] for s in events}  # the packets that carry x(s)
    for q in packets:
        if q.payload[1] == HLI1:
            carriers[q.seq - round(q.payload[2])].append(q.seq)
    assert sum(len(c) == 1 for c in carriers.values()) == 1  # only start-up sample 0 (followed by an HLI2)
    covered = [s for s in events if any(q not in lost for q in carriers[s])]
    rebuilt = [s for s in covered if s in lost]
    assert len(events) - len(covered) <= 3 and len(rebuilt) > 50
    assert [s for s in covered if played[s + n] != signal[s]] == []
    assert dec.counters["rebuilt"] == len(rebuilt)


def test_the_compiled_loops_compose_cores_hli() -> None:
    # the HLI kernel's encoder and decoder steps are core/hli_codec.py's functions, compiled: no copy
    from haptic_teleop.core import hli_codec
    from haptic_teleop.engine.compiled import codec_hli

    for name in ("hli_send", "hli_receive", "hli_sample"):
        assert getattr(codec_hli, name).py_func.__code__ is getattr(hli_codec, name).__code__, name
    # and the tick calls them (and nothing else of its own but the link's)
    names = set(codec_hli.hli_tick.py_func.__code__.co_names)
    assert {"hli_send", "hli_receive", "hli_sample", "link_send", "link_next"} <= names


def test_a_late_packet_and_a_wide_spread_of_seqs_keep_the_dict_semantics() -> None:
    """The decoder's history is a ring that grows: packets received far apart before the first
    sample, and a late one, are handled as a dict of seqs would."""
    cfg = HliConfig(p=0.2, r=0.8)
    enc, dec = build_hli_codec(cfg, PERIOD_NS, 2)
    n = enc.n_hli1
    sig = [(1e-3 * k * k, -2e-3 * k) for k in range(400)]
    pk = {p.seq: p for p in run(enc, sig)}
    assert len(pk) > 300
    seqs = sorted(pk)
    # the first 250 packets arrive at once (a history many times the ring's first 16 rows)
    for s in seqs[:250]:
        dec.receive(pk[s], 0)
    t0 = seqs[249] + 1  # lag 1: the first sample plays up to seqs[249] - n, then a tick each
    played = [dec.sample(t, 0) for t in range(t0, t0 + n + 1)]
    assert played[-1] == sig[seqs[249]]
    assert all(type(v) is float for v in played[-1])
    assert len(dec.X) >= 256
    dec.receive(pk[seqs[10]], 0)  # late: its tick was played
    assert dec.counters["late"] == 1 and dec.counters["received"] == 251
    assert dec.counters["played_received"] == 250
