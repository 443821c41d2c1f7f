"""ARQ inside the compiled loops (numba): pending samples, retransmissions, the decoder's ACKs through
the ACK link, planned a chunk ahead (`arq_block`: nothing it decides depends on the samples), and
each tick's samples moved by `arq_tick`.
"""

from __future__ import annotations

import numpy as np

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import arq
from haptic_teleop.core import codec_layout as L
from haptic_teleop.engine.compiled.codec_fec import rec_choose, rec_give, rec_take
from haptic_teleop.engine.compiled.codec_link import (
    DELIVERED,
    LOST_NETWORK,
    fate_of,
    inline,
    link_next,
    link_send,
    part_jit,
)

ACK_WIDTH = arq.ACK_WIDTH


# The receiver's cumulative ACKs, one definition (core/arq.py: `ArqDecoder` calls the same
# functions); the seqs below the window in W from W_OLD.
ack_mark = compile_tree(arq.ack_mark, inline=True)


ack_due = compile_tree(arq.ack_due, inline=True)


# the sender's timeout rule and its reading of a cumulative ACK, one definition (core/arq.py:
# `ArqEncoder.send`, `cumulative_seqs`)
retry_verdict = compile_tree(arq.retry_verdict, inline=True)


named_mask = compile_tree(arq.named_mask, inline=True)


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
        full = named_mask(int(aring[head, L.ACK_RING_BITS]))  # bit i: seq - i
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
    cnt = ack_due(C, S, n)
    if cnt < 0:
        return
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
                    if X[k, L.X_PEND] == c and X[k, L.X_ACK_AT] > n:
                        verdict = retry_verdict(X[k, L.X_TRIES], X[k, L.X_LAST_NS], now, timeout, nu)
                        if verdict == arq.GIVE_UP:
                            X[k, L.X_PEND] = -1.0
                            gave_up += 1
                        elif verdict == arq.RETRANSMIT:
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
                ack_mark(C, S, W, seq, L.W_OLD)
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
