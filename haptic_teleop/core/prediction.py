"""The "prediction only" codec baseline of seed 000, and the receiver-side reconstruction that the
FEC and ARQ baselines (core/fec.py, core/arq.py) share.

Sender: every sample it is given goes out in one packet (payload = the sample, nothing else).
Receiver: plays the newest sample; over ticks that bring nothing new it predicts by linear
extrapolation from the last two samples it holds (`gap: extrapolate`, the default) or holds the
last one (`gap: hold`), for at most `max_extrapolation_s`, then holds the value reached there.

Playout slot (which sender tick a receiver tick stands for), as `core.playout.PlayOnArrival`:
a fresh arrival (an original transmission newer than anything received) is played at once and
sets the slot to its seq; every tick without one advances the slot by one. A sample that arrives
later by another way (an FEC recovery, an ARQ retransmission) joins the decoder's history: it is
played if the slot has not yet passed it (with `wait_ticks` the decoder plays `wait_ticks` behind
the slot, so recoveries within that many ticks are in time), and otherwise it only improves the
extrapolation base; it never moves the slot back. docs/codec_baselines.md has the details.

Pure core: time and tick index are passed in; no I/O, no clock, no randomness.
"""

from __future__ import annotations

import dataclasses
import math
from bisect import bisect_right, insort
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from haptic_teleop.core.link import Packet

Sample = tuple[float, ...]
SizeOf = Callable[[int], int]

KIND = "prediction"
GAP_MODES = ("extrapolate", "hold")
# Samples the history keeps behind the newest one (besides wait_ticks and the extrapolation reach).
_HISTORY_TICKS = 64


def float64_multiarray_size(floats: int) -> int:
    """CDR bytes of a std_msgs/Float64MultiArray with an empty layout carrying `floats` values:
    4 (encapsulation) + 4 (dim sequence length 0) + 4 (data_offset) + 4 (data length)
    + 4 (alignment of the float64 data to 8) + 8 per value = 20 + 8 floats."""
    if floats < 0:
        raise ValueError(f"floats must be >= 0, got {floats}")
    return 20 + 8 * floats


def check_fields(cfg: object) -> None:
    """Check a frozen config dataclass's fields against their metadata ("min", "max", "gt",
    "lt", "choices"), for configs built in code rather than through typedconfig."""
    assert dataclasses.is_dataclass(cfg)
    for f in dataclasses.fields(cfg):
        _check(f.name, getattr(cfg, f.name), f.metadata)


def _check(name: str, value: object, meta: Mapping[str, Any]) -> None:
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value}")
        lo, hi, gt, lt = meta.get("min"), meta.get("max"), meta.get("gt"), meta.get("lt")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise ValueError(f"{name} must be in [{lo}, {hi}], got {value}")
        if (gt is not None and not value > gt) or (lt is not None and not value < lt):
            raise ValueError(f"{name} must be > {gt} and < {lt}, got {value}")


def extrapolate1(a: float, b: float, ahead: int, span: int) -> float:
    """One value's linear extrapolation: b at tick t, a at t - span, to tick t + ahead."""
    return b + (b - a) * (ahead / span)


def extrapolate(
    prev_seq: int, prev: Sample, last_seq: int, last: Sample, target_seq: int, max_ahead_ticks: int
) -> Sample:
    """Linear extrapolation of two samples (at ticks prev_seq < last_seq) to tick `target_seq`,
    at most `max_ahead_ticks` past `last_seq` (beyond that, the value reached there: a hold)."""
    if not prev_seq < last_seq:
        raise ValueError(f"prev_seq ({prev_seq}) must be before last_seq ({last_seq})")
    ahead = min(target_seq - last_seq, max_ahead_ticks)
    span = last_seq - prev_seq
    return tuple(extrapolate1(a, b, ahead, span) for a, b in zip(prev, last, strict=True))


class Reconstructor:
    """The receiver's sample history and what it plays each tick (see the module docstring).

    `add` a sample with its seq (fresh: an original transmission); `sample(n)` the value for
    tick n. Counts samples that arrived in time for their slot and those that came too late to
    be played (`late`; kept for the record and the extrapolation base).
    """

    def __init__(self, gap: str = "extrapolate", max_extrapolation_ticks: int = 50, wait_ticks: int = 0) -> None:
        if gap not in GAP_MODES:
            raise ValueError(f"gap must be one of {', '.join(GAP_MODES)}, got {gap!r}")
        if max_extrapolation_ticks < 0 or wait_ticks < 0:
            raise ValueError(
                f"max_extrapolation_ticks and wait_ticks must be >= 0, got {max_extrapolation_ticks}, {wait_ticks}"
            )
        self.extrapolates = gap == "extrapolate"
        self.max_extrapolation_ticks = max_extrapolation_ticks
        self.wait_ticks = wait_ticks
        self._keep = _HISTORY_TICKS + wait_ticks + max_extrapolation_ticks
        self._seqs: list[int] = []  # sorted
        self._values: dict[int, Sample] = {}
        self._newest_fresh: int | None = None
        self._slot: int | None = None  # sender tick the last sample() call stood for
        self._slot_n = 0
        self._fresh_pending = False
        self.last_played_seq: int | None = None  # target of the last sample() call
        self.late = 0  # non-fresh samples added after their slot was played
        self.predicted = 0  # ticks played from a prediction (or a hold past the history)

    def has(self, seq: int) -> bool:
        return seq in self._values

    def get(self, seq: int) -> Sample | None:
        return self._values.get(seq)

    @property
    def keep_ticks(self) -> int:
        """How far behind the newest sample the history reaches."""
        return self._keep

    @property
    def newest_seq(self) -> int | None:
        return self._seqs[-1] if self._seqs else None

    def add(self, seq: int, value: Sample, fresh: bool) -> bool:
        """Add a sample; False if its seq is already held (a duplicate) or too old to keep."""
        if seq in self._values:
            return False
        newest = self._seqs[-1] if self._seqs else None
        if newest is not None and seq < newest - self._keep:
            if not fresh:
                self.late += 1
            return False
        if not fresh and self.last_played_seq is not None and seq <= self.last_played_seq:
            self.late += 1
        self._values[seq] = value
        insort(self._seqs, seq)
        if fresh and (self._newest_fresh is None or seq > self._newest_fresh):
            self._newest_fresh = seq
            self._fresh_pending = True
        # Forget what is too old to matter.
        cut = self._seqs[-1] - self._keep
        drop = 0
        while self._seqs[drop] < cut:
            del self._values[self._seqs[drop]]
            drop += 1
        if drop:
            del self._seqs[:drop]
        return True

    def sample(self, n: int) -> Sample | None:
        """The value to use at receiver tick n (None before anything usable arrived)."""
        if self._fresh_pending:
            assert self._newest_fresh is not None
            self._slot, self._slot_n = self._newest_fresh, n
            self._fresh_pending = False
        elif self._slot is not None:
            self._slot, self._slot_n = self._slot + (n - self._slot_n), n
        elif self._seqs:  # only non-fresh samples so far: start from the newest
            self._slot, self._slot_n = self._seqs[-1], n
        else:
            return None
        target = self._slot - self.wait_ticks
        if self.last_played_seq is None or target > self.last_played_seq:
            self.last_played_seq = target
        value = self._values.get(target)
        if value is not None:
            return value
        i = bisect_right(self._seqs, target)
        if i == 0:
            return None  # everything held is newer than the target (start-up with wait_ticks)
        self.predicted += 1
        last_seq = self._seqs[i - 1]
        last = self._values[last_seq]
        if not self.extrapolates or i == 1:
            return last
        prev_seq = self._seqs[i - 2]
        return extrapolate(prev_seq, self._values[prev_seq], last_seq, last, target, self.max_extrapolation_ticks)


@dataclass(frozen=True)
class PredictionConfig:
    """Codec `prediction`: send every sample; the receiver predicts over missing ticks."""

    gap: str = field(
        default="extrapolate",
        metadata={"choices": GAP_MODES, "help": "missing tick: extrapolate the last two samples or hold the last"},
    )
    max_extrapolation_s: float = field(
        default=0.05, metadata={"min": 0.0, "max": 10.0, "help": "extrapolate at most this far, then hold"}
    )

    def __post_init__(self) -> None:
        check_fields(self)


def ticks(seconds: float, period_ns: int) -> int:
    """Whole ticks in `seconds` (rounded to the nearest tick)."""
    if not period_ns > 0:
        raise ValueError(f"period_ns must be > 0, got {period_ns}")
    return round(seconds * 1e9 / period_ns)


class PredictionEncoder:
    """Every sample in its own packet: payload = the sample; size = `size_of(len(sample))`."""

    def __init__(self, size_of: SizeOf = float64_multiarray_size) -> None:
        self._size_of = size_of
        self.counters: dict[str, int] = {"samples": 0, "sent": 0, "bytes": 0}

    def send(self, n: int, now_ns: int, sample: Sample) -> list[Packet]:
        size = self._size_of(len(sample))
        c = self.counters
        c["samples"] += 1
        c["sent"] += 1
        c["bytes"] += size
        return [Packet(n, now_ns, tuple(sample), size)]

    def feedback(self, packet: Packet, now_ns: int) -> None:
        """No return path."""


class PredictionDecoder:
    """Plays the newest sample, predicts over missing ticks (`Reconstructor`)."""

    def __init__(self, gap: str = "extrapolate", max_extrapolation_ticks: int = 50) -> None:
        self.rec = Reconstructor(gap, max_extrapolation_ticks)
        self.counters: dict[str, int] = {"received": 0, "duplicates": 0}

    def receive(self, packet: Packet, now_ns: int) -> list[Packet]:
        self.counters["received"] += 1
        if not self.rec.add(packet.seq, tuple(packet.payload), fresh=True):
            self.counters["duplicates"] += 1
        return []

    def sample(self, n: int, now_ns: int) -> Sample | None:
        return self.rec.sample(n)


def build_prediction(
    cfg: PredictionConfig, period_ns: int, *, size_of: SizeOf = float64_multiarray_size
) -> tuple[PredictionEncoder, PredictionDecoder]:
    """Encoder and decoder of codec `prediction` for a stream with one sample every `period_ns`.
    `size_of(floats)` is the message size of a payload of that many floats (the default assumes
    a std_msgs/Float64MultiArray; the wiring may pass record.layouts' JointState sizes)."""
    return PredictionEncoder(size_of), PredictionDecoder(cfg.gap, ticks(cfg.max_extrapolation_s, period_ns))
