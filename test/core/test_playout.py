"""Playout buffers: schedules, accounting, clock-offset invariance and each policy's estimator."""

from __future__ import annotations

import itertools
import math
import random
from collections.abc import Callable, Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop import typedconfig
from haptic_teleop.core.link import DELIVERED, LOST_LATE, Packet
from haptic_teleop.core.playout import (
    GAP_MODES,
    POLICIES,
    RAMJEE_SMOOTHING,
    AdaptiveBuffer,
    ExtrapolatedPacket,
    FixedBuffer,
    PercentileBuffer,
    PlayOnArrival,
    PlayoutBuffer,
    contact_force_slope,
)
from haptic_teleop.core.playout_config import BufferConfig, build_buffer
from haptic_teleop.core.playout_seed import TransparencyBuffer
from haptic_teleop.errors import ConfigError

T = 1_000_000  # 1 ms period
MS = 1_000_000
SCHEDULED = ("fixed", "adaptive", "percentile", "transparency", "network_adaptive")

Arrival = tuple[int, Packet]  # (arrival time on the receiver's clock, packet)
Trace = list[tuple[int, int | None, int, int, int]]  # per tick: seq released, buffering, occupancy, late


def payload_of(k: int) -> tuple[float, ...]:
    return (float(k * k), -float(k))


def stream(n: int, delay_ns: Callable[[int], int], drop: Sequence[int] = ()) -> list[Arrival]:
    """Sample k sent at k T with seq k, arriving delay_ns(k) later; `drop` never arrive."""
    return [(k * T + delay_ns(k), Packet(k, k * T, payload_of(k))) for k in range(n) if k not in drop]


def run(
    buf: PlayoutBuffer,
    arrivals: Sequence[Arrival],
    n_ticks: int,
    offset_ns: int = 0,
    exact: bool = False,
) -> tuple[list[tuple[int, Packet]], Trace]:
    """Engine-like loop: at tick i (receiver clock i T + offset) push what has arrived, then release.

    exact=False pushes with the tick's time (as the engine does); exact=True with the arrival time.
    Returns the released packets with their tick and a per-tick trace of what the engine logs.
    """
    order = sorted(arrivals, key=lambda a: a[0])  # stable: equal arrival times keep their order
    out: list[tuple[int, Packet]] = []
    trace: Trace = []
    j = 0
    for i in range(n_ticks):
        now = i * T
        while j < len(order) and order[j][0] <= now:
            a, p = order[j]
            buf.push(p, (a if exact else now) + offset_ns)
            j += 1
        r = buf.release(now + offset_ns)
        if r is not None:
            out.append((i, r))
        trace.append((i, None if r is None else r.seq, buf.last_buffering_ns, buf.occupancy, buf.late))
    return out, trace


def make(policy: str, **kw: object) -> PlayoutBuffer:
    params: dict[str, object] = {"policy": policy, "buffering_time_s": 0.01}
    params.update(kw)
    return build_buffer(BufferConfig(**params), T)  # type: ignore[arg-type]


EXPECTED_BUFFERING = {
    "none": 0,
    "fixed": 10 * MS,
    "adaptive": 0,
    "percentile": 0,
    "transparency": 0,
    "network_adaptive": 0,
}


@pytest.mark.parametrize("policy", POLICIES)
def test_in_order_constant_delay_plays_every_sample_on_schedule(policy: str) -> None:
    n, d = 300, 20 * MS
    buf = make(policy)
    out, _ = run(buf, stream(n, lambda k: d), n + 100)
    b = EXPECTED_BUFFERING[policy]
    assert [p.seq for _, p in out] == list(range(n))
    assert all(i * T - p.send_time_ns == d + b for i, p in out)
    assert buf.played == n and buf.late == 0 and buf.duplicates == 0 and buf.occupancy == 0
    assert buf.last_buffering_ns == b


def test_buffering_log_is_release_time_minus_arrival() -> None:
    buf = make("fixed")
    _, trace = run(buf, stream(50, lambda k: 20 * MS + (k % 3) * MS), 100)
    played = [(i, seq, bufns) for i, seq, bufns, _, _ in trace if seq is not None]
    # Playout at send + D, arrival at send + 20..22 ms: buffering = D - delay, exact per sample.
    delay = {k: 20 * MS + (k % 3) * MS for k in range(50)}
    big_d = played[0][0] * T - played[0][1] * T
    assert all(bufns == big_d - delay[seq] for _, seq, bufns in played)
    # Occupancy after each release: arrived, and not yet due.
    expected = [sum(k * T + delay[k] <= i * T < k * T + big_d for k in range(50)) for i in range(100)]
    assert [occ for _, _, _, occ, _ in trace] == expected and max(expected) >= 8


@pytest.mark.parametrize("extra_ms", [1, 3])
@pytest.mark.parametrize("policy", POLICIES)
def test_reordering(policy: str, extra_ms: int) -> None:
    # Sample 100 takes 20 + extra ms instead of 20 ms. With 1 ms it arrives in the same tick as
    # 101 (both due: the newer wins); with 3 ms after 101 was played (too old on arrival). The
    # 100 samples before it settle every estimator on the 20 ms delay.
    n = 140
    arrivals = stream(n, lambda k: (20 + extra_ms) * MS if k == 100 else 20 * MS)
    late_packet = next(p for _, p in arrivals if p.seq == 100)
    buf = make(policy)
    out, _ = run(buf, arrivals, n + 100)
    seqs = [p.seq for _, p in out]
    if policy == "fixed":  # 10 ms of buffering absorbs it
        assert seqs == list(range(n)) and buf.late == 0
    else:  # no buffering: 101 is played first, 100 is too old when it comes
        assert seqs == [k for k in range(n) if k != 100]
        assert buf.late == 1 and late_packet.fate == LOST_LATE
    assert buf.played + buf.late == n


@pytest.mark.parametrize("policy", POLICIES)
def test_duplicates_are_ignored_not_lost(policy: str) -> None:
    n = 60
    arrivals = stream(n, lambda k: 20 * MS)
    copies = [(a + MS, Packet(p.seq, p.send_time_ns, p.payload, duplicate=True)) for a, p in arrivals]
    copies.append((5 * T + 80 * MS, Packet(5, 5 * T, payload_of(5), duplicate=True)))  # long after playout
    buf = make(policy)
    out, _ = run(buf, arrivals + copies, n + 150)
    assert [p.seq for _, p in out] == list(range(n))
    assert all(not p.duplicate for _, p in out)  # the first arrival is the one played
    assert buf.duplicates == n + 1 and buf.late == 0
    assert all(p.fate == DELIVERED for _, p in copies)


@pytest.mark.parametrize("policy", POLICIES)
def test_gap_hold_releases_nothing_for_missing_slots(policy: str) -> None:
    buf = make(policy)
    out, trace = run(buf, stream(20, lambda k: 20 * MS, drop=(5, 6)), 60)
    b = EXPECTED_BUFFERING[policy]
    assert [p.seq for _, p in out] == [k for k in range(20) if k not in (5, 6)]
    slot_tick = {k: (k * T + 20 * MS + b) // T for k in range(20)}
    assert trace[slot_tick[5]][1] is None and trace[slot_tick[6]][1] is None
    assert trace[slot_tick[7]][1] == 7
    assert buf.extrapolated == 0


@pytest.mark.parametrize("policy", POLICIES)
def test_gap_extrapolate_continues_the_last_two_samples(policy: str) -> None:
    buf = make(policy, gap="extrapolate")
    out, _ = run(buf, stream(20, lambda k: 20 * MS, drop=(5, 6)), 70)
    b = EXPECTED_BUFFERING[policy]
    by_seq = {p.seq: (i, p) for i, p in out if p.seq < 20}
    assert sorted(by_seq) == list(range(20))
    # After the stream ends it extrapolates on, up to max_extrapolation_s (50 ms), then holds.
    tail = [p for _, p in out if p.seq >= 20]
    assert all(isinstance(p, ExtrapolatedPacket) for p in tail)
    last_tick = by_seq[19][0]
    assert [p.seq for p in tail] == list(range(20, 20 + min(50, 69 - last_tick)))
    assert tail[0].payload == (19.0**2 + 37.0, -20.0)
    for k, expected in ((5, (23.0, -5.0)), (6, (30.0, -6.0))):  # from (9, -3) at 3 and (16, -4) at 4
        i, p = by_seq[k]
        assert isinstance(p, ExtrapolatedPacket) and p.extrapolated
        assert p.payload == expected
        assert i * T == k * T + 20 * MS + b and p.send_time_ns == k * T
    assert not any(isinstance(p, ExtrapolatedPacket) for k, (_, p) in by_seq.items() if k not in (5, 6))
    assert buf.extrapolated == 2 + len(tail) and buf.played == 18 and buf.late == 0


@pytest.mark.parametrize("policy", POLICIES)
def test_extrapolation_stops_at_its_limit_and_needs_two_samples(policy: str) -> None:
    buf = make(policy, gap="extrapolate", max_extrapolation_s=0.001)
    out, _ = run(buf, stream(20, lambda k: 20 * MS, drop=(1, 5, 6, 7)), 60)
    seqs = [p.seq for _, p in out]
    # Slot 1: only one sample so far, hold. Slot 5: one period past sample 4, extrapolated;
    # slots 6 and 7 are past the 1 ms limit: hold (the made-up slot-5 value). Likewise slot 20.
    assert seqs == [0, 2, 3, 4, 5, *range(8, 21)]
    assert [p.seq for _, p in out if isinstance(p, ExtrapolatedPacket)] == [5, 20]


def test_play_on_arrival_keeps_its_old_interface() -> None:
    buf = PlayOnArrival()
    a, b, c = Packet(0, 0, (0.0,)), Packet(2, 2 * T, (2.0,)), Packet(1, T, (1.0,))
    buf.push(a, 5 * MS)
    buf.push(b, 5 * MS)  # newest wins: a is late
    assert buf.release(5 * MS) is b
    buf.push(c, 6 * MS)
    assert buf.release(6 * MS) is None
    assert a.fate == LOST_LATE and c.fate == LOST_LATE and buf.late == 2 and buf.played == 1


def test_none_extrapolation_never_makes_a_received_sample_late() -> None:
    # 10 comes 2 ms late and 11, 12 are lost: ticks 30 and 31 extrapolate slots 10 and 11, and
    # 10 is still played when it comes (no schedule: it is newer than anything received).
    buf = PlayOnArrival(T, "extrapolate", 50 * MS)
    arrivals = stream(40, lambda k: 22 * MS if k == 10 else 20 * MS, drop=(11, 12))
    out, _ = run(buf, arrivals, 100)
    assert [(i, p.seq, isinstance(p, ExtrapolatedPacket)) for i, p in out[9:14]] == [
        (29, 9, False),
        (30, 10, True),
        (31, 11, True),
        (32, 10, False),
        (33, 13, False),
    ]
    assert buf.late == 0 and buf.played == 38


# --- fixed ---------------------------------------------------------------------------------------


def jittered(n: int, base_ns: int, jitter_ns: int, seed: int) -> list[Arrival]:
    rng = random.Random(seed)
    delays = [base_ns + rng.randrange(jitter_ns) for _ in range(n)]
    return stream(n, lambda k: delays[k])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_fixed_absorbs_jitter_below_its_buffering_with_constant_latency(seed: int) -> None:
    n = 2000
    buf = make("fixed", buffering_time_s=0.010)
    out, _ = run(buf, jittered(n, 20 * MS, 8 * MS, seed), n + 100)
    latencies = {i * T - p.send_time_ns for i, p in out}
    assert buf.late == 0 and buf.played == n
    assert len(latencies) == 1
    (latency,) = latencies
    assert isinstance(buf, FixedBuffer) and latency == buf.playout_delay_ns
    assert 30 * MS <= latency < 38 * MS  # minimum delay (20..28 ms) + 10 ms


def test_fixed_loses_late_packets_when_jitter_exceeds_its_buffering() -> None:
    n = 2000
    buf = make("fixed", buffering_time_s=0.004)
    run(buf, jittered(n, 20 * MS, 8 * MS, 1), n + 100)
    assert buf.late > n // 10


def test_fixed_base_is_the_minimum_before_playout_starts() -> None:
    # The first packet is 5 ms slower than the next ones: the base must come from those.
    arrivals = stream(100, lambda k: 25 * MS if k == 0 else 20 * MS)
    buf = make("fixed", buffering_time_s=0.010)
    out, _ = run(buf, arrivals, 200)
    assert isinstance(buf, FixedBuffer) and buf.playout_delay_ns == 30 * MS
    assert [p.seq for _, p in out] == list(range(100))


def test_fixed_keeps_its_latency_when_the_delay_drops_later() -> None:
    # 25 ms for the first 200 samples, then 20 ms: a fixed buffer does not re-base once playing.
    buf = make("fixed", buffering_time_s=0.010)
    out, _ = run(buf, stream(400, lambda k: 25 * MS if k < 200 else 20 * MS), 500)
    assert {i * T - p.send_time_ns for i, p in out} == {35 * MS}
    assert buf.played == 400 and buf.late == 0


# --- adaptive ------------------------------------------------------------------------------------


def test_adaptive_tracks_the_ramjee_recursion_and_converges_to_d_plus_4v() -> None:
    n, base, jitter = 20000, 20 * MS, 20 * MS
    arrivals = jittered(n, base, jitter, 7)
    buf = make("adaptive")
    run(buf, arrivals, n + 100, exact=True)
    # Direct computation of algorithm 1 over the relative delays in arrival order.
    a = RAMJEE_SMOOTHING
    d = v = 0.0
    for i, (arr, p) in enumerate(sorted(arrivals, key=lambda x: x[0])):
        rel = arr - p.send_time_ns
        if i == 0:
            d, v = float(rel), 0.0
        else:
            d = a * d + (1 - a) * rel
            v = a * v + (1 - a) * abs(d - rel)
    assert isinstance(buf, AdaptiveBuffer)
    assert buf.delay_estimate_ns == pytest.approx(d, rel=1e-9)
    assert buf.variation_estimate_ns == pytest.approx(v, rel=1e-9)
    assert buf.target_delay_ns == pytest.approx(d + 4 * v, abs=1)
    # Stationary uniform jitter on [0, J): d -> base + J/2, v -> E|n - d| = J/4, so D -> base + 1.5 J.
    # The estimates' own noise is about 0.03 sigma (alpha = 0.998), far below the 3 % allowed here.
    assert d == pytest.approx(base + jitter / 2, rel=0.03)
    assert v == pytest.approx(jitter / 4, rel=0.03)
    assert buf.playout_delay_ns is not None and buf.target_delay_ns is not None
    assert abs(buf.playout_delay_ns - buf.target_delay_ns) <= 2 * MS  # within the hysteresis


def test_adaptive_delay_step_is_slew_limited_and_the_timeline_never_goes_backwards() -> None:
    n, rate = 4000, 0.05
    arrivals = stream(n, lambda k: 60 * MS if 1000 <= k < 3000 else 20 * MS)  # a step up, then down
    buf = make("adaptive", smoothing=0.9, max_slew_rate=rate)
    assert isinstance(buf, AdaptiveBuffer)
    cutoffs: list[int] = []
    seqs: list[int] = []
    j = 0
    order = sorted(arrivals, key=lambda x: x[0])
    for i in range(n + 200):
        now = i * T
        while j < len(order) and order[j][0] <= now:
            buf.push(order[j][1], now)
            j += 1
        r = buf.release(now)
        if r is not None:
            seqs.append(r.seq)
        if buf.playout_delay_ns is not None and seqs:
            cutoffs.append(now - buf.playout_delay_ns)
    steps = [b - a for a, b in itertools.pairwise(cutoffs)]
    assert min(steps) >= round(T * (1 - rate)) and max(steps) <= round(T * (1 + rate))
    assert min(steps) < T < max(steps)  # it did move both ways
    assert all(b > a for a, b in itertools.pairwise(seqs))
    assert max(b - a for a, b in itertools.pairwise(seqs)) <= 2


@pytest.mark.parametrize("hysteresis_s", [0.002, 0.0])
def test_target_changes_within_the_hysteresis_do_not_move_the_schedule(hysteresis_s: float) -> None:
    # Blocks of 10 samples at 20 ms and 10 at 21 ms: the median of a 4-packet window flips
    # between them. Within a 2 ms hysteresis D stays where playout started; without, it follows.
    buf = make("percentile", quantile=0.5, window_packets=4, hysteresis_s=hysteresis_s, max_slew_rate=1.0)
    assert isinstance(buf, PercentileBuffer)
    order = stream(300, lambda k: 21 * MS if (k // 10) % 2 else 20 * MS)
    targets, delays = set(), set()
    j = 0
    for i in range(350):
        while j < len(order) and order[j][0] <= i * T:
            buf.push(order[j][1], i * T)
            j += 1
        if buf.release(i * T) is not None or buf.played:
            targets.add(buf.target_delay_ns)
            delays.add(buf.playout_delay_ns)
    assert targets == {20 * MS, 21 * MS}
    assert delays == ({20 * MS} if hysteresis_s else {20 * MS, 21 * MS})
    assert buf.played + buf.late == 300


# --- percentile ----------------------------------------------------------------------------------


@pytest.mark.parametrize("quantile", [0.9, 0.95])
def test_percentile_late_fraction_is_one_minus_quantile(quantile: float) -> None:
    # i.i.d. uniform jitter over 200 ms, arrivals pushed at their exact time, a window that keeps
    # every packet: about 1 - q of the packets must come after D. The tolerance is 4 standard
    # deviations of the sum of two binomial errors: the packets' own and the window quantile's.
    # No hysteresis here: with one, D lags a drifting target by up to h, which moves the late
    # fraction by up to f(D) h (docs/playout.md); that is a different property.
    n, warmup = 20000, 2000
    arrivals = jittered(n, 20 * MS, 200 * MS, 11)
    packets = [p for _, p in arrivals]
    buf = make("percentile", quantile=quantile, window_packets=n, max_slew_rate=1.0, hysteresis_s=0.0)
    run(buf, arrivals, n + 300, exact=True)
    counted = packets[warmup:]
    late = sum(p.fate == LOST_LATE for p in counted) / len(counted)
    p = 1 - quantile
    assert abs(late - p) < 4 * math.sqrt(2 * p * (1 - p) / len(counted))
    assert isinstance(buf, PercentileBuffer) and buf.target_delay_ns is not None
    # and D is the window's nearest-rank quantile
    rels = sorted(arr - pk.send_time_ns for arr, pk in arrivals)
    assert buf.target_delay_ns == rels[math.ceil(quantile * n) - 1]


def test_percentile_uses_a_sliding_window() -> None:
    # 500 packets with 60 ms delay, then 500 with 20 ms: a 100-packet window forgets the first.
    arrivals = stream(1000, lambda k: 60 * MS if k < 500 else 20 * MS)
    buf = make("percentile", quantile=0.9, window_packets=100, max_slew_rate=1.0)
    run(buf, arrivals, 1200)
    assert buf.target_delay_ns == 20 * MS  # type: ignore[attr-defined]


# --- transparency --------------------------------------------------------------------------------


def exp_jitter(n: int, seed: int, mean_ns: int = 5 * MS) -> list[Arrival]:
    rng = random.Random(seed)
    delays = [20 * MS + round(rng.expovariate(1.0 / mean_ns)) for _ in range(n)]
    return stream(n, lambda k: delays[k])


def brute_force_buffering(rels: Sequence[int], horizon_ns: int, cap_ns: float) -> int:
    """argmin over b in {0} and the window's values, b <= cap, of b + H * P(x > b)."""
    lo = min(rels)
    xs = [r - lo for r in rels]
    cands = sorted({0, *xs})
    cands = [b for b in cands if b <= cap_ns] or [0]
    return min(cands, key=lambda b: (b + horizon_ns * sum(x > b for x in xs) / len(xs), b))


def transparency_run(slope: float | None, d0_s: float = 0.0, n: int = 64 * 47) -> tuple[TransparencyBuffer, list[int]]:
    arrivals = exp_jitter(n, 5)
    buf = make("transparency", force_slope_n_per_s=slope, min_one_way_delay_s=d0_s, allowed_force_error_n=0.1)
    assert isinstance(buf, TransparencyBuffer)
    run(buf, arrivals, n + 400, exact=True)
    rels = [arr - p.send_time_ns for arr, p in sorted(arrivals, key=lambda x: x[0])]
    return buf, rels[-1000:]  # the window at the last decision (every 64th arrival)


def test_transparency_minimises_latency_plus_expected_hold() -> None:
    buf, window = transparency_run(None)
    b = buf.buffering_ns
    assert b == brute_force_buffering(window, 10**9, math.inf)
    # For exponential jitter of mean mu, b + H exp(-b / mu) is least at mu ln(H / mu) = 26 ms.
    assert 15 * MS < b < 40 * MS
    assert buf.target_delay_ns == min(window) + b
    assert buf.playout_delay_ns is not None and abs(buf.playout_delay_ns - buf.target_delay_ns) <= 2 * MS


def test_transparency_buffers_less_when_the_force_slope_is_steep() -> None:
    gentle, window = transparency_run(0.1)  # D_allow = 1 s: no cap in effect
    steep, _ = transparency_run(10.0, d0_s=0.002)  # D_allow = 10 ms, minus d0 = 2 ms: b <= 8 ms
    steeper, _ = transparency_run(100.0, d0_s=0.002)  # D_allow = 1 ms < d0: no buffering at all
    assert steep.allowed_latency_ns == 10 * MS and steeper.allowed_latency_ns == MS
    assert gentle.buffering_ns == brute_force_buffering(window, 10**9, 1e9)
    assert steep.buffering_ns == brute_force_buffering(window, 10**9, 8 * MS)
    assert gentle.buffering_ns > steep.buffering_ns > steeper.buffering_ns == 0
    assert 6 * MS < steep.buffering_ns <= 8 * MS
    # the prediction: s (d0 + b + H P(x > b))
    hold = 10**9 * sum(r - min(window) > steep.buffering_ns for r in window) / len(window)
    assert steep.expected_force_error_n == pytest.approx(10.0 * (2 * MS + steep.buffering_ns + hold) * 1e-9)


def test_transparency_follows_the_slope_the_engine_passes() -> None:
    buf = make("transparency", allowed_force_error_n=0.1)
    assert isinstance(buf, TransparencyBuffer)
    arrivals = exp_jitter(3000, 5)
    order = sorted(arrivals, key=lambda x: x[0])
    j = 0
    for i in range(3400):
        now = i * T
        if i == 2000:
            buf.set_force_slope(contact_force_slope(1000.0, -0.02))  # 20 N/s: D_allow = 5 ms
        while j < len(order) and order[j][0] <= now:
            buf.push(order[j][1], now)
            j += 1
        buf.release(now)
    assert buf.allowed_latency_ns == 5 * MS
    assert 3 * MS < buf.buffering_ns <= 5 * MS
    assert buf.playout_delay_ns is not None and buf.target_delay_ns is not None
    assert abs(buf.playout_delay_ns - buf.target_delay_ns) <= 2 * MS  # slewed down to it


# --- invariants ----------------------------------------------------------------------------------


def messy(seed: int) -> list[Arrival]:
    """Jitter, reordering, losses and duplicates."""
    rng = random.Random(seed)
    out: list[Arrival] = []
    for k in range(1500):
        if rng.random() < 0.05:
            continue
        delay = 20 * MS + rng.randrange(15 * MS)
        out.append((k * T + delay, Packet(k, k * T, payload_of(k))))
        if rng.random() < 0.03:
            out.append((k * T + delay + rng.randrange(30 * MS), Packet(k, k * T, payload_of(k), duplicate=True)))
    return out


Log = tuple[list[tuple[int, int, tuple[float, ...], str]], Trace, int, int, int, int]


def logged(policy: str, gap: str, offset_ns: int, seed: int = 3) -> Log:
    buf = make(policy, gap=gap, window_packets=200, force_slope_n_per_s=5.0)
    out, trace = run(buf, messy(seed), 1700, offset_ns=offset_ns)
    released = [(i, p.seq, p.payload, type(p).__name__) for i, p in out]
    return released, trace, buf.late, buf.duplicates, buf.played, buf.extrapolated


@pytest.mark.parametrize("gap", GAP_MODES)
@pytest.mark.parametrize("policy", POLICIES)
def test_a_receiver_clock_offset_changes_nothing(policy: str, gap: str) -> None:
    reference = logged(policy, gap, 0)
    assert reference[2] > 0 and reference[3] > 0  # the scene does exercise late loss and duplicates
    for offset in (987_654_321_123, -5_000_000_017):
        assert logged(policy, gap, offset) == reference


@pytest.mark.parametrize("policy", POLICIES)
def test_runs_are_deterministic(policy: str) -> None:
    assert logged(policy, "extrapolate", 0, seed=9) == logged(policy, "extrapolate", 0, seed=9)
    assert logged(policy, "hold", 0, seed=9) != logged(policy, "hold", 0, seed=10)


EVENTS = st.lists(
    st.tuples(st.integers(0, 40), st.integers(0, 60 * MS)),  # (seq, one-way delay)
    max_size=80,
)


@settings(max_examples=200, deadline=None)
@given(
    policy=st.sampled_from(POLICIES),
    gap=st.sampled_from(GAP_MODES),
    events=EVENTS,
    offset=st.integers(-(10**12), 10**12),
    exact=st.booleans(),
)
def test_every_packet_is_played_late_or_duplicate_exactly_once(
    policy: str, gap: str, events: list[tuple[int, int]], offset: int, exact: bool
) -> None:
    buf = make(
        policy,
        gap=gap,
        buffering_time_s=0.005,
        window_packets=8,
        quantile=0.75,
        hysteresis_s=0.001,
        max_slew_rate=0.5,
        max_extrapolation_s=0.005,
        force_slope_n_per_s=5.0,
    )
    arrivals = [(seq * T + delay, Packet(seq, seq * T, payload_of(seq))) for seq, delay in events]
    out, _ = run(buf, arrivals, 40 + 60 + 20, offset_ns=offset, exact=exact)
    flush = buf.release(offset + 10**12)  # everything is due now
    if flush is not None:
        out.append((-1, flush))
    pushed = [p for _, p in sorted(arrivals, key=lambda a: a[0])]
    released_real = [p for _, p in out if not isinstance(p, ExtrapolatedPacket)]
    released_ids = {id(p) for p in released_real}
    first: dict[int, Packet] = {}
    for p in pushed:
        first.setdefault(p.seq, p)
    for p in pushed:
        played, late = id(p) in released_ids, p.fate == LOST_LATE
        if first[p.seq] is p:
            assert played != late  # exactly one of the two
        else:
            assert not played and not late  # a duplicate
    assert len(released_ids) == len(released_real) == buf.played
    assert buf.late == sum(p.fate == LOST_LATE for p in pushed)
    assert buf.duplicates == len(pushed) - len(first)
    assert buf.occupancy == 0
    real_seqs = [p.seq for p in released_real]
    assert all(b > a for a, b in itertools.pairwise(real_seqs))
    if policy != "none":  # with a schedule, made-up samples keep the order too
        all_seqs = [p.seq for _, p in out]
        assert all(b > a for a, b in itertools.pairwise(all_seqs))
    assert buf.extrapolated == len(out) - len(released_real)
    assert gap == "extrapolate" or buf.extrapolated == 0


# --- config --------------------------------------------------------------------------------------


def test_build_buffer_makes_each_policy() -> None:
    kinds = {"none": PlayOnArrival, "fixed": FixedBuffer, "adaptive": AdaptiveBuffer}
    kinds |= {"percentile": PercentileBuffer, "transparency": TransparencyBuffer}
    for policy, kind in kinds.items():
        buf = build_buffer(BufferConfig(policy=policy), T)
        assert type(buf) is kind and buf.name == policy
    with pytest.raises(ValueError, match="period_ns"):
        build_buffer(BufferConfig(), 0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"policy": "jitterbuffer"}, "policy must be one of"),
        ({"gap": "interpolate"}, "gap must be one of"),
        ({"quantile": 1.0}, "quantile"),
        ({"smoothing": 0.0}, "smoothing"),
        ({"max_slew_rate": 1.5}, "max_slew_rate"),
        ({"buffering_time_s": -0.001}, "buffering_time_s"),
        ({"buffering_time_s": math.nan}, "finite"),
        ({"gap": "extrapolate", "max_extrapolation_s": 0.0}, "never extrapolates"),
        ({"policy": "percentile", "quantile": 0.99, "window_packets": 50}, "at least 100 packets"),
    ],
)
def test_config_contradictions_raise(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        BufferConfig(**kwargs)  # type: ignore[arg-type]


def test_config_builds_from_scene_data() -> None:
    cfg = typedconfig.build(BufferConfig, {"policy": "percentile", "quantile": 0.9, "window_packets": 10})
    assert cfg.policy == "percentile" and cfg.window_packets == 10
    assert BufferConfig(policy="percentile", quantile=0.99, window_packets=100).window_packets == 100
    with pytest.raises(ConfigError, match="contradiction"):
        typedconfig.build(BufferConfig, {"policy": "percentile", "quantile": 0.9, "window_packets": 5})
    with pytest.raises(ConfigError, match="quantile"):
        typedconfig.build(BufferConfig, {"quantile": 1.5})
    keys = {row[0] for row in typedconfig.describe(BufferConfig)}
    assert {"policy", "gap", "buffering_time_s", "allowed_force_error_n", "force_slope_n_per_s"} <= keys
