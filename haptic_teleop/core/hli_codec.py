"""Seed 000's priority-based filtering as a codec (docs/codec_hli.md; interface: the codec stage).

Sender (`HliEncoder`): classifies each sample against the receiver's track it mirrors (see
`core/hli.classify`), never sends HLI0, always sends HLI2, and sends the N_HLI1 HLI1 followers of
an HLI2 event unless an allowed bandwidth is set and sending would push the rate over it: then it
filters those of the followers that the filtering pattern (sequential: the first j*, alternate:
the 1st, 3rd, ... up to j* of them) allows, j* the largest j with P_N,j <= P_allowable.

Payload: (x..., class, offset, previous x...[, copy...]): the sample, its class code (2.0 or 1.0),
the offset m of an HLI1 event from its HLI2 event (0 for HLI2), the true sample before it (so the
receiver's prediction takes the true slope), and in an HLI1 packet a copy of the HLI2 event's
sample, so that any one received follower rebuilds a lost HLI2 event exactly.

Receiver (`HliDecoder`): runs N_HLI1 ticks behind its newest possible packet, so that the HLI1
followers of a tick's HLI2 event (in the worst case only the N_HLI1-th, seed slide 48) are in
before the tick is played. A tick's sample is the received sample, else the rebuilt HLI2 sample,
else the prediction (the sender's predictor) from the two samples played before it.

Both are plain functions over core/codec_layout.py's arrays (`hli_send`; `hli_receive`,
`hli_sample`), which the objects hold and call and the compiled loop inlines
(engine/compiled/codec_hli.py): one definition.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from haptic_teleop.core import codec_layout as L
from haptic_teleop.core.hli import (
    CLOCKS,
    DEFAULT_ALPHA,
    DEFAULT_THRESHOLD_M,
    FILTERINGS,
    HLI0,
    HLI1,
    HLI2,
    PREDICTORS,
    GilbertChannel,
    filter_count,
    n_hli1,
    p_all_lost_filtered,
    sent_slots,
)
from haptic_teleop.core.link import DEFAULT_OVERHEAD_BYTES, Packet

KIND = "hli"  # the scene's `codec: {kind: hli, ...}`
_P = {"min": 0.0, "max": 1.0}
# The objects' counters: where S keeps them
ENCODER_COUNTERS = {
    "samples": L.S_OFFERED,
    "sent": L.S_SENT,
    "hli0": L.S_HLI0,
    "hli1": L.S_HLI1,
    "hli2": L.S_HLI2,
    "filtered_hli0": L.S_FILT0,
    "filtered_hli1": L.S_FILT1,
    "wire_bits": L.S_WIRE_BITS,
    "over_budget": L.S_OVER,
}
DECODER_COUNTERS = {
    "received": L.S_RECEIVED,
    "rebuilt": L.S_REBUILT,
    "predicted": L.S_DPREDICTED,
    "played_received": L.S_PLAYED,
    "late": L.S_DLATE,
}


@dataclass(frozen=True)
class HliConfig:
    """Priority-based filtering of one stream (seed 000). The Gilbert parameters are the scene's
    loss model's (core/loss.py names); the wiring fills them in from the scene when unset."""

    threshold_m: float = field(
        default=DEFAULT_THRESHOLD_M,
        metadata={"gt": 0.0, "max": 1e3, "help": "TH_HLI in the stream's unit (0.4 mm for positions)"},
    )
    predictor: str = field(default="linear", metadata={"choices": PREDICTORS, "help": "x_pred from the last two"})
    alpha: float = field(
        default=DEFAULT_ALPHA, metadata={"gt": 0.0, "lt": 1.0, "help": "N_HLI1: smallest i with P_i < alpha"}
    )
    p: float | None = field(default=None, metadata={**_P, "help": "Gilbert P(good -> bad) per step"})
    r: float | None = field(default=None, metadata={**_P, "help": "Gilbert P(bad -> good) per step"})
    one_minus_h: float = field(default=1.0, metadata={**_P, "help": "loss probability in the bad state"})
    one_minus_k: float = field(default=0.0, metadata={**_P, "help": "loss probability in the good state"})
    clock: str = field(
        default="slot", metadata={"choices": CLOCKS, "help": "the Gilbert chain moves per time slot or per sent packet"}
    )
    filtering: str = field(default="sequential", metadata={"choices": FILTERINGS, "help": "which HLI1 events to drop"})
    allowed_bandwidth_bps: float | None = field(
        default=None, metadata={"gt": 0.0, "max": 1e12, "help": "wire bits/s incl. headers (unset: no HLI1 filtering)"}
    )
    p_allowable: float = field(
        default=1e-3, metadata={"gt": 0.0, "lt": 1.0, "help": "P_N,j may rise to this when HLI1 events are filtered"}
    )
    rate_window_s: float = field(
        default=0.1, metadata={"gt": 0.0, "max": 60.0, "help": "the sent rate is measured over this window"}
    )
    max_n_hli1: int = field(default=200, metadata={"min": 0, "max": 100_000, "help": "refuse channels needing more"})

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            _check_field(f.name, getattr(self, f.name), f.metadata)
        if self.p_allowable < self.alpha:
            raise ValueError(
                f"codec hli: p_allowable ({self.p_allowable}) must be >= alpha ({self.alpha}): "
                "filtering can only raise P_N,j above P_N"
            )

    def channel(self) -> GilbertChannel:
        if self.p is None or self.r is None:
            raise ValueError("codec hli needs the Gilbert loss parameters p and r (set them, or name a gilbert loss)")
        return GilbertChannel(self.p, self.r, self.one_minus_h, self.one_minus_k)


def _check_field(name: str, value: object, m: Mapping[str, Any]) -> None:
    if value is None:
        return
    choices = m.get("choices")
    if choices is not None and value not in choices:
        raise ValueError(f"codec hli: {name} must be one of {', '.join(choices)}, got {value!r}")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    if not math.isfinite(value):
        raise ValueError(f"codec hli: {name} must be finite, got {value}")
    lo, hi, gt, lt = m.get("min"), m.get("max"), m.get("gt"), m.get("lt")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ValueError(f"codec hli: {name} must be in [{lo}, {hi}], got {value}")
    if (gt is not None and not value > gt) or (lt is not None and not value < lt):
        raise ValueError(f"codec hli: {name} must be > {gt} and < {lt}, got {value}")


def joint_state_bytes(values_per_name: int, names: int) -> int:
    """CDR size of a sensor_msgs/JointState with `names` 8-character names and `values_per_name`
    of its position/velocity/effort filled (the rest empty): 48 + 12 f + (names - 1)(16 + 8 f).
    Equal to record/layouts.joint_state_size(f, names) for names <= 3 (tested); core cannot import it."""
    if not (1 <= values_per_name <= 3 and names >= 1):
        raise ValueError(f"a JointState has 1 to 3 value fields and >= 1 name, got {values_per_name}, {names}")
    return 48 + 12 * values_per_name + (names - 1) * (16 + 8 * values_per_name)


def hli_message_bytes(dim: int, cls: int) -> int:
    """Wire message of an HLI packet: a JointState with the stream's `dim` axes and one more name
    ("hli"); position = (x..., class), velocity = (previous sample..., offset), and in HLI1
    packets effort = (copy of the HLI2 sample..., 0)."""
    return joint_state_bytes(3 if cls == HLI1 else 2, dim + 1)


def linear1(a: float, b: float) -> float:
    """The linear predictor of one value: a at n-1, b at n-2, to n."""
    return 2.0 * a - b


# The same prediction and distance over tuples (core/event_codec.py's objects)
def _pred(t1: tuple[float, ...] | None, t2: tuple[float, ...] | None, linear: bool) -> tuple[float, ...] | None:
    if t1 is None:
        return None
    if not linear or t2 is None:
        return t1
    return tuple(linear1(a, b) for a, b in zip(t1, t2, strict=True))


def _norm(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return math.sqrt(sum((x - y) * (x - y) for x, y in zip(a, b, strict=True)))


# The encoder's and the decoder's steps over codec_layout arrays (one definition: `HliEncoder` and
# `HliDecoder` call them over their own arrays, the compiled loop's tick over its direction's,
# engine/compiled/codec_hli.py). C: C_DIM and the C_H* constants; S: the S_E* (encoder) and S_D*,
# S_LAG* .. S_FR* (decoder) scalars, the tracks' vectors at the places passed (et1, et2, eh2, eprev;
# dt1, dt2); W (the encoder's): from 1 the filtering pattern (1.0: the k-th follower may be
# filtered), from N_HLI1 + 1 the followers after position k that are sent whatever the rate, from
# 2 N_HLI1 + 2 the rate window, a ring of (tick, wire bits) pairs of C_HWIN + 1 places; X: a row
# per seq modulo its (power-of-two) length, a packet's payload from H_PAY in the wire's order
# (x..., class, offset, previous x...[, copy...]), the decoder's tags and rebuilt sample at the
# places passed (rtag, btag, bx). The places that differ between layouts are passed.


def hli_send(
    C: Any, S: Any, W: Any, X: Any, n: int, smp: Any, pred: Any, et1: int, et2: int, eh2: int, eprev: int
) -> bool:
    """`HliEncoder.send` of tick n's sample `smp` (`pred`: scratch for the mirrored track's
    prediction): the rate window, the class, the filtering of a follower, the track. Returns whether
    a packet goes out; its payload is then in n's row of X from H_PAY and its message size in
    C_SIZE."""
    dim = int(C[L.C_DIM])
    N = int(C[L.C_HN])
    S[L.S_OFFERED] += 1.0
    # the rate window: drop the packets sent C_HWIN ticks ago or more
    wt = int(C[L.C_HWIN])
    base = 2 * N + 2
    cap = wt + 1
    while S[L.S_WIN_COUNT] > 0.0:
        h = int(S[L.S_WIN_HEAD])
        if W[base + 2 * h] > n - wt:
            break
        S[L.S_WIN_BITS] -= W[base + 2 * h + 1]
        S[L.S_WIN_HEAD] = (h + 1) % cap
        S[L.S_WIN_COUNT] -= 1.0
    # the prediction of the mirrored receiver track
    has_pred = S[L.S_ET1H] != 0.0
    if has_pred:
        linear = C[L.C_HLINEAR] != 0.0 and S[L.S_ET2H] != 0.0
        for i in range(dim):
            pred[i] = linear1(S[et1 + i], S[et2 + i]) if linear else S[et1 + i]
    S[L.S_ESINCE] += 1.0
    cls = HLI0
    big = S[L.S_ESEEN] < C[L.C_HWARMUP] or not has_pred
    if not big:  # |x - x_pred|: the squares summed in order, one square root
        acc = 0.0
        for i in range(dim):
            d = smp[i] - pred[i]
            acc += d * d
        big = math.sqrt(acc) >= C[L.C_HTHRESH]
    if big:
        cls = HLI2
        S[L.S_ESINCE] = 0.0
        for i in range(dim):
            S[eh2 + i] = smp[i]
    elif S[L.S_ESINCE] <= N:
        cls = HLI1
    S[L.S_ESEEN] += 1.0
    S[L.S_LAST_CLASS] = cls
    S[L.S_HLI0 + cls] += 1.0
    send = cls != HLI0
    since = int(S[L.S_ESINCE])
    if cls == HLI1 and W[since] != 0.0:
        # filter it if sending it and the followers that cannot be filtered would overrun the
        # budget of the current window (nothing assumed to leave the window meanwhile)
        need = C[L.C_HBITS1] * (1.0 + W[N + 1 + since])
        if S[L.S_WIN_BITS] + need > C[L.C_HBUDGET]:
            send = False
            S[L.S_FILT1] += 1.0
    elif cls == HLI0:
        S[L.S_FILT0] += 1.0
    # the true sample before this one (the first: itself) into the payload, and the track: a sent
    # sample re-anchors it with the true slope
    j = n & (X.shape[0] - 1)
    pv = L.H_PAY + dim + 2
    first = S[L.S_EPREVH] == 0.0
    anchor = send or not has_pred
    for i in range(dim):
        prev = smp[i] if first else S[eprev + i]
        if send:
            X[j, pv + i] = prev
        S[eprev + i] = smp[i]
        S[et2 + i] = prev if anchor else S[et1 + i]
        S[et1 + i] = smp[i] if anchor else pred[i]
    S[L.S_EPREVH] = 1.0
    S[L.S_ET2H] = 1.0 if anchor else S[L.S_ET1H]
    S[L.S_ET1H] = 1.0
    if not send:
        return False
    for i in range(dim):
        X[j, L.H_PAY + i] = smp[i]
    X[j, L.H_PAY + dim] = cls
    X[j, L.H_PAY + dim + 1] = 0.0 if cls == HLI2 else since
    if cls == HLI1:
        for i in range(dim):
            X[j, pv + dim + i] = S[eh2 + i]
    bits = C[L.C_HBITS2] if cls == HLI2 else C[L.C_HBITS1]
    k = (int(S[L.S_WIN_HEAD]) + int(S[L.S_WIN_COUNT])) % cap
    W[base + 2 * k] = n
    W[base + 2 * k + 1] = bits
    S[L.S_WIN_COUNT] += 1.0
    S[L.S_WIN_BITS] += bits
    S[L.S_SENT] += 1.0
    S[L.S_WIRE_BITS] += bits
    if S[L.S_WIN_BITS] > C[L.C_HBUDGET]:
        S[L.S_OVER] += 1.0
    C[L.C_SIZE] = C[L.C_HSIZE2] if cls == HLI2 else C[L.C_HSIZE1]
    return True


def hli_receive(C: Any, S: Any, X: Any, seq: int, P: Any, p: int, rtag: int, btag: int, bx: int) -> None:
    """`HliDecoder.receive` of packet `seq` with its payload in row p of P from H_PAY (the compiled
    loop's: the sender's row of X, which is seq's): unless its tick was played (late), its sample
    and the one before it into seq's row of X, the row marked received; a follower's copy of its
    HLI2 sample kept for the event's tick unless that was played or one is kept already."""
    dim = int(C[L.C_DIM])
    mask = X.shape[0] - 1
    S[L.S_RECEIVED] += 1.0
    if S[L.S_CURH] != 0.0 and seq <= S[L.S_CUR]:
        S[L.S_DLATE] += 1.0
        return
    j = seq & mask
    pv = L.H_PAY + dim + 2
    for i in range(dim):
        X[j, L.H_PAY + i] = P[p, L.H_PAY + i]
        X[j, pv + i] = P[p, pv + i]
    X[j, rtag] = seq
    if S[L.S_CURH] == 0.0 and (S[L.S_MINH] == 0.0 or seq < S[L.S_MIN]):
        S[L.S_MIN] = seq
        S[L.S_MINH] = 1.0
    if P[p, L.H_PAY + dim] == HLI1:
        key = seq - int(P[p, L.H_PAY + dim + 1])
        if S[L.S_CURH] == 0.0 or key > S[L.S_CUR]:
            jr = key & mask
            if X[jr, btag] != key:
                X[jr, btag] = key
                for i in range(dim):
                    X[jr, bx + i] = P[p, pv + dim + i]
    if S[L.S_FRH] == 0.0 or seq > S[L.S_FRMAX]:
        S[L.S_FRMAX] = seq
        S[L.S_FRH] = 1.0


def hli_play(C: Any, S: Any, X: Any, t: int, rtag: int, btag: int, bx: int, dt1: int, dt2: int) -> None:
    """The decoder's tick t onto its track (dt1: the sample played, dt2: the one before): the
    received sample with its true predecessor, else the rebuilt HLI2 sample, else the prediction
    (the sender's predictor) from the two played before it, else nothing."""
    dim = int(C[L.C_DIM])
    j = t & (X.shape[0] - 1)
    got = X[j, rtag] == t
    if got:
        X[j, rtag] = L.H_NONE
    rb = X[j, btag] == t
    if rb:
        X[j, btag] = L.H_NONE
    if got:
        S[L.S_PLAYED] += 1.0
        pv = L.H_PAY + dim + 2
        for i in range(dim):
            S[dt2 + i] = X[j, pv + i]
            S[dt1 + i] = X[j, L.H_PAY + i]
        S[L.S_DT1H] = 1.0
        S[L.S_DT2H] = 1.0
        return
    if rb:
        S[L.S_REBUILT] += 1.0
        for i in range(dim):
            S[dt2 + i] = S[dt1 + i]
            S[dt1 + i] = X[j, bx + i]
        S[L.S_DT2H] = S[L.S_DT1H]
        S[L.S_DT1H] = 1.0
        return
    if S[L.S_DT1H] == 0.0:
        return
    S[L.S_DPREDICTED] += 1.0
    linear = C[L.C_HLINEAR] != 0.0 and S[L.S_DT2H] != 0.0
    for i in range(dim):
        a = S[dt1 + i]
        x = linear1(a, S[dt2 + i]) if linear else a
        S[dt2 + i] = a
        S[dt1 + i] = x
    S[L.S_DT2H] = 1.0


def hli_sample(C: Any, S: Any, X: Any, n: int, out: Any, rtag: int, btag: int, bx: int, dt1: int, dt2: int) -> bool:
    """`HliDecoder.sample` of tick n into `out` (False: none yet): the lag (the link's smallest
    delay in ticks: n - the newest seq received since the last call, the smallest so far), then
    the ticks up to n - lag - C_HDELAY played in turn (the first call starts at the oldest packet
    received, or at that tick)."""
    if S[L.S_FRH] != 0.0:
        lag = n - int(S[L.S_FRMAX])
        if S[L.S_LAGH] == 0.0 or lag < S[L.S_LAG]:
            S[L.S_LAG] = lag
            S[L.S_LAGH] = 1.0
        S[L.S_FRH] = 0.0
    if S[L.S_LAGH] == 0.0:
        return False
    target = n - int(S[L.S_LAG]) - int(C[L.C_HDELAY])
    if S[L.S_CURH] == 0.0:
        first = int(S[L.S_MIN]) if S[L.S_MINH] != 0.0 else target
        S[L.S_CUR] = min(first, target + 1) - 1
        S[L.S_CURH] = 1.0
    while S[L.S_CUR] < target:
        S[L.S_CUR] += 1.0
        hli_play(C, S, X, int(S[L.S_CUR]), rtag, btag, bx, dt1, dt2)
    if S[L.S_DT1H] == 0.0:
        return False
    for i in range(int(C[L.C_DIM])):
        out[i] = S[dt1 + i]
    return True


class HliEncoder:
    """The sender: classify, filter, packetize (`hli_send` over its own arrays: C, S with the
    tracks' vectors after S_SIZE_X, the pattern and rate window in W, the payload in X's one row).
    One object per stream direction."""

    def __init__(self, cfg: HliConfig, period_ns: int, dim: int) -> None:
        if not period_ns > 0:
            raise ValueError(f"period_ns must be > 0, got {period_ns}")
        if dim < 1:
            raise ValueError(f"dim must be >= 1, got {dim}")
        ch = cfg.channel()
        self.cfg = cfg
        self.dim = dim
        self.period_ns = period_ns
        self.n_hli1 = N = n_hli1(ch, cfg.alpha, cfg.max_n_hli1)
        if cfg.allowed_bandwidth_bps is None:
            self.j_max = 0
        else:
            self.j_max = filter_count(ch, N, cfg.p_allowable, cfg.filtering, cfg.clock)
        self.p_n = p_all_lost_filtered(ch, N, 0, cfg.filtering, cfg.clock)
        self.p_n_j = p_all_lost_filtered(ch, N, self.j_max, cfg.filtering, cfg.clock)
        kept = set(sent_slots(N, self.j_max, cfg.filtering))
        window_ticks = max(1, round(cfg.rate_window_s * 1e9 / period_ns))
        bw = cfg.allowed_bandwidth_bps
        C = [0.0] * L.C_SIZE_X
        C[L.C_DIM], C[L.C_HN], C[L.C_HTHRESH], C[L.C_HWIN] = dim, N, cfg.threshold_m, window_ticks
        linear = cfg.predictor == "linear"
        C[L.C_HLINEAR], C[L.C_HWARMUP] = 1.0 if linear else 0.0, 2 if linear else 1
        C[L.C_HBUDGET] = math.inf if bw is None else bw * window_ticks * period_ns * 1e-9
        C[L.C_HSIZE1], C[L.C_HSIZE2] = hli_message_bytes(dim, HLI1), hli_message_bytes(dim, HLI2)
        C[L.C_HBITS1], C[L.C_HBITS2] = (8 * (DEFAULT_OVERHEAD_BYTES + C[k]) for k in (L.C_HSIZE1, L.C_HSIZE2))
        self.C: Any = C
        # W: the followers that may be filtered (1..N), the followers after position k sent
        # whatever the rate (not in the pattern), the rate window's ring
        W = [0.0] * (2 * N + 2 + 2 * (window_ticks + 1))
        for k in range(N + 1):
            W[k] = 1.0 if k and k not in kept else 0.0
            W[N + 1 + k] = sum(1 for q in range(k + 1, N + 1) if q in kept)
        self.W: Any = W
        self.S: Any = [0.0] * (L.S_SIZE_X + 4 * dim)
        self.S[L.S_ESINCE] = N + 1  # ticks since the last HLI2 event
        self._places = tuple(L.S_SIZE_X + q * dim for q in range(4))  # the tracks at n-1, n-2, HLI2, previous
        self.X: Any = np.zeros((1, 3 * dim + 2))
        self._pred = [0.0] * dim

    @property
    def last_class(self) -> int:
        return int(self.S[L.S_LAST_CLASS])

    @property
    def counters(self) -> dict[str, int]:
        return {name: int(self.S[k]) for name, k in ENCODER_COUNTERS.items()}

    def load(self, S: Any) -> None:
        """Take the scalar state of an encoder run elsewhere (a compiled loop's S)."""
        self.S[: L.S_SIZE_X] = [float(v) for v in S[: L.S_SIZE_X]]

    def send(self, n: int, now_ns: int, sample: tuple[float, ...]) -> list[Packet]:
        if len(sample) != self.dim:
            raise ValueError(f"codec hli: sample has {len(sample)} values, the stream has {self.dim}")
        C, X = self.C, self.X
        if not hli_send(C, self.S, self.W, X, n, sample, self._pred, *self._places):
            return []
        floats = 3 * self.dim + 2 if X[0, L.H_PAY + self.dim] == HLI1 else 2 * self.dim + 2
        payload = tuple(X[0, L.H_PAY : L.H_PAY + floats].tolist())
        return [Packet(seq=n, send_time_ns=now_ns, payload=payload, size_bytes=int(C[L.C_SIZE]))]

    def feedback(self, packet: Packet, now_ns: int) -> None:
        """No return path."""


class HliDecoder:
    """The receiver: hold packets N_HLI1 ticks, rebuild lost HLI2 events, predict the rest
    (`hli_receive` and `hli_sample` over its own arrays: C, S with its track's vectors after
    S_SIZE_X, and X, a row per seq with the received payload, its tags and rebuilt sample, which
    grows as the packets not yet played need)."""

    def __init__(self, cfg: HliConfig, dim: int, n_followers: int | None = None) -> None:
        if dim < 1:
            raise ValueError(f"dim must be >= 1, got {dim}")
        self.dim = dim
        self.delay_ticks = n_hli1(cfg.channel(), cfg.alpha, cfg.max_n_hli1) if n_followers is None else n_followers
        if self.delay_ticks < 0:
            raise ValueError(f"n_followers must be >= 0, got {n_followers}")
        C = [0.0] * L.C_SIZE_X
        C[L.C_DIM], C[L.C_HLINEAR], C[L.C_HDELAY] = dim, 1.0 if cfg.predictor == "linear" else 0.0, self.delay_ticks
        self.C: Any = C
        self.S: Any = [0.0] * (L.S_SIZE_X + 2 * dim)
        # X's places: the payload (3 dim + 2), the received tag, the rebuilt tag and sample
        self._tags = (3 * dim + 2, 3 * dim + 3, 3 * dim + 4)
        self._track = (L.S_SIZE_X, L.S_SIZE_X + dim)
        self.X: Any = self._rows(16)
        self._lo: int | None = None  # the oldest seq or rebuilt tick taken while nothing was played
        self._hi = 0  # the newest seq or rebuilt tick taken
        self._packet: Any = np.zeros((1, 3 * dim + 2))
        self._out = [0.0] * dim

    def _rows(self, n: int) -> Any:
        X = np.zeros((n, 4 * self.dim + 4))
        X[:, self._tags[0]] = L.H_NONE
        X[:, self._tags[1]] = L.H_NONE
        return X

    @property
    def counters(self) -> dict[str, int]:
        return {name: int(self.S[k]) for name, k in DECODER_COUNTERS.items()}

    def load(self, S: Any) -> None:
        """Take the scalar state of a decoder run elsewhere (a compiled loop's S)."""
        self.S[: L.S_SIZE_X] = [float(v) for v in S[: L.S_SIZE_X]]

    def _room(self, seq: int, key: int) -> None:
        """X's rows for every packet and rebuilt tick not yet played (the compiled loop's are sized
        by its link's delay): doubled, its tags moved, when `seq` would wrap onto one of them."""
        S, X = self.S, self.X
        if self._lo is None:
            self._lo, self._hi = min(seq, key), max(seq, key)
        else:
            self._lo, self._hi = min(self._lo, seq, key), max(self._hi, seq, key)
        lo = int(S[L.S_CUR]) + 1 if S[L.S_CURH] else self._lo
        rows = len(X)
        while rows <= self._hi - lo:
            rows *= 2
        if rows == len(X):
            return
        rtag, btag, _ = self._tags
        new = self._rows(rows)
        for r in range(len(X)):
            t, b = X[r, rtag], X[r, btag]
            if t != L.H_NONE and t >= lo:
                new[int(t) & (rows - 1), : rtag + 1] = X[r, : rtag + 1]
            if b != L.H_NONE and b >= lo:
                new[int(b) & (rows - 1), btag:] = X[r, btag:]
        self.X = new

    def receive(self, packet: Packet, now_ns: int) -> list[Packet]:
        d = self.dim
        pl = packet.payload
        if len(pl) < 2 * d + 2:
            raise ValueError(f"codec hli: payload of {len(pl)} values, need at least {2 * d + 2}")
        hli1 = round(pl[d]) == HLI1
        if hli1 and len(pl) < 3 * d + 2:
            raise ValueError(f"codec hli: HLI1 payload of {len(pl)} values, need {3 * d + 2}")
        P = self._packet
        P[0, L.H_PAY : L.H_PAY + 2 * d + 2] = pl[: 2 * d + 2]
        P[0, L.H_PAY + d : L.H_PAY + d + 2] = (HLI1, round(pl[d + 1])) if hli1 else (HLI2, 0.0)
        if hli1:
            P[0, L.H_PAY + 2 * d + 2 : L.H_PAY + 3 * d + 2] = pl[2 * d + 2 : 3 * d + 2]
        seq = packet.seq
        self._room(seq, seq - round(pl[d + 1]) if hli1 else seq)
        hli_receive(self.C, self.S, self.X, seq, P, 0, *self._tags)
        return []

    def sample(self, n: int, now_ns: int) -> tuple[float, ...] | None:
        """The sample for tick n: that of tick n - lag - N_HLI1 (lag = the link's smallest delay in
        ticks, learnt from the packets: tick received - seq)."""
        if not hli_sample(self.C, self.S, self.X, n, self._out, *self._tags, *self._track):
            return None
        return tuple(map(float, self._out))


def build_hli_codec(cfg: HliConfig, period_ns: int, dim: int) -> tuple[HliEncoder, HliDecoder]:
    """The sender and receiver of one stream direction (`codec: {kind: hli, ...}`)."""
    enc = HliEncoder(cfg, period_ns, dim)
    return enc, HliDecoder(cfg, dim, enc.n_hli1)
