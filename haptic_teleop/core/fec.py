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

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from haptic_teleop.core.link import Packet
from haptic_teleop.core.prediction import (
    GAP_MODES,
    Reconstructor,
    Sample,
    SizeOf,
    check_fields,
    float64_multiarray_size,
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
    compiled loop's parity sums, engine/compiled/codec_kernel.py; the Python classes call `math.fsum`).
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


class FecEncoder:
    """One packet per sample with the redundancy of its scheme (module docstring)."""

    def __init__(self, scheme: str, k: int, size_of: SizeOf = float64_multiarray_size) -> None:
        if scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        self.scheme, self.k = scheme, k
        self._size_of = size_of
        self._recent: deque[Sample] = deque(maxlen=k)  # x(n-k) .. x(n-1), newest last
        self._dim: int | None = None
        self.counters: dict[str, int] = {"samples": 0, "sent": 0, "bytes": 0}

    def send(self, n: int, now_ns: int, sample: Sample) -> list[Packet]:
        x = tuple(float(v) for v in sample)
        if self._dim is None:
            self._dim = len(x)
        elif len(x) != self._dim:
            raise ValueError(f"sample has {len(x)} values, the stream started with {self._dim}")
        recent = self._recent
        if self.scheme == "repetition":
            older = list(reversed(recent))  # x(n-1), x(n-2), ...
            older += [older[-1] if older else x] * (self.k - len(older))
            payload = x + tuple(v for s in older for v in s)
        else:
            sums = tuple(math.fsum(s[i] for s in recent) for i in range(len(x)))
            payload = x + sums
        recent.append(x)
        size = self._size_of(len(payload))
        c = self.counters
        c["samples"] += 1
        c["sent"] += 1
        c["bytes"] += size
        return [Packet(n, now_ns, payload, size)]

    def feedback(self, packet: Packet, now_ns: int) -> None:
        """No return path."""


class FecDecoder:
    """Recovers what the received packets allow, predicts the rest (module docstring).

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
        self._sums: dict[int, Sample] = {}  # parity: seq of a received packet -> its S
        self.recovered_log: list[Packet] = []
        self.counters: dict[str, int] = {"received": 0, "duplicates": 0, "recovered": 0, "recovered_late": 0}

    def receive(self, packet: Packet, now_ns: int) -> list[Packet]:
        c = self.counters
        c["received"] += 1
        p = packet.payload
        groups = 1 + self.k if self.scheme == "repetition" else 2
        if len(p) % groups or not p:
            raise ValueError(f"fec {self.scheme} k={self.k}: a payload of {len(p)} floats is not {groups} equal groups")
        d = len(p) // groups
        n = packet.seq
        if not self._add(n, tuple(p[:d]), packet, fresh=True):
            # Held already: a duplicate, or an original its recovery beat (jitter). Its redundancy
            # may still be news (parity: its sum completes windows), so it is used all the same.
            c["duplicates"] += 1
            if n in self._sums:
                return []
        if self.scheme == "repetition":
            for j in range(1, self.k + 1):
                m = n - j
                if m >= 0:
                    self._add(m, tuple(p[j * d : (j + 1) * d]), packet, fresh=False)
        else:
            self._sums[n] = tuple(p[d:])
            self._parity_recover(packet)
        return []

    def _add(self, seq: int, value: Sample, carrier: Packet, fresh: bool) -> bool:
        late_before = self.rec.late
        if not self.rec.add(seq, value, fresh):
            return False
        if not fresh:
            c = self.counters
            c["recovered"] += 1
            if self.rec.late > late_before:
                c["recovered_late"] += 1
            self.recovered_log.append(Packet(seq, carrier.send_time_ns, value, 0))
        return True

    def _parity_recover(self, carrier: Packet) -> None:
        """Solve every window with exactly one unknown that the carrier's arrival may have
        completed: the carrier's own, those covering its sample, and, for each sample recovered,
        those covering it (a worklist: cost O(k) per window looked at, not per sum held)."""
        rec, k, sums = self.rec, self.k, self._sums
        newest = rec.newest_seq
        assert newest is not None
        oldest = newest - rec.keep_ticks
        while sums:  # sums arrive nearly in seq order: drop from the front what reaches past the history
            first = next(iter(sums))
            if first - k >= oldest:
                break
            del sums[first]
        n = carrier.seq
        work = [n, *(p for p in range(n + 1, n + k + 1) if p in sums)]
        while work:
            p = work.pop()
            total = sums.get(p)
            if total is None:
                continue
            window = range(max(0, p - k), p)
            missing = [m for m in window if not rec.has(m)]
            if len(missing) != 1 or missing[0] < oldest:
                continue
            m = missing[0]
            others = [o for j in window if j != m and (o := rec.get(j)) is not None]
            value = tuple(math.fsum([total[i], *(-o[i] for o in others)]) for i in range(len(total)))
            if self._add(m, value, carrier, fresh=False):
                work.extend(q for q in range(m + 1, m + k + 1) if q in sums)

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
