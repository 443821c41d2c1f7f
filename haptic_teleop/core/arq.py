"""Automatic repeat request over the same lossy network in both directions: a baseline of seed 000.

Seed 000's parameters are a retransmission timeout mu and at most nu retransmissions; the
experiment uses (mu = 25 ms, nu = 4) and (mu = 4 ms, nu = 1) (`SEED_000_EXPERIMENT`).

Protocol (positive acknowledgement per sample, selective repeat):
- Sender: each tick sends the new sample (attempt 0). It keeps every unacknowledged sample with
  the time of its last transmission. At the first tick at least mu after that transmission
  without an ACK it retransmits the sample (attempt + 1), at most nu times; when the nu-th
  retransmission has gone mu without an ACK it gives the sample up (counter `gave_up`). An ACK
  removes the sample from the pending set, whichever transmission it acknowledges.
- Receiver: acknowledges every data packet it is handed, duplicates included (so a lost ACK is
  repaired by the ACK of the retransmission it causes; the duplicate sample is ignored). ACKs go
  back over the reverse direction's Link with its own effects and can be lost too; a lost ACK
  costs one needless retransmission (a harmless duplicate at the receiver).
- Playing: an original transmission newer than anything received is played at once; a
  retransmitted sample joins the history and is played only if its slot has not passed (never
  with wait_ticks 0 unless it arrives in the same tick as its slot would be played); otherwise
  it is kept for the record (`recovered_log`, counter `recovered_late`) and improves the
  extrapolation base. Ticks with nothing are predicted (`core.prediction.Reconstructor`).

Layouts: data payload = sample (d floats), attempt number (0 = original, 1..nu = retransmission);
size `size_of(d + 1)`. ACK payload = (seq,) with `Packet.seq` = the acknowledged seq; size
`size_of(1)`. Costs: one ACK per received data packet on the reverse path, plus one data packet
per retransmission; no added latency for what is played (nothing waits for a retransmission).

Cumulative selective ACKs (`ack_every_ticks` k > 1; k = 1 is the per-packet ACK above): the
receiver ACKs nothing in `receive`; at the end of each tick's deliveries (`acks`) it sends one
ACK if it received any data packet (duplicates included) since its last ACK and its last ACK is
at least k ticks old (so at most one every k ticks, and none on quiet ticks). ACK payload =
(N, B, r_1, .., r_j): N the newest seq received so far (`Packet.seq` = N), B a bitmap of the
`ACK_WINDOW` = 52 seqs below it, bit i set when seq N - 1 - i was received (a float64 holds it
exactly: B < 2^52), then the seqs received since the last ACK that lie below the window
(retransmissions of old samples, each named once); size `size_of(2 + j)`. The sender takes every
seq named as acknowledged. ACK loss: the bitmap repeats in every ACK, so a seq within the window
is acknowledged again by each later ACK; with a constant delay the originals of 2k ticks fit in
52 bits for k <= 26 (`ack_every_ticks`' maximum), so one lost ACK (up to 52 / k - 1 in a row)
costs no retransmission if the next ACK arrives before the timeout, i.e. when
(k - 1) period + round trip < mu; a seq below the window (a retransmission) is named once, as
k = 1 names it: its lost ACK costs one more retransmission, whose duplicate is ACKed again.
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
    ticks,
)

KIND = "arq"
ACK_WINDOW = 52  # seqs below the newest in a cumulative ACK's bitmap (a float64 holds 2^52 - 1 exactly)


@dataclass(frozen=True)
class ArqConfig:
    """Codec `arq`: retransmit after `timeout_s` (mu) without an ACK, at most `max_retransmissions` (nu)."""

    timeout_s: float = field(
        default=0.025, metadata={"gt": 0.0, "max": 10.0, "help": "mu: retransmit a sample not acknowledged this long"}
    )
    max_retransmissions: int = field(
        default=4, metadata={"min": 0, "max": 100, "help": "nu: retransmissions per sample, then give it up"}
    )
    wait_ticks: int = field(
        default=0,
        metadata={"min": 0, "max": 10000, "help": "play this many ticks late so retransmissions are in time"},
    )
    gap: str = field(
        default="extrapolate",
        metadata={"choices": GAP_MODES, "help": "missing tick: extrapolate the last two samples or hold"},
    )
    max_extrapolation_s: float = field(
        default=0.05, metadata={"min": 0.0, "max": 10.0, "help": "extrapolate at most this far, then hold"}
    )
    ack_every_ticks: int = field(
        default=1,
        metadata={
            "min": 1,
            "max": ACK_WINDOW // 2,
            "help": "1: an ACK per data packet; k > 1: one cumulative selective ACK at most every k ticks",
        },
    )

    def __post_init__(self) -> None:
        check_fields(self)


# Seed 000's experiment (slide 51): prediction + ARQ with (mu, nu) = (25 ms, 4) and (4 ms, 1).
SEED_000_EXPERIMENT = (
    ArqConfig(timeout_s=0.025, max_retransmissions=4),
    ArqConfig(timeout_s=0.004, max_retransmissions=1),
)


# The sender's rules as plain functions: the one definition `ArqEncoder` calls and the compiled
# loops' plan inlines (engine/compiled/codec_arq.py).
WAIT, GIVE_UP, RETRANSMIT = 0, 1, 2


def retry_verdict(tries: float, last_ns: float, now_ns: float, timeout_ns: float, max_retransmissions: float) -> int:
    """A pending sample at `now_ns`, retransmitted `tries` times so far, last sent at `last_ns`:
    WAIT while that transmission is less than mu old, then GIVE_UP after nu retransmissions, else
    RETRANSMIT (one more try, sent now)."""
    if now_ns - last_ns < timeout_ns:
        return WAIT
    if tries >= max_retransmissions:
        return GIVE_UP
    return RETRANSMIT


def named_mask(bits: int) -> int:
    """A cumulative ACK (N, B, ...) as one mask: bit i names seq N - i (N itself; bit i of B names
    N - 1 - i)."""
    return (bits << 1) | 1


class ArqEncoder:
    """Sender side: new samples, retransmissions after `timeout_ns`, at most `max_retransmissions`.

    Counters: `samples`, `sent` (data packets, retransmissions included), `retransmitted`,
    `acked` (samples acknowledged), `acks_stale` (ACKs for samples no longer pending),
    `gave_up`, `bytes`. `pending` is the number of samples awaiting an ACK.
    """

    def __init__(self, timeout_ns: int, max_retransmissions: int, size_of: SizeOf = float64_multiarray_size) -> None:
        if not timeout_ns > 0:
            raise ValueError(f"timeout_ns must be > 0, got {timeout_ns}")
        if max_retransmissions < 0:
            raise ValueError(f"max_retransmissions must be >= 0, got {max_retransmissions}")
        self.timeout_ns, self.max_retransmissions = timeout_ns, max_retransmissions
        self._size_of = size_of
        # seq -> [sample, retransmissions so far, time of the last transmission]; insertion = seq order
        self._pending: dict[int, tuple[Sample, int, int]] = {}
        self.counters: dict[str, int] = {
            "samples": 0,
            "sent": 0,
            "retransmitted": 0,
            "acked": 0,
            "acks_stale": 0,
            "gave_up": 0,
            "bytes": 0,
        }

    @property
    def pending(self) -> int:
        return len(self._pending)

    def _packet(self, seq: int, now_ns: int, sample: Sample, attempt: int) -> Packet:
        payload = (*sample, float(attempt))
        size = self._size_of(len(payload))
        self.counters["sent"] += 1
        self.counters["bytes"] += size
        return Packet(seq, now_ns, payload, size)

    def send(self, n: int, now_ns: int, sample: Sample) -> list[Packet]:
        c = self.counters
        x = tuple(float(v) for v in sample)
        c["samples"] += 1
        out = [self._packet(n, now_ns, x, 0)]
        pending = self._pending
        for seq, (value, tries, last_ns) in list(pending.items()):
            verdict = retry_verdict(tries, last_ns, now_ns, self.timeout_ns, self.max_retransmissions)
            if verdict == WAIT:
                continue
            if verdict == GIVE_UP:
                del pending[seq]
                c["gave_up"] += 1
                continue
            pending[seq] = (value, tries + 1, now_ns)
            c["retransmitted"] += 1
            out.append(self._packet(seq, now_ns, value, tries + 1))
        pending[n] = (x, 0, now_ns)
        return out

    def feedback(self, packet: Packet, now_ns: int) -> None:
        """An ACK from the receiver: payload (seq,) with `packet.seq` the acknowledged sample, or a
        cumulative one (N, B, r...) acknowledging every seq it names (module docstring); `acked`
        counts the samples it acknowledged, `acks_stale` the ACKs that acknowledged none."""
        pending = self._pending
        if len(packet.payload) == 1:
            if pending.pop(packet.seq, None) is None:
                self.counters["acks_stale"] += 1
            else:
                self.counters["acked"] += 1
            return
        acked = 0
        for seq in cumulative_seqs(packet.payload):
            if pending.pop(seq, None) is not None:
                acked += 1
        if acked:
            self.counters["acked"] += acked
        else:
            self.counters["acks_stale"] += 1


def cumulative_seqs(payload: tuple[float, ...]) -> list[int]:
    """The seqs a cumulative ACK (N, B, r...) names: N, N - 1 - i for each bit i of B, the r."""
    newest, mask = int(payload[0]), named_mask(int(payload[1]))
    out = []
    i = 0
    while mask:
        if mask & 1:
            out.append(newest - i)
        mask >>= 1
        i += 1
    out.extend(int(r) for r in payload[2:])
    return out


# The receiver's cumulative ACKs as functions over codec_layout arrays: the one definition
# `ArqDecoder` calls and the compiled loops inline (engine/compiled/codec_arq.py). C: C_ACK_EVERY
# (k), C_ACK_CAP (room for the seqs below the window); S: S_AK_NEWEST (the newest seq received,
# -1 none), S_AK_BITS and S_AK_NEW (bit i: seq newest - i received, ever and since the last ACK;
# 53 bits, exact in a float64), S_AK_DUE, S_AK_LAST_N (the tick of the last ACK; far in the past
# before the first), S_AK_OLD (how many seqs below the window the next ACK names, in W from
# `wold`).
ACK_WIDTH = ACK_WINDOW + 1  # the newest seq and the window below it


def ack_old(C: Any, S: Any, W: Any, seq: int, wold: int) -> None:
    """A seq below the window joins the list the next ACK names (while there is room)."""
    cnt = int(S[L.S_AK_OLD])
    if cnt < C[L.C_ACK_CAP]:
        W[wold + cnt] = seq
        S[L.S_AK_OLD] = cnt + 1


def ack_mark(C: Any, S: Any, W: Any, seq: int, wold: int) -> None:
    """A data packet of `seq` received: into the window's bitmaps; a seq of the since-last-ACK map
    pushed out of the window by a newer one, or a seq received below the window (once), onto the
    list the next ACK names."""
    S[L.S_AK_DUE] = 1.0
    newest = int(S[L.S_AK_NEWEST])
    if seq > newest:
        shift = seq - newest
        new = int(S[L.S_AK_NEW])
        if shift >= ACK_WIDTH:
            out, off, bits, new = new, 0, 0, 0
        else:
            off = ACK_WIDTH - shift
            keep = (1 << off) - 1
            out = new >> off
            bits = (int(S[L.S_AK_BITS]) & keep) << shift
            new = (new & keep) << shift
        i = 0
        while out != 0:  # bit i of `out`: seq newest - off - i
            if out & 1:
                ack_old(C, S, W, newest - i - off, wold)
            out >>= 1
            i += 1
        S[L.S_AK_BITS] = float(bits | 1)
        S[L.S_AK_NEW] = float(new | 1)
        S[L.S_AK_NEWEST] = seq
    elif newest - seq < ACK_WIDTH:
        b = 1 << (newest - seq)
        S[L.S_AK_BITS] = float(int(S[L.S_AK_BITS]) | b)
        S[L.S_AK_NEW] = float(int(S[L.S_AK_NEW]) | b)
    else:
        for q in range(int(S[L.S_AK_OLD])):
            if W[wold + q] == seq:
                return
        ack_old(C, S, W, seq, wold)


def ack_due(C: Any, S: Any, n: int) -> int:
    """The cumulative ACK of tick n: -1 if none is due (nothing received since the last one, or it
    is less than k ticks old); else the number of seqs below the window it names (in W from
    `wold`; its N and B are S_AK_NEWEST and S_AK_BITS / 2), and the next ACK starts here."""
    if S[L.S_AK_DUE] == 0.0 or n - S[L.S_AK_LAST_N] < C[L.C_ACK_EVERY]:
        return -1
    cnt = int(S[L.S_AK_OLD])
    S[L.S_AK_OLD] = 0.0
    S[L.S_AK_NEW] = 0.0
    S[L.S_AK_DUE] = 0.0
    S[L.S_AK_LAST_N] = n
    return cnt


# The decoder's counters and where its reconstruction's S keeps them.
DECODER_COUNTERS = {
    "received": L.S_RECEIVED,
    "duplicates": L.S_DUPLICATES,
    "acks_sent": L.S_ACKS_SENT,
    "recovered": L.S_RECOVERED,
    "recovered_late": L.S_RECOVERED_LATE,
}


class ArqDecoder:
    """Receiver side: ACKs every data packet, plays the newest, predicts over gaps.

    Counters: `received` data packets, `duplicates` (a sample already held), `acks_sent`,
    `recovered` (samples first received in a retransmission), `recovered_late` (of them, after
    their slot was played). `recovered_log` holds those samples for the record (drainable).
    """

    def __init__(
        self,
        *,
        wait_ticks: int = 0,
        gap: str = "extrapolate",
        max_extrapolation_ticks: int = 50,
        size_of: SizeOf = float64_multiarray_size,
        ack_every_ticks: int = 1,
    ) -> None:
        if not 1 <= ack_every_ticks <= ACK_WINDOW // 2:
            raise ValueError(f"ack_every_ticks must be 1 to {ACK_WINDOW // 2}, got {ack_every_ticks}")
        self.rec = Reconstructor(gap, max_extrapolation_ticks, wait_ticks)
        self._ack_size = size_of(1)
        self._size_of = size_of
        self.ack_every_ticks = ack_every_ticks
        # cumulative ACKs: the state `ack_mark` and `ack_due` act on (the receiver's reconstruction's
        # C and S, the seqs below the window in W: a list that grows, the Python list's room)
        C, S = self.rec.C, self.rec.S
        C[L.C_ACK_EVERY] = ack_every_ticks
        S[L.S_AK_NEWEST], S[L.S_AK_LAST_N] = -1.0, -1e18
        self.W: Any = []
        self.recovered_log: list[Packet] = []

    @property
    def counters(self) -> dict[str, int]:
        return self.rec.counts(DECODER_COUNTERS)

    def load(self, S: Any) -> None:
        """Take the scalar state of a decoder run elsewhere (a compiled loop's S)."""
        self.rec.load(S)

    def receive(self, packet: Packet, now_ns: int) -> list[Packet]:
        S = self.rec.S
        p = packet.payload
        if len(p) < 2:
            raise ValueError(f"arq: a data payload needs the sample and the attempt number, got {len(p)} floats")
        S[L.S_RECEIVED] += 1.0
        value, attempt = tuple(p[:-1]), int(p[-1])
        if not self.rec.add(packet.seq, value, fresh=attempt == 0):
            S[L.S_DUPLICATES] += 1.0
        elif attempt > 0:  # (counted recovered, and late, by the reconstruction)
            self.recovered_log.append(Packet(packet.seq, packet.send_time_ns, value, 0))
        if self.ack_every_ticks > 1:
            W, C = self.W, self.rec.C
            room = int(S[L.S_AK_OLD]) + ACK_WIDTH + 1  # (a mark names at most ACK_WIDTH more)
            if len(W) < room:
                W.extend([0.0] * (2 * room - len(W)))
            C[L.C_ACK_CAP] = len(W)
            ack_mark(C, S, W, packet.seq, 0)
            return []
        S[L.S_ACKS_SENT] += 1.0
        return [Packet(packet.seq, now_ns, (float(packet.seq),), self._ack_size)]

    def acks(self, n: int, now_ns: int) -> list[Packet]:
        """After tick n's deliveries: the cumulative ACK due (k > 1; module docstring), if any."""
        S = self.rec.S
        cnt = ack_due(self.rec.C, S, n)
        if cnt < 0:
            return []
        newest = int(S[L.S_AK_NEWEST])
        payload = (float(newest), float(int(S[L.S_AK_BITS]) >> 1), *(float(r) for r in self.W[:cnt]))
        S[L.S_ACKS_SENT] += 1.0
        return [Packet(newest, now_ns, payload, self._size_of(len(payload)))]

    def sample(self, n: int, now_ns: int) -> Sample | None:
        return self.rec.sample(n)


def build_arq(
    cfg: ArqConfig, period_ns: int, *, size_of: SizeOf = float64_multiarray_size
) -> tuple[ArqEncoder, ArqDecoder]:
    """Encoder and decoder of codec `arq` for a stream with one sample every `period_ns`."""
    enc = ArqEncoder(round(cfg.timeout_s * 1e9), cfg.max_retransmissions, size_of)
    dec = ArqDecoder(
        wait_ticks=cfg.wait_ticks,
        gap=cfg.gap,
        max_extrapolation_ticks=ticks(cfg.max_extrapolation_s, period_ns),
        size_of=size_of,
        ack_every_ticks=cfg.ack_every_ticks,
    )
    return enc, dec
