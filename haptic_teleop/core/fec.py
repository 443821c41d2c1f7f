"""Forward error correction of recent samples in each packet: a baseline of seed 000.

Every tick the sender sends one packet with the sample and redundancy about the k samples before
it; the receiver recovers lost samples from the packets that do arrive and predicts the rest
(`core.prediction.Reconstructor`). Two schemes (d = floats per sample):

- `repetition`: payload = x(n), x(n-1), ..., x(n-k) ((1+k) d floats). A loss burst of length
  L <= k is recovered exactly from the first packet after it; of a longer burst only the last k
  samples are.
- `parity`: payload = x(n), S(n) with S(n) = sum of x(n-k) .. x(n-1) per component (2 d floats,
  whatever k). A sample x(m) is recovered as S(p) - (the other k-1 samples of p's window) from
  any received packet p in m+1 .. m+k whose window holds no other missing sample; recoveries
  chain (a recovered sample completes another window). Thus an isolated loss comes back with
  the next packet, and a burst of L <= k comes back (last sample first) once the k packets after
  it have arrived; of a longer burst only the last k samples are recovered. Exact up to the
  rounding of the float sums (each recovery is one correctly rounded `math.fsum`; values that
  add exactly, such as small dyadic fractions, come back bit for bit); a chain of recoveries
  can add one rounding per step.

Before tick k (the start of the stream) the missing older samples are taken as copies of x(0)
(repetition) or left out of the sum (parity: the window is clipped at 0), so the layout and the
packet size stay fixed. Packet size = `size_of(floats)`: the payload grows with k for repetition
and the wire accounting sees it. Receiver latency: none unless `wait_ticks` > 0: with 0 the
receiver plays the newest sample and a recovery that comes after its slot is kept only for the
record (`recovered_log`, counter `recovered_late`) and as the extrapolation base; with
`wait_ticks` = w every sample is played w ticks after it would otherwise be, so recoveries that
come within w ticks are played (w = k makes repetition lossless for bursts <= k; parity needs up
to 2k - 1). docs/codec_baselines.md has the layouts, sizes and costs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from haptic_teleop.core import codec_layout as L
from haptic_teleop.core.link import Packet
from haptic_teleop.core.prediction import (
    GAP_MODES,
    Reconstructor,
    Sample,
    SizeOf,
    check_fields,
    float64_multiarray_size,
    rec_held,
    rec_take,
    ticks,
)

KIND = "fec"
SCHEMES = ("repetition", "parity")


@dataclass(frozen=True)
class FecConfig:
    """Codec `fec`: redundancy about the last k samples in every packet."""

    scheme: str = field(
        default="repetition",
        metadata={"choices": SCHEMES, "help": "repetition: k previous samples; parity: their sum"},
    )
    k: int = field(default=2, metadata={"min": 1, "max": 64, "help": "how many previous samples each packet covers"})
    wait_ticks: int = field(
        default=0,
        metadata={"min": 0, "max": 1000, "help": "play this many ticks late so recoveries are in time (0: newest)"},
    )
    gap: str = field(
        default="extrapolate",
        metadata={"choices": GAP_MODES, "help": "unrecovered tick: extrapolate the last two samples or hold"},
    )
    max_extrapolation_s: float = field(
        default=0.05, metadata={"min": 0.0, "max": 10.0, "help": "extrapolate at most this far, then hold"}
    )

    def __post_init__(self) -> None:
        check_fields(self)


def payload_floats(scheme: str, k: int, dim: int) -> int:
    """Floats in one packet's payload for a sample of `dim` floats."""
    if scheme == "repetition":
        return (1 + k) * dim
    if scheme == "parity":
        return 2 * dim
    raise ValueError(f"scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")


def rounded_sum(xs: Any, start: int, count: int, partials: Any) -> float:
    """The sum of the finite floats xs[start:start + count] rounded once, the value `math.fsum` gives (the
    parity sums of `fec_payload` and `fec_receive`).
    Shewchuk's exact partials (non-overlapping, kept in `partials` from index 0, room for `count`; it may be
    `xs` itself when the two regions do not meet), then
    the top partials added with the half-way case rounded as one rounding would."""
    m = 0
    for t in range(start, start + count):
        x = xs[t]
        i = 0
        for j in range(m):
            y = partials[j]
            if abs(x) < abs(y):
                x, y = y, x
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                partials[i] = lo
                i += 1
            x = hi
        m = i
        if x != 0.0:
            partials[m] = x
            m += 1
    if m == 0:
        return 0.0
    m -= 1
    hi = partials[m]
    lo = 0.0
    while m > 0:
        x = hi
        m -= 1
        y = partials[m]
        hi = x + y
        lo = y - (hi - x)
        if lo != 0.0:
            break
    if m > 0 and ((lo < 0.0 and partials[m - 1] < 0.0) or (lo > 0.0 and partials[m - 1] > 0.0)):
        y = lo * 2.0
        x = hi + y
        if y == x - hi:
            hi = x
    return float(hi)


# The FEC steps as functions over codec_layout arrays: the one definition `FecEncoder` and
# `FecDecoder` call and the compiled loops inline (engine/compiled/codec_fec.py). C: C_DIM, C_K,
# C_PARITY, C_WPAY, C_WLOG and the reconstruction's (core/prediction.py); S: the sender's S_FHAS,
# S_FFIRST, S_FLAST and the reconstruction's; X: a row per seq modulo its (power-of-two) length:
# the decoder's held sample (X_HELD, X_VALUE), a parity sum received (its seq at `xsum`, its
# values after it), the sender's sample of that tick (from `xsent`); W: scratch (partial sums
# from 0, a recovered value at W_VALUE, a sum's terms from `wterms`, the recovery worklist at
# W_STACK), the packet's payload from C_WPAY, the samples a packet recovered from C_WLOG (their
# count, then their seqs). The places that differ between layouts are passed.


def fec_sent(C: Any, S: Any, X: Any, n: int, smp: Any, xsent: int) -> None:
    """The sender's sample of tick `n` into its row of X. The first seq starts the stream; ticks
    a sender skipped since its last one (a live sender's overrun) hold that last sample (at most
    k of them: a payload reaches k back)."""
    mask = X.shape[0] - 1
    dim = int(C[L.C_DIM])
    if S[L.S_FHAS] == 0.0:
        S[L.S_FHAS] = 1.0
        S[L.S_FFIRST] = n
        S[L.S_FLAST] = n
    elif n > S[L.S_FLAST]:
        last = int(S[L.S_FLAST])
        jl = last & mask
        for m in range(max(last + 1, n - int(C[L.C_K])), n):
            jm = m & mask
            for i in range(dim):
                X[jm, xsent + i] = X[jl, xsent + i]
        S[L.S_FLAST] = n
    j = n & mask
    for i in range(dim):
        X[j, xsent + i] = smp[i]


def fec_payload(C: Any, S: Any, X: Any, W: Any, n: int, xsent: int, wterms: int) -> int:
    """Packet n's payload into W from C_WPAY (returns its length), from the sender's rows of X:
    x(n), then x(n-1) .. x(n-k) (repetition; before the stream's first seq, its first sample) or
    the sums of x(n-k) .. x(n-1) per value (parity: each rounded once, as `math.fsum`; the window
    clipped at the first seq)."""
    mask = X.shape[0] - 1
    dim, k, at = int(C[L.C_DIM]), int(C[L.C_K]), int(C[L.C_WPAY])
    first = int(S[L.S_FFIRST])
    j = n & mask
    for i in range(dim):
        W[at + i] = X[j, xsent + i]
    if C[L.C_PARITY] == 0.0:
        for q in range(1, k + 1):
            jm = max(first, n - q) & mask
            for i in range(dim):
                W[at + q * dim + i] = X[jm, xsent + i]
        return (1 + k) * dim
    for i in range(dim):
        c = 0
        for q in range(max(first, n - k), n):
            W[wterms + c] = X[q & mask, xsent + i]
            c += 1
        W[at + dim + i] = rounded_sum(W, wterms, c, W)
    return 2 * dim


def fec_add(C: Any, S: Any, X: Any, W: Any, seq: int, at: int, fresh: bool) -> bool:
    """The reconstruction's `rec_take` of `seq` with its values from W[at:]; a recovery (not
    `fresh`) is logged from C_WLOG."""
    if not rec_take(C, S, X, seq, fresh):
        return False
    j = seq & (X.shape[0] - 1)
    for i in range(int(C[L.C_DIM])):
        X[j, L.X_VALUE + i] = W[at + i]
    if not fresh:
        log = int(C[L.C_WLOG])
        c = int(W[log])
        W[log + 1 + c] = seq
        W[log] = c + 1
    return True


def sum_held(C: Any, S: Any, X: Any, p: int, xsum: int) -> bool:
    """Whether packet p's parity sum is held (and still of use: its window within the history)."""
    if p < S[L.S_MAXHELD] - C[L.C_KEEP] + C[L.C_K]:
        return False
    return X[p & (X.shape[0] - 1), xsum] == p  # type: ignore[no-any-return]


def fec_receive(C: Any, S: Any, X: Any, W: Any, n: int, xsum: int, wterms: int) -> None:
    """Packet n with its payload in W from C_WPAY (`fec_payload`'s layout): its sample is
    held; then repetition adds x(n-1) .. x(n-k), parity keeps its sum and solves every window with
    exactly one unknown that the packet may have completed (its own, those covering its sample,
    and, for each sample recovered, those covering it: a LIFO worklist, cost O(k) per window
    looked at). A packet whose sample was held already (a copy, or an original its recovery beat)
    is a duplicate; its redundancy is still used unless its sum is held too."""
    mask = X.shape[0] - 1
    dim, k, at = int(C[L.C_DIM]), int(C[L.C_K]), int(C[L.C_WPAY])
    W[int(C[L.C_WLOG])] = 0.0
    S[L.S_RECEIVED] += 1.0
    if not fec_add(C, S, X, W, n, at, True):
        S[L.S_DUPLICATES] += 1.0
        if C[L.C_PARITY] != 0.0 and sum_held(C, S, X, n, xsum):
            return
    if C[L.C_PARITY] == 0.0:
        for q in range(1, k + 1):
            if n - q >= 0:
                fec_add(C, S, X, W, n - q, at + q * dim, False)
        return
    if n >= S[L.S_MAXHELD] - C[L.C_KEEP] + C[L.C_K]:  # (a sum reaching past the history is of no use)
        jn = n & mask
        X[jn, xsum] = n
        for i in range(dim):
            X[jn, xsum + 1 + i] = W[at + dim + i]
    oldest = int(S[L.S_MAXHELD]) - int(C[L.C_KEEP])
    W[L.W_STACK] = n
    top = 1
    for q in range(n + 1, n + k + 1):
        if sum_held(C, S, X, q, xsum):
            W[L.W_STACK + top] = q
            top += 1
    while top > 0:
        top -= 1
        p = int(W[L.W_STACK + top])
        if not sum_held(C, S, X, p, xsum):
            continue
        missing = 0
        m = -1
        for q in range(max(0, p - k), p):
            if not rec_held(C, S, X, q):
                missing += 1
                m = q
                if missing > 1:
                    break
        if missing != 1 or m < oldest:
            continue
        jp = p & mask
        for i in range(dim):  # x(m) = S(p) - the window's other samples, rounded once
            W[wterms] = X[jp, xsum + 1 + i]
            c = 1
            for q in range(max(0, p - k), p):
                if q != m:
                    W[wterms + c] = -X[q & mask, L.X_VALUE + i]
                    c += 1
            W[L.W_VALUE + i] = rounded_sum(W, wterms, c, W)
        if fec_add(C, S, X, W, m, L.W_VALUE, False):
            for q in range(m + 1, m + k + 1):
                if sum_held(C, S, X, q, xsum):
                    W[L.W_STACK + top] = q
                    top += 1


def fec_scratch(k: int, keep: int, dim: int, wterms: int) -> tuple[int, int, int]:
    """A decoder's W: where the payload (C_WPAY) and the recovery log (C_WLOG) start and its length
    (the worklist at W_STACK holds the packet, k sums after it and k for each recovery)."""
    if wterms + k + 1 > L.W_STACK:
        raise ValueError(f"fec: a sample of {dim} values with k={k} does not fit the scratch's layout")
    wpay = L.W_STACK + 1 + k + k * (keep + 1)
    wlog = wpay + (1 + k) * dim
    return wpay, wlog, wlog + 1 + keep + k + 1


class FecEncoder:
    """One packet per sample with the redundancy of its scheme (module docstring): `fec_sent` and
    `fec_payload` over its own arrays (the sender's samples from column 0 of X)."""

    def __init__(self, scheme: str, k: int, size_of: SizeOf = float64_multiarray_size) -> None:
        if scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        self.scheme, self.k = scheme, k
        self._size_of = size_of
        self._dim: int | None = None
        C = [0.0] * L.C_SIZE_X
        C[L.C_K], C[L.C_PARITY] = k, 1.0 if scheme == "parity" else 0.0
        # W: partial sums from 0 (k at most), a sum's terms from k, the payload from 2 k
        C[L.C_WPAY] = 2 * k
        self.C: Any = C
        self.S: Any = [0.0] * L.S_SIZE_X
        self.X: Any = None
        self.W: Any = None
        self.counters: dict[str, int] = {"samples": 0, "sent": 0, "bytes": 0}

    def send(self, n: int, now_ns: int, sample: Sample) -> list[Packet]:
        x = tuple(float(v) for v in sample)
        if self._dim is None:
            import numpy as np

            self._dim = len(x)
            self.C[L.C_DIM] = len(x)
            rows = 4
            while rows < self.k + 2:
                rows *= 2
            self.X = np.zeros((rows, len(x)))
            self.W = [0.0] * (2 * self.k + (1 + self.k) * len(x))
        elif len(x) != self._dim:
            raise ValueError(f"sample has {len(x)} values, the stream started with {self._dim}")
        fec_sent(self.C, self.S, self.X, n, x, 0)
        at = 2 * self.k
        payload = tuple(self.W[at : at + fec_payload(self.C, self.S, self.X, self.W, n, 0, self.k)])
        size = self._size_of(len(payload))
        c = self.counters
        c["samples"] += 1
        c["sent"] += 1
        c["bytes"] += size
        return [Packet(n, now_ns, payload, size)]

    def feedback(self, packet: Packet, now_ns: int) -> None:
        """No return path."""


# The decoder's counters and where its reconstruction's S keeps them.
DECODER_COUNTERS = {
    "received": L.S_RECEIVED,
    "duplicates": L.S_DUPLICATES,
    "recovered": L.S_RECOVERED,
    "recovered_late": L.S_RECOVERED_LATE,
}


class FecDecoder:
    """Recovers what the received packets allow, predicts the rest (module docstring):
    `fec_receive` over its reconstruction's arrays (`rec`'s C, S and X, whose rows hold a parity
    sum after the sample) and its scratch.

    Counters: `received` packets, `duplicates` (the sample was held already: a copy, or an original
    its recovery beat; its redundancy is still used), `recovered` samples first obtained from
    redundancy, of them `recovered_late` (after their slot was played). `recovered_log` holds a
    Packet per recovered sample (seq, the carrier's send time, the sample) for the record; its
    reader may drain it.
    """

    def __init__(
        self,
        scheme: str,
        k: int,
        *,
        wait_ticks: int = 0,
        gap: str = "extrapolate",
        max_extrapolation_ticks: int = 50,
    ) -> None:
        if scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        self.scheme, self.k = scheme, k
        self.rec = Reconstructor(gap, max_extrapolation_ticks, wait_ticks)
        C = self.rec.C
        C[L.C_K], C[L.C_PARITY] = k, 1.0 if scheme == "parity" else 0.0
        self._dim: int | None = None
        self.W: Any = None
        self.recovered_log: list[Packet] = []

    @property
    def counters(self) -> dict[str, int]:
        return self.rec.counts(DECODER_COUNTERS)

    def load(self, S: Any) -> None:
        """Take the scalar state of a decoder run elsewhere (a compiled loop's S)."""
        self.rec.load(S)

    def receive(self, packet: Packet, now_ns: int) -> list[Packet]:
        p = packet.payload
        groups = 1 + self.k if self.scheme == "repetition" else 2
        if len(p) % groups or not p:
            raise ValueError(f"fec {self.scheme} k={self.k}: a payload of {len(p)} floats is not {groups} equal groups")
        d = len(p) // groups
        rec, C = self.rec, self.rec.C
        if self._dim is None:
            self._dim = d
            rec.history(d, 1 + d)  # the sample, then a parity sum's seq and values
            C[L.C_WPAY], C[L.C_WLOG], size = fec_scratch(self.k, rec.keep_ticks, d, L.W_VALUE + d)
            self.W = [0.0] * size
        elif d != self._dim:
            raise ValueError(f"fec: a packet of {d}-value samples, the stream carries {self._dim}")
        W, at = self.W, int(C[L.C_WPAY])
        W[at : at + len(p)] = p
        fec_receive(C, rec.S, rec.X, W, packet.seq, L.X_VALUE + d, L.W_VALUE + d)
        log = int(C[L.C_WLOG])
        for i in range(int(W[log])):
            seq = int(W[log + 1 + i])
            value = rec.get(seq)
            assert value is not None
            self.recovered_log.append(Packet(seq, packet.send_time_ns, value, 0))
        return []

    def sample(self, n: int, now_ns: int) -> Sample | None:
        return self.rec.sample(n)


def build_fec(
    cfg: FecConfig, period_ns: int, *, size_of: SizeOf = float64_multiarray_size
) -> tuple[FecEncoder, FecDecoder]:
    """Encoder and decoder of codec `fec` for a stream with one sample every `period_ns`."""
    dec = FecDecoder(
        cfg.scheme,
        cfg.k,
        wait_ticks=cfg.wait_ticks,
        gap=cfg.gap,
        max_extrapolation_ticks=ticks(cfg.max_extrapolation_s, period_ns),
    )
    return FecEncoder(cfg.scheme, cfg.k, size_of), dec
