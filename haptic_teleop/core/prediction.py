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
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from haptic_teleop.core import codec_layout as L
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


# The reconstruction over a sample history as functions over codec_layout arrays: the one
# definition the Python `Reconstructor` calls and the compiled loops inline (FEC, ARQ). C: C_DIM,
# C_KEEP (how far behind the newest held sample the history reaches), C_WAIT, C_EXTRAP,
# C_MAX_TICKS; S: the history's scalars (S_HAS_HELD, S_MAXHELD, S_HAS_FRESH, S_NEWEST_FRESH,
# S_PENDING, S_HAS_SLOT, S_SLOT, S_SLOT_N, S_HAS_PLAYED, S_LAST_PLAYED, S_PREDICTED, S_LATE,
# S_RECOVERED, S_RECOVERED_LATE); X: a row per seq modulo its (power-of-two) length, more rows than
# C_KEEP: the seq held there (X_HELD) and its values from X_VALUE.


def rec_held(C: Any, S: Any, X: Any, seq: int) -> bool:
    """Whether `seq` is held (and not yet forgotten: within C_KEEP of the newest held)."""
    if seq < 0 or S[L.S_HAS_HELD] == 0.0 or seq < S[L.S_MAXHELD] - C[L.C_KEEP]:
        return False
    return X[seq & (X.shape[0] - 1), L.X_HELD] == seq  # type: ignore[no-any-return]


def rec_take(C: Any, S: Any, X: Any, seq: int, fresh: bool) -> bool:
    """Take `seq` into the history (its values are the caller's to write into its X row); False
    if held already or too old to keep. Not `fresh` (an FEC recovery, an ARQ retransmission):
    counted recovered, and late (and recovered late) if its slot was already played."""
    if rec_held(C, S, X, seq):
        return False
    if S[L.S_HAS_HELD] != 0.0 and seq < S[L.S_MAXHELD] - C[L.C_KEEP]:
        if not fresh:
            S[L.S_LATE] += 1.0
        return False
    if not fresh:
        S[L.S_RECOVERED] += 1.0
        if S[L.S_HAS_PLAYED] != 0.0 and seq <= S[L.S_LAST_PLAYED]:
            S[L.S_LATE] += 1.0
            S[L.S_RECOVERED_LATE] += 1.0
    X[seq & (X.shape[0] - 1), L.X_HELD] = seq
    if S[L.S_HAS_HELD] == 0.0 or seq > S[L.S_MAXHELD]:
        S[L.S_MAXHELD] = seq
        S[L.S_HAS_HELD] = 1.0
    if fresh and (S[L.S_HAS_FRESH] == 0.0 or seq > S[L.S_NEWEST_FRESH]):
        S[L.S_NEWEST_FRESH] = seq
        S[L.S_HAS_FRESH] = 1.0
        S[L.S_PENDING] = 1.0
    return True


def rec_choose(C: Any, S: Any, X: Any, n: int) -> tuple[int, int, int, int]:
    """What tick `n` plays, its values aside (`rec_give`): the playout slot (a fresh arrival sets
    it, each tick advances it; only recoveries so far: the newest held), then the held seq to give
    (the sample at the slot, C_WAIT behind, or the newest held before it; -1: none) and, for a
    prediction from the newest two held at or before the target, the one before it (-1: hold),
    the ticks ahead and the span."""
    if S[L.S_PENDING] != 0.0:
        S[L.S_SLOT] = S[L.S_NEWEST_FRESH]
        S[L.S_SLOT_N] = n
        S[L.S_PENDING] = 0.0
        S[L.S_HAS_SLOT] = 1.0
    elif S[L.S_HAS_SLOT] != 0.0:
        S[L.S_SLOT] = S[L.S_SLOT] + (n - S[L.S_SLOT_N])
        S[L.S_SLOT_N] = n
    elif S[L.S_HAS_HELD] != 0.0:
        S[L.S_SLOT] = S[L.S_MAXHELD]
        S[L.S_SLOT_N] = n
        S[L.S_HAS_SLOT] = 1.0
    else:
        return -1, -1, 0, 0
    target = int(S[L.S_SLOT]) - int(C[L.C_WAIT])
    if S[L.S_HAS_PLAYED] == 0.0 or target > S[L.S_LAST_PLAYED]:
        S[L.S_LAST_PLAYED] = target
        S[L.S_HAS_PLAYED] = 1.0
    mask = X.shape[0] - 1
    newest = int(S[L.S_MAXHELD])
    lo = max(0, newest - int(C[L.C_KEEP]))
    last = min(target, newest)
    while last >= lo and X[last & mask, L.X_HELD] != last:
        last -= 1
    if last < lo:
        return -1, -1, 0, 0  # everything held is newer than the target
    if last == target:
        return last, -1, 0, 0
    S[L.S_PREDICTED] += 1.0
    if C[L.C_EXTRAP] == 0.0:
        return last, -1, 0, 0
    prev = last - 1
    while prev >= lo and X[prev & mask, L.X_HELD] != prev:
        prev -= 1
    if prev < lo:
        return last, -1, 0, 0
    return last, prev, min(target - last, int(C[L.C_MAX_TICKS])), last - prev


def rec_give(C: Any, X: Any, last: int, prev: int, ahead: int, span: int, out: Any) -> bool:
    """The values of `rec_choose`'s choice into `out` (False: nothing to give): the sample held, or
    its extrapolation from the one before it (`extrapolate1`)."""
    if last < 0:
        return False
    mask = X.shape[0] - 1
    j = last & mask
    if prev < 0:
        for i in range(int(C[L.C_DIM])):
            out[i] = X[j, L.X_VALUE + i]
        return True
    k = prev & mask
    for i in range(int(C[L.C_DIM])):
        out[i] = extrapolate1(X[k, L.X_VALUE + i], X[j, L.X_VALUE + i], ahead, span)
    return True


def rec_sample(C: Any, S: Any, X: Any, n: int, out: Any) -> bool:
    """What tick `n` plays into `out` (`rec_choose`, `rec_give`); False before anything usable."""
    last, prev, ahead, span = rec_choose(C, S, X, n)
    return rec_give(C, X, last, prev, ahead, span, out)


class Reconstructor:
    """The receiver's sample history and what it plays each tick (see the module docstring).

    `add` a sample with its seq (fresh: an original transmission); `sample(n)` the value for
    tick n. Counts samples that arrived in time for their slot and those that came too late to
    be played (`late`; kept for the record and the extrapolation base). Its state is codec_layout
    arrays (C and S as lists, X a float64 array made at the first sample, when its width is
    known) that `rec_take` and `rec_sample` act on, as in the compiled loops.
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
        C = [0.0] * L.C_SIZE_X
        C[L.C_KEEP], C[L.C_WAIT] = self._keep, wait_ticks
        C[L.C_EXTRAP], C[L.C_MAX_TICKS] = (1.0 if self.extrapolates else 0.0), max_extrapolation_ticks
        self.C: Any = C
        self.S: Any = [0.0] * L.S_SIZE_X
        self.X: Any = None
        self._out: Any = None

    def history(self, dim: int, extra: int = 0) -> Any:
        """Make X for samples of `dim` values, with `extra` columns after them (a codec's own,
        FEC's parity sums), at the first sample."""
        import numpy as np

        rows = 4
        while rows <= self._keep + 1:
            rows *= 2
        X = np.full((rows, L.X_VALUE + dim + extra), -1.0)
        self.C[L.C_DIM] = dim
        self._out = [0.0] * dim
        self.X = X
        return X

    def has(self, seq: int) -> bool:
        return self.X is not None and rec_held(self.C, self.S, self.X, seq)

    def get(self, seq: int) -> Sample | None:
        if not self.has(seq):
            return None
        j = seq & (self.X.shape[0] - 1)
        return tuple(self.X[j, L.X_VALUE : L.X_VALUE + int(self.C[L.C_DIM])].tolist())

    @property
    def keep_ticks(self) -> int:
        """How far behind the newest sample the history reaches."""
        return self._keep

    @property
    def newest_seq(self) -> int | None:
        return int(self.S[L.S_MAXHELD]) if self.S[L.S_HAS_HELD] != 0.0 else None

    @property
    def last_played_seq(self) -> int | None:
        """The target of the last `sample` call."""
        return int(self.S[L.S_LAST_PLAYED]) if self.S[L.S_HAS_PLAYED] != 0.0 else None

    @property
    def late(self) -> int:
        """Non-fresh samples added after their slot was played (or too old to keep)."""
        return int(self.S[L.S_LATE])

    @property
    def predicted(self) -> int:
        """Ticks played from a prediction (or a hold past the history)."""
        return int(self.S[L.S_PREDICTED])

    def load(self, S: Any) -> None:
        """Take the scalar state of a history kept elsewhere (a compiled loop's S): its counts,
        and those of the decoder around it (`counts`)."""
        self.S[: L.S_SIZE_X] = [float(v) for v in S[: L.S_SIZE_X]]

    def counts(self, places: Mapping[str, int]) -> dict[str, int]:
        """The counters the decoder around it keeps in S, by name (`places`: name -> place)."""
        S = self.S
        return {name: int(S[k]) for name, k in places.items()}

    def add(self, seq: int, value: Sample, fresh: bool) -> bool:
        """Add a sample; False if its seq is already held (a duplicate) or too old to keep."""
        X = self.X if self.X is not None else self.history(len(value))
        dim = int(self.C[L.C_DIM])
        if len(value) != dim:
            raise ValueError(f"reconstruction: a sample of {len(value)} values, the history holds {dim}")
        if not rec_take(self.C, self.S, X, seq, fresh):
            return False
        X[seq & (X.shape[0] - 1), L.X_VALUE : L.X_VALUE + dim] = value
        return True

    def sample(self, n: int) -> Sample | None:
        """The value to use at receiver tick n (None before anything usable arrived)."""
        if self.X is None:
            return None
        out = self._out
        if not rec_sample(self.C, self.S, self.X, n, out):
            return None
        return tuple(out)


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
