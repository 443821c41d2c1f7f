"""The compiled 1-DoF loop with the codec stage (numba), imported only when a scene with a codec
runs compiled, so codec-less runs never compile or load it (engine/compiled_codec.py has the
design, engine/codec_layout.py the arrays' layouts).

The tick is `axis_kernel.run_ticks`'s (the same helpers: `control`, `accept2`, `accept3`,
`finish_tick`); a direction with a codec replaces its schedule lookup by `codec_tick`, which is
`CodecChannel.step` line for line: encoder, link (blackout, loss, constant delay), deliveries,
decoder; it dispatches on the kind: deadband and prediction inlined (`deadband_prediction_tick`),
FEC, ARQ (with its ACK link) and HLI compiled once each (`fec_tick`, `arq_tick`, `hli_tick`). The
per-sample formulas are compiled from their one definition in core/deadband.py,
core/prediction.py, core/loss.py, core/hli_codec.py; the parity sums (`math.fsum` in core/fec.py's classes) from
`fec.rounded_sum`, which gives the same value.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from haptic_teleop.core import deadband as db
from haptic_teleop.core import fec, hli_codec, loss
from haptic_teleop.core import prediction as pr
from haptic_teleop.engine.axis_kernel import MASTER, S_CONTACT, SLAVE, accept2, accept3, control, finish_tick
from haptic_teleop.engine.codec_layout import (
    ARQ,
    C_ACK_SIZE,
    C_DELAY_NS,
    C_DIM,
    C_EXTRAP,
    C_GAIN,
    C_HBITS1,
    C_HBITS2,
    C_HBUDGET,
    C_HDELAY,
    C_HLINEAR,
    C_HN,
    C_HSIZE1,
    C_HSIZE2,
    C_HTHRESH,
    C_HWARMUP,
    C_HWIN,
    C_K,
    C_KEEP,
    C_KIND,
    C_LBAD,
    C_LGOOD,
    C_LOSS,
    C_LP,
    C_LR,
    C_MAX_AHEAD,
    C_MAX_TICKS,
    C_MIN,
    C_NU,
    C_P0,
    C_PARITY,
    C_PERIOD_NS,
    C_PMAX,
    C_SENDS_RATE,
    C_SIZE,
    C_TIMEOUT_NS,
    C_TRIG0,
    C_VEL,
    C_WAIT,
    DEADBAND,
    FEC,
    H_BTAG,
    H_BX,
    H_CLASS,
    H_COPY,
    H_NONE,
    H_OFF,
    H_PREV,
    H_RTAG,
    H_SMP,
    HLI,
    LOSS_BERNOULLI,
    LOSS_GILBERT,
    NO_CODEC,
    RING_ATTEMPT,
    RING_SENT,
    S_ACK_BYTES,
    S_ACK_PACKETS,
    S_ACKED,
    S_ACKS_SENT,
    S_ACKS_STALE,
    S_BAD,
    S_BLACKOUT_I,
    S_BYTES,
    S_COUNT,
    S_CUR,
    S_CURH,
    S_DLATE,
    S_DPREDICTED,
    S_DROP_BLACKOUT,
    S_DROP_LOSS,
    S_DT1,
    S_DT1H,
    S_DT2,
    S_DT2H,
    S_DUPLICATES,
    S_EH2,
    S_EPREV,
    S_EPREVH,
    S_ESEEN,
    S_ESINCE,
    S_ET1,
    S_ET1H,
    S_ET2,
    S_ET2H,
    S_EXTRAPOLATED,
    S_FILT0,
    S_FILT1,
    S_FILTERED,
    S_FRH,
    S_FRMAX,
    S_GAVE_UP,
    S_HAS_FRESH,
    S_HAS_HELD,
    S_HAS_LAST,
    S_HAS_OLD,
    S_HAS_PLAYED,
    S_HAS_PREV,
    S_HAS_RATE,
    S_HAS_SENT,
    S_HAS_SLOT,
    S_HEAD,
    S_HLI0,
    S_LAG,
    S_LAGH,
    S_LAST0,
    S_LAST_CLASS,
    S_LAST_PLAYED,
    S_LAST_SEQ,
    S_LATE,
    S_LINK_LOST,
    S_LINK_SENT,
    S_MAXHELD,
    S_MIN,
    S_MINH,
    S_NEWEST,
    S_NEWEST_FRESH,
    S_OFFERED,
    S_OLD0,
    S_OLD_SEQ,
    S_OVER,
    S_PENDING,
    S_PLAYED,
    S_PREDICTED,
    S_PREV0,
    S_PREV_NS,
    S_RATE0,
    S_REBUILT,
    S_RECEIVED,
    S_RECOVERED,
    S_RECOVERED_LATE,
    S_RECS,
    S_RETRANSMITTED,
    S_SENT,
    S_SENT0,
    S_SLOT,
    S_SLOT_N,
    S_STALE,
    S_U,
    S_WIN_BITS,
    S_WIN_COUNT,
    S_WIN_HEAD,
    S_WIRE_BITS,
    W_STACK,
    W_TERMS,
    W_VALUE,
    X_HELD,
    X_LAST_NS,
    X_PEND,
    X_SENT,
    X_SUM_SEQ,
    X_TRIES,
    X_VALUE,
)

jit = numba.njit(cache=True, nogil=True)
inline = numba.njit(cache=True, nogil=True, inline="always")  # as axis_kernel's tick parts
# The loop itself without numba's reference counting (NRT): it allocates nothing, and every
# array handed to an inlined part would otherwise be counted in and out with atomic operations,
# which cost ten times the codec's own work (180 against 15 ns a tick for `prediction`).
loop_jit = numba.njit(cache=True, nogil=True, _nrt=False)
# The FEC and ARQ ticks are compiled once (not inlined into each direction: compile time), also
# without reference counting (every array they are handed would be counted in and out).
part_jit = numba.njit(cache=True, nogil=True, _nrt=False)
deadband_p = jit(db.deadband_p)
outside = jit(db.outside)
extrapolated = jit(db.extrapolated)
extrapolate1 = jit(pr.extrapolate1)
gilbert_step = jit(loss.gilbert_step)
rounded_sum = part_jit(fec.rounded_sum)
linear1 = jit(hli_codec.linear1)

DELIVERED = 0.0
LOST_NETWORK = 1.0


@inline  # type: ignore[misc]
def link_send(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    seq: int,
    now: int,
    smp: np.ndarray,
    rate: np.ndarray,
    with_rate: bool,
) -> None:
    # Link.send of one packet: blackout, loss (its draws whatever the fate), constant delay;
    # the record; a delivered packet joins the in-flight FIFO.
    fate = DELIVERED
    nb = B.shape[0]
    if nb > 0:  # Blackout.apply: the window starting at or before `now` (send times only grow)
        i = int(S[S_BLACKOUT_I])
        while i < nb and B[i, 0] <= now:
            i += 1
        S[S_BLACKOUT_I] = i
        if i > 0 and now < B[i - 1, 1]:
            fate = LOST_NETWORK
            S[S_DROP_BLACKOUT] += 1.0
    kind = C[C_LOSS]
    if kind == LOSS_BERNOULLI:
        u = U[int(S[S_U])]
        S[S_U] += 1.0
        if u < C[C_LP] and fate == DELIVERED:
            fate = LOST_NETWORK
            S[S_DROP_LOSS] += 1.0
    elif kind == LOSS_GILBERT:
        k = int(S[S_U])
        S[S_U] += 2.0
        bad, lost = gilbert_step(S[S_BAD] != 0.0, U[k], U[k + 1], C[C_LP], C[C_LR], C[C_LBAD], C[C_LGOOD])
        S[S_BAD] = 1.0 if bad else 0.0
        if lost and fate == DELIVERED:
            fate = LOST_NETWORK
            S[S_DROP_LOSS] += 1.0
    arrival = now + int(C[C_DELAY_NS])
    S[S_LINK_SENT] += 1.0
    # (2-D arrays are indexed in full, never sliced: a view costs reference counting)
    r = int(S[S_RECS])
    S[S_RECS] += 1.0
    rec[r, 0] = seq
    rec[r, 1] = float(now) * 1e-9
    rec[r, 3] = fate
    rec[r, 4] = 0.0
    rec[r, 5] = C[C_SIZE]
    if fate != DELIVERED:
        S[S_LINK_LOST] += 1.0
        rec[r, 2] = np.nan
        return
    rec[r, 2] = float(arrival) * 1e-9
    depth = ring.shape[0]
    count = int(S[S_COUNT])
    j = (int(S[S_HEAD]) + count) & (depth - 1)
    S[S_COUNT] = count + 1
    ring[j, 0] = seq
    ring[j, 1] = arrival
    dim = int(C[C_DIM])
    for i in range(dim):
        ring[j, 2 + i] = smp[i]
        if with_rate:
            ring[j, 2 + dim + i] = rate[i]


@inline  # type: ignore[misc]
def packet_send(
    C: np.ndarray, S: np.ndarray, U: np.ndarray, B: np.ndarray, ring: np.ndarray, rec: np.ndarray,
    seq: int, now: int, value: np.ndarray, unused: np.ndarray,
) -> None:  # fmt: skip
    # An encoder's packet of `value` (no rate) counted and into Link.send.
    S[S_SENT] += 1.0
    S[S_BYTES] += C[C_SIZE]
    link_send(C, S, U, B, ring, rec, seq, now, value, unused, False)


@inline  # type: ignore[misc]
def link_next(S: np.ndarray, ring: np.ndarray, now: int) -> int:
    # Link.deliver, one packet: the ring row of the next packet due by `now` (taken off the
    # in-flight FIFO), or -1.
    if S[S_COUNT] <= 0.0:
        return -1
    head = int(S[S_HEAD])
    if ring[head, 1] > now:
        return -1
    S[S_HEAD] = (head + 1) & (ring.shape[0] - 1)
    S[S_COUNT] -= 1.0
    return head


@inline  # type: ignore[misc]
def newest(S: np.ndarray, seq: int, rx: int) -> int:
    # The `received` column's seq after a delivery of `seq` (the newest delivered so far, else rx).
    if seq > S[S_NEWEST]:
        S[S_NEWEST] = seq
        return seq
    return rx


@inline  # type: ignore[misc]
def deadband_receive(C: np.ndarray, S: np.ndarray, seq: int, ring: np.ndarray, j: int) -> None:
    # DeadbandDecoder.receive; the payload: ring row j from column 2 on.
    dim = int(C[C_DIM])
    if S[S_HAS_LAST] != 0.0 and seq <= S[S_LAST_SEQ]:
        S[S_STALE] += 1.0
        return
    S[S_RECEIVED] += 1.0
    S[S_HAS_OLD] = S[S_HAS_LAST]
    S[S_OLD_SEQ] = S[S_LAST_SEQ]
    for i in range(dim):
        S[S_OLD0 + i] = S[S_LAST0 + i]
        S[S_LAST0 + i] = ring[j, 2 + i]
    S[S_HAS_LAST] = 1.0
    S[S_LAST_SEQ] = seq
    if C[C_EXTRAP] != 0.0:
        if C[C_SENDS_RATE] != 0.0:
            dt_tick = C[C_PERIOD_NS] / 1e9
            for i in range(dim):
                S[S_RATE0 + i] = ring[j, 2 + dim + i] * dt_tick
            S[S_HAS_RATE] = 1.0
        elif S[S_HAS_OLD] != 0.0:
            span = int(S[S_LAST_SEQ]) - int(S[S_OLD_SEQ])
            for i in range(dim):
                S[S_RATE0 + i] = (S[S_LAST0 + i] - S[S_OLD0 + i]) / span
            S[S_HAS_RATE] = 1.0


@inline  # type: ignore[misc]
def deadband_sample(C: np.ndarray, S: np.ndarray, n: int, out: np.ndarray) -> bool:
    # DeadbandDecoder.sample: hold, or extrapolate at most the cap, then hold.
    if S[S_HAS_LAST] == 0.0:
        return False
    dim = int(C[C_DIM])
    seq = int(S[S_LAST_SEQ])
    if S[S_HAS_RATE] == 0.0 or n <= seq:
        for i in range(dim):
            out[i] = S[S_LAST0 + i]
        return True
    ahead = float(n - seq)
    if ahead > C[C_MAX_AHEAD]:
        ahead = C[C_MAX_AHEAD]
    else:
        S[S_EXTRAPOLATED] += 1.0
    for i in range(dim):
        out[i] = extrapolated(S[S_LAST0 + i], S[S_RATE0 + i], ahead)
    return True


@inline  # type: ignore[misc]
def prediction_receive(C: np.ndarray, S: np.ndarray, seq: int, ring: np.ndarray, j: int) -> None:
    # PredictionDecoder.receive -> Reconstructor.add(fresh=True). A constant delay keeps the order
    # and nothing is duplicated, so every arrival is the newest: the history needs only the
    # newest two samples (the older one kept while within `keep_ticks`, as `add` forgets).
    dim = int(C[C_DIM])
    S[S_RECEIVED] += 1.0
    S[S_HAS_OLD] = S[S_HAS_LAST]
    S[S_OLD_SEQ] = S[S_LAST_SEQ]
    for i in range(dim):
        S[S_OLD0 + i] = S[S_LAST0 + i]
        S[S_LAST0 + i] = ring[j, 2 + i]
    S[S_HAS_LAST] = 1.0
    S[S_LAST_SEQ] = seq
    if S[S_HAS_OLD] != 0.0 and S[S_OLD_SEQ] < seq - C[C_KEEP]:
        S[S_HAS_OLD] = 0.0
    S[S_PENDING] = 1.0


@inline  # type: ignore[misc]
def prediction_sample(C: np.ndarray, S: np.ndarray, n: int, out: np.ndarray) -> bool:
    # Reconstructor.sample: the playout slot (a fresh arrival sets it, each tick advances it),
    # the sample at the slot or the prediction from the newest two (the slot is never behind the
    # newest sample: every arrival is fresh).
    if S[S_PENDING] != 0.0:
        S[S_SLOT] = S[S_LAST_SEQ]
        S[S_SLOT_N] = n
        S[S_PENDING] = 0.0
        S[S_HAS_SLOT] = 1.0
    elif S[S_HAS_SLOT] != 0.0:
        S[S_SLOT] = S[S_SLOT] + (n - S[S_SLOT_N])
        S[S_SLOT_N] = n
    else:
        return False
    dim = int(C[C_DIM])
    target = int(S[S_SLOT])
    last_seq = int(S[S_LAST_SEQ])
    if target == last_seq:
        for i in range(dim):
            out[i] = S[S_LAST0 + i]
        return True
    S[S_PREDICTED] += 1.0
    if C[C_EXTRAP] == 0.0 or S[S_HAS_OLD] == 0.0:
        for i in range(dim):
            out[i] = S[S_LAST0 + i]
        return True
    ahead = min(target - last_seq, int(C[C_MAX_TICKS]))
    span = last_seq - int(S[S_OLD_SEQ])
    for i in range(dim):
        out[i] = extrapolate1(S[S_OLD0 + i], S[S_LAST0 + i], ahead, span)
    return True


@inline  # type: ignore[misc]
def deadband_triggered(C: np.ndarray, S: np.ndarray, smp: np.ndarray) -> bool:
    # GroupedDeadbandEncoder.send's test (a sample was sent before): a trigger value outside its
    # deadband around the last sent (1-value groups; the arm loop's: arm_codec_kernel.py).
    p = C[C_P0]
    if C[C_GAIN] > 0.0:
        p = deadband_p(C[C_P0], C[C_GAIN], C[C_PMAX], abs(smp[int(C[C_VEL])]))
    for i in range(int(C[C_DIM])):
        if C[C_TRIG0 + i] != 0.0:
            last = S[S_SENT0 + i]
            if outside(abs(last - smp[i]), abs(last), p, C[C_MIN]):
                return True
    return False


@inline  # type: ignore[misc]
def deadband_prediction_tick(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    n: int,
    now: int,
    smp: np.ndarray,
    rate: np.ndarray,
    out: np.ndarray,
) -> tuple[int, bool]:
    # CodecChannel.step with deadband or prediction (decoders that keep the newest two samples):
    # encode, send, deliver, decode. Returns (the `received` column's seq or -1, whether `out`
    # holds the tick's remote sample). The arm loop compiles it with its layout (`relaid`).
    dim = int(C[C_DIM])
    deadband = C[C_KIND] == DEADBAND
    if deadband:  # GroupedDeadbandEncoder.send
        sends_rate = C[C_SENDS_RATE] != 0.0
        if sends_rate:
            if S[S_HAS_PREV] == 0.0 or now <= S[S_PREV_NS]:
                for i in range(dim):
                    rate[i] = 0.0
            else:
                dt = (now - int(S[S_PREV_NS])) * 1e-9
                for i in range(dim):
                    rate[i] = (smp[i] - S[S_PREV0 + i]) / dt
        for i in range(dim):
            S[S_PREV0 + i] = smp[i]
        S[S_HAS_PREV] = 1.0
        S[S_PREV_NS] = now
        S[S_OFFERED] += 1.0
        send = True
        if S[S_HAS_SENT] != 0.0:
            send = deadband_triggered(C, S, smp)
            if not send:
                S[S_FILTERED] += 1.0
        if send:
            for i in range(dim):
                S[S_SENT0 + i] = smp[i]
            S[S_HAS_SENT] = 1.0
            S[S_SENT] += 1.0
            link_send(C, S, U, B, ring, rec, n, now, smp, rate, sends_rate)
    else:  # PredictionEncoder.send
        S[S_OFFERED] += 1.0
        packet_send(C, S, U, B, ring, rec, n, now, smp, rate)
    # Link.deliver, Decoder.receive
    rx = -1
    while True:
        head = link_next(S, ring, now)
        if head < 0:
            break
        seq = int(ring[head, 0])
        if deadband:
            deadband_receive(C, S, seq, ring, head)
        else:
            prediction_receive(C, S, seq, ring, head)
        rx = newest(S, seq, rx)
    if deadband:
        return rx, deadband_sample(C, S, n, out)
    return rx, prediction_sample(C, S, n, out)


# ------------------------------------------------------------------------------------------
# FEC: the decoder's history of samples (`Reconstructor` over any seqs), recovery, the tick.


@inline  # type: ignore[misc]
def rec_held(C: np.ndarray, S: np.ndarray, X: np.ndarray, seq: int) -> bool:
    # Reconstructor.has: held and not yet forgotten (within keep_ticks of the newest held).
    if seq < 0 or S[S_HAS_HELD] == 0.0 or seq < S[S_MAXHELD] - C[C_KEEP]:
        return False
    return X[seq & (X.shape[0] - 1), X_HELD] == seq


@inline  # type: ignore[misc]
def rec_add(C: np.ndarray, S: np.ndarray, X: np.ndarray, W: np.ndarray, seq: int, fresh: bool) -> bool:
    # Reconstructor.add of the value in W[W_VALUE:]; False if held already or too old to keep.
    # Not `fresh`: a recovered sample, counted.
    if rec_held(C, S, X, seq):
        return False
    if S[S_HAS_HELD] != 0.0 and seq < S[S_MAXHELD] - C[C_KEEP]:
        if not fresh:
            S[S_LATE] += 1.0
        return False
    if not fresh:  # a recovered sample (FecDecoder._add, ArqDecoder's retransmission), maybe late
        S[S_RECOVERED] += 1.0
        if S[S_HAS_PLAYED] != 0.0 and seq <= S[S_LAST_PLAYED]:
            S[S_LATE] += 1.0
            S[S_RECOVERED_LATE] += 1.0
    j = seq & (X.shape[0] - 1)
    X[j, X_HELD] = seq
    for i in range(int(C[C_DIM])):
        X[j, X_VALUE + i] = W[W_VALUE + i]
    if S[S_HAS_HELD] == 0.0 or seq > S[S_MAXHELD]:
        S[S_MAXHELD] = seq
        S[S_HAS_HELD] = 1.0
    if fresh and (S[S_HAS_FRESH] == 0.0 or seq > S[S_NEWEST_FRESH]):
        S[S_NEWEST_FRESH] = seq
        S[S_HAS_FRESH] = 1.0
        S[S_PENDING] = 1.0
    return True


@inline  # type: ignore[misc]
def rec_sample(C: np.ndarray, S: np.ndarray, X: np.ndarray, n: int, out: np.ndarray) -> bool:
    # Reconstructor.sample: the playout slot, the sample at the slot (wait_ticks behind), or the
    # prediction from the newest two held at or before it.
    if S[S_PENDING] != 0.0:
        S[S_SLOT] = S[S_NEWEST_FRESH]
        S[S_SLOT_N] = n
        S[S_PENDING] = 0.0
        S[S_HAS_SLOT] = 1.0
    elif S[S_HAS_SLOT] != 0.0:
        S[S_SLOT] = S[S_SLOT] + (n - S[S_SLOT_N])
        S[S_SLOT_N] = n
    elif S[S_HAS_HELD] != 0.0:
        S[S_SLOT] = S[S_MAXHELD]
        S[S_SLOT_N] = n
        S[S_HAS_SLOT] = 1.0
    else:
        return False
    target = int(S[S_SLOT]) - int(C[C_WAIT])
    if S[S_HAS_PLAYED] == 0.0 or target > S[S_LAST_PLAYED]:
        S[S_LAST_PLAYED] = target
        S[S_HAS_PLAYED] = 1.0
    dim = int(C[C_DIM])
    mask = X.shape[0] - 1
    newest = int(S[S_MAXHELD])
    lo = max(0, newest - int(C[C_KEEP]))
    last = min(target, newest)
    while last >= lo and X[last & mask, X_HELD] != last:
        last -= 1
    if last < lo:
        return False  # everything held is newer than the target
    j = last & mask
    if last == target:
        for i in range(dim):
            out[i] = X[j, X_VALUE + i]
        return True
    S[S_PREDICTED] += 1.0
    prev = last - 1
    if C[C_EXTRAP] != 0.0:
        while prev >= lo and X[prev & mask, X_HELD] != prev:
            prev -= 1
    if C[C_EXTRAP] == 0.0 or prev < lo:
        for i in range(dim):
            out[i] = X[j, X_VALUE + i]
        return True
    ahead = min(target - last, int(C[C_MAX_TICKS]))
    span = last - prev
    k = prev & mask
    for i in range(dim):
        out[i] = extrapolate1(X[k, X_VALUE + i], X[j, X_VALUE + i], ahead, span)
    return True


@inline  # type: ignore[misc]
def sum_held(C: np.ndarray, S: np.ndarray, X: np.ndarray, p: int) -> bool:
    # `p in FecDecoder._sums` after its front was dropped (what reaches past the history).
    if p < S[S_MAXHELD] - C[C_KEEP] + C[C_K]:
        return False
    return X[p & (X.shape[0] - 1), X_SUM_SEQ] == p


@inline  # type: ignore[misc]
def fec_receive(C: np.ndarray, S: np.ndarray, X: np.ndarray, W: np.ndarray, n: int) -> None:
    # FecDecoder.receive of packet n. A constant delay keeps the stream in order, so the payload
    # is the sender's samples of ticks n, n-1, ..., n-k (repetition) or x(n) and the sum of
    # x(n-k) .. x(n-1) (parity): read here from the sender's rows of X (as many as the packets
    # in flight and k need), the same floats the packet carries.
    dim = int(C[C_DIM])
    mask = X.shape[0] - 1
    k = int(C[C_K])
    S[S_RECEIVED] += 1.0
    jn = n & mask
    for i in range(dim):
        W[W_VALUE + i] = X[jn, X_SENT + i]
    if not rec_add(C, S, X, W, n, True):
        S[S_DUPLICATES] += 1.0
        if C[C_PARITY] != 0.0 and sum_held(C, S, X, n):
            return
    if C[C_PARITY] == 0.0:
        for q in range(1, k + 1):
            m = n - q
            if m >= 0:
                jm = m & mask
                for i in range(dim):
                    W[W_VALUE + i] = X[jm, X_SENT + i]
                rec_add(C, S, X, W, m, False)
        return
    # the carrier's parity sum is the encoder's math.fsum of x(n-k) .. x(n-1): computed when a
    # window is solved, from the sender's rows (they reach back far enough: CodecNet)
    X[jn, X_SUM_SEQ] = n
    # FecDecoder._parity_recover: solve each window with one unknown (a LIFO worklist)
    oldest = int(S[S_MAXHELD]) - int(C[C_KEEP])
    W[W_STACK] = n
    top = 1
    while top > 0:
        top -= 1
        p = int(W[W_STACK + top])
        if not sum_held(C, S, X, p):
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
        for i in range(dim):
            c = 0
            for q in range(max(0, p - k), p):
                W[W_TERMS + c] = X[q & mask, X_SENT + i]
                c += 1
            W[W_TERMS] = rounded_sum(W, W_TERMS, c, W)  # S(p), as the encoder's math.fsum
            c = 1
            for q in range(max(0, p - k), p):
                if q != m:
                    W[W_TERMS + c] = -X[q & mask, X_VALUE + i]
                    c += 1
            W[W_VALUE + i] = rounded_sum(W, W_TERMS, c, W)
        if rec_add(C, S, X, W, m, False):
            for q in range(m + 1, m + k + 1):
                if sum_held(C, S, X, q):
                    W[W_STACK + top] = q
                    top += 1


@part_jit  # type: ignore[misc]
def fec_tick(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    X: np.ndarray,
    W: np.ndarray,
    n: int,
    now: int,
    smp: np.ndarray,
    rate: np.ndarray,
    out: np.ndarray,
) -> tuple[int, bool]:
    # CodecChannel.step with FecEncoder / FecDecoder.
    dim = int(C[C_DIM])
    j = n & (X.shape[0] - 1)
    for i in range(dim):
        X[j, X_SENT + i] = smp[i]
    S[S_OFFERED] += 1.0
    packet_send(C, S, U, B, ring, rec, n, now, smp, rate)
    rx = -1
    while True:
        head = link_next(S, ring, now)
        if head < 0:
            break
        seq = int(ring[head, 0])
        fec_receive(C, S, X, W, seq)
        rx = newest(S, seq, rx)
    return rx, rec_sample(C, S, X, n, out)


# ------------------------------------------------------------------------------------------
# ARQ: pending samples, retransmissions, the decoder's ACKs through the ACK link (A: its arrays,
# as a codec direction's C, S, U, B, ring, records; the records are not kept).


@inline  # type: ignore[misc]
def arq_send(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    seq: int,
    now: int,
    value: np.ndarray,
    attempt: int,
    unused: np.ndarray,
) -> None:
    # ArqEncoder._packet into Link.send; a delivered packet carries its attempt and send tick.
    before = S[S_COUNT]
    packet_send(C, S, U, B, ring, rec, seq, now, value, unused)
    if S[S_COUNT] > before:
        j = (int(S[S_HEAD]) + int(before)) & (ring.shape[0] - 1)
        ring[j, RING_ATTEMPT] = attempt
        ring[j, RING_SENT] = now // int(C[C_PERIOD_NS])


@part_jit  # type: ignore[misc]
def arq_tick(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    X: np.ndarray,
    W: np.ndarray,
    A: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    n: int,
    now: int,
    smp: np.ndarray,
    rate: np.ndarray,
    out: np.ndarray,
) -> tuple[int, bool]:
    # CodecChannel.step with ArqEncoder / ArqDecoder and the ACK link.
    aC, aS, aU, aB, aring, arec = A
    dim = int(C[C_DIM])
    mask = X.shape[0] - 1
    # the ACKs due: ArqEncoder.feedback
    while True:
        head = link_next(aS, aring, now)
        if head < 0:
            break
        seq = int(aring[head, 0])
        j = seq & mask
        if X[j, X_PEND] == seq:
            X[j, X_PEND] = -1.0
            S[S_ACKED] += 1.0
        else:
            S[S_ACKS_STALE] += 1.0
    # ArqEncoder.send: the new sample, then the pending ones due (in seq order)
    S[S_OFFERED] += 1.0
    j = n & mask
    for i in range(dim):
        X[j, X_SENT + i] = smp[i]
    arq_send(C, S, U, B, ring, rec, n, now, smp, 0, out)
    # A pending sample is due every m = ceil(mu / period) ticks after it was sent (the encoder
    # runs every tick), so the only candidates this tick are n - j m, j = nu + 1 .. 1 (seq order).
    timeout = C[C_TIMEOUT_NS]
    m_ticks = int(-(-int(timeout) // int(C[C_PERIOD_NS])))
    for jj in range(int(C[C_NU]) + 1, 0, -1):
        seq = n - jj * m_ticks
        if seq < 0:
            continue
        k = seq & mask
        if X[k, X_PEND] != seq or now - X[k, X_LAST_NS] < timeout:
            continue
        if X[k, X_TRIES] >= C[C_NU]:
            X[k, X_PEND] = -1.0
            S[S_GAVE_UP] += 1.0
            continue
        X[k, X_TRIES] += 1.0
        X[k, X_LAST_NS] = now
        S[S_RETRANSMITTED] += 1.0
        for i in range(dim):
            rate[i] = X[k, X_SENT + i]
        arq_send(C, S, U, B, ring, rec, seq, now, rate, int(X[k, X_TRIES]), out)
    X[j, X_PEND] = n
    X[j, X_TRIES] = 0.0
    X[j, X_LAST_NS] = now
    # Link.deliver, ArqDecoder.receive, its ACK into the ACK link
    rx = -1
    while True:
        head = link_next(S, ring, now)
        if head < 0:
            break
        seq = int(ring[head, 0])
        S[S_RECEIVED] += 1.0
        for i in range(dim):
            W[W_VALUE + i] = ring[head, 2 + i]
        if not rec_add(C, S, X, W, seq, ring[head, RING_ATTEMPT] == 0.0):
            S[S_DUPLICATES] += 1.0
        S[S_ACKS_SENT] += 1.0
        rx = newest(S, seq, rx)
        S[S_ACK_PACKETS] += 1.0
        S[S_ACK_BYTES] += C[C_ACK_SIZE]
        link_send(aC, aS, aU, aB, aring, arec, seq, now, out, out, False)
    return rx, rec_sample(C, S, X, n, out)


# ------------------------------------------------------------------------------------------
# HLI: the sender's classes and rate window, the receiver N_HLI1 ticks behind its newest packet
# (X's rows: H_* of codec_layout; W: which followers may be filtered, how many follow that may
# not, the window's (tick, bits) ring).


@inline  # type: ignore[misc]
def hli_play(C: np.ndarray, S: np.ndarray, X: np.ndarray, t: int) -> None:
    # HliDecoder._play
    dim = int(C[C_DIM])
    j = t & (X.shape[0] - 1)
    got = X[j, H_RTAG] == t
    if got:
        X[j, H_RTAG] = H_NONE
    rb = X[j, H_BTAG] == t
    if rb:
        X[j, H_BTAG] = H_NONE
    if got:
        S[S_PLAYED] += 1.0
        for i in range(dim):
            S[S_DT2 + i] = X[j, H_PREV + i]
            S[S_DT1 + i] = X[j, H_SMP + i]
        S[S_DT1H] = 1.0
        S[S_DT2H] = 1.0
        return
    if rb:
        S[S_REBUILT] += 1.0
        for i in range(dim):
            S[S_DT2 + i] = S[S_DT1 + i]
            S[S_DT1 + i] = X[j, H_BX + i]
        S[S_DT2H] = S[S_DT1H]
        S[S_DT1H] = 1.0
        return
    if S[S_DT1H] == 0.0:
        return
    S[S_DPREDICTED] += 1.0
    linear = C[C_HLINEAR] != 0.0 and S[S_DT2H] != 0.0
    for i in range(dim):
        a = S[S_DT1 + i]
        x = linear1(a, S[S_DT2 + i]) if linear else a
        S[S_DT2 + i] = a
        S[S_DT1 + i] = x
    S[S_DT2H] = 1.0


@part_jit  # type: ignore[misc]
def hli_tick(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    X: np.ndarray,
    W: np.ndarray,
    n: int,
    now: int,
    smp: np.ndarray,
    rate: np.ndarray,
    out: np.ndarray,
) -> tuple[int, bool]:
    # CodecChannel.step with HliEncoder / HliDecoder.
    dim = int(C[C_DIM])
    mask = X.shape[0] - 1
    N = int(C[C_HN])
    S[S_OFFERED] += 1.0
    # HliEncoder.send: the rate window
    wt = int(C[C_HWIN])
    base = 2 * N + 2
    cap = wt + 1
    while S[S_WIN_COUNT] > 0.0:
        h = int(S[S_WIN_HEAD])
        if W[base + 2 * h] > n - wt:
            break
        S[S_WIN_BITS] -= W[base + 2 * h + 1]
        S[S_WIN_HEAD] = (h + 1) % cap
        S[S_WIN_COUNT] -= 1.0
    # the prediction of the mirrored track (into `rate`, unused by HLI)
    has_pred = S[S_ET1H] != 0.0
    if has_pred:
        linear = C[C_HLINEAR] != 0.0 and S[S_ET2H] != 0.0
        for i in range(dim):
            rate[i] = linear1(S[S_ET1 + i], S[S_ET2 + i]) if linear else S[S_ET1 + i]
    S[S_ESINCE] += 1.0
    cls = 0
    big = S[S_ESEEN] < C[C_HWARMUP] or not has_pred
    if not big:
        acc = 0.0
        for i in range(dim):
            d = smp[i] - rate[i]
            acc += d * d
        big = math.sqrt(acc) >= C[C_HTHRESH]
    if big:
        cls = 2
        S[S_ESINCE] = 0.0
        for i in range(dim):
            S[S_EH2 + i] = smp[i]
    elif S[S_ESINCE] <= N:
        cls = 1
    S[S_ESEEN] += 1.0
    S[S_LAST_CLASS] = cls
    S[S_HLI0 + cls] += 1.0
    send = cls != 0
    since = int(S[S_ESINCE])
    if cls == 1 and W[since] != 0.0:
        need = C[C_HBITS1] * (1.0 + W[N + 1 + since])
        if S[S_WIN_BITS] + need > C[C_HBUDGET]:
            send = False
            S[S_FILT1] += 1.0
    elif cls == 0:
        S[S_FILT0] += 1.0
    # the previous true sample (into `out` for now), the track
    for i in range(dim):
        out[i] = smp[i] if S[S_EPREVH] == 0.0 else S[S_EPREV + i]
        S[S_EPREV + i] = smp[i]
    S[S_EPREVH] = 1.0
    if send or not has_pred:
        for i in range(dim):
            S[S_ET2 + i] = out[i]
            S[S_ET1 + i] = smp[i]
        S[S_ET2H] = 1.0
    else:
        for i in range(dim):
            S[S_ET2 + i] = S[S_ET1 + i]
            S[S_ET1 + i] = rate[i]
        S[S_ET2H] = S[S_ET1H]
    S[S_ET1H] = 1.0
    if send:
        j = n & mask
        for i in range(dim):
            X[j, H_SMP + i] = smp[i]
            X[j, H_PREV + i] = out[i]
            X[j, H_COPY + i] = S[S_EH2 + i]
        X[j, H_CLASS] = cls
        X[j, H_OFF] = 0.0 if cls == 2 else since
        bits = C[C_HBITS2] if cls == 2 else C[C_HBITS1]
        k = (int(S[S_WIN_HEAD]) + int(S[S_WIN_COUNT])) % cap
        W[base + 2 * k] = n
        W[base + 2 * k + 1] = bits
        S[S_WIN_COUNT] += 1.0
        S[S_WIN_BITS] += bits
        S[S_SENT] += 1.0
        S[S_WIRE_BITS] += bits
        if S[S_WIN_BITS] > C[C_HBUDGET]:
            S[S_OVER] += 1.0
        C[C_SIZE] = C[C_HSIZE2] if cls == 2 else C[C_HSIZE1]
        link_send(C, S, U, B, ring, rec, n, now, smp, rate, False)
    # Link.deliver, HliDecoder.receive
    rx = -1
    while True:
        head = link_next(S, ring, now)
        if head < 0:
            break
        seq = int(ring[head, 0])
        S[S_RECEIVED] += 1.0
        rx = newest(S, seq, rx)
        if S[S_CURH] != 0.0 and seq <= S[S_CUR]:
            S[S_DLATE] += 1.0
            continue
        j = seq & mask
        X[j, H_RTAG] = seq
        if S[S_CURH] == 0.0 and (S[S_MINH] == 0.0 or seq < S[S_MIN]):
            S[S_MIN] = seq
            S[S_MINH] = 1.0
        if X[j, H_CLASS] == 1.0:
            key = seq - int(X[j, H_OFF])
            if S[S_CURH] == 0.0 or key > S[S_CUR]:
                jr = key & mask
                if X[jr, H_BTAG] != key:
                    X[jr, H_BTAG] = key
                    for i in range(dim):
                        X[jr, H_BX + i] = X[j, H_COPY + i]
        if S[S_FRH] == 0.0 or seq > S[S_FRMAX]:
            S[S_FRMAX] = seq
            S[S_FRH] = 1.0
    # HliDecoder.sample
    if S[S_FRH] != 0.0:
        lag = n - int(S[S_FRMAX])
        if S[S_LAGH] == 0.0 or lag < S[S_LAG]:
            S[S_LAG] = lag
            S[S_LAGH] = 1.0
        S[S_FRH] = 0.0
    if S[S_LAGH] == 0.0:
        return rx, False
    target = n - int(S[S_LAG]) - int(C[C_HDELAY])
    if S[S_CURH] == 0.0:
        first = int(S[S_MIN]) if S[S_MINH] != 0.0 else target
        S[S_CUR] = min(first, target + 1) - 1
        S[S_CURH] = 1.0
    while S[S_CUR] < target:
        S[S_CUR] += 1.0
        hli_play(C, S, X, int(S[S_CUR]))
    if S[S_DT1H] == 0.0:
        return rx, False
    for i in range(dim):
        out[i] = S[S_DT1 + i]
    return rx, True


@inline  # type: ignore[misc]
def codec_tick(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    X: np.ndarray,
    W: np.ndarray,
    A: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    n: int,
    now: int,
    smp: np.ndarray,
    rate: np.ndarray,
    out: np.ndarray,
) -> tuple[int, bool]:
    # CodecChannel.step of a direction, whatever its compiled kind (FEC, ARQ, HLI: X, W, A their
    # history, scratch and ACK link).
    if C[C_KIND] == HLI:
        return hli_tick(C, S, U, B, ring, rec, X, W, n, now, smp, rate, out)
    if C[C_KIND] == ARQ:
        return arq_tick(C, S, U, B, ring, rec, X, W, A, n, now, smp, rate, out)
    if C[C_KIND] == FEC:
        return fec_tick(C, S, U, B, ring, rec, X, W, n, now, smp, rate, out)
    return deadband_prediction_tick(C, S, U, B, ring, rec, n, now, smp, rate, out)


@loop_jit  # type: ignore[misc]
def run_ticks_codec(
    n0: int,
    n1: int,
    models: np.ndarray,
    mq: np.ndarray,
    mv: np.ndarray,
    mctrl: np.ndarray,
    sq: np.ndarray,
    sv: np.ndarray,
    sctrl: np.ndarray,
    sqfrc: np.ndarray,
    fwd_rel: np.ndarray,
    fwd_occ: np.ndarray,
    bwd_rel: np.ndarray,
    bwd_occ: np.ndarray,
    fwd_hist: np.ndarray,
    bwd_hist: np.ndarray,
    P: np.ndarray,
    S: np.ndarray,
    data: np.ndarray,
    w0: int,
    d0: int,
    fC: np.ndarray,
    fS: np.ndarray,
    fU: np.ndarray,
    fB: np.ndarray,
    fring: np.ndarray,
    frec: np.ndarray,
    bC: np.ndarray,
    bS: np.ndarray,
    bU: np.ndarray,
    bB: np.ndarray,
    bring: np.ndarray,
    brec: np.ndarray,
    scratch: np.ndarray,
    fX: np.ndarray,
    fW: np.ndarray,
    fA: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    bX: np.ndarray,
    bW: np.ndarray,
    bA: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> int:
    # `axis_kernel.run_ticks` with a codec on the directions whose C_KIND is not NO_CODEC (the
    # others read their window of the schedule as there).
    fmask = fwd_hist.shape[0] - 1
    bmask = bwd_hist.shape[0] - 1
    fcodec = fC[C_KIND] != NO_CODEC
    bcodec = bC[C_KIND] != NO_CODEC
    period_ns = int(fC[C_PERIOD_NS])
    smp = scratch[0]  # the sample, its rate, the decoder's output (3 values each)
    rate = scratch[1]
    out = scratch[2]
    for n in range(n0, n1):
        now = n * period_ns
        x_m = mq[0]
        v_m = mv[0]
        x_s = sq[0]
        v_s = sv[0]
        f_env = S[SLAVE + S_CONTACT]
        # master
        fm, m_desired = control(P, S, MASTER, x_m, v_m, True)
        if fcodec:
            smp[0] = x_m
            smp[1] = v_m
            frx, got = codec_tick(fC, fS, fU, fB, fring, frec, fX, fW, fA, n, now, smp, rate, out)
            if got:
                accept2(P, S, out[0], out[1])
            focc = 0.0
        else:
            fwd_hist[n & fmask, 0] = x_m
            fwd_hist[n & fmask, 1] = v_m
            frx = fwd_rel[n - w0]
            if frx >= 0:
                accept2(P, S, fwd_hist[frx & fmask, 0], fwd_hist[frx & fmask, 1])
            focc = fwd_occ[n - w0]
        # slave
        fs, s_desired = control(P, S, SLAVE, x_s, v_s, False)
        if bcodec:
            smp[0] = f_env
            smp[1] = x_s
            smp[2] = v_s
            brx, got = codec_tick(bC, bS, bU, bB, bring, brec, bX, bW, bA, n, now, smp, rate, out)
            if got:
                accept3(P, S, out[0], out[1], out[2])
            bocc = 0.0
        else:
            bwd_hist[n & bmask, 0] = f_env
            bwd_hist[n & bmask, 1] = x_s
            bwd_hist[n & bmask, 2] = v_s
            brx = bwd_rel[n - w0]
            if brx >= 0:
                accept3(P, S, bwd_hist[brx & bmask, 0], bwd_hist[brx & bmask, 1], bwd_hist[brx & bmask, 2])
            bocc = bwd_occ[n - w0]
        finish_tick(
            n, models, mctrl, sctrl, sqfrc, P, S, data[n - d0], x_m, v_m, x_s, v_s, f_env,
            fm, m_desired, fs, s_desired, frx, brx, focc, bocc,
        )  # fmt: skip
    return n1


@loop_jit  # type: ignore[misc]
def codec_ticks(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    samples: np.ndarray,
    period_ns: int,
    scratch: np.ndarray,
    X: np.ndarray,
    W: np.ndarray,
    A: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> int:
    """One direction's codec stage alone over `samples` (a row a tick): what it costs a tick
    (`bench codec`). X, W, A: `CodecNet.history`. Returns the ticks with a remote sample."""
    smp = scratch[0]
    rate = scratch[1]
    out = scratch[2]
    got_ticks = 0
    for n in range(samples.shape[0]):
        for i in range(samples.shape[1]):
            smp[i] = samples[n, i]
        _rx, got = codec_tick(C, S, U, B, ring, rec, X, W, A, n, n * period_ns, smp, rate, out)
        if got:
            got_ticks += 1
    return got_ticks
