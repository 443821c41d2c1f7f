"""Network effects against their models: loss rates and bursts, jitter shapes, token bucket,
reorder / duplicate / corrupt / blackout, stream independence, determinism and config errors.

Statistical checks use fixed seeds and tolerances of 5 standard deviations derived from each
model's own variance (Markov-chain loss counts have several times the binomial variance); the
expected values come from formulas written here, independently of the module under test.
"""

import itertools
import math
from fractions import Fraction
from pathlib import Path
from statistics import NormalDist

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.core.delay import ConstantDelay, Delay, TokenBucket
from haptic_teleop.core.link import (
    CANONICAL_ORDER,
    DEFAULT_OVERHEAD_BYTES,
    DELIVERED,
    LOST_CORRUPT,
    LOST_NETWORK,
    LOST_QUEUE,
    Link,
    Packet,
)
from haptic_teleop.core.loss import BernoulliLoss
from haptic_teleop.core.netconfig import LinkTraces, LossConfig, NetworkEffectsConfig, build_link, canonical_order
from haptic_teleop.core.uniform import effect_rng
from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.traces import build_scene_link, load_delay_trace, load_loss_trace, resolve_trace_paths
from haptic_teleop.typedconfig import build

MS = 1_000_000
Z = 5.0  # tolerance in standard deviations


def make_link(effects: dict, seed: int = 7, direction: str = "forward") -> Link:
    # Through the scene layer, which reads the trace files a config names (core reads none).
    return build_scene_link(build(NetworkEffectsConfig, effects), seed, direction)


def run(effects: dict, n: int, seed: int = 7, size: int = 100, period_ns: int = MS, direction: str = "forward") -> Link:
    link = make_link(effects, seed, direction)
    send = link.send
    for k in range(n):
        send(Packet(k, k * period_ns, (0.0,), size))
    return link


def originals(link: Link) -> list[Packet]:
    return [p for p in link.log if not p.duplicate]


def lost_mask(link: Link) -> np.ndarray:
    return np.array([p.fate != DELIVERED for p in originals(link)])


# ---------------------------------------------------------------------------------------------
# Markov loss theory, written independently of the module: a chain T over states, loss
# probability ell[s] of a packet that meets state s.


def stationary(T: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eig(T.T)
    pi = np.real(v[:, np.argmin(abs(w - 1.0))])
    return pi / pi.sum()


def markov_loss_theory(T: np.ndarray, ell: np.ndarray, start: np.ndarray, n: int) -> dict[str, float]:
    """Loss rate, asymptotic variance per packet of the loss count, expected count of n packets
    from `start` (the transient included), and mean loss-burst length."""
    pi = stationary(T)
    q = float(pi @ ell)
    k = len(pi)
    Zf = np.linalg.inv(np.eye(k) - T + np.outer(np.ones(k), pi))  # fundamental matrix
    # Var(L) for a 0/1 variable is q(1-q); covariances at lags >= 1 sum to (pi*ell)^T (Z - I) ell.
    var = q * (1 - q) + 2 * float((pi * ell) @ (Zf - np.eye(k)) @ ell)
    bias = float((start - pi) @ Zf @ ell)  # sum over n of P(L_n = 1) - q
    p01 = float((pi * (1 - ell)) @ T @ ell)  # P(packet n-1 delivered, packet n lost)
    return {"rate": q, "var": var, "expected": n * q + bias, "burst": q / p01}


def ge_chain(p: float, r: float, bad_loss: float, good_loss: float) -> tuple[np.ndarray, np.ndarray]:
    return np.array([[1 - p, p], [r, 1 - r]]), np.array([good_loss, bad_loss])


def four_state_chain(p13, p31, p32, p23, p14) -> tuple[np.ndarray, np.ndarray]:
    T = np.array(
        [
            [1 - p13 - p14, 0.0, p13, p14],
            [0.0, 1 - p23, p23, 0.0],
            [p31, p32, 1 - p31 - p32, 0.0],
            [1.0, 0.0, 0.0, 0.0],
        ]
    )
    return T, np.array([0.0, 0.0, 1.0, 1.0])  # lost when the chain is in state 3 or 4


def bursts(mask: np.ndarray) -> tuple[int, int]:
    """(lost packets, loss runs)."""
    starts = int(mask[0]) + int(np.count_nonzero(mask[1:] & ~mask[:-1]))
    return int(mask.sum()), starts


def batch_ratio(mask: np.ndarray, batches: int = 50) -> tuple[float, float]:
    """Mean burst length (losses / runs) and its standard error from batch means (delta method)."""
    losses, runs = [], []
    for chunk in np.array_split(mask, batches):
        a, b = bursts(chunk)
        losses.append(a)
        runs.append(b)
    L, S = np.array(losses, float), np.array(runs, float)
    ratio = L.sum() / S.sum()
    resid = L - ratio * S
    se = math.sqrt(resid.var(ddof=1) * batches) / S.sum()
    return ratio, se


N_LOSS = 300_000

LOSS_CASES = [
    ("bernoulli", {"model": "bernoulli", "probability": 0.05}, ge_chain(0.05, 0.95, 1.0, 0.0), "ge"),
    ("simple_gilbert", {"model": "gilbert", "p": 0.02, "r": 0.3}, ge_chain(0.02, 0.3, 1.0, 0.0), "ge"),
    ("gilbert", {"model": "gilbert", "p": 0.05, "r": 0.4, "one_minus_h": 0.6}, ge_chain(0.05, 0.4, 0.6, 0.0), "ge"),
    (
        "gilbert_elliott_scene",
        {"model": "gilbert_elliott", "p": 0.01, "r": 0.25, "one_minus_h": 0.7, "one_minus_k": 0.001},
        ge_chain(0.01, 0.25, 0.7, 0.001),
        "ge",
    ),
    (
        "gilbert_elliott",
        {"model": "gilbert_elliott", "p": 0.1, "r": 0.5, "one_minus_h": 0.9, "one_minus_k": 0.05},
        ge_chain(0.1, 0.5, 0.9, 0.05),
        "ge",
    ),
    (
        "four_state",
        {"model": "four_state", "p13": 0.01, "p31": 0.3, "p32": 0.2, "p23": 0.4, "p14": 0.02},
        four_state_chain(0.01, 0.3, 0.2, 0.4, 0.02),
        "4s",
    ),
    ("four_state_p13_only", {"model": "four_state", "p13": 0.05}, four_state_chain(0.05, 0.95, 0.0, 1.0, 0.0), "4s"),
]


@pytest.mark.parametrize(("name", "loss", "chain", "kind"), LOSS_CASES, ids=[c[0] for c in LOSS_CASES])
def test_loss_rate_and_burst_length_match_markov_theory(name, loss, chain, kind):
    T, ell = chain
    k = len(ell)
    # netem's GE starts in the good state and decides the loss in the state the packet meets;
    # the 4-state chain starts in state 1 and the packet's fate is the state it moves to.
    start = np.eye(k)[0] if kind == "ge" else np.eye(k)[0] @ T
    th = markov_loss_theory(T, ell, start, N_LOSS)
    mask = lost_mask(run({"loss": loss}, N_LOSS))
    count = int(mask.sum())
    assert abs(count - th["expected"]) <= Z * math.sqrt(th["var"] * N_LOSS), (count, th)
    # Bursty models really are over-dispersed: the tolerance is not just binomial.
    if name in ("simple_gilbert", "gilbert_elliott_scene", "four_state"):
        assert th["var"] > 2 * th["rate"] * (1 - th["rate"])
    ratio, se = batch_ratio(mask)
    assert abs(ratio - th["burst"]) <= Z * se, (ratio, se, th["burst"])
    # The config's own closed forms agree with the matrix computation.
    cfg = build(LossConfig, loss)
    assert cfg.expected_loss_rate() == pytest.approx(th["rate"], rel=1e-9)
    assert cfg.expected_mean_burst_packets() == pytest.approx(th["burst"], rel=1e-9)


def test_closed_forms_in_docs():
    """GE: rate = (r(1-k) + p(1-h)) / (p + r); simple Gilbert mean burst = 1/r."""
    p, r, h1, k1 = 0.01, 0.25, 0.7, 0.001
    ge = build(LossConfig, {"model": "gilbert_elliott", "p": p, "r": r, "one_minus_h": h1, "one_minus_k": k1})
    assert ge.expected_loss_rate() == pytest.approx((r * k1 + p * h1) / (p + r))
    sg = build(LossConfig, {"model": "gilbert", "p": 0.02, "r": 0.3})
    assert sg.expected_mean_burst_packets() == pytest.approx(1 / 0.3)
    assert sg.expected_loss_rate() == pytest.approx(0.02 / 0.32)


def test_loss_trace_replays_and_repeats(tmp_path: Path):
    pattern = [1, 0, 0, 1, 1, 0, 1]
    f = tmp_path / "loss.csv"
    f.write_text("lost\n# a comment\n" + "\n".join(map(str, pattern)) + "\n")
    assert load_loss_trace(f).tolist() == [bool(x) for x in pattern]
    link = run({"loss": {"model": "trace", "file": str(f)}}, 20)
    assert lost_mask(link).tolist() == [bool(pattern[i % 7]) for i in range(20)]
    once = run({"loss": {"model": "trace", "file": str(f), "repeat": False}}, 20)
    assert lost_mask(once).tolist() == [bool(x) for x in pattern] + [False] * 13


# ---------------------------------------------------------------------------------------------
# Jitter.

N_JIT = 100_000
MU, SIG = 0.05, 0.01


def delays_s(link: Link) -> np.ndarray:
    return np.array([(p.arrival_time_ns - p.send_time_ns) * 1e-9 for p in originals(link)])


def pareto_q(q):
    return ((1.0 - np.asarray(q)) ** (-1.0 / 3.0) - 1.5) * 4.0 / 3.0


def unit_quantile(dist: str, q):
    q = np.asarray(q, dtype=float)
    if dist == "uniform":
        return 2 * q - 1
    nq = np.vectorize(NormalDist().inv_cdf)(q)
    if dist == "normal":
        return nq
    if dist == "pareto":
        return np.minimum(pareto_q(q), 32767 / 8192)  # netem's table saturates at int16 max
    return np.minimum((nq + 3 * pareto_q(q)) / 4, 32767 / 8192)


@pytest.mark.parametrize("dist", ["uniform", "normal", "pareto", "paretonormal"])
def test_jitter_mean_std_and_quantiles_match_distribution(dist):
    d = delays_s(run({"delay": {"delay_s": MU, "jitter_s": SIG, "distribution": dist}}, N_JIT))
    # Moments of the distribution from its quantile function on a fine grid.
    grid = (np.arange(1 << 18) + 0.5) / (1 << 18)
    x = MU + SIG * unit_quantile(dist, grid)
    mean, std = x.mean(), x.std()
    table_err = 2e-3 * SIG  # a 4096-entry quantile table vs the continuous distribution
    assert abs(d.mean() - mean) <= Z * std / math.sqrt(N_JIT) + table_err
    kurt = ((x - mean) ** 4).mean() / std**4
    se_std = std * math.sqrt((kurt - 1) / (4 * N_JIT))
    assert abs(d.std() - std) <= Z * se_std + table_err
    for q in (0.01, 0.05, 0.25, 0.5, 0.75, 0.95):
        xq = MU + SIG * float(unit_quantile(dist, q))
        frac = float(np.mean(d <= xq + 0.5e-9))
        assert abs(frac - q) <= Z * math.sqrt(q * (1 - q) / N_JIT) + 1 / 4096, (q, frac)


def test_normal_jitter_sigma_is_jitter():
    d = delays_s(run({"delay": {"delay_s": MU, "jitter_s": SIG, "distribution": "normal"}}, N_JIT))
    assert d.std() == pytest.approx(SIG, rel=Z / math.sqrt(2 * N_JIT) + 1e-3)


def lag1(x: np.ndarray) -> float:
    return float(np.corrcoef(x[:-1], x[1:])[0, 1])


def test_netem_correlation_shrinks_spread_as_documented():
    """netem's u_n = (1-rho) v_n + rho u_(n-1): lag-1 correlation rho, variance times (1-rho)/(1+rho)."""
    rho = 0.5
    d = delays_s(run({"delay": {"delay_s": MU, "jitter_s": SIG, "distribution": "uniform", "correlation": rho}}, N_JIT))
    # delay = MU + SIG (2u - 1): std = 2 SIG sqrt(Var u) = SIG sqrt((1 - rho) / (3 (1 + rho))).
    expected_std = SIG * math.sqrt((1 - rho) / (3 * (1 + rho)))
    batches = np.array_split(d, 50)
    stds = np.array([b.std() for b in batches])
    assert abs(d.std() - expected_std) <= Z * stds.std(ddof=1) / math.sqrt(50)
    assert abs(lag1(d) - rho) <= Z * math.sqrt((1 - rho**2) / N_JIT) * 2
    assert abs(d.mean() - MU) <= Z * d.std() * math.sqrt((1 + rho) / ((1 - rho) * N_JIT))
    # and without correlation the full uniform spread SIG / sqrt(3) comes back
    d0 = delays_s(run({"delay": {"delay_s": MU, "jitter_s": SIG, "distribution": "uniform"}}, N_JIT))
    assert d0.std() == pytest.approx(SIG / math.sqrt(3), rel=0.01)
    assert abs(lag1(d0)) <= Z / math.sqrt(N_JIT)


def test_gaussian_copula_keeps_the_marginal_and_the_correlation():
    rho = 0.25
    cfg = {
        "delay": {"delay_s": MU, "jitter_s": SIG, "distribution": "normal", "correlation": rho},
        "correlation_model": "gaussian_copula",
    }
    d = delays_s(run(cfg, N_JIT))
    inflate = math.sqrt((1 + rho) / (1 - rho))
    assert abs(d.mean() - MU) <= Z * SIG / math.sqrt(N_JIT) * inflate
    se_std = SIG * math.sqrt((1 + rho**2) / (2 * N_JIT * (1 - rho**2)))
    assert abs(d.std() - SIG) <= Z * se_std + 1e-3 * SIG
    assert abs(lag1(d) - rho) <= Z * math.sqrt((1 - rho**2) / N_JIT) * 1.5


def bivariate_normal_both_below(c: float, rho: float) -> float:
    """P(Z1 < c, Z2 < c) for standard normals with correlation rho, by quadrature."""
    nd = NormalDist()
    x = np.linspace(-9.0, c, 200_001)
    dens = np.exp(-0.5 * x**2) / math.sqrt(2 * math.pi)
    inner = np.vectorize(nd.cdf)((c - rho * x) / math.sqrt(1 - rho**2))
    y = dens * inner
    return float(np.sum((y[1:] + y[:-1]) / 2 * np.diff(x)))


def test_copula_correlated_bernoulli_keeps_rate_and_lengthens_bursts():
    p, rho, n = 0.1, 0.6, 200_000
    link = run({"loss": {"probability": p, "correlation": rho}, "correlation_model": "gaussian_copula"}, n)
    mask = lost_mask(link)
    c = NormalDist().inv_cdf(p)
    p11 = bivariate_normal_both_below(c, rho)
    expected_burst = p / (p - p11)  # losses / P(delivered then lost)
    ratio, se = batch_ratio(mask)
    assert abs(ratio - expected_burst) <= Z * se
    assert ratio > 1 / (1 - p) + Z * se  # clearly burstier than independent loss
    rates = np.array([c.mean() for c in np.array_split(mask, 50)])
    assert abs(mask.mean() - p) <= Z * rates.std(ddof=1) / math.sqrt(50)


# ---------------------------------------------------------------------------------------------
# Time-varying delay.


def test_sinusoid_schedule_and_trace_give_the_configured_delay(tmp_path: Path):
    n = 8000
    sin = delays_s(run({"delay": {"sinusoid": {"min_delay_s": 0.03, "max_delay_s": 0.12, "period_s": 4.0}}}, n))
    t = np.arange(n) * 1e-3
    want = 0.075 - 0.045 * np.cos(2 * np.pi * t / 4.0)
    assert np.max(np.abs(sin - want)) <= 1e-9
    ramp = {"times_s": [1.0, 2.0, 5.0], "delays_s": [0.01, 0.05, 0.02]}
    got = delays_s(run({"delay": {"delay_s": 0.005, "schedule": ramp}}, n))
    assert np.max(np.abs(got - (0.005 + np.interp(t, ramp["times_s"], ramp["delays_s"])))) <= 1e-9
    steps = {**ramp, "interpolation": "step"}
    got = delays_s(run({"delay": {"schedule": steps}}, n))
    idx = np.clip(np.searchsorted(ramp["times_s"], t, side="right") - 1, 0, None)
    assert np.max(np.abs(got - np.array(ramp["delays_s"])[idx])) <= 1e-9
    f = tmp_path / "delay.csv"
    f.write_text("time_s,delay_s\n0.0,0.02\n3.0,0.08\n6.0,0.04\n")
    ts, ds = load_delay_trace(f)
    assert ts.tolist() == [0.0, 3.0, 6.0] and ds.tolist() == [0.02, 0.08, 0.04]
    got = delays_s(run({"delay": {"trace": {"file": str(f)}}}, n))
    assert np.max(np.abs(got - np.interp(t, ts, ds))) <= 1e-9


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("time_s,delay_s\n0,0.01\n1,abc\n", "row 3"),
        ("0,0.01\n0,0.02\n", "increase strictly"),
        ("0,0.01\n1,-0.5\n", "delay_s must be >= 0"),
        ("0,0.01,7\n", "expected 2 column"),
        ("0,nan\n", "finite"),
        ("# only a comment\n", "no data rows"),
    ],
)
def test_bad_delay_trace_names_file_row_and_problem(tmp_path: Path, text, problem):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(ValueError, match=problem) as exc:
        load_delay_trace(f)
    assert str(f) in str(exc.value)


def test_bad_loss_trace_and_missing_file(tmp_path: Path):
    f = tmp_path / "bad.csv"
    f.write_text("0\n1\n2\n")
    with pytest.raises(ValueError, match=r"row 3: expected 0 or 1"):
        load_loss_trace(f)
    with pytest.raises(ValueError, match="cannot read"):
        load_loss_trace(tmp_path / "missing.csv")


def test_resolve_trace_paths_makes_relative_paths_absolute(tmp_path: Path):
    (tmp_path / "d.csv").write_text("0,0.01\n")
    cfg = build(NetworkEffectsConfig, {"delay": {"trace": {"file": "d.csv"}}})
    resolved = resolve_trace_paths(cfg, tmp_path)
    assert resolved.delay is not None and resolved.delay.trace is not None
    assert Path(resolved.delay.trace.file) == (tmp_path / "d.csv").resolve()
    assert build_scene_link(cfg, 1, "forward", base_dir=tmp_path).effects[0].name == "delay"
    (tmp_path / "bad.csv").write_text("x\n")
    bad = build(NetworkEffectsConfig, {"loss": {"model": "trace", "file": "bad.csv"}})
    with pytest.raises(ValueError, match=r"bad\.csv"):
        resolve_trace_paths(bad, tmp_path)


def test_core_builds_a_trace_link_from_rows_and_reads_no_file(tmp_path: Path):
    missing = str(tmp_path / "never_written.csv")
    cfg = build(
        NetworkEffectsConfig, {"delay": {"trace": {"file": missing}}, "loss": {"model": "trace", "file": missing}}
    )
    with pytest.raises(ValueError, match=r"never_written\.csv: its rows were not given \(LinkTraces\.loss\)"):
        build_link(cfg, 1, "forward")
    rows = LinkTraces(delay=(np.array([0.0, 1.0]), np.array([0.01, 0.03])), loss=np.array([False, True]))
    link = build_link(cfg, 1, "forward", traces=rows)
    for k in range(4):
        link.send(Packet(k, k * 500 * MS, (0.0,), 100))
    assert [p.fate for p in link.log] == [DELIVERED, LOST_NETWORK, DELIVERED, LOST_NETWORK]
    assert [p.arrival_time_ns - p.send_time_ns for p in link.log if p.fate == DELIVERED] == [10 * MS, 30 * MS]
    with pytest.raises(ValueError, match=r"its rows were not given \(LinkTraces\.delay\)"):
        build_link(cfg, 1, "forward", traces=LinkTraces(loss=rows.loss))


# ---------------------------------------------------------------------------------------------
# Ordering.


def inversions(link: Link) -> int:
    delivered = sorted((p.arrival_time_ns, p.seq) for p in link.log if p.fate == DELIVERED and not p.duplicate)
    seqs = np.array([s for _, s in delivered])
    return int(np.count_nonzero(np.diff(seqs) < 0))


def test_jitter_reorders_unless_keep_order():
    cfg = {"delay_s": 0.05, "jitter_s": 0.01, "distribution": "normal"}
    free = run({"delay": cfg}, 5000)
    assert inversions(free) > 100
    kept = run({"delay": {**cfg, "keep_order": True}}, 5000)
    assert inversions(kept) == 0
    # keep_order only holds packets back behind their predecessor: arrival = max(own, previous).
    own = delays_s(free)
    arrivals = np.array([p.arrival_time_ns for p in originals(kept)])
    sends = np.arange(5000) * MS
    assert np.array_equal(arrivals, np.maximum.accumulate(sends + np.round(own * 1e9).astype(np.int64)))


def test_link_delivers_in_arrival_order_exactly_once():
    link = make_link({"delay": {"delay_s": 0.02, "jitter_s": 0.01}, "duplicate": {"probability": 0.1}})
    got: list[Packet] = []
    for k in range(3000):
        link.send(Packet(k, k * MS, (float(k),), 50))
        got.extend(link.deliver(k * MS))
    got.extend(link.deliver(10**15))
    expected = [p for p in link.log if p.fate == DELIVERED]
    assert len(got) == len(expected) and link.in_flight == 0
    assert {id(p) for p in got} == {id(p) for p in expected}
    assert all(a.arrival_time_ns <= b.arrival_time_ns for a, b in itertools.pairwise(got))


@settings(max_examples=200, deadline=None)
@given(
    delays=st.lists(st.integers(0, 50), min_size=1, max_size=80),
    polls=st.lists(st.integers(0, 200), max_size=20),
)
def test_deliver_matches_a_sorted_reference(delays, polls):
    """The deque+heap queue releases exactly what a sort by (arrival, send order) would."""

    class Fixed:
        name = "delay"

        def __init__(self):
            self.i = 0

        def apply(self, p):
            p.arrival_time_ns += delays[self.i]
            self.i += 1

    link = Link([Fixed()])
    for k in range(len(delays)):
        link.send(Packet(k, k, ()))
    out: list[int] = []
    for now in [*sorted(polls), 10**9]:
        batch = link.deliver(now)
        assert all(p.arrival_time_ns <= now for p in batch)
        out.extend(p.seq for p in batch)
    assert out == [k for _, k in sorted((k + d, k) for k, d in enumerate(delays))]


# ---------------------------------------------------------------------------------------------
# Rate limit.

RATE = 400_000.0
SIZE = 100
WIRE_BITS = (SIZE + DEFAULT_OVERHEAD_BYTES) * 8


def test_throughput_equals_rate_and_overflow_is_tail_dropped():
    n, limit = 20_000, 50
    link = run({"rate_limit": {"rate_bps": RATE, "queue_limit_packets": limit}}, n, size=SIZE)
    pk = originals(link)
    ok = [p for p in pk if p.fate == DELIVERED]
    assert {p.fate for p in pk} == {DELIVERED, LOST_QUEUE}
    deps = np.array([p.arrival_time_ns for p in ok])
    throughput = (len(ok) - 1) * WIRE_BITS / ((deps[-1] - deps[0]) * 1e-9)
    assert throughput == pytest.approx(RATE, rel=0.01)
    # Saturated, packets leave back to back, one transmit time apart (1376 bits at 400 kbit/s).
    assert set(np.diff(deps[20:]).tolist()) == {WIRE_BITS * 10**9 // int(RATE)}
    # Every accepted packet leaves: those the tokens allow by the last send, the initial bucket
    # (1500 bytes) and the packets still queued.
    t_end = (n - 1) * MS * 1e-9
    expected = (RATE * t_end + 1500 * 8) / WIRE_BITS + limit
    assert abs(len(ok) - expected) <= 2
    # Dropped fraction in overload: 1 - service rate / offered rate.
    offered = 1000 * WIRE_BITS
    assert link.lost / n == pytest.approx(1 - RATE / offered, abs=0.01)
    # The queue never holds more than the limit, and drops only happen when it is full.
    sends = np.array([p.send_time_ns for p in ok])
    for p in pk:
        t = p.send_time_ns
        waiting = np.count_nonzero((sends < t) & (deps > t))
        assert waiting <= limit
        if p.fate == LOST_QUEUE:
            assert waiting == limit
    # Queueing delay is bounded by the queue: (limit + 1) transmit times.
    tx_ns = WIRE_BITS * 1e9 / RATE
    assert max(deps - sends) <= (limit + 1) * tx_ns + limit + 1


def test_rate_limit_under_load_adds_nothing_and_policer_never_queues():
    fast = run({"rate_limit": {"rate_bps": 10e6}}, 2000, size=SIZE)
    assert all(p.fate == DELIVERED and p.arrival_time_ns == p.send_time_ns for p in fast.log)
    police = run({"rate_limit": {"rate_bps": RATE, "queue_limit_packets": 0}}, 5000, size=SIZE)
    ok = [p for p in police.log if p.fate == DELIVERED]
    assert all(p.arrival_time_ns == p.send_time_ns for p in ok)
    expected = (RATE * 4.999 + 1500 * 8) / WIRE_BITS
    assert abs(len(ok) - expected) <= 2


def test_oversize_packet_is_an_error():
    link = make_link({"rate_limit": {"rate_bps": RATE, "burst_bytes": 200}})
    link.send(Packet(0, 0, (), 100))
    with pytest.raises(ValueError, match="exceeds burst_bytes"):
        link.send(Packet(1, MS, (), 200))


@settings(max_examples=150, deadline=None)
@given(
    rate=st.integers(8_000, 2_000_000),
    burst=st.integers(600, 5000),
    limit=st.integers(0, 20),
    gaps=st.lists(st.tuples(st.integers(0, 3 * MS), st.integers(0, 500)), min_size=1, max_size=120),
)
def test_token_bucket_is_the_greedy_shaper(rate, burst, limit, gaps):
    """Accepted packets leave as the greedy (sigma, rho) shaper of network calculus says:
    d_j = max over i <= j of a_i + (L_i + ... + L_j - sigma)^+ / rho, rounded up to the next ns;
    a packet is dropped only when `limit` packets are waiting."""
    tb = TokenBucket(rate, burst, limit, overhead_bytes=DEFAULT_OVERHEAD_BYTES)
    t = 0
    sent: list[Packet] = []
    for k, (gap, size) in enumerate(gaps):
        t += gap
        p = Packet(k, t, (), size)
        p.arrival_time_ns = t
        tb.apply(p)
        sent.append(p)
    ok = [p for p in sent if p.fate == DELIVERED]
    sigma = burst * 8
    bits = [(p.size_bytes + DEFAULT_OVERHEAD_BYTES) * 8 for p in ok]
    for j, pj in enumerate(ok):
        exact = max(
            Fraction(ok[i].send_time_ns) + Fraction(max(0, sum(bits[i : j + 1]) - sigma) * 10**9, rate)
            for i in range(j + 1)
        )
        assert pj.arrival_time_ns == math.ceil(exact), (j, pj.arrival_time_ns, float(exact))
    for p in sent:
        waiting = sum(1 for q in ok if q.seq < p.seq and q.arrival_time_ns > p.send_time_ns)
        assert waiting <= limit
        if p.fate == LOST_QUEUE:
            assert waiting == limit


# ---------------------------------------------------------------------------------------------
# Reorder, duplicate, corrupt, blackout.


def binom_ok(count: int, n: int, p: float) -> bool:
    return abs(count - n * p) <= Z * math.sqrt(n * p * (1 - p))


def test_reorder_fraction_skips_the_delay():
    n, p = 50_000, 0.1
    link = run({"delay": {"delay_s": 0.05}, "reorder": {"probability": p}}, n)
    pk = originals(link)
    immediate = [q for q in pk if q.arrival_time_ns == q.send_time_ns]
    assert binom_ok(len(immediate), n, p)
    assert all(q.arrival_time_ns - q.send_time_ns in (0, 50 * MS) for q in pk)
    assert inversions(link) >= len(immediate) - 60  # each one overtakes the 49 packets in flight


def test_reorder_gap_renewal_fraction_and_spacing():
    n, p, gap = 60_000, 0.25, 5
    link = run({"delay": {"delay_s": 0.02}, "reorder": {"probability": p, "gap_packets": gap}}, n)
    idx = np.array([q.seq for q in originals(link) if q.arrival_time_ns == q.send_time_ns])
    # Renewal cycle: gap-1 delayed packets, then a geometric number of tries ending in a reorder.
    mean_c = gap - 1 + 1 / p
    var_c = (1 - p) / p**2
    expected = n / mean_c
    assert abs(len(idx) - expected) <= Z * math.sqrt(n * var_c / mean_c**3) + 1
    assert np.diff(idx).min() >= gap
    every5 = run({"delay": {"delay_s": 0.02}, "reorder": {"probability": 1.0, "gap_packets": 5}}, 100)
    assert [q.seq for q in every5.log if q.arrival_time_ns == q.send_time_ns] == list(range(4, 100, 5))


def test_duplicate_fraction_and_copies():
    n, p = 50_000, 0.05
    link = run({"delay": {"delay_s": 0.02, "jitter_s": 0.005}, "duplicate": {"probability": p}}, n)
    copies = [q for q in link.log if q.duplicate]
    assert binom_ok(len(copies), n, p) and link.duplicates == len(copies)
    assert all(q.fate == DELIVERED for q in copies) and link.lost == 0
    by_seq = {q.seq: q for q in originals(link)}
    assert all(q.send_time_ns == by_seq[q.seq].send_time_ns for q in copies)
    # Each copy gets its own jitter draw.
    assert sum(q.arrival_time_ns != by_seq[q.seq].arrival_time_ns for q in copies) > 0.9 * len(copies)


def test_corruption_fraction_and_fate():
    n, p = 50_000, 0.03
    link = run({"delay": {"delay_s": 0.01}, "corrupt": {"probability": p}, "duplicate": {"probability": 0.2}}, n)
    corrupt = [q for q in originals(link) if q.fate == LOST_CORRUPT]
    assert binom_ok(len(corrupt), n, p) and link.lost == len(corrupt)
    copies = [q for q in link.log if q.duplicate]
    assert binom_ok(sum(q.fate == LOST_CORRUPT for q in copies), len(copies), p)
    assert link.fate_counts()["corruption"] == len(corrupt)


def test_blackout_loses_exactly_the_packets_sent_in_the_windows():
    cfg = {"delay": {"delay_s": 0.02}, "blackout": {"starts_s": [3.0, 4.2], "ends_s": [3.5, 4.25]}}
    link = run(cfg, 6000)
    lost = [q.seq for q in link.log if q.fate == LOST_NETWORK]
    assert lost == list(range(3000, 3500)) + list(range(4200, 4250))
    # Packets already in flight when the link goes down still arrive.
    assert link.log[2999].fate == DELIVERED and link.log[2999].arrival_time_ns == 3019 * MS


# ---------------------------------------------------------------------------------------------
# Independence of streams and determinism.

LOSS_GE = {"model": "gilbert_elliott", "p": 0.02, "r": 0.3, "one_minus_h": 0.8, "one_minus_k": 0.01}


def loss_fates(link: Link) -> list[bool]:
    return [q.fate == LOST_NETWORK for q in originals(link)]


def test_adding_effects_does_not_change_which_packets_the_loss_drops():
    base = run({"loss": LOSS_GE}, 20_000)
    more = run(
        {
            "loss": LOSS_GE,
            "duplicate": {"probability": 0.3},
            "corrupt": {"probability": 0.05},
            "delay": {"delay_s": 0.03, "jitter_s": 0.01},
            "reorder": {"probability": 0.1},
        },
        20_000,
    )
    assert sum(loss_fates(base)) > 500
    assert loss_fates(base) == loss_fates(more)
    # A blackout only adds its own window: outside it the same packets are lost.
    dark = run({"loss": LOSS_GE, "blackout": {"starts_s": [5.0], "ends_s": [6.0]}}, 20_000)
    fb, fd = loss_fates(base), loss_fates(dark)
    assert fb[:5000] == fd[:5000] and fb[6000:] == fd[6000:]
    assert all(fd[5000:6000])


def test_adding_loss_or_duplicates_does_not_change_survivors_delays():
    jit = {"delay_s": 0.05, "jitter_s": 0.01, "correlation": 0.3}
    base = originals(run({"delay": jit}, 10_000))
    more = originals(run({"delay": jit, "loss": {"probability": 0.2}, "duplicate": {"probability": 0.2}}, 10_000))
    pairs = [(a, b) for a, b in zip(base, more) if b.fate == DELIVERED]
    assert len(pairs) > 7000
    assert all(a.arrival_time_ns == b.arrival_time_ns for a, b in pairs)


EVERYTHING = {
    "blackout": {"starts_s": [1.0], "ends_s": [1.2]},
    "rate_limit": {"rate_bps": 2e6, "queue_limit_packets": 20},
    "loss": LOSS_GE,
    "duplicate": {"probability": 0.05},
    "corrupt": {"probability": 0.01},
    "delay": {"delay_s": 0.03, "jitter_s": 0.008, "distribution": "paretonormal", "correlation": 0.2},
    "reorder": {"probability": 0.05, "gap_packets": 3},
}


def signature(link: Link) -> list[tuple]:
    return [(p.seq, p.send_time_ns, p.arrival_time_ns, p.fate, p.duplicate) for p in link.log]


def test_same_seed_same_fates_other_seed_or_direction_differs():
    a = run(EVERYTHING, 5000, seed=11)
    b = run(EVERYTHING, 5000, seed=11)
    assert signature(a) == signature(b)
    assert signature(a) != signature(run(EVERYTHING, 5000, seed=12))
    assert signature(a) != signature(run(EVERYTHING, 5000, seed=11, direction="backward"))


def test_build_link_builds_only_named_effects_in_canonical_order():
    assert make_link({}).effects == ()
    only = make_link({"delay": {"delay_s": 0.01}}).effects
    assert len(only) == 1 and isinstance(only[0], ConstantDelay)
    cfg = build(NetworkEffectsConfig, EVERYTHING)
    names = [e.name for e in build_link(cfg, 1, "forward").effects]
    assert names == ["blackout", "rate_limit", "loss", "duplicate", "corrupt", "delay"]
    assert canonical_order(cfg) == CANONICAL_ORDER
    assert canonical_order(build(NetworkEffectsConfig, {"loss": {"probability": 0.1}})) == ("loss",)
    assert isinstance(make_link({"delay": {"delay_s": 0.01, "jitter_s": 0.001}}).effects[0], Delay)


def test_plain_effects_still_compose_by_hand():
    link = Link([BernoulliLoss(0.5, effect_rng(3, "forward", "loss")), ConstantDelay(0.01)])
    for k in range(1000):
        link.send(Packet(k, k * MS, ()))
    assert binom_ok(link.lost, 1000, 0.5)
    assert all(p.arrival_time_ns == p.send_time_ns + 10 * MS for p in link.log if p.fate == DELIVERED)
    assert link.loss_rate() == link.lost / 1000


# ---------------------------------------------------------------------------------------------
# Config errors: each names the key path and what is allowed or contradictory.

BAD = [
    ({"jitter": {"jitter_s": 0.01}}, "jitter", "unknown key"),
    ({"delay": {"delay_s": -0.01}}, "delay.delay_s", ">= 0.0"),
    ({"delay": {"delay_s": "fast"}}, "delay.delay_s", "a number"),
    ({"delay": {"jitter_s": 0.01, "distribution": "gaussian"}}, "delay.distribution", "one of uniform"),
    ({"delay": {"jitter_s": 0.01, "correlation": 1.0}}, "delay.correlation", "< 1.0"),
    (
        {
            "delay": {
                "schedule": {"times_s": [0, 1], "delays_s": [0.1, 0.2]},
                "sinusoid": {"min_delay_s": 0, "max_delay_s": 1, "period_s": 1},
            }
        },
        "delay",
        "at most one time-varying delay",
    ),
    (
        {"delay": {"schedule": {"times_s": [0, 1, 1], "delays_s": [0.1, 0.2, 0.3]}}},
        "delay.schedule",
        "increase strictly",
    ),
    ({"delay": {"schedule": {"times_s": [0, 1], "delays_s": [0.1]}}}, "delay.schedule", "same number"),
    ({"delay": {"schedule": {"times_s": [0], "delays_s": [-0.1]}}}, "delay.schedule.delays_s[0]", ">= 0.0"),
    (
        {"delay": {"sinusoid": {"min_delay_s": 0.2, "max_delay_s": 0.1, "period_s": 4}}},
        "delay.sinusoid",
        "below min_delay_s",
    ),
    (
        {"delay": {"sinusoid": {"min_delay_s": 0.0, "max_delay_s": 0.1, "period_s": 0}}},
        "delay.sinusoid.period_s",
        "> 0.0",
    ),
    ({"loss": {"probability": 1.5}}, "loss.probability", "<= 1.0"),
    ({"loss": {"model": "bursty"}}, "loss.model", "one of bernoulli"),
    ({"loss": {"model": "bernoulli"}}, "loss", "needs probability"),
    ({"loss": {"model": "gilbert", "p": 0.1}}, "loss", "needs r"),
    ({"loss": {"model": "gilbert", "p": 0.1, "r": 0.2, "one_minus_k": 0.1}}, "loss", "one_minus_k not used"),
    ({"loss": {"probability": 0.1, "p13": 0.1}}, "loss", "p13 not used"),
    ({"loss": {"model": "gilbert_elliott", "p": 0.1, "r": 0.0}}, "loss", "absorbing"),
    ({"loss": {"model": "four_state", "p13": 0.6, "p31": 0.5, "p14": 0.6}}, "loss", "p13 + p14"),
    ({"loss": {"model": "four_state", "p13": 0.1, "p31": 0.7, "p32": 0.5}}, "loss", "p31 + p32"),
    ({"loss": {"model": "four_state", "p13": 0.1, "p31": 0.0}}, "loss", "never ends a burst"),
    ({"loss": {"model": "four_state", "p13": 0.1, "p31": 0.3, "p32": 0.2, "p23": 0.0}}, "loss", "state 2 absorbing"),
    ({"loss": {"model": "four_state", "p13": 0.1, "p14": 0.01}}, "loss", "give p31 too"),
    ({"loss": {"model": "trace"}}, "loss", "needs file"),
    ({"reorder": {"probability": 0.1}}, "<top level>", "reorder needs a delay"),
    ({"reorder": {"probability": 0.1}, "delay": {"delay_s": 0.0}}, "<top level>", "reorder needs a delay"),
    ({"reorder": {"probability": 0.1, "gap_packets": 0}, "delay": {"delay_s": 0.1}}, "reorder.gap_packets", ">= 1"),
    ({"duplicate": {"probability": -0.1}}, "duplicate.probability", ">= 0.0"),
    ({"corrupt": {}}, "corrupt.probability", "required key is missing"),
    ({"rate_limit": {}}, "rate_limit.rate_bps", "required key is missing"),
    ({"rate_limit": {"rate_bps": 0}}, "rate_limit.rate_bps", ">= 1.0"),
    ({"rate_limit": {"rate_bps": 1e5, "queue_limit_packets": -1}}, "rate_limit.queue_limit_packets", ">= 0"),
    ({"rate_limit": {"rate_bps": 1e5, "burst_bytes": 50}}, "rate_limit", "no packet would ever fit"),
    ({"rate_limit": {"rate_bps": 1e5, "queue_limit_packets": 2.5}}, "rate_limit.queue_limit_packets", "an integer"),
    ({"blackout": {"starts_s": [1.0], "ends_s": [0.5]}}, "blackout", "ends before it starts"),
    ({"blackout": {"starts_s": [1.0, 1.5], "ends_s": [2.0, 3.0]}}, "blackout", "without overlap"),
    ({"blackout": {"starts_s": [1.0, 2.0], "ends_s": [1.5]}}, "blackout", "same number"),
    ({"blackout": {"starts_s": 1.0, "ends_s": [1.5]}}, "blackout.starts_s", "a list"),
    ({"correlation_model": "ar2"}, "correlation_model", "one of netem"),
]


@pytest.mark.parametrize(("data", "key", "allowed"), BAD, ids=[f"{i}-{b[1]}" for i, b in enumerate(BAD)])
def test_bad_parameters_raise_config_error_naming_key(data, key, allowed):
    with pytest.raises(ConfigError) as exc:
        build(NetworkEffectsConfig, data, source="scene.yaml")
    msg = str(exc.value)
    assert msg.startswith(f"scene.yaml: {key}"), msg
    assert allowed in msg, msg


def test_direct_construction_checks_parameters():
    with pytest.raises(ValueError, match="probability"):
        BernoulliLoss(1.2, np.random.default_rng(0))
    with pytest.raises(ValueError, match="delay_s"):
        ConstantDelay(-1.0)
    with pytest.raises(ValueError, match="rate_bps"):
        TokenBucket(0.1, 1500, 10)
    with pytest.raises(ValueError, match="correlation"):
        Delay(0.01, jitter_s=0.01, rng=np.random.default_rng(0), correlation=1.0)


# A loss model's effect config from a probability p (bursty at every p: the chains' states matter).
MARKOV = {
    "bernoulli": lambda p: {"probability": p},
    "gilbert_elliott": lambda p: {
        "model": "gilbert_elliott",
        "p": p,
        "r": 0.25,
        "one_minus_h": 0.7,
        "one_minus_k": p / 10,
    },
    "four_state": lambda p: {"model": "four_state", "p13": p * 0.8, "p31": 0.3, "p32": 0.2, "p23": 0.1, "p14": p / 5},
}


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    p=st.sampled_from([0.0, 0.01, 0.3, 1.0]),
    delay_ms=st.sampled_from([0.0, 0.4, 1.0, 50.0, 123.4]),
    blackout=st.booleans(),
    model=st.sampled_from(["bernoulli", "gilbert_elliott", "four_state"]),
)
def test_vectorized_schedule_equals_send(seed, p, delay_ms, blackout, model):
    """`Link.schedule_all` decides what `send` decides, packet by packet, from the same draws
    (the Markov chains too: their runs over a window, `gilbert_run` and `four_state_run`)."""
    effects: dict = {"delay": {"delay_s": delay_ms / 1000}, "loss": MARKOV[model](p)}
    if blackout:
        effects["blackout"] = {"starts_s": [0.5, 2.0], "ends_s": [0.7, 2.001]}
    n = 5000  # more than one block of draws
    one_by_one = run(effects, n, seed=seed)
    at_once = make_link(effects, seed=seed)
    assert at_once.vectorized
    arrival, fate = at_once.schedule_all(np.arange(n, dtype=np.int64) * MS)
    assert [q.fate for q in one_by_one.log] == fate.tolist()
    assert [q.arrival_time_ns for q in one_by_one.log] == arrival.tolist()
    assert (at_once.sent, at_once.lost) == (one_by_one.sent, one_by_one.lost)
    # In windows (the compiled loop's): each call goes on where the last one left the draws.
    windowed = make_link(effects, seed=seed)
    cuts = [0, 1, 999, 1000, 3333, n]
    parts = [windowed.schedule_all(np.arange(a, b, dtype=np.int64) * MS) for a, b in itertools.pairwise(cuts)]
    assert np.array_equal(np.concatenate([f for _, f in parts]), fate)
    assert np.array_equal(np.concatenate([a for a, _ in parts]), arrival)
    assert (windowed.sent, windowed.lost) == (at_once.sent, at_once.lost)


def test_schedule_all_refuses_what_it_cannot_decide_at_once():
    correlated = make_link({"loss": {"probability": 0.1, "correlation": 0.5}, "correlation_model": "gaussian_copula"})
    copula = {"delay": {"delay_s": 0.01, "jitter_s": 0.002, "correlation": 0.3}, "correlation_model": "gaussian_copula"}
    jitter = make_link(copula)  # (uncorrelated and netem-correlated draws are: test_*_vectorized.py)
    used = run({"delay": {"delay_s": 0.01}}, 3)
    markov_used = run({"loss": MARKOV["gilbert_elliott"](0.1)}, 3)
    for link in (correlated, jitter, used, markov_used):
        assert not link.vectorized
        with pytest.raises(ValueError, match="cannot decide a run at once"):
            link.schedule_all(np.arange(3, dtype=np.int64))
