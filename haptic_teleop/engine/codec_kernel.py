"""The compiled 1-DoF loop with the codec stage (numba), imported only when a scene with a codec
runs compiled, so codec-less runs never compile or load it (engine/compiled_codec.py has the
design, engine/codec_layout.py the arrays' layouts).

The tick is `axis_kernel.run_ticks`'s (the same helpers: `control`, `forward_released`,
`backward_released`, `accept2`, `accept3`, `finish_tick`); a direction with a codec replaces
its schedule lookup by `codec_tick`, which is
`CodecChannel.step` line for line: encoder, link (blackout, loss, constant delay; a deadband's
jitter), deliveries, decoder; it dispatches on the kind: deadband and prediction inlined (`deadband_prediction_tick`),
FEC and HLI compiled once each (`fec_tick`, `hli_tick`), ARQ (with its ACK link) planned ahead
a chunk at a time by `arq_block`, compiled once, and its samples moved by `arq_tick`. The
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
from haptic_teleop.engine import codec_layout as L
from haptic_teleop.engine.axis_kernel import (
    MASTER,
    S_CONTACT,
    SLAVE,
    accept2,
    accept3,
    backward_released,
    control,
    finish_tick,
    forward_released,
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
four_state_step = jit(loss.four_state_step)
rounded_sum = part_jit(fec.rounded_sum)
linear1 = jit(hli_codec.linear1)

DELIVERED = 0.0
LOST_NETWORK = 1.0


@part_jit  # type: ignore[misc]
def chain_or_trace_fate(C: np.ndarray, S: np.ndarray, U: np.ndarray, u: int) -> tuple[bool, int]:
    # `loss_fate` of the 4-state chain and of a trace (U its pattern, u the packets so far):
    # compiled once, not inlined into every link (cold compile time).
    if C[L.C_LOSS] == L.LOSS_FOUR_STATE:
        state = four_state_step(int(S[L.S_BAD]), U[u], C[L.C_LP], C[L.C_LR], C[L.C_LBAD], C[L.C_LGOOD], C[L.C_LP14])
        S[L.S_BAD] = state
        return state >= 3, u + 1
    n = u
    if n >= U.shape[0]:
        if C[L.C_LP] == 0.0:  # (not repeated: the packets after it all pass)
            return False, u + 1
        n %= U.shape[0]
    return U[n] != 0.0, u + 1


@inline  # type: ignore[misc]
def loss_fate(C: np.ndarray, S: np.ndarray, U: np.ndarray, u: int) -> tuple[bool, int]:
    # The loss effect's verdict on the next packet (its draws whatever the packet's fate) from
    # its numbers U from index u; and the next index. Bernoulli (netem-correlated if C_LRHO:
    # NetemCorrelatedUniform.next), Gilbert-Elliott (two numbers), the 4-state chain and a
    # trace (`chain_or_trace_fate`).
    kind = C[L.C_LOSS]
    if kind == L.LOSS_BERNOULLI:
        x = U[u]
        rho = C[L.C_LRHO]
        if rho != 0.0:
            x = (1.0 - rho) * x + rho * S[L.S_LLAST]
            S[L.S_LLAST] = x
        return x < C[L.C_LP], u + 1
    if kind == L.LOSS_GILBERT:
        bad, lost = gilbert_step(S[L.S_BAD] != 0.0, U[u], U[u + 1], C[L.C_LP], C[L.C_LR], C[L.C_LBAD], C[L.C_LGOOD])
        S[L.S_BAD] = 1.0 if bad else 0.0
        return lost, u + 2
    return chain_or_trace_fate(C, S, U, u)


@inline  # type: ignore[misc]
def fate_of(C: np.ndarray, S: np.ndarray, U: np.ndarray, B: np.ndarray, now: int, u: int) -> tuple[int, int]:
    # Link.send's effects on one packet sent at `now` (blackout, loss: its draws whatever the
    # fate), the link's counts and its next random number kept by the caller: 0 delivered,
    # 1 lost in a blackout, 2 lost by the loss model; and the next random number.
    fate = 0
    nb = B.shape[0]
    if nb > 0:
        i = int(S[L.S_BLACKOUT_I])
        while i < nb and B[i, 0] <= now:
            i += 1
        S[L.S_BLACKOUT_I] = i
        if i > 0 and now < B[i - 1, 1]:
            fate = 1
    if C[L.C_LOSS] != L.LOSS_NONE:
        lost, u = loss_fate(C, S, U, u)
        if lost and fate == 0:
            fate = 2
    return fate, u


@inline  # type: ignore[misc]
def link_fate(C: np.ndarray, S: np.ndarray, U: np.ndarray, B: np.ndarray, now: int) -> float:
    # `fate_of` with the link's counts and its next random number in S. Returns the fate.
    fate, u = fate_of(C, S, U, B, now, int(S[L.S_U]))
    S[L.S_U] = u
    S[L.S_LINK_SENT] += 1.0
    if fate == 0:
        return DELIVERED
    S[L.S_LINK_LOST] += 1.0
    if fate == 1:
        S[L.S_DROP_BLACKOUT] += 1.0
    else:
        S[L.S_DROP_LOSS] += 1.0
    return LOST_NETWORK


@inline  # type: ignore[misc]
def jitter_arrival(C: np.ndarray, S: np.ndarray, W: np.ndarray, now: int, fate: float) -> int:
    # Delay.apply without a time-varying part or reordering: delay_s + jitter_s J, J the
    # distribution's value of the packet's uniform number (every packet draws one, lost or not;
    # netem-correlated with the one before if C_JRHO),
    # rounded to the ns, 0 if not positive; with keep_order a delivered packet arrives no earlier
    # than the one delivered before it. W: the distribution's table (C_JN values), then the
    # uniform numbers.
    n = int(C[L.C_JN])
    u = W[n + int(S[L.S_JU])]
    S[L.S_JU] += 1.0
    rho = C[L.C_JRHO]
    if rho != 0.0:  # NetemCorrelatedUniform.next
        u = (1.0 - rho) * u + rho * S[L.S_JLAST]
        S[L.S_JLAST] = u
    q = 2.0 * u - 1.0 if n == 0 else W[int(u * n)]
    d = C[L.C_JBASE_NS]
    d += C[L.C_JSIGMA_NS] * q
    t = now + int(C[L.C_DELAY_NS])  # (a constant delay before it: none that build_link makes)
    arrival = t + int(d + 0.5) if d > 0.0 else t
    if C[L.C_JKEEP] != 0.0 and fate == DELIVERED:
        if arrival < S[L.S_LAST_ARRIVAL]:
            arrival = int(S[L.S_LAST_ARRIVAL])
        S[L.S_LAST_ARRIVAL] = arrival
    return arrival


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
    with_record: bool = True,
    with_payload: bool = True,
    W: np.ndarray | None = None,
) -> None:
    # Link.send of one packet: blackout, loss (its draws whatever the fate), constant delay;
    # the record; a delivered packet joins the in-flight FIFO. (ARQ's ACK link keeps neither its
    # records nor a payload: `with_record`, `with_payload` False, constants once inlined.) With
    # `W` (a deadband direction's) the link may have jitter (`jitter_arrival`): the packet then
    # joins the FIFO in arrival order.
    fate = link_fate(C, S, U, B, now)
    jitter = W is not None and C[L.C_JIT] != 0.0
    if jitter:
        arrival = jitter_arrival(C, S, W, now, fate)
    else:
        arrival = now + int(C[L.C_DELAY_NS])
    # (2-D arrays are indexed in full, never sliced: a view costs reference counting)
    r = int(S[L.S_RECS])
    if with_record:
        S[L.S_RECS] += 1.0
        rec[r, 0] = seq
        rec[r, 1] = float(now) * 1e-9
        rec[r, 3] = fate
        rec[r, 4] = 0.0
        rec[r, 5] = C[L.C_SIZE]
    if fate != DELIVERED:
        if with_record:
            rec[r, 2] = np.nan
        return
    if with_record:
        rec[r, 2] = float(arrival) * 1e-9
    depth = ring.shape[0]
    count = int(S[L.S_COUNT])
    j = (int(S[L.S_HEAD]) + count) & (depth - 1)
    S[L.S_COUNT] = count + 1
    if jitter:  # Link._enqueue: in arrival order, equal arrivals in send order
        head = int(S[L.S_HEAD])
        while count > 0 and ring[(head + count - 1) & (depth - 1), 1] > arrival:
            k = (head + count - 1) & (depth - 1)
            for c in range(ring.shape[1]):
                ring[j, c] = ring[k, c]
            j = k
            count -= 1
    ring[j, 0] = seq
    ring[j, 1] = arrival
    if not with_payload:
        return
    dim = int(C[L.C_DIM])
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
    S[L.S_SENT] += 1.0
    S[L.S_BYTES] += C[L.C_SIZE]
    link_send(C, S, U, B, ring, rec, seq, now, value, unused, False)


@inline  # type: ignore[misc]
def link_next(S: np.ndarray, ring: np.ndarray, now: int) -> int:
    # Link.deliver, one packet: the ring row of the next packet due by `now` (taken off the
    # in-flight FIFO), or -1.
    if S[L.S_COUNT] <= 0.0:
        return -1
    head = int(S[L.S_HEAD])
    if ring[head, 1] > now:
        return -1
    S[L.S_HEAD] = (head + 1) & (ring.shape[0] - 1)
    S[L.S_COUNT] -= 1.0
    return head


@inline  # type: ignore[misc]
def newest(S: np.ndarray, seq: int, rx: int) -> int:
    # The `received` column's seq after a delivery of `seq` (the newest delivered so far, else rx).
    if seq > S[L.S_NEWEST]:
        S[L.S_NEWEST] = seq
        return seq
    return rx


@inline  # type: ignore[misc]
def deadband_receive(C: np.ndarray, S: np.ndarray, seq: int, ring: np.ndarray, j: int) -> None:
    # DeadbandDecoder.receive; the payload: ring row j from column 2 on.
    dim = int(C[L.C_DIM])
    if S[L.S_HAS_LAST] != 0.0 and seq <= S[L.S_LAST_SEQ]:
        S[L.S_STALE] += 1.0
        return
    S[L.S_RECEIVED] += 1.0
    S[L.S_HAS_OLD] = S[L.S_HAS_LAST]
    S[L.S_OLD_SEQ] = S[L.S_LAST_SEQ]
    for i in range(dim):
        S[L.S_OLD0 + i] = S[L.S_LAST0 + i]
        S[L.S_LAST0 + i] = ring[j, 2 + i]
    S[L.S_HAS_LAST] = 1.0
    S[L.S_LAST_SEQ] = seq
    if C[L.C_EXTRAP] != 0.0:
        if C[L.C_SENDS_RATE] != 0.0:
            dt_tick = C[L.C_PERIOD_NS] / 1e9
            for i in range(dim):
                S[L.S_RATE0 + i] = ring[j, 2 + dim + i] * dt_tick
            S[L.S_HAS_RATE] = 1.0
        elif S[L.S_HAS_OLD] != 0.0:
            span = int(S[L.S_LAST_SEQ]) - int(S[L.S_OLD_SEQ])
            for i in range(dim):
                S[L.S_RATE0 + i] = (S[L.S_LAST0 + i] - S[L.S_OLD0 + i]) / span
            S[L.S_HAS_RATE] = 1.0


@inline  # type: ignore[misc]
def deadband_sample(C: np.ndarray, S: np.ndarray, n: int, out: np.ndarray) -> bool:
    # DeadbandDecoder.sample: hold, or extrapolate at most the cap, then hold.
    if S[L.S_HAS_LAST] == 0.0:
        return False
    dim = int(C[L.C_DIM])
    seq = int(S[L.S_LAST_SEQ])
    if S[L.S_HAS_RATE] == 0.0 or n <= seq:
        for i in range(dim):
            out[i] = S[L.S_LAST0 + i]
        return True
    ahead = float(n - seq)
    if ahead > C[L.C_MAX_AHEAD]:
        ahead = C[L.C_MAX_AHEAD]
    else:
        S[L.S_EXTRAPOLATED] += 1.0
    for i in range(dim):
        out[i] = extrapolated(S[L.S_LAST0 + i], S[L.S_RATE0 + i], ahead)
    return True


@inline  # type: ignore[misc]
def prediction_receive(C: np.ndarray, S: np.ndarray, seq: int, ring: np.ndarray, j: int) -> None:
    # PredictionDecoder.receive -> Reconstructor.add(fresh=True). A constant delay keeps the order
    # and nothing is duplicated, so every arrival is the newest: the history needs only the
    # newest two samples (the older one kept while within `keep_ticks`, as `add` forgets).
    dim = int(C[L.C_DIM])
    S[L.S_RECEIVED] += 1.0
    S[L.S_HAS_OLD] = S[L.S_HAS_LAST]
    S[L.S_OLD_SEQ] = S[L.S_LAST_SEQ]
    for i in range(dim):
        S[L.S_OLD0 + i] = S[L.S_LAST0 + i]
        S[L.S_LAST0 + i] = ring[j, 2 + i]
    S[L.S_HAS_LAST] = 1.0
    S[L.S_LAST_SEQ] = seq
    if S[L.S_HAS_OLD] != 0.0 and S[L.S_OLD_SEQ] < seq - C[L.C_KEEP]:
        S[L.S_HAS_OLD] = 0.0
    S[L.S_PENDING] = 1.0


@inline  # type: ignore[misc]
def prediction_sample(C: np.ndarray, S: np.ndarray, n: int, out: np.ndarray) -> bool:
    # Reconstructor.sample: the playout slot (a fresh arrival sets it, each tick advances it),
    # the sample at the slot or the prediction from the newest two (the slot is never behind the
    # newest sample: every arrival is fresh).
    if S[L.S_PENDING] != 0.0:
        S[L.S_SLOT] = S[L.S_LAST_SEQ]
        S[L.S_SLOT_N] = n
        S[L.S_PENDING] = 0.0
        S[L.S_HAS_SLOT] = 1.0
    elif S[L.S_HAS_SLOT] != 0.0:
        S[L.S_SLOT] = S[L.S_SLOT] + (n - S[L.S_SLOT_N])
        S[L.S_SLOT_N] = n
    else:
        return False
    dim = int(C[L.C_DIM])
    target = int(S[L.S_SLOT])
    last_seq = int(S[L.S_LAST_SEQ])
    if target == last_seq:
        for i in range(dim):
            out[i] = S[L.S_LAST0 + i]
        return True
    S[L.S_PREDICTED] += 1.0
    if C[L.C_EXTRAP] == 0.0 or S[L.S_HAS_OLD] == 0.0:
        for i in range(dim):
            out[i] = S[L.S_LAST0 + i]
        return True
    ahead = min(target - last_seq, int(C[L.C_MAX_TICKS]))
    span = last_seq - int(S[L.S_OLD_SEQ])
    for i in range(dim):
        out[i] = extrapolate1(S[L.S_OLD0 + i], S[L.S_LAST0 + i], ahead, span)
    return True


@inline  # type: ignore[misc]
def deadband_triggered(C: np.ndarray, S: np.ndarray, smp: np.ndarray) -> bool:
    # GroupedDeadbandEncoder.send's test (a sample was sent before): a trigger value outside its
    # deadband around the last sent (1-value groups; the arm loop's: arm_codec_kernel.py).
    p = C[L.C_P0]
    if C[L.C_GAIN] > 0.0:
        p = deadband_p(C[L.C_P0], C[L.C_GAIN], C[L.C_PMAX], abs(smp[int(C[L.C_VEL])]))
    for i in range(int(C[L.C_DIM])):
        if C[L.C_TRIG0 + i] != 0.0:
            last = S[L.S_SENT0 + i]
            if outside(abs(last - smp[i]), abs(last), p, C[L.C_MIN]):
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
    W: np.ndarray,
    n: int,
    now: int,
    smp: np.ndarray,
    rate: np.ndarray,
    out: np.ndarray,
) -> tuple[int, bool]:
    # CodecChannel.step with deadband or prediction (decoders that keep the newest two samples):
    # encode, send, deliver, decode. Returns (the `received` column's seq or -1, whether `out`
    # holds the tick's remote sample). The arm loop compiles it with its layout (`relaid`).
    dim = int(C[L.C_DIM])
    deadband = C[L.C_KIND] == L.DEADBAND
    if deadband:  # GroupedDeadbandEncoder.send
        sends_rate = C[L.C_SENDS_RATE] != 0.0
        if sends_rate:
            if S[L.S_HAS_PREV] == 0.0 or now <= S[L.S_PREV_NS]:
                for i in range(dim):
                    rate[i] = 0.0
            else:
                dt = (now - int(S[L.S_PREV_NS])) * 1e-9
                for i in range(dim):
                    rate[i] = (smp[i] - S[L.S_PREV0 + i]) / dt
        for i in range(dim):
            S[L.S_PREV0 + i] = smp[i]
        S[L.S_HAS_PREV] = 1.0
        S[L.S_PREV_NS] = now
        S[L.S_OFFERED] += 1.0
        send = True
        if S[L.S_HAS_SENT] != 0.0:
            send = deadband_triggered(C, S, smp)
            if not send:
                S[L.S_FILTERED] += 1.0
        if send:
            for i in range(dim):
                S[L.S_SENT0 + i] = smp[i]
            S[L.S_HAS_SENT] = 1.0
            S[L.S_SENT] += 1.0
            link_send(C, S, U, B, ring, rec, n, now, smp, rate, sends_rate, True, True, W)
    else:  # PredictionEncoder.send
        S[L.S_OFFERED] += 1.0
        packet_send(C, S, U, B, ring, rec, n, now, smp, rate)
    # Link.deliver, Decoder.receive
    # (`link_next` and `newest` written out: through them the deadband's stage measured 1 ns a
    # tick, 4 to 6 %, slower in `bench codec`; the other kinds' ticks are not)
    rx = -1
    depth = ring.shape[0]
    while S[L.S_COUNT] > 0.0:
        head = int(S[L.S_HEAD])
        if ring[head, 1] > now:
            break
        S[L.S_HEAD] = (head + 1) & (depth - 1)
        S[L.S_COUNT] -= 1.0
        seq = int(ring[head, 0])
        if deadband:
            deadband_receive(C, S, seq, ring, head)
        else:
            prediction_receive(C, S, seq, ring, head)
        if seq > S[L.S_NEWEST]:
            S[L.S_NEWEST] = seq
            rx = seq
    if deadband:
        return rx, deadband_sample(C, S, n, out)
    return rx, prediction_sample(C, S, n, out)


# ------------------------------------------------------------------------------------------
# FEC: the decoder's history of samples (`Reconstructor` over any seqs), recovery, the tick.


@inline  # type: ignore[misc]
def rec_held(C: np.ndarray, S: np.ndarray, X: np.ndarray, seq: int) -> bool:
    # Reconstructor.has: held and not yet forgotten (within keep_ticks of the newest held).
    if seq < 0 or S[L.S_HAS_HELD] == 0.0 or seq < S[L.S_MAXHELD] - C[L.C_KEEP]:
        return False
    return X[seq & (X.shape[0] - 1), L.X_HELD] == seq


@inline  # type: ignore[misc]
def rec_take(C: np.ndarray, S: np.ndarray, X: np.ndarray, seq: int, fresh: bool) -> bool:
    # Reconstructor.add of `seq` but its value (`rec_add`; ARQ's plan moves the value later);
    # False if held already or too old to keep. Not `fresh`: a recovered sample, counted.
    if rec_held(C, S, X, seq):
        return False
    if S[L.S_HAS_HELD] != 0.0 and seq < S[L.S_MAXHELD] - C[L.C_KEEP]:
        if not fresh:
            S[L.S_LATE] += 1.0
        return False
    if not fresh:  # a recovered sample (FecDecoder._add, ArqDecoder's retransmission), maybe late
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


@inline  # type: ignore[misc]
def rec_add(C: np.ndarray, S: np.ndarray, X: np.ndarray, W: np.ndarray, seq: int, fresh: bool) -> bool:
    # Reconstructor.add of the value in W[W_VALUE:] (`rec_take`, then the value).
    if not rec_take(C, S, X, seq, fresh):
        return False
    j = seq & (X.shape[0] - 1)
    for i in range(int(C[L.C_DIM])):
        X[j, L.X_VALUE + i] = W[L.W_VALUE + i]
    return True


@inline  # type: ignore[misc]
def rec_choose(C: np.ndarray, S: np.ndarray, X: np.ndarray, n: int) -> tuple[int, int, int, int]:
    # Reconstructor.sample but its values (`rec_sample`; ARQ's plan keeps the choice): the
    # playout slot, then the held seq to give (the sample at the slot, wait_ticks behind, or the
    # newest held before it; -1: none) and, for a prediction from the newest two held at or
    # before the target, the one before it (-1: hold), the ticks ahead and the span.
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


@inline  # type: ignore[misc]
def rec_give(C: np.ndarray, X: np.ndarray, last: int, prev: int, ahead: int, span: int, out: np.ndarray) -> bool:
    # The values of `rec_choose`'s choice into `out` (False: nothing to give).
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


@inline  # type: ignore[misc]
def rec_sample(C: np.ndarray, S: np.ndarray, X: np.ndarray, n: int, out: np.ndarray) -> bool:
    # Reconstructor.sample: the choice (`rec_choose`) and its values.
    last, prev, ahead, span = rec_choose(C, S, X, n)
    return rec_give(C, X, last, prev, ahead, span, out)


@inline  # type: ignore[misc]
def sum_held(C: np.ndarray, S: np.ndarray, X: np.ndarray, p: int) -> bool:
    # `p in FecDecoder._sums` after its front was dropped (what reaches past the history).
    if p < S[L.S_MAXHELD] - C[L.C_KEEP] + C[L.C_K]:
        return False
    return X[p & (X.shape[0] - 1), L.X_SUM_SEQ] == p


@inline  # type: ignore[misc]
def fec_receive(C: np.ndarray, S: np.ndarray, X: np.ndarray, W: np.ndarray, n: int) -> None:
    # FecDecoder.receive of packet n. A constant delay keeps the stream in order, so the payload
    # is the sender's samples of ticks n, n-1, ..., n-k (repetition) or x(n) and the sum of
    # x(n-k) .. x(n-1) (parity): read here from the sender's rows of X (as many as the packets
    # in flight and k need), the same floats the packet carries.
    dim = int(C[L.C_DIM])
    mask = X.shape[0] - 1
    k = int(C[L.C_K])
    S[L.S_RECEIVED] += 1.0
    jn = n & mask
    for i in range(dim):
        W[L.W_VALUE + i] = X[jn, L.X_SENT + i]
    if not rec_add(C, S, X, W, n, True):
        S[L.S_DUPLICATES] += 1.0
        if C[L.C_PARITY] != 0.0 and sum_held(C, S, X, n):
            return
    if C[L.C_PARITY] == 0.0:
        for q in range(1, k + 1):
            m = n - q
            if m >= 0:
                jm = m & mask
                for i in range(dim):
                    W[L.W_VALUE + i] = X[jm, L.X_SENT + i]
                rec_add(C, S, X, W, m, False)
        return
    # the carrier's parity sum is the encoder's math.fsum of x(n-k) .. x(n-1): computed when a
    # window is solved, from the sender's rows (they reach back far enough: CodecNet)
    X[jn, L.X_SUM_SEQ] = n
    # FecDecoder._parity_recover: solve each window with one unknown (a LIFO worklist)
    oldest = int(S[L.S_MAXHELD]) - int(C[L.C_KEEP])
    W[L.W_STACK] = n
    top = 1
    while top > 0:
        top -= 1
        p = int(W[L.W_STACK + top])
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
                W[L.W_TERMS + c] = X[q & mask, L.X_SENT + i]
                c += 1
            W[L.W_TERMS] = rounded_sum(W, L.W_TERMS, c, W)  # S(p), as the encoder's math.fsum
            c = 1
            for q in range(max(0, p - k), p):
                if q != m:
                    W[L.W_TERMS + c] = -X[q & mask, L.X_VALUE + i]
                    c += 1
            W[L.W_VALUE + i] = rounded_sum(W, L.W_TERMS, c, W)
        if rec_add(C, S, X, W, m, False):
            for q in range(m + 1, m + k + 1):
                if sum_held(C, S, X, q):
                    W[L.W_STACK + top] = q
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
    dim = int(C[L.C_DIM])
    j = n & (X.shape[0] - 1)
    for i in range(dim):
        X[j, L.X_SENT + i] = smp[i]
    S[L.S_OFFERED] += 1.0
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
#
# What ARQ sends, when, what arrives and what the decoder plays do not depend on the samples,
# only on the links' fates: `arq_block` runs the encoder, both links and the decoder ahead for
# up to L.PLAN_TICKS ticks (never past the kernel's chunk, so the state is exact wherever the run
# stops) and writes the plan of each tick into W from C_PLAN: what the decoder gives (nothing,
# a held sample, or an extrapolation from two) and the seqs it accepted. `arq_tick` then only
# moves the samples: the tick's sample into X, each accepted seq's sample from the sender's
# column of its row to the decoder's, the plan's output. (The packets in flight carry no
# payload here: a packet's payload is its seq's sample, X_SENT of its row until that row is
# reused, which the history's length puts after the last copy of the seq can arrive.)


ACK_WIDTH = 53  # core/arq.ACK_WINDOW + 1: the newest seq and the window below it


@inline  # type: ignore[misc]
def ack_old(C: np.ndarray, S: np.ndarray, W: np.ndarray, seq: int) -> None:
    # ArqDecoder: a seq below the window joins the list the next ACK names
    cnt = int(S[L.S_AK_OLD])
    if cnt < C[L.C_ACK_CAP]:
        W[L.W_OLD + cnt] = seq
        S[L.S_AK_OLD] = cnt + 1


@inline  # type: ignore[misc]
def ack_mark(C: np.ndarray, S: np.ndarray, W: np.ndarray, seq: int) -> None:
    # ArqDecoder._mark: the window's bitmaps (as int64: 53 bits), a seq of the since-last-ACK map
    # pushed out of the window onto the list, a seq received below the window onto it once
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
        while out != 0:
            if out & 1:
                ack_old(C, S, W, newest - i - off)
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
            if W[L.W_OLD + q] == seq:
                return
        ack_old(C, S, W, seq)


@inline  # type: ignore[misc]
def ack_one(S: np.ndarray, X: np.ndarray, seq: int) -> float:
    # ArqEncoder.feedback of one seq a cumulative ACK names: 1 if it was pending
    if seq < 0:
        return 0.0
    j = seq & (X.shape[0] - 1)
    if X[j, L.X_PEND] == seq:
        X[j, L.X_PEND] = -1.0
        return 1.0
    return 0.0


@inline  # type: ignore[misc]
def arq_feedback(S: np.ndarray, X: np.ndarray, aS: np.ndarray, aring: np.ndarray, now: int) -> None:
    # ArqEncoder.feedback of the cumulative ACKs due by `now`: (N, B, r...) names N, N - 1 - i
    # for each bit i of B, and the r. A seq an ACK taken before named is pending no more: only
    # the others are looked up, as the window of those named so far allows (ACKs come in order
    # over a constant delay).
    while True:
        head = link_next(aS, aring, now)
        if head < 0:
            break
        seq = int(aring[head, 0])
        full = (int(aring[head, L.ACK_RING_BITS]) << 1) | 1  # bit i: seq - i
        todo = full
        shift = seq - int(S[L.S_FB_N])
        if shift >= 0:
            seen = 0
            if shift < ACK_WIDTH:
                seen = (int(S[L.S_FB_BITS]) & ((1 << (ACK_WIDTH - shift)) - 1)) << shift
            todo = full & ~seen
            S[L.S_FB_N] = seq
            S[L.S_FB_BITS] = float(full | seen)
        acked = 0.0
        i = 0
        while todo != 0:
            if todo & 1:
                acked += ack_one(S, X, seq - i)
            todo >>= 1
            i += 1
        for q in range(int(aring[head, L.ACK_RING_COUNT])):
            acked += ack_one(S, X, int(aring[head, L.ACK_RING_OLD + q]))
        if acked > 0.0:
            S[L.S_ACKED] += acked
        else:
            S[L.S_ACKS_STALE] += 1.0


@inline  # type: ignore[misc]
def arq_cumulative_ack(
    C: np.ndarray, S: np.ndarray, W: np.ndarray, aC: np.ndarray, aS: np.ndarray, aU: np.ndarray, aB: np.ndarray,
    aring: np.ndarray, arec: np.ndarray, n: int, now: int,
) -> None:  # fmt: skip
    # ArqDecoder.acks: the cumulative ACK of tick n (k > 1), at most one every k ticks, into the
    # ACK link (its records not kept, no payload: the ring's columns carry the ACK)
    if S[L.S_AK_DUE] == 0.0 or n - S[L.S_AK_LAST_N] < C[L.C_ACK_EVERY]:
        return
    cnt = int(S[L.S_AK_OLD])
    cap = int(C[L.C_ACK_CAP])
    size = W[L.W_OLD + cap + 1 + cnt]
    S[L.S_ACKS_SENT] += 1.0
    S[L.S_ACK_PACKETS] += 1.0
    S[L.S_ACK_BYTES] += size
    aC[L.C_SIZE] = size
    before = aS[L.S_COUNT]
    link_send(aC, aS, aU, aB, aring, arec, int(S[L.S_AK_NEWEST]), now, W, W, False, False, False)
    if aS[L.S_COUNT] > before:
        j = (int(aS[L.S_HEAD]) + int(before)) & (aring.shape[0] - 1)
        aring[j, L.ACK_RING_BITS] = float(int(S[L.S_AK_BITS]) >> 1)
        aring[j, L.ACK_RING_COUNT] = cnt
        for q in range(cnt):
            aring[j, L.ACK_RING_OLD + q] = W[L.W_OLD + q]
    S[L.S_AK_OLD] = 0.0
    S[L.S_AK_NEW] = 0.0
    S[L.S_AK_DUE] = 0.0
    S[L.S_AK_LAST_N] = n


@part_jit  # type: ignore[misc]
def arq_block(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    X: np.ndarray,
    W: np.ndarray,
    A: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    n0: int,
    n1: int,
) -> None:
    # CodecChannel.step with ArqEncoder / ArqDecoder and the ACK link for ticks n0 .. n1 - 1,
    # all but the samples; the plan of tick n in W's row n - n0 from C_PLAN. The state the
    # ticks change most (the data link's, the sender's, the ACK link's) is kept in locals and
    # written back at the end; the decoder's is `rec_take`'s and `rec_choose`'s, as FEC's. An ACK per data packet
    # (ack_every_ticks 1) is not carried through the ACK link's ring: over its constant delay it
    # is taken D = max(1, ceil(delay / period)) ticks after it is sent, and what `feedback` will
    # make of it is known when it is sent (below); the sender's pending test reads X_ACK_AT.
    aC, aS, aU, aB, aring, arec = A
    mask = X.shape[0] - 1
    dmask = ring.shape[0] - 1
    period_ns = int(C[L.C_PERIOD_NS])
    delay_ns = int(C[L.C_DELAY_NS])
    size = C[L.C_SIZE]
    timeout = C[L.C_TIMEOUT_NS]
    m_ticks = int(C[L.C_M_TICKS])
    nu = C[L.C_NU]
    cumulative = C[L.C_ACK_EVERY] > 1.0
    plan = int(C[L.C_PLAN])
    taken_at = plan + L.PLAN_TICKS * L.P_WIDTH  # the seqs the decoder takes
    # the data link, the sender, the decoder
    u = int(S[L.S_U])
    recs = int(S[L.S_RECS])
    head = int(S[L.S_HEAD])
    count = int(S[L.S_COUNT])
    link_sent = 0
    link_lost = 0
    drop_blackout = 0
    drop_loss = 0
    sent = 0
    retransmitted = 0
    gave_up = 0
    lo = int(S[L.S_PEND_LO])
    received = 0
    duplicates = 0
    newest_rx = int(S[L.S_NEWEST])
    # the ACK link (an ACK per data packet; cumulative ACKs keep its state in aS)
    au = int(aS[L.S_U])
    ahead = int(aS[L.S_HEAD])
    amask = aring.shape[0] - 1
    ack_ticks = int(C[L.C_ACK_TICKS])
    give_up = (nu + 1.0) * C[L.C_M_TICKS]  # a sample is given up at seq + (nu + 1) m
    acks = 0
    acked = 0
    stale = 0
    a_lost = 0
    a_blackout = 0
    a_loss = 0
    taken = 0  # the seqs the decoder took in the plan's ticks so far
    for n in range(n0, n1):
        now = n * period_ns
        row = plan + (n - n0) * L.P_WIDTH
        if cumulative:  # the cumulative ACKs due: ArqEncoder.feedback
            arq_feedback(S, X, aS, aring, now)
        # ArqEncoder.send: the new sample (its value: `arq_tick`), then the pending ones due
        # (in seq order). A pending sample is due every m = ceil(mu / period) ticks after it was
        # sent (the encoder runs every tick), so the only candidates this tick are n - j m,
        # j = nu + 1 .. 1. Every seq below `lo` was acknowledged or given up: its rows are not
        # read. Moved up lazily, a row at a time.
        j = n & mask
        seq = n
        attempt = 0
        jj = int(nu) + 2
        while True:
            # ArqEncoder._packet into Link.send: blackout, loss (its draws whatever the fate),
            # the constant delay, the record; a delivered packet joins the in-flight FIFO with
            # its attempt and send tick
            fate, u = fate_of(C, S, U, B, now, u)
            sent += 1
            link_sent += 1
            rec[recs, 0] = seq
            rec[recs, 1] = float(now) * 1e-9
            rec[recs, 4] = 0.0
            rec[recs, 5] = size
            if fate == 0:
                arrival = now + delay_ns
                rec[recs, 2] = float(arrival) * 1e-9
                rec[recs, 3] = DELIVERED
                k = (head + count) & dmask
                count += 1
                ring[k, 0] = seq
                ring[k, 1] = arrival
                ring[k, L.RING_ATTEMPT] = attempt
                ring[k, L.RING_SENT] = n
            else:
                rec[recs, 2] = np.nan
                rec[recs, 3] = LOST_NETWORK
                link_lost += 1
                if fate == 1:
                    drop_blackout += 1
                else:
                    drop_loss += 1
            recs += 1
            if jj == int(nu) + 2:  # (after the new sample: the candidates' floor)
                while lo < n and not (X[lo & mask, L.X_PEND] == lo and X[lo & mask, L.X_ACK_AT] > n):
                    lo += 1
            # the next candidate due
            seq = -1
            jj -= 1
            while jj > 0:
                c = n - jj * m_ticks
                if c >= lo:
                    k = c & mask
                    if X[k, L.X_PEND] == c and X[k, L.X_ACK_AT] > n and now - X[k, L.X_LAST_NS] >= timeout:
                        if X[k, L.X_TRIES] >= nu:
                            X[k, L.X_PEND] = -1.0
                            gave_up += 1
                        else:
                            X[k, L.X_TRIES] += 1.0
                            X[k, L.X_LAST_NS] = now
                            retransmitted += 1
                            seq = c
                            attempt = int(X[k, L.X_TRIES])
                            break
                jj -= 1
            if seq < 0:
                break
        X[j, L.X_PEND] = n
        X[j, L.X_TRIES] = 0.0
        X[j, L.X_LAST_NS] = now
        X[j, L.X_ACK_AT] = L.X_NO_ACK
        # Link.deliver, ArqDecoder.receive (Reconstructor.add), its ACK into the ACK link
        rx = -1
        while count > 0 and ring[head, 1] <= now:
            h = head
            head = (head + 1) & dmask
            count -= 1
            seq = int(ring[h, 0])
            fresh = ring[h, L.RING_ATTEMPT] == 0.0
            received += 1
            k = seq & mask
            if rec_take(C, S, X, seq, fresh):
                W[taken_at + taken] = seq
                taken += 1
            else:
                duplicates += 1
            if seq > newest_rx:
                newest_rx = seq
                rx = seq
            if cumulative:
                ack_mark(C, S, W, seq)
                continue
            # The ACK of `seq` into the ACK link (its fate: blackout, loss) and, when it gets
            # through, what ArqEncoder.feedback makes of it at tick t = n + D: it takes the
            # sample off the pending ones if the sample is still pending then, that is: still
            # the sample of its row of X (not given up, the row not reused), no ACK on its way
            # before this one (ACKs arrive in the order they are sent), and t not after the tick
            # it would be given up at (ACKs are taken before the sends of a tick). Else the ACK
            # is stale. The counts are the encoder's at t: an ACK still on its way when the run
            # ends is taken back (`CodecNet.store`) from the ring of ACKs on their way (t, taken).
            acks += 1
            afate, au = fate_of(aC, aS, aU, aB, now, au)
            if afate != 0:
                a_lost += 1
                if afate == 1:
                    a_blackout += 1
                else:
                    a_loss += 1
                continue
            t = n + ack_ticks
            took = X[k, L.X_PEND] == seq and X[k, L.X_ACK_AT] == L.X_NO_ACK and t <= seq + give_up
            if took:
                X[k, L.X_ACK_AT] = t
                acked += 1
            else:
                stale += 1
            a = ahead & amask
            ahead += 1
            aring[a, 0] = t
            aring[a, 1] = 1.0 if took else 0.0
        if cumulative:  # ArqDecoder.acks: the cumulative ACK of the tick, at most one every k ticks
            arq_cumulative_ack(C, S, W, aC, aS, aU, aB, aring, arec, n, now)
        W[row + L.P_RX] = rx
        W[row + L.P_TAKEN] = taken
        # Reconstructor.sample's choice (its values: `arq_tick`)
        last, prev, ahead_ticks, span = rec_choose(C, S, X, n)
        W[row + L.P_LAST] = last
        W[row + L.P_PREV] = prev
        W[row + L.P_AHEAD] = ahead_ticks
        W[row + L.P_SPAN] = span
    S[L.S_U] = u
    S[L.S_RECS] = recs
    S[L.S_HEAD] = head
    S[L.S_COUNT] = count
    S[L.S_LINK_SENT] += link_sent
    S[L.S_LINK_LOST] += link_lost
    S[L.S_DROP_BLACKOUT] += drop_blackout
    S[L.S_DROP_LOSS] += drop_loss
    S[L.S_OFFERED] += n1 - n0
    S[L.S_SENT] += sent
    S[L.S_BYTES] += sent * size
    S[L.S_RETRANSMITTED] += retransmitted
    S[L.S_GAVE_UP] += gave_up
    S[L.S_PEND_LO] = lo
    S[L.S_RECEIVED] += received
    S[L.S_DUPLICATES] += duplicates
    S[L.S_NEWEST] = newest_rx
    if not cumulative:
        S[L.S_ACKS_SENT] += acks
        S[L.S_ACK_PACKETS] += acks
        S[L.S_ACK_BYTES] += acks * C[L.C_ACK_SIZE]
        S[L.S_ACKED] += acked
        S[L.S_ACKS_STALE] += stale
        aS[L.S_U] = au
        aS[L.S_HEAD] = ahead
        aS[L.S_LINK_SENT] += acks
        aS[L.S_LINK_LOST] += a_lost
        aS[L.S_DROP_BLACKOUT] += a_blackout
        aS[L.S_DROP_LOSS] += a_loss


@inline  # type: ignore[misc]
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
    n1: int,
    smp: np.ndarray,
    out: np.ndarray,
) -> tuple[int, bool]:
    # CodecChannel.step with ArqEncoder / ArqDecoder at tick n (the kernel's chunk ends at n1):
    # the plan of the next ticks made when the last one is used up (`arq_block`), then the
    # tick's samples moved as it says.
    if n >= S[L.S_PLAN_END]:
        end = min(n + L.PLAN_TICKS, n1)
        arq_block(C, S, U, B, ring, rec, X, W, A, n, end)
        S[L.S_PLAN_N0] = n
        S[L.S_PLAN_END] = end
    dim = int(C[L.C_DIM])
    mask = X.shape[0] - 1
    j = n & mask
    for i in range(dim):
        X[j, L.X_SENT + i] = smp[i]
    plan = int(C[L.C_PLAN])
    i0 = n - int(S[L.S_PLAN_N0])
    row = plan + i0 * L.P_WIDTH
    first = 0 if i0 == 0 else int(W[row - L.P_WIDTH + L.P_TAKEN])
    taken_at = plan + L.PLAN_TICKS * L.P_WIDTH
    for q in range(taken_at + first, taken_at + int(W[row + L.P_TAKEN])):
        k = int(W[q]) & mask
        for i in range(dim):
            X[k, L.X_VALUE + i] = X[k, L.X_SENT + i]
    last, prev = int(W[row + L.P_LAST]), int(W[row + L.P_PREV])
    got = rec_give(C, X, last, prev, int(W[row + L.P_AHEAD]), int(W[row + L.P_SPAN]), out)
    return int(W[row + L.P_RX]), got


# ------------------------------------------------------------------------------------------
# HLI: the sender's classes and rate window, the receiver N_HLI1 ticks behind its newest packet
# (X's rows: H_* of codec_layout; W: which followers may be filtered, how many follow that may
# not, the window's (tick, bits) ring).


@inline  # type: ignore[misc]
def hli_play(C: np.ndarray, S: np.ndarray, X: np.ndarray, t: int) -> None:
    # HliDecoder._play
    dim = int(C[L.C_DIM])
    j = t & (X.shape[0] - 1)
    got = X[j, L.H_RTAG] == t
    if got:
        X[j, L.H_RTAG] = L.H_NONE
    rb = X[j, L.H_BTAG] == t
    if rb:
        X[j, L.H_BTAG] = L.H_NONE
    if got:
        S[L.S_PLAYED] += 1.0
        for i in range(dim):
            S[L.S_DT2 + i] = X[j, L.H_PREV + i]
            S[L.S_DT1 + i] = X[j, L.H_SMP + i]
        S[L.S_DT1H] = 1.0
        S[L.S_DT2H] = 1.0
        return
    if rb:
        S[L.S_REBUILT] += 1.0
        for i in range(dim):
            S[L.S_DT2 + i] = S[L.S_DT1 + i]
            S[L.S_DT1 + i] = X[j, L.H_BX + i]
        S[L.S_DT2H] = S[L.S_DT1H]
        S[L.S_DT1H] = 1.0
        return
    if S[L.S_DT1H] == 0.0:
        return
    S[L.S_DPREDICTED] += 1.0
    linear = C[L.C_HLINEAR] != 0.0 and S[L.S_DT2H] != 0.0
    for i in range(dim):
        a = S[L.S_DT1 + i]
        x = linear1(a, S[L.S_DT2 + i]) if linear else a
        S[L.S_DT2 + i] = a
        S[L.S_DT1 + i] = x
    S[L.S_DT2H] = 1.0


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
    dim = int(C[L.C_DIM])
    mask = X.shape[0] - 1
    N = int(C[L.C_HN])
    S[L.S_OFFERED] += 1.0
    # HliEncoder.send: the rate window
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
    # the prediction of the mirrored track (into `rate`, unused by HLI)
    has_pred = S[L.S_ET1H] != 0.0
    if has_pred:
        linear = C[L.C_HLINEAR] != 0.0 and S[L.S_ET2H] != 0.0
        for i in range(dim):
            rate[i] = linear1(S[L.S_ET1 + i], S[L.S_ET2 + i]) if linear else S[L.S_ET1 + i]
    S[L.S_ESINCE] += 1.0
    cls = 0
    big = S[L.S_ESEEN] < C[L.C_HWARMUP] or not has_pred
    if not big:
        acc = 0.0
        for i in range(dim):
            d = smp[i] - rate[i]
            acc += d * d
        big = math.sqrt(acc) >= C[L.C_HTHRESH]
    if big:
        cls = 2
        S[L.S_ESINCE] = 0.0
        for i in range(dim):
            S[L.S_EH2 + i] = smp[i]
    elif S[L.S_ESINCE] <= N:
        cls = 1
    S[L.S_ESEEN] += 1.0
    S[L.S_LAST_CLASS] = cls
    S[L.S_HLI0 + cls] += 1.0
    send = cls != 0
    since = int(S[L.S_ESINCE])
    if cls == 1 and W[since] != 0.0:
        need = C[L.C_HBITS1] * (1.0 + W[N + 1 + since])
        if S[L.S_WIN_BITS] + need > C[L.C_HBUDGET]:
            send = False
            S[L.S_FILT1] += 1.0
    elif cls == 0:
        S[L.S_FILT0] += 1.0
    # the previous true sample (into `out` for now), the track
    for i in range(dim):
        out[i] = smp[i] if S[L.S_EPREVH] == 0.0 else S[L.S_EPREV + i]
        S[L.S_EPREV + i] = smp[i]
    S[L.S_EPREVH] = 1.0
    if send or not has_pred:
        for i in range(dim):
            S[L.S_ET2 + i] = out[i]
            S[L.S_ET1 + i] = smp[i]
        S[L.S_ET2H] = 1.0
    else:
        for i in range(dim):
            S[L.S_ET2 + i] = S[L.S_ET1 + i]
            S[L.S_ET1 + i] = rate[i]
        S[L.S_ET2H] = S[L.S_ET1H]
    S[L.S_ET1H] = 1.0
    if send:
        j = n & mask
        for i in range(dim):
            X[j, L.H_SMP + i] = smp[i]
            X[j, L.H_PREV + i] = out[i]
            X[j, L.H_COPY + i] = S[L.S_EH2 + i]
        X[j, L.H_CLASS] = cls
        X[j, L.H_OFF] = 0.0 if cls == 2 else since
        bits = C[L.C_HBITS2] if cls == 2 else C[L.C_HBITS1]
        k = (int(S[L.S_WIN_HEAD]) + int(S[L.S_WIN_COUNT])) % cap
        W[base + 2 * k] = n
        W[base + 2 * k + 1] = bits
        S[L.S_WIN_COUNT] += 1.0
        S[L.S_WIN_BITS] += bits
        S[L.S_SENT] += 1.0
        S[L.S_WIRE_BITS] += bits
        if S[L.S_WIN_BITS] > C[L.C_HBUDGET]:
            S[L.S_OVER] += 1.0
        C[L.C_SIZE] = C[L.C_HSIZE2] if cls == 2 else C[L.C_HSIZE1]
        link_send(C, S, U, B, ring, rec, n, now, smp, rate, False)
    # Link.deliver, HliDecoder.receive
    rx = -1
    while True:
        head = link_next(S, ring, now)
        if head < 0:
            break
        seq = int(ring[head, 0])
        S[L.S_RECEIVED] += 1.0
        rx = newest(S, seq, rx)
        if S[L.S_CURH] != 0.0 and seq <= S[L.S_CUR]:
            S[L.S_DLATE] += 1.0
            continue
        j = seq & mask
        X[j, L.H_RTAG] = seq
        if S[L.S_CURH] == 0.0 and (S[L.S_MINH] == 0.0 or seq < S[L.S_MIN]):
            S[L.S_MIN] = seq
            S[L.S_MINH] = 1.0
        if X[j, L.H_CLASS] == 1.0:
            key = seq - int(X[j, L.H_OFF])
            if S[L.S_CURH] == 0.0 or key > S[L.S_CUR]:
                jr = key & mask
                if X[jr, L.H_BTAG] != key:
                    X[jr, L.H_BTAG] = key
                    for i in range(dim):
                        X[jr, L.H_BX + i] = X[j, L.H_COPY + i]
        if S[L.S_FRH] == 0.0 or seq > S[L.S_FRMAX]:
            S[L.S_FRMAX] = seq
            S[L.S_FRH] = 1.0
    # HliDecoder.sample
    if S[L.S_FRH] != 0.0:
        lag = n - int(S[L.S_FRMAX])
        if S[L.S_LAGH] == 0.0 or lag < S[L.S_LAG]:
            S[L.S_LAG] = lag
            S[L.S_LAGH] = 1.0
        S[L.S_FRH] = 0.0
    if S[L.S_LAGH] == 0.0:
        return rx, False
    target = n - int(S[L.S_LAG]) - int(C[L.C_HDELAY])
    if S[L.S_CURH] == 0.0:
        first = int(S[L.S_MIN]) if S[L.S_MINH] != 0.0 else target
        S[L.S_CUR] = min(first, target + 1) - 1
        S[L.S_CURH] = 1.0
    while S[L.S_CUR] < target:
        S[L.S_CUR] += 1.0
        hli_play(C, S, X, int(S[L.S_CUR]))
    if S[L.S_DT1H] == 0.0:
        return rx, False
    for i in range(dim):
        out[i] = S[L.S_DT1 + i]
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
    n1: int,
    now: int,
    smp: np.ndarray,
    rate: np.ndarray,
    out: np.ndarray,
) -> tuple[int, bool]:
    # CodecChannel.step of a direction at tick n, whatever its compiled kind (FEC, ARQ, HLI: X,
    # W, A their history, scratch and ACK link; ARQ plans ahead up to n1, the end of the chunk).
    if C[L.C_KIND] == L.HLI:
        return hli_tick(C, S, U, B, ring, rec, X, W, n, now, smp, rate, out)
    if C[L.C_KIND] == L.ARQ:
        return arq_tick(C, S, U, B, ring, rec, X, W, A, n, n1, smp, out)
    if C[L.C_KIND] == L.FEC:
        return fec_tick(C, S, U, B, ring, rec, X, W, n, now, smp, rate, out)
    return deadband_prediction_tick(C, S, U, B, ring, rec, W, n, now, smp, rate, out)


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
    fcodec = fC[L.C_KIND] != L.NO_CODEC
    bcodec = bC[L.C_KIND] != L.NO_CODEC
    period_ns = int(fC[L.C_PERIOD_NS])
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
            frx, got = codec_tick(fC, fS, fU, fB, fring, frec, fX, fW, fA, n, n1, now, smp, rate, out)
            if got:
                accept2(P, S, out[0], out[1])
            focc = 0.0
        else:
            frx = forward_released(P, S, n - w0, n & fmask, fmask, fwd_rel, fwd_hist, x_m, v_m)
            focc = fwd_occ[n - w0]
        # slave
        fs, s_desired = control(P, S, SLAVE, x_s, v_s, False)
        if bcodec:
            smp[0] = f_env
            smp[1] = x_s
            smp[2] = v_s
            brx, got = codec_tick(bC, bS, bU, bB, bring, brec, bX, bW, bA, n, n1, now, smp, rate, out)
            if got:
                accept3(P, S, out[0], out[1], out[2])
            bocc = 0.0
        else:
            brx = backward_released(P, S, n - w0, n & bmask, bmask, bwd_rel, bwd_hist, f_env, x_s, v_s)
            bocc = bwd_occ[n - w0]
        finish_tick(
            n, models, mq, mv, mctrl, sctrl, sqfrc, P, S, data[n - d0], x_m, v_m, x_s, v_s, f_env,
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
        _rx, got = codec_tick(C, S, U, B, ring, rec, X, W, A, n, samples.shape[0], n * period_ns, smp, rate, out)
        if got:
            got_ticks += 1
    return got_ticks
