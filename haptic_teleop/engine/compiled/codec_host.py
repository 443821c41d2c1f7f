"""The codec stage in the compiled 1-DoF loop (docs/codec_compiled.md).

With a deadband the packets a direction sends depend on the samples, so its network cannot be
decided ahead of the loop as `axis_host.schedule` does. A codec direction whose link effects
all give a packet its fate from the packet's index in the stream and its send time alone (a
blackout, uncorrelated or netem-correlated Bernoulli loss, Gilbert-Elliott loss, a constant delay) is run inside the
kernel instead (engine/compiled/codec_kernel.py): each tick the encoder decides, the k-th packet it sends
takes the k-th random number(s) of the loss effect, a blackout is a table of windows, the arrival
is the send time plus the delay, packets in flight wait in a FIFO ring (a constant delay keeps
their order), the decoder takes the arrivals and gives the tick's remote sample, and each
packet's record (record.layouts.PACKET_FIELDS) is written as it is sent. A deadband's link may
also jitter (uncorrelated or netem-correlated, from the delay effect's own numbers): the ring is
then kept in arrival order, and the deadband's decoder counts an overtaken packet as stale.

FEC and ARQ keep a sample history (X: the decoder's held samples as `Reconstructor`'s, the
sender's samples, ARQ's pending ones) and ARQ runs its ACK link in the kernel too (its own arrays
and random numbers); ARQ may send several packets a tick (its retransmissions), so its arrays are
sized for every pending sample retransmitted in one tick.

The random numbers are the effect's own: drawn here in blocks from the effect's numpy Generator,
the numbers `UniformSource` hands out one at a time in the Python loop (`rng.random(n)` continues
one stream whatever the block sizes; Gilbert-Elliott takes two per packet, the transition then
the loss). The kernel never runs out: before the kernel runs the next ticks (up to
`windows.READY_TICKS` of them) `CodecNet.ready` tops the numbers up to what their
packets may take and makes room for their records.

This module is the Python side (the layouts of the kernel's per-direction arrays are in
engine/compiled/codec_layout.py); it needs no numba. What it cannot run is said by `codec_reason`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from haptic_teleop.assembly.channel import CodecChannel
from haptic_teleop.core import codec_layout as L
from haptic_teleop.core.deadband import DeadbandDecoder, GroupedDeadbandEncoder
from haptic_teleop.core.delay import ConstantDelay, Delay
from haptic_teleop.core.fec import fec_scratch, payload_floats
from haptic_teleop.core.hli_codec import HliDecoder, HliEncoder
from haptic_teleop.core.link import Link
from haptic_teleop.core.loss import BernoulliLoss, Blackout, FourStateLoss, GilbertElliottLoss, TraceLoss
from haptic_teleop.core.uniform import NetemCorrelatedUniform, UniformSource, jitter_table

_BLOCK = 4096  # random numbers drawn per refill
ARQ_MAX_SPAN_S = 2.0  # how long ARQ may keep a sample pending in the compiled loop (array sizes)


def codec_reason(ch: CodecChannel, kinds: tuple[str, ...] = L.COMPILED_KINDS) -> str | None:
    """Why the compiled loop cannot run codec direction `ch` (None: it can); `kinds`: the codecs
    that loop compiles (the arm loop's: codec_layout.ARM_COMPILED_KINDS)."""
    if ch.kind not in kinds:
        return (
            f"codec {ch.kind} on the {ch.direction} link runs in the Python loop only "
            f"(compiled codecs: {', '.join(kinds)})"
        )
    if ch.kind == "arq":
        enc = ch.encoder
        span_s = (enc.max_retransmissions + 1) * enc.timeout_ns * 1e-9
        if span_s > ARQ_MAX_SPAN_S:
            return (
                f"arq on the {ch.direction} link keeps a sample up to (max_retransmissions + 1) timeout_s = "
                f"{span_s:g} s (compiled: at most {ARQ_MAX_SPAN_S:g} s)"
            )
        assert ch.ack_link is not None
        why = link_reason(f"{ch.direction}:ack", ch.ack_link)
        if why is not None:
            return why
    return link_reason(ch.direction, ch.link, jitter=ch.kind == "deadband")


def link_reason(direction: str, link: Link, jitter: bool = False) -> str | None:
    """Why the kernel cannot run `link`'s effects for a codec direction (None: it can); `jitter`:
    the direction's decoder takes packets out of order (the deadband's), so the link may jitter."""
    allowed = (
        "compiled codec links take only blackout, loss (uncorrelated or netem-correlated bernoulli, "
        "gilbert(_elliott), four_state or trace) and a constant delay (a deadband's also uncorrelated or "
        "netem-correlated jitter, with or without keep_order): effects that decide a packet's fate and "
        "arrival from its index in the stream and its send time"
    )
    for e in link.effects:
        t = type(e)
        if t is BernoulliLoss and not e.vectorized and _netem(e._u) is None:  # type: ignore[attr-defined]
            return f"gaussian_copula-correlated loss on the {direction} link with a codec ({allowed})"
        if t is Delay and jitter:
            why = _jitter_reason(e)  # type: ignore[arg-type]
            if why is not None:
                return f"{why} on the {direction} link with a codec ({allowed})"
            continue
        if t not in (Blackout, BernoulliLoss, GilbertElliottLoss, FourStateLoss, TraceLoss, ConstantDelay):
            return f"effect {e.name} ({t.__name__}) on the {direction} link with a codec ({allowed})"
    return None


def _jitter_reason(e: Delay) -> str | None:
    """What of a Delay the kernel does not run (None: it runs it)."""
    if e._profile is not None:
        return "a time-varying delay (schedule, sinusoid or trace)"
    if e._ru is not None:
        return "reordering"
    if e._ju is not None and not isinstance(getattr(e._ju, "__self__", None), UniformSource | NetemCorrelatedUniform):
        return "gaussian_copula-correlated jitter"
    return None


def _netem(draw: Any) -> NetemCorrelatedUniform | None:
    """The netem-correlated source behind an effect's draw function (None: another source)."""
    src = getattr(draw, "__self__", None)
    return src if type(src) is NetemCorrelatedUniform else None


def _stream(draw: Any) -> tuple[UniformSource, float, float]:
    """An effect's uniform numbers (its draw function: a loss's `_u`, a jitter's `_ju`) as the
    kernel takes them: the `UniformSource` they come from, netem's correlation (0: none) and its
    last correlated number."""
    src = _netem(draw)
    if src is not None:
        return src._fresh.__self__, src._rho, src._last  # type: ignore[attr-defined, return-value]
    return draw.__self__, 0.0, 0.0


class LinkArrays:
    """A link run in the kernel: C's link fields, S, the random numbers U, the blackout windows,
    the in-flight ring and the records (codec_layout); topped up between chunks, written back."""

    C: np.ndarray
    S: np.ndarray
    per_tick = 1
    _ring_width = L.RING_WIDTH  # an arm scene's directions: wider (arm_host.ArmCodecNet)

    def _load(self, link: Link, C: np.ndarray, S: np.ndarray, period_ns: int, per_tick: int = 0) -> None:
        if per_tick:
            self.per_tick = per_tick
        self.link = link
        self._loss: Any = None
        self._blackout: Blackout | None = None
        windows: list[tuple[int, int]] = []
        delay_ns = 0
        jitter_ns = 0  # the longest a Delay with jitter holds a packet
        self._jitter: Delay | None = None
        self.jitter_table = np.zeros(0)
        for e in link.effects:
            if type(e) is ConstantDelay:
                delay_ns += e.delay_ns
            elif type(e) is Delay:  # (`link_reason`: a deadband's; no profile, no reorder, no copula)
                self._jitter = e
                table = () if e.distribution == "uniform" else jitter_table(e.distribution)
                self.jitter_table = np.array(table, dtype=float)
                C[L.C_JIT], C[L.C_JN], C[L.C_JKEEP] = 1.0, len(self.jitter_table), 1.0 if e._keep_order else 0.0
                C[L.C_JBASE_NS], C[L.C_JSIGMA_NS] = e._base_ns, e._sigma_ns
                S[L.S_LAST_ARRIVAL] = e._last_arrival
                # the longest delay: the table's largest value (uniform: 1) jitters
                top = 1.0 if len(self.jitter_table) == 0 else max(0.0, float(self.jitter_table.max()))
                jitter_ns = int(e._base_ns + e._sigma_ns * top + 1.0)
            elif type(e) is Blackout:
                self._blackout = e
                windows = [(int(a), int(b)) for a, b in e.windows]
            elif type(e) is BernoulliLoss:
                self._loss = e
                C[L.C_LOSS], C[L.C_LP] = L.LOSS_BERNOULLI, e.probability
            elif type(e) is GilbertElliottLoss:
                self._loss = e
                C[L.C_LOSS] = L.LOSS_GILBERT
                C[L.C_LP], C[L.C_LR], C[L.C_LBAD], C[L.C_LGOOD] = e.p, e.r, e.loss_bad, e.loss_good
            elif type(e) is FourStateLoss:
                self._loss = e
                C[L.C_LOSS] = L.LOSS_FOUR_STATE
                C[L.C_LP], C[L.C_LR], C[L.C_LBAD], C[L.C_LGOOD] = e.p13, e.p31, e.p32, e.p23
                C[L.C_LP14] = e.p14
            elif type(e) is TraceLoss:
                self._loss = e
                C[L.C_LOSS], C[L.C_LP] = L.LOSS_TRACE, 1.0 if e._repeat else 0.0
        C[L.C_DELAY_NS] = delay_ns
        self.C = C
        self.blackouts = np.array(windows, dtype=np.int64).reshape(-1, 2)
        draws = {L.LOSS_NONE: 0, L.LOSS_BERNOULLI: 1, L.LOSS_GILBERT: 2, L.LOSS_FOUR_STATE: 1, L.LOSS_TRACE: 0}
        self._draws_per_packet = draws[C[L.C_LOSS]]
        self._rng = None
        if type(self._loss) is GilbertElliottLoss:
            S[L.S_BAD] = 1.0 if self._loss.bad else 0.0
        elif type(self._loss) is FourStateLoss:
            S[L.S_BAD] = self._loss.state
        self.S = S
        self.U = np.zeros(0)
        if type(self._loss) is TraceLoss:  # U: its pattern; S_U: the packets so far
            self.U = np.array(self._loss._pattern, dtype=float)
            S[L.S_U], S[L.S_U_END] = self._loss._n, len(self.U)
        elif self._loss is not None:  # the numbers left of its source's last block first (`ready`:
            # then the Generator's; netem's source drew its first block when it was built)
            src, C[L.C_LRHO], S[L.S_LLAST] = _stream(self._loss._u)
            self._rng = src._rng
            self.U = np.array(src.take_rest())
            S[L.S_U], S[L.S_U_END] = 0.0, float(len(self.U))
        depth = 4
        # in flight: at most the ticks of the delay, + 2, times the packets a tick
        while depth < ((delay_ns + jitter_ns) // period_ns + 3) * self.per_tick:
            depth *= 2
        self.ring = np.zeros((depth, self._ring_width))
        self.records = np.zeros((1024, 6))

    def ready(self, ticks: int) -> None:
        """Before the kernel runs `ticks` ticks: random numbers and record rows for `per_tick`
        packets a tick."""
        S = self.S
        need = ticks * self.per_tick * self._draws_per_packet
        u, end = int(S[L.S_U]), int(S[L.S_U_END])
        if need and end - u < need:
            assert self._rng is not None
            fresh = self._rng.random(max(_BLOCK, need if self.per_tick == 1 else 4 * need))
            self.U = np.concatenate((self.U[u:end], fresh))
            S[L.S_U], S[L.S_U_END] = 0.0, float(len(self.U))
        recs, rows = int(S[L.S_RECS]), ticks * self.per_tick
        if len(self.records) - recs < rows:
            grown = np.zeros((2 * (recs + rows), 6))
            grown[:recs] = self.records[:recs]
            self.records = grown

    def store_link(self) -> None:
        """The link's and its effects' counts and the Gilbert state, as the kernel left them."""
        S = self.S
        link = self.link
        link.sent, link.lost = int(S[L.S_LINK_SENT]), int(S[L.S_LINK_LOST])
        if self._jitter is not None:
            self._jitter._last_arrival = int(S[L.S_LAST_ARRIVAL])
            if (src := _netem(self._jitter._ju)) is not None:
                src._last = S[L.S_JLAST]
        if self._blackout is not None:
            self._blackout.dropped = int(S[L.S_DROP_BLACKOUT])
        if self._loss is not None:
            self._loss.dropped = int(S[L.S_DROP_LOSS])
            if type(self._loss) is BernoulliLoss and (src := _netem(self._loss._u)) is not None:
                src._last = S[L.S_LLAST]
            if type(self._loss) is GilbertElliottLoss:
                self._loss.bad = bool(S[L.S_BAD])
            elif type(self._loss) is FourStateLoss:
                self._loss.state = int(S[L.S_BAD])
            elif type(self._loss) is TraceLoss:
                self._loss._n = int(S[L.S_U])

    def args(self) -> tuple[np.ndarray, ...]:
        """The kernel's arguments for this direction (re-read after `ready`: it may replace arrays)."""
        return self.C, self.S, self.U, self.blackouts, self.ring, self.records


# The encoder's and the decoder's counters of each compiled kind: where the kernel keeps them in S
# (`CodecNet.store` writes them back; the deadband's and HLI's objects take their state instead).
STORED_COUNTERS: dict[str, tuple[dict[str, int], dict[str, int]]] = {
    "prediction": (
        {"samples": L.S_OFFERED, "sent": L.S_SENT, "bytes": L.S_BYTES},
        {"received": L.S_RECEIVED, "duplicates": L.S_DUPLICATES},
    ),
    "arq": (
        {
            "samples": L.S_OFFERED,
            "sent": L.S_SENT,
            "retransmitted": L.S_RETRANSMITTED,
            "acked": L.S_ACKED,
            "acks_stale": L.S_ACKS_STALE,
            "gave_up": L.S_GAVE_UP,
            "bytes": L.S_BYTES,
        },
        {},  # (the decoder: `load`)
    ),
    "fec": ({"samples": L.S_OFFERED, "sent": L.S_SENT, "bytes": L.S_BYTES}, {}),  # (the decoder: `load`)
}


class CodecNet(LinkArrays):
    """One codec direction of the compiled loop: the kernel's arrays and what Python does between
    chunks (random numbers, records, the counters written back)."""

    # The arrays' sizes, where the trigger flags start, the in-flight ring's width, and the
    # places of X's, W's and the ring's columns that differ from codec_layout's (an arm scene's
    # directions: arm_host.ArmCodecNet, codec_layout's ARM_* layout and ARM_LAYOUT).
    _c_size, _trig0, _s_size, _ring_width = L.C_SIZE_X, L.C_TRIG0, L.S_SIZE_X, L.RING_WIDTH
    _places: ClassVar[dict[str, int]] = {}

    def _at(self, name: str) -> int:
        """codec_layout's place `name` in this direction's layout."""
        return self._places.get(name, getattr(L, name))  # type: ignore[no-any-return]

    def __init__(self, ch: CodecChannel, period_ns: int) -> None:
        self.ch = ch
        self.period_ns = period_ns
        C = np.zeros(self._c_size)
        C[L.C_DIM] = ch.dim
        C[L.C_PERIOD_NS] = period_ns
        enc, dec = ch.encoder, ch.decoder
        if ch.kind == "deadband":  # the constants the encoder and the decoder hold (core/deadband.py)
            assert type(enc) is GroupedDeadbandEncoder and type(dec) is DeadbandDecoder
            C[L.C_KIND] = L.DEADBAND
            for k in (L.C_SIZE, L.C_P0, L.C_MIN, L.C_GAIN, L.C_PMAX, L.C_SENDS_RATE, L.C_VEL):
                C[k] = enc.C[k]
            C[L.C_EXTRAP], C[L.C_MAX_AHEAD] = dec.C[L.C_EXTRAP], dec.C[L.C_MAX_AHEAD]
            C[self._trig0 : self._trig0 + ch.dim] = enc.C[enc.trig0 : enc.trig0 + ch.dim]
        elif ch.kind == "hli":  # the constants the encoder and the decoder hold (core/hli_codec.py)
            assert type(enc) is HliEncoder and type(dec) is HliDecoder
            C[L.C_KIND] = L.HLI
            for k in range(L.C_HN, L.C_HDELAY):  # N_HLI1 .. the sizes by class
                C[k] = enc.C[k]
            C[L.C_HDELAY] = dec.C[L.C_HDELAY]
        else:
            fec, arq = ch.kind == "fec", ch.kind == "arq"
            C[L.C_KIND] = L.FEC if fec else L.ARQ if arq else L.PREDICTION
            floats = payload_floats(enc.scheme, enc.k, ch.dim) if fec else ch.dim + 1 if arq else ch.dim
            C[L.C_SIZE] = enc._size_of(floats)
            rec = dec.rec
            C[L.C_EXTRAP] = 1.0 if rec.extrapolates else 0.0
            C[L.C_KEEP] = rec.keep_ticks
            C[L.C_MAX_TICKS] = rec.max_extrapolation_ticks
            C[L.C_WAIT] = rec.wait_ticks
            if fec:
                C[L.C_PARITY] = 1.0 if enc.scheme == "parity" else 0.0
                C[L.C_K] = enc.k
            if arq:
                C[L.C_TIMEOUT_NS], C[L.C_NU], C[L.C_ACK_SIZE] = enc.timeout_ns, enc.max_retransmissions, dec._ack_size
                C[L.C_M_TICKS] = -(-int(enc.timeout_ns) // period_ns)
                C[L.C_ACK_EVERY] = dec.ack_every_ticks
                if dec.ack_every_ticks > 1:  # the data packets of k ticks: 1 + nu a tick at most
                    C[L.C_ACK_CAP] = dec.ack_every_ticks * (1 + enc.max_retransmissions)
        # Packets a tick at most: one, and with ARQ nu retransmissions: a sample is due every
        # m = ceil(mu / period) ticks after it was sent, so at tick n only n - j m (j = 1 .. nu)
        # can go out again (n - (nu + 1) m is given up). A sample is pending for at most `span`.
        self.span = 0
        self.per_tick = 1
        if ch.kind == "arq":
            self.span = (int(C[L.C_NU]) + 1) * -(-int(C[L.C_TIMEOUT_NS]) // period_ns) + 2
            self.per_tick = 1 + int(C[L.C_NU])
        S = np.zeros(self._s_size)
        S[L.S_NEWEST] = -1.0
        if ch.kind == "arq":
            S[L.S_AK_NEWEST], S[L.S_AK_LAST_N] = -1.0, -1e18  # nothing received, no ACK yet
            S[L.S_FB_N] = -1e18  # no cumulative ACK taken yet (all its seqs are looked up)
        self._load(ch.link, C, S, period_ns)
        self.ack: LinkArrays | None = None
        if ch.kind == "arq":
            assert ch.ack_link is not None
            aC = np.zeros(L.C_SIZE_X)
            aC[L.C_PERIOD_NS] = period_ns
            aC[L.C_SIZE] = C[L.C_ACK_SIZE]
            self.ack = LinkArrays()
            cap = int(C[L.C_ACK_CAP])
            if cap:  # a cumulative ACK's ring row: its bitmap, count and the seqs below the window
                self.ack._ring_width = max(L.RING_WIDTH, L.ACK_RING_OLD + cap)
            self.ack._load(ch.ack_link, aC, np.zeros(L.S_SIZE_X), period_ns, self.per_tick)
            if not cap:  # an ACK per data packet: taken D ticks after it is sent (codec_arq.arq_block);
                # the ACK link's ring holds those on their way as (tick taken, taken or stale)
                C[L.C_ACK_TICKS] = max(1, -(-int(aC[L.C_DELAY_NS]) // period_ns))
                self.ack.ring[:, 0] = -1.0
        # The sample history (FEC, ARQ): the decoder's held samples reach keep_ticks back, the
        # sender's the packets in flight and k more (FEC; parity: and keep_ticks) or the pending
        # span (ARQ); the scratch's
        # worklist: at most k per recovery.
        self.X, self.W, _ = no_history()
        if C[L.C_JIT] != 0.0:  # a deadband's jitter: its table, then its uniform numbers (`ready`)
            assert self._jitter is not None and self._jitter._ju is not None
            # (netem's source drew its first block when it was built: the rest of it comes first)
            src, C[L.C_JRHO], S[L.S_JLAST] = _stream(self._jitter._ju)
            rest = src.take_rest()
            self.W = np.concatenate((self.jitter_table, rest))
            S[L.S_JU], S[L.S_JU_END] = 0.0, float(len(rest))
            self._jitter_rng = src._rng
        if ch.kind == "hli":
            # X: a packet's row until it is played (the link's delay and twice N_HLI1 at most)
            N = int(C[L.C_HN])
            rows = 4
            while rows < 2 * (C[L.C_DELAY_NS] // period_ns + 2 * (N + C[L.C_HDELAY]) + 8):
                rows *= 2
            self.X = np.zeros((rows, self._at("H_WIDTH")))
            self.X[:, self._at("H_RTAG")] = L.H_NONE
            self.X[:, self._at("H_BTAG")] = L.H_NONE
            self.W = np.array(enc.W, dtype=np.float64)  # the pattern and the empty rate window
            S[L.S_ESINCE] = enc.S[L.S_ESINCE]
        if ch.kind == "prediction":  # the decoder's held samples (core/prediction.py's Reconstructor)
            rows = 4
            while rows < C[L.C_KEEP] + 2:
                rows *= 2
            self.X = np.full((rows, self._at("X_WIDTH")), -1.0)
        if ch.kind in ("fec", "arq"):
            rows = 4
            # (FEC: a packet's payload is made from them when it arrives)
            sender = C[L.C_DELAY_NS] // period_ns + C[L.C_K] + 3
            # (ARQ: a sample's last copy arrives up to the delay after its span; its value is read
            # from the sender's column of its row then)
            arq_values = self.span + C[L.C_DELAY_NS] // period_ns + 2 if ch.kind == "arq" else 0
            while rows < max(C[L.C_KEEP] + 2, sender, self.span + 2, arq_values):
                rows *= 2
            self.X = np.zeros((rows, self._at("X_WIDTH")))
            self.X[:, self._at("X_HELD")] = -1.0
            self.X[:, self._at("X_SUM_SEQ")] = -1.0  # (ARQ: X_PEND)
            if ch.kind == "fec":  # the worklist, the payload, the recovery log (core/fec.py)
                k, keep = int(C[L.C_K]), int(C[L.C_KEEP])
                C[L.C_WPAY], C[L.C_WLOG], size = fec_scratch(k, keep, ch.dim, self._at("W_TERMS"))
                self.W = np.zeros(size)
            else:
                self.W = np.zeros(self._at("W_STACK") + 1)
            cap = int(C[L.C_ACK_CAP])
            if cap:  # ARQ's cumulative ACKs: the seqs below the window, the ACK's size by their count
                w_old = self._at("W_OLD")
                self.W = np.zeros(w_old + 2 * cap + 2)
                for j in range(cap + 1):
                    self.W[w_old + cap + 1 + j] = dec._size_of(2 + j)
            if ch.kind == "arq":  # its plan after the rest (`codec_arq.arq_block`)
                C[L.C_PLAN] = len(self.W)
                plan = L.PLAN_TICKS * (L.P_WIDTH + int(C[L.C_NU]) + 2)
                self.W = np.concatenate((self.W, np.zeros(plan)))

    def ready(self, ticks: int) -> None:
        """Before the kernel runs `ticks` ticks: random numbers and record rows for the packets
        they may send (the kernel writes none for the ACK link: they are not kept)."""
        LinkArrays.ready(self, ticks)
        if self.ack is not None:
            self.ack.ready(ticks)
        if self.C[L.C_JIT] != 0.0:  # a number a packet (one packet a tick at most)
            S, n = self.S, int(self.C[L.C_JN])
            u, end = int(S[L.S_JU]), int(S[L.S_JU_END])
            if end - u < ticks:
                fresh = self._jitter_rng.random(max(_BLOCK, ticks))
                self.W = np.concatenate((self.jitter_table, self.W[n + u : n + end], fresh))
                S[L.S_JU], S[L.S_JU_END] = 0.0, float(len(self.W) - n)

    def settled(self, sent: int, final: bool) -> np.ndarray | None:
        """As `CodecChannel.settled`: the records of packets sent before tick `sent` and older than
        the oldest one in flight (a packet's seq is its send tick, except ARQ's retransmissions:
        the ring keeps their send tick, the records their send time)."""
        S = self.S
        mark = sent
        col = self._at("RING_SENT") if self.C[L.C_KIND] == L.ARQ else 0
        if not final and S[L.S_COUNT] > 0:
            head, count, depth = int(S[L.S_HEAD]), int(S[L.S_COUNT]), len(self.ring)
            if self.C[L.C_JIT] != 0.0:  # in arrival order: the oldest sent is any of them
                oldest = int(self.ring[(head + np.arange(count)) & (depth - 1), col].min())
            else:
                oldest = int(self.ring[head, col])
            mark = min(mark, oldest)
        recs = int(S[L.S_RECS])
        # the records' send times are float(tick * period_ns) * 1e-9, as this mark's
        k = int(np.searchsorted(self.records[:recs, 1], float(mark * int(self.C[L.C_PERIOD_NS])) * 1e-9))
        if k == 0:
            return None
        rows = self.records[:k].copy()
        self.records[: recs - k] = self.records[k:recs]
        S[L.S_RECS] = recs - k
        return rows

    def store(self) -> None:
        """Write what the kernel decided back into the Python objects (the run facts read the
        codec's counters; the link's and its effects' counts and the Gilbert state follow too)."""
        S, ch = self.S, self.ch
        enc, dec = ch.encoder, ch.decoder
        if ch.kind == "arq" and self.C[L.C_ACK_EVERY] <= 1.0:
            # the kernel counted each ACK as it was sent: those still on their way are not the
            # encoder's yet (taken at a tick the run did not reach)
            assert self.ack is not None
            on_way = self.ack.ring[self.ack.ring[:, 0] >= S[L.S_OFFERED]]
            taken = int(np.count_nonzero(on_way[:, 1]))
            S[L.S_ACKED] -= taken
            S[L.S_ACKS_STALE] -= len(on_way) - taken
            self.ack.ring[:, 0] = -1.0  # (counted back once)
        if ch.kind == "deadband":  # the encoder's and decoder's whole state (core/deadband.py)
            enc.load(S, self._at("S_SENT0"), self._at("S_PREV0"))
            dec.load(S, self._at("S_LAST0"), self._at("S_OLD0"), self._at("S_RATE0"))
        elif ch.kind == "hli":  # their counters and scalars, from S (core/hli_codec.py)
            enc.load(S)
            dec.load(S)
        else:
            enc_counts, dec_counts = STORED_COUNTERS[ch.kind]
            enc.counters.update({name: int(S[k]) for name, k in enc_counts.items()})
            if ch.kind in ("fec", "arq"):  # its counters and its history's scalars, from S
                dec.load(S)  # (its recovered_log, for a reader of the decoder alone, stays empty)
            else:
                dec.counters.update({name: int(S[k]) for name, k in dec_counts.items()})
        if ch.kind == "prediction":
            dec.rec.load(S)
        if ch.kind == "arq":
            ch.ack_packets, ch.ack_bytes = int(S[L.S_ACK_PACKETS]), int(S[L.S_ACK_BYTES])
            assert self.ack is not None
            self.ack.store_link()
        ch.newest_seq = int(S[L.S_NEWEST])
        self.store_link()

    def history(self) -> tuple[Any, ...]:
        """The kernel's sample history, scratch and ACK link for this direction (X, W, A)."""
        return self.X, self.W, (no_codec(1) if self.ack is None else self.ack.args())


def no_history() -> tuple[Any, ...]:
    """X, W and A of a direction whose codec keeps no sample history (or that has no codec)."""
    return np.full((1, L.X_WIDTH), -1.0), np.zeros(1), no_codec(1)


def no_codec(period_ns: int) -> tuple[np.ndarray, ...]:
    """The kernel's arguments for a direction without a codec (C_KIND 0: it runs on its schedule)."""
    C = np.zeros(L.C_SIZE_X)
    C[L.C_PERIOD_NS] = period_ns
    return (
        C,
        np.zeros(L.S_SIZE_X),
        np.zeros(1),
        np.zeros((0, 2), dtype=np.int64),
        np.zeros((1, L.RING_WIDTH)),
        np.zeros((1, 6)),
    )
