"""HLI formulas (core/hli.py) against the Markov chain itself and against core/loss.py's model."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from haptic_teleop.core import hli
from haptic_teleop.core.link import Packet
from haptic_teleop.core.loss import GilbertElliottLoss

# Channels: Gilbert-Elliott, Gilbert, simple Gilbert (bursty and memoryless), negative memory.
CHANNELS = [
    hli.GilbertChannel(0.05, 0.3, 0.9, 0.02),
    hli.GilbertChannel(0.01, 0.25, 0.7, 0.001),
    hli.GilbertChannel(0.125, 0.5, 0.8),
    hli.GilbertChannel(0.0625, 0.25),
    hli.GilbertChannel(0.2, 0.8),
    hli.GilbertChannel(0.7, 0.6, 0.95, 0.1),
]


def chain_by_enumeration(ch: hli.GilbertChannel, slots: list[int]) -> float:
    """Sum over every state path s_0..s_K (K = last slot) of pi(s_0) prod T(s_k, s_k+1) times the
    loss probability of each sent slot's state: the definition, no matrix algebra."""
    pi = (ch.pi_good, ch.pi_bad)
    t = ((1 - ch.p, ch.p), (ch.r, 1 - ch.r))
    loss = (ch.one_minus_k, ch.one_minus_h)
    sent = set(slots)
    total = 0.0
    for path in itertools.product((0, 1), repeat=slots[-1] + 1):
        w = pi[path[0]]
        for a, b in itertools.pairwise(path):
            w *= t[a][b]
        for k in sent:
            w *= loss[path[k]]
        total += w
    return total


def chain_by_products(ch: hli.GilbertChannel, slots: list[int]) -> float:
    """pi L T^(gap) L ... L 1 with numpy matrix powers (forward algorithm over the sent slots)."""
    t, loss = ch.transition(), ch.loss_matrix()
    v = ch.stationary() @ loss
    for a, b in itertools.pairwise(slots):
        v = v @ np.linalg.matrix_power(t, b - a) @ loss
    return float(v.sum())


def reference(ch: hli.GilbertChannel, i: int, j: int, filtering: str, clock: str) -> float:
    slots = hli.sent_slots(i, j, filtering)
    if clock == "packet":
        slots = list(range(len(slots)))  # the chain moves once per sent packet
    return chain_by_enumeration(ch, slots) if slots[-1] <= 9 else chain_by_products(ch, slots)


@pytest.mark.parametrize("ch", CHANNELS, ids=lambda c: f"p{c.p}-r{c.r}-h{c.one_minus_h}-k{c.one_minus_k}")
def test_p_i_matches_the_chain(ch: hli.GilbertChannel) -> None:
    for i in range(10):
        assert hli.p_all_lost(ch, i) == pytest.approx(chain_by_enumeration(ch, list(range(i + 1))), abs=1e-12)
    for i in (15, 30, 60):
        assert hli.p_all_lost(ch, i) == pytest.approx(chain_by_products(ch, list(range(i + 1))), abs=1e-12, rel=1e-9)


@pytest.mark.parametrize("ch", CHANNELS, ids=lambda c: f"p{c.p}-r{c.r}-h{c.one_minus_h}-k{c.one_minus_k}")
@pytest.mark.parametrize("clock", hli.CLOCKS)
@pytest.mark.parametrize("filtering", hli.FILTERINGS)
def test_p_ij_matches_the_chain(ch: hli.GilbertChannel, clock: str, filtering: str) -> None:
    for i in range(0, 10):
        for j in range(hli.max_filtered(i, filtering) + 1):
            got = hli.p_all_lost_filtered(ch, i, j, filtering, clock)
            assert got == pytest.approx(reference(ch, i, j, filtering, clock), abs=1e-12), (i, j)
    for i, j in ((20, 7), (31, 12), (40, 20)):
        got = hli.p_all_lost_filtered(ch, i, j, filtering, clock)
        assert got == pytest.approx(reference(ch, i, j, filtering, clock), abs=1e-12, rel=1e-9), (i, j)


def test_simple_gilbert_closed_forms_by_hand() -> None:
    """The simple-Gilbert formulas of docs/codec_hli.md, typed in from the derivation."""
    p, r = 0.1, 0.3
    ch = hli.GilbertChannel(p, r)
    pb, pg, rho = p / (p + r), r / (p + r), 1 - p - r

    def pbb(d: int) -> float:
        return pb + pg * rho**d

    for i in range(1, 9):
        assert hli.p_all_lost(ch, i) == pytest.approx(pb * (1 - r) ** i, rel=1e-12)
        for j in range(i):
            seq = pb * pbb(j + 1) * (1 - r) ** (i - j - 1)
            assert hli.p_all_lost_filtered(ch, i, j, "sequential", "slot") == pytest.approx(seq, rel=1e-12)
        for j in range(hli.max_filtered(i, "alternate") + 1):
            alt = pb * pbb(2) ** j * (1 - r) ** (i - 2 * j) if 2 * j <= i else pb * pbb(2) ** (j - 1)
            assert hli.p_all_lost_filtered(ch, i, j, "alternate", "slot") == pytest.approx(alt, rel=1e-12)
            assert hli.p_all_lost_filtered(ch, i, j, "alternate", "packet") == pytest.approx(
                pb * (1 - r) ** (i - j), rel=1e-12
            )


def _gilbert_losses(ch: hli.GilbertChannel, calls: int, seed: int) -> np.ndarray:
    """Loss flags of `calls` consecutive apply() calls of core/loss.py's own model."""
    model = GilbertElliottLoss(ch.p, ch.r, ch.one_minus_h, ch.one_minus_k, np.random.default_rng(seed))
    out = np.zeros(calls, dtype=bool)
    for k in range(calls):
        pkt = Packet(seq=k, send_time_ns=k, payload=())
        model.apply(pkt)
        out[k] = pkt.fate != 0
    return out


@pytest.mark.parametrize("filtering", hli.FILTERINGS)
def test_p_ij_against_monte_carlo_of_the_loss_model(filtering: str) -> None:
    """Windows spaced far apart (memory rho^spacing < 1e-6) are independent trials: the estimate is
    binomial; accept within 5 standard deviations. Slot clock: the model is called every tick;
    packet clock: only for the sent packets (plus spacers between windows)."""
    ch = hli.GilbertChannel(0.05, 0.15, 0.95, 0.02)
    i, j = 4, 2
    spacing, trials, burn = 60, 12_000, 200
    slots = hli.sent_slots(i, j, filtering)
    for clock, width, idx in (("slot", i + 1, slots), ("packet", len(slots), list(range(len(slots))))):
        flags = _gilbert_losses(ch, burn + trials * spacing, seed=1234 if clock == "slot" else 99)
        starts = burn + spacing * np.arange(trials)
        assert width <= spacing
        hits = np.ones(trials, dtype=bool)
        for k in idx:
            hits &= flags[starts + k]
        est = hits.mean()
        exact = hli.p_all_lost_filtered(ch, i, j, filtering, clock)
        sigma = math.sqrt(exact * (1 - exact) / trials)
        assert abs(est - exact) < 5 * sigma, (clock, est, exact, sigma)
        other = hli.p_all_lost_filtered(ch, i, j, filtering, "packet" if clock == "slot" else "slot")
        assert abs(other - exact) > 10 * sigma  # the Monte-Carlo tells the two readings apart
    ests = []
    flags = _gilbert_losses(ch, burn + trials * spacing, seed=7)
    for n in range(4):
        starts = burn + spacing * np.arange(trials)
        hits = np.all(np.stack([flags[starts + k] for k in range(n + 1)]), axis=0)
        ests.append(hits.mean())
        exact = hli.p_all_lost(ch, n)
        assert abs(ests[-1] - exact) < 5 * math.sqrt(exact * (1 - exact) / trials), (n, ests[-1], exact)


@pytest.mark.parametrize("ch", CHANNELS, ids=lambda c: f"p{c.p}-r{c.r}")
@pytest.mark.parametrize("alpha", [1e-4, 1e-3, 1e-6])
def test_n_hli1_is_the_smallest_i_below_alpha(ch: hli.GilbertChannel, alpha: float) -> None:
    n = hli.n_hli1(ch, alpha)
    assert chain_by_products(ch, list(range(n + 1))) < alpha
    if n > 0:
        assert chain_by_products(ch, list(range(n))) >= alpha


def test_n_hli1_for_twenty_percent_loss() -> None:
    """Simple Gilbert with mean loss 20 %: memoryless (p + r = 1) gives P_i = 0.2^(i+1), so
    0.2^6 = 6.4e-5 < 1e-4 <= 0.2^5: N = 5; mean burst 2 (r = 0.5, p = 0.125) gives
    P_i = 0.2 * 0.5^i: 0.2 / 2^11 < 1e-4 <= 0.2 / 2^10: N = 11."""
    assert hli.n_hli1(hli.GilbertChannel(0.2, 0.8), 1e-4) == 5
    assert hli.n_hli1(hli.GilbertChannel(0.125, 0.5), 1e-4) == 11


def test_filter_count_is_the_largest_allowed_j() -> None:
    ch = hli.GilbertChannel(0.125, 0.5)
    n = hli.n_hli1(ch)
    for filtering in hli.FILTERINGS:
        for clock in hli.CLOCKS:
            for p_allow in (1e-4, 3e-4, 1e-3, 1e-2):
                j = hli.filter_count(ch, n, p_allow, filtering, clock)
                assert reference(ch, n, j, filtering, clock) <= p_allow
                if j < hli.max_filtered(n, filtering):
                    assert all(
                        reference(ch, n, k, filtering, clock) > p_allow
                        for k in range(j + 1, hli.max_filtered(n, filtering) + 1)
                    )


# --------------------------------------------------------------------------------------------
# Classification on constructed signals

TH = hli.DEFAULT_THRESHOLD_M


def test_constant_velocity_ramp_is_hli0_after_the_first_two() -> None:
    """The two start-up samples are HLI2 (nothing to predict from) and, as any HLI2 event, get
    their N_HLI1 followers; after those the ramp is exactly predicted."""
    x = [(0.3e-3 * k, -0.2e-3 * k, 1e-3) for k in range(200)]
    cls = hli.classify(x, TH, n_followers=5)
    assert cls[:7] == [hli.HLI2, hli.HLI2] + [hli.HLI1] * 5
    assert set(cls[7:]) == {hli.HLI0}
    assert hli.classify(x, TH, n_followers=0)[2:] == [hli.HLI0] * 198


def test_velocity_step_makes_one_hli2_and_n_hli1_followers() -> None:
    n0, v1, v2, n_f = 50, 0.1e-3, 0.6e-3, 5  # |v2 - v1| = 0.5 mm >= 0.4 mm
    x = [(v1 * k,) if k < n0 else (v1 * (n0 - 1) + v2 * (k - n0 + 1),) for k in range(120)]
    cls = hli.classify(x, TH, n_followers=n_f)
    want = [hli.HLI2, hli.HLI2] + [hli.HLI1] * n_f + [hli.HLI0] * (n0 - 2 - n_f) + [hli.HLI2] + [hli.HLI1] * n_f
    want += [hli.HLI0] * (len(x) - len(want))
    assert cls == want
    # a step of 0.3 mm/tick is under the threshold at n0; the receiver's track keeps the old slope
    # (n0 is filtered), so the deviation is 0.6 mm at n0 + 1: the event is one tick later
    y = [(v1 * k,) if k < n0 else (v1 * (n0 - 1) + (v1 + 0.3e-3) * (k - n0 + 1),) for k in range(120)]
    late = hli.classify(y, TH, n_followers=n_f)
    assert [k for k, c in enumerate(late) if c == hli.HLI2] == [0, 1, n0 + 1]


def test_position_step_makes_two_hli2_with_the_linear_predictor() -> None:
    """A jump of 1 mm: x_pred(n0) = 0 (LE 1 mm), then x_pred(n0+1) = 2 mm (LE 1 mm again), then exact."""
    n0, n_f = 30, 4
    x = [(0.0,) if k < n0 else (1e-3,) for k in range(60)]
    cls = hli.classify(x, TH, n_followers=n_f)
    assert cls[n0 : n0 + 2] == [hli.HLI2, hli.HLI2]
    assert cls[n0 + 2 : n0 + 2 + n_f] == [hli.HLI1] * n_f
    assert set(cls[n0 + 2 + n_f :]) == {hli.HLI0}
    # the hold predictor sees one event
    held = hli.classify(x, TH, n_followers=n_f, predictor="hold")
    assert held[n0] == hli.HLI2 and held[n0 + 1 : n0 + 1 + n_f] == [hli.HLI1] * n_f
    assert hli.HLI2 not in held[n0 + 1 :]


def test_loss_effect_is_the_vector_norm() -> None:
    """A 3-D kink of (0.3, 0.3, 0) mm per tick: each axis under 0.4 mm, the norm 0.42 mm over it."""
    n0 = 20
    x = [(0.0, 0.0, 0.0) if k < n0 else (0.3e-3 * (k - n0 + 1), 0.3e-3 * (k - n0 + 1), 0.0) for k in range(40)]
    assert hli.loss_effect(x[n0], hli.predict(x[n0 - 2 : n0])) == pytest.approx(math.hypot(0.3e-3, 0.3e-3))
    assert hli.classify(x, TH, n_followers=2)[n0] == hli.HLI2
    y = [(0.0, 0.0, 0.0) if k < n0 else (0.25e-3 * (k - n0 + 1), 0.25e-3 * (k - n0 + 1), 0.0) for k in range(40)]
    assert hli.classify(y, TH, n_followers=2)[n0] == hli.HLI0


def test_filtered_samples_leave_the_prediction_on_the_track() -> None:
    """A slow parabola: every sample is predictable from the true two before it, but the sender
    mirrors the receiver, whose track drifts from the truth until an HLI2 event resets it."""
    x = [(0.5 * 2e-5 * k * k,) for k in range(200)]  # second difference 0.02 mm per tick
    cls = hli.classify(x, TH, n_followers=0)
    assert hli.HLI2 in cls[2:]


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: hli.GilbertChannel(1.5, 0.2), "p must be in"),
        (lambda: hli.GilbertChannel(0.1, 0.2, one_minus_h=-0.1), "one_minus_h must be in"),
        (lambda: hli.GilbertChannel(0.0, 0.0), "p \\+ r > 0"),
        (lambda: hli.n_hli1(hli.GilbertChannel(0.1, 0.2), 0.0), "alpha must be in"),
        (lambda: hli.n_hli1(hli.GilbertChannel(0.5, 0.0), 1e-4, max_n=50), "no N_HLI1 <= 50"),
        (
            lambda: hli.p_all_lost_filtered(hli.GilbertChannel(0.1, 0.2), 4, 3, "alternate"),
            "j .* must be in \\[0, 2\\]",
        ),
        (lambda: hli.p_all_lost_filtered(hli.GilbertChannel(0.1, 0.2), 4, 1, "sequential", "tick"), "clock must be"),
        (lambda: hli.max_filtered(3, "random"), "filtering must be one of"),
        (lambda: hli.predict([(0.0,)], "cubic"), "predictor must be one of"),
        (lambda: hli.classify([(0.0,)], 0.0), "threshold must be > 0"),
    ],
)
def test_bad_arguments_raise_a_clear_value_error(call: object, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()  # type: ignore[operator]
