"""Haptic event prioritisation of seed 000 (HLI, "haptic event loss index"): the formulas.

A predictor guesses each sample from the two before it; the loss effect LE(n) = |x(n) - x_pred(n)|
(vector norm) says what losing sample n would cost. Classes: HLI0 (LE < TH_HLI, predictable),
HLI2 (LE >= TH_HLI, critical) and HLI1 (the up to N_HLI1 redundant events after an HLI2 event).
N_HLI1 is the smallest i with P_i < alpha, P_i the probability that an HLI2 event and the i HLI1
events after it are all lost on a Gilbert(-Elliott) channel. P_i,j is the same probability when
j of the HLI1 events are filtered (not sent), sequentially (the first j) or alternately (every
other one, starting with the first).

The channel is `core/loss.py`'s GilbertElliottLoss: p = P(good -> bad), r = P(bad -> good) per
step, loss probability 1-h in bad and 1-k in good, the loss drawn in the state a packet meets and
the chain moved after it. Two readings of "a step" give different P_i,j (P_i is the same in both):
`slot` (the chain moves every tick, sent or not: the project's default, since a network's burst
state evolves in time) and `packet` (it moves once per sent packet). The closed forms below are
written with 2x2 matrix powers evaluated by Cayley-Hamilton (two eigenvalue terms), no repeated
products; their derivation is in docs/codec_hli.md, and the tests check them against the chain
itself.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

CLOCKS = ("slot", "packet")
FILTERINGS = ("sequential", "alternate")
PREDICTORS = ("linear", "hold")
HLI0, HLI1, HLI2 = 0, 1, 2
DEFAULT_THRESHOLD_M = 0.4e-3  # TH_HLI, seed 000: 0.01 to 0.4 mm deviations go unnoticed
DEFAULT_ALPHA = 1e-4

_Mat = tuple[float, float, float, float]  # row-major 2x2 (a, b, c, d) = [[a, b], [c, d]]
_Vec = tuple[float, float]


@dataclass(frozen=True)
class GilbertChannel:
    """Gilbert-Elliott loss parameters, as core/loss.py and the scene's `loss` section name them."""

    p: float
    r: float
    one_minus_h: float = 1.0  # loss probability in the bad state
    one_minus_k: float = 0.0  # loss probability in the good state

    def __post_init__(self) -> None:
        for key in ("p", "r", "one_minus_h", "one_minus_k"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0.0 <= v <= 1.0):
                raise ValueError(f"Gilbert channel {key} must be in [0, 1], got {v!r}")
        if self.p + self.r <= 0.0:
            raise ValueError("Gilbert channel needs p + r > 0 (with p = r = 0 the chain has no stationary state)")

    @property
    def pi_bad(self) -> float:
        """Stationary probability of the bad state, p / (p + r)."""
        return self.p / (self.p + self.r)

    @property
    def pi_good(self) -> float:
        return self.r / (self.p + self.r)

    @property
    def rho(self) -> float:
        """1 - p - r: the chain's second eigenvalue (memory per step)."""
        return 1.0 - self.p - self.r

    @property
    def mean_loss(self) -> float:
        return self.pi_good * self.one_minus_k + self.pi_bad * self.one_minus_h

    def transition(self) -> np.ndarray:
        """T (rows: from good, from bad)."""
        return np.array([[1.0 - self.p, self.p], [self.r, 1.0 - self.r]])

    def loss_matrix(self) -> np.ndarray:
        """L = diag(1-k, 1-h)."""
        return np.diag([self.one_minus_k, self.one_minus_h])

    def stationary(self) -> np.ndarray:
        return np.array([self.pi_good, self.pi_bad])


# --------------------------------------------------------------------------------------------
# 2x2 algebra on tuples (closed forms)


def _mul(a: _Mat, b: _Mat) -> _Mat:
    return (
        a[0] * b[0] + a[1] * b[2],
        a[0] * b[1] + a[1] * b[3],
        a[2] * b[0] + a[3] * b[2],
        a[2] * b[1] + a[3] * b[3],
    )


def _vm(v: _Vec, m: _Mat) -> _Vec:
    return (v[0] * m[0] + v[1] * m[2], v[0] * m[1] + v[1] * m[3])


def _pow(m: _Mat, k: int) -> _Mat:
    """M^k = c1 M + c0 I (Cayley-Hamilton), c1 = (l1^k - l2^k)/(l1 - l2), c0 = (l1 l2^k - l2 l1^k)/(l1 - l2)
    with l1, l2 the eigenvalues; for a double eigenvalue l: c1 = k l^(k-1), c0 = (1 - k) l^k."""
    if k < 0:
        raise ValueError(f"matrix power needs k >= 0, got {k}")
    if k == 0:
        return (1.0, 0.0, 0.0, 1.0)
    tr = m[0] + m[3]
    det = m[0] * m[3] - m[1] * m[2]
    disc = tr * tr - 4.0 * det
    disc = max(disc, 0.0)  # the eigenvalues here are real; rounding may make disc slightly negative
    s = math.sqrt(disc)
    l1, l2 = 0.5 * (tr + s), 0.5 * (tr - s)
    if s <= 1e-9 * max(1.0, abs(tr)):
        lam = 0.5 * tr
        c1 = k * lam ** (k - 1)
        c0 = (1 - k) * lam**k
    else:
        c1 = (l1**k - l2**k) / s
        c0 = (l1 * l2**k - l2 * l1**k) / s
    return (c1 * m[0] + c0, c1 * m[1], c1 * m[2], c1 * m[3] + c0)


def _parts(ch: GilbertChannel) -> tuple[_Vec, _Mat, _Mat]:
    """(pi L, T, L) of the channel."""
    g, b = ch.one_minus_k, ch.one_minus_h
    t: _Mat = (1.0 - ch.p, ch.p, ch.r, 1.0 - ch.r)
    loss: _Mat = (g, 0.0, 0.0, b)
    return (ch.pi_good * g, ch.pi_bad * b), t, loss


def _t_pow(ch: GilbertChannel, d: int) -> _Mat:
    """T^d = 1 pi + rho^d (I - 1 pi): the d-step transition."""
    pg, pb, rd = ch.pi_good, ch.pi_bad, ch.rho**d
    return (pg + rd * pb, pb - rd * pb, pg - rd * pg, pb + rd * pg)


# --------------------------------------------------------------------------------------------
# P_i, P_i,j, N_HLI1


def sent_slots(i: int, j: int, filtering: str) -> list[int]:
    """Slots (0 = the HLI2 event, 1..i its HLI1 events) sent when j HLI1 events are filtered."""
    _check_ij(i, j, filtering)
    if filtering == "sequential":
        filtered = set(range(1, j + 1))
    else:
        filtered = set(range(1, 2 * j, 2))
    return [0, *(k for k in range(1, i + 1) if k not in filtered)]


def max_filtered(i: int, filtering: str) -> int:
    """The most HLI1 events a filtering can drop out of i: i (sequential), ceil(i/2) (alternate)."""
    if filtering not in FILTERINGS:
        raise ValueError(f"filtering must be one of {', '.join(FILTERINGS)}, got {filtering!r}")
    return i if filtering == "sequential" else (i + 1) // 2


def _check_ij(i: int, j: int, filtering: str) -> None:
    if i < 0:
        raise ValueError(f"i (HLI1 events) must be >= 0, got {i}")
    jmax = max_filtered(i, filtering)
    if not 0 <= j <= jmax:
        raise ValueError(f"j (filtered HLI1 events) must be in [0, {jmax}] for {filtering} filtering of {i}, got {j}")


def p_all_lost(ch: GilbertChannel, i: int) -> float:
    """P_i = pi L (T L)^i 1: an HLI2 event and the i HLI1 events after it all lost (either clock)."""
    pil, t, loss = _parts(ch)
    v = _vm(pil, _pow(_mul(t, loss), i))
    return v[0] + v[1]


def p_all_lost_filtered(ch: GilbertChannel, i: int, j: int, filtering: str, clock: str = "slot") -> float:
    """P_i,j: the HLI2 event and its i - j sent HLI1 events all lost, j of the i filtered.

    clock "packet": the chain moves per sent packet, so only the count matters: P_i,j = P_(i-j).
    clock "slot": it moves every tick; with M = T L and N = T^2 L,
      sequential, j < i: P_i,j = pi L T^(j+1) L M^(i-j-1) 1   (j = i: P_0)
      alternate, 2j <= i: P_i,j = pi L N^j M^(i-2j) 1         (2j = i + 1: pi L N^(j-1) 1)
    """
    _check_ij(i, j, filtering)
    if clock not in CLOCKS:
        raise ValueError(f"clock must be one of {', '.join(CLOCKS)}, got {clock!r}")
    if clock == "packet":
        return p_all_lost(ch, i - j)
    pil, t, loss = _parts(ch)
    m = _mul(t, loss)
    if filtering == "sequential":
        if j == i:
            return pil[0] + pil[1]
        v = _vm(_vm(_vm(pil, _t_pow(ch, j + 1)), loss), _pow(m, i - j - 1))
    else:
        n2 = _mul(_t_pow(ch, 2), loss)
        if 2 * j == i + 1:
            v = _vm(pil, _pow(n2, j - 1))
        else:
            v = _vm(_vm(pil, _pow(n2, j)), _pow(m, i - 2 * j))
    return v[0] + v[1]


def n_hli1(ch: GilbertChannel, alpha: float = DEFAULT_ALPHA, max_n: int = 10_000) -> int:
    """N_HLI1: the smallest i with P_i < alpha."""
    if not (math.isfinite(alpha) and 0.0 < alpha < 1.0):
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    for i in range(max_n + 1):
        if p_all_lost(ch, i) < alpha:
            return i
    raise ValueError(
        f"no N_HLI1 <= {max_n} gives P_i < alpha = {alpha} on this channel (p={ch.p}, r={ch.r}, "
        f"1-h={ch.one_minus_h}, 1-k={ch.one_minus_k}): losses this persistent cannot be covered by redundancy"
    )


def filter_count(ch: GilbertChannel, i: int, p_allowable: float, filtering: str, clock: str = "slot") -> int:
    """The largest j with P_i,j <= p_allowable (0 if even P_i is above it)."""
    best = 0
    for j in range(max_filtered(i, filtering) + 1):
        if p_all_lost_filtered(ch, i, j, filtering, clock) <= p_allowable:
            best = j
    return best


# --------------------------------------------------------------------------------------------
# Prediction and classification


def predict(history: Sequence[Sequence[float] | np.ndarray], predictor: str = "linear") -> np.ndarray | None:
    """x_pred(n) from the samples before n (oldest first): linear x(n-1) + (x(n-1) - x(n-2)), hold
    x(n-1); with one sample both hold; with none, None."""
    if predictor not in PREDICTORS:
        raise ValueError(f"predictor must be one of {', '.join(PREDICTORS)}, got {predictor!r}")
    if not history:
        return None
    last = np.asarray(history[-1], dtype=float)
    if predictor == "hold" or len(history) < 2:
        return last
    out: np.ndarray = 2.0 * last - np.asarray(history[-2], dtype=float)
    return out


def loss_effect(sample: Sequence[float] | np.ndarray, predicted: Sequence[float] | np.ndarray | None) -> float:
    """LE(n) = |x(n) - x_pred(n)| (Euclidean norm); infinite when nothing can be predicted."""
    if predicted is None:
        return math.inf
    return float(np.linalg.norm(np.asarray(sample, dtype=float) - np.asarray(predicted, dtype=float)))


def classify(
    samples: Sequence[Sequence[float]] | np.ndarray,
    threshold: float = DEFAULT_THRESHOLD_M,
    n_followers: int = 1,
    predictor: str = "linear",
) -> list[int]:
    """HLI class of every sample of a stream, all sent as classified (no bandwidth filtering).

    The predictor runs on the receiver's track as the sender mirrors it: a sent sample (HLI1 or
    HLI2) puts itself and the true sample before it (carried in its packet) on the track, a
    filtered one (HLI0) leaves the prediction there. The first
    samples (two for linear, one for hold) are HLI2: the receiver has nothing to predict from.
    """
    if not threshold > 0.0:
        raise ValueError(f"threshold must be > 0, got {threshold}")
    if n_followers < 0:
        raise ValueError(f"n_followers (N_HLI1) must be >= 0, got {n_followers}")
    warmup = 2 if predictor == "linear" else 1
    track: list[np.ndarray] = []
    out: list[int] = []
    prev: np.ndarray | None = None
    since_hli2 = n_followers + 1
    for k, s in enumerate(samples):
        x = np.asarray(s, dtype=float)
        pred = predict(track[-2:], predictor)
        le = loss_effect(x, pred)
        since_hli2 += 1
        if k < warmup or le >= threshold:
            cls = HLI2
            since_hli2 = 0
        elif since_hli2 <= n_followers:
            cls = HLI1
        else:
            cls = HLI0
        out.append(cls)
        if cls == HLI0 and pred is not None:
            track = [track[-1], pred]
        else:  # a sent sample carries the one before it: the track takes the true slope
            track = [x if prev is None else prev, x]
        prev = x
    return out
