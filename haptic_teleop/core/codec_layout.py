"""The state layouts of the codecs and their links: one direction's constants (C) and state (S)
as float64 vectors, its sample history (X), scratch (W) and in-flight ring, and the codes kept in
them. core's array functions (`deadband.decoder_receive`, ...) read and write these places, the
Python objects that hold such state (`deadband.DeadbandDecoder`) and the compiled loops
(engine/compiled/codec_*.py, their host codec_host.py) both hand them the same arrays; the module
imports nothing (docs/codec_compiled.md)."""

# Codec kinds the kernel runs (C_KIND; 0: the direction has no codec and runs on its schedule).
NO_CODEC, DEADBAND, PREDICTION = 0.0, 1.0, 2.0
COMPILED_KINDS = ("deadband", "prediction", "fec", "arq", "hli")
ARM_COMPILED_KINDS = COMPILED_KINDS  # the compiled arm loop's (engine/compiled/arm_codec_kernel.py)
FEC, ARQ, HLI = 3.0, 4.0, 5.0
LOSS_NONE, LOSS_BERNOULLI, LOSS_GILBERT, LOSS_FOUR_STATE, LOSS_TRACE = 0.0, 1.0, 2.0, 3.0, 4.0

# C: one direction's constants.
(
    C_KIND, C_DIM, C_PERIOD_NS, C_SIZE, C_DELAY_NS, C_LOSS, C_LP, C_LR, C_LBAD, C_LGOOD,
    C_P0, C_MIN, C_GAIN, C_PMAX, C_EXTRAP, C_SENDS_RATE, C_MAX_AHEAD, C_VEL,
    C_TRIG0, C_TRIG1, C_TRIG2, C_KEEP, C_MAX_TICKS,
) = range(23)  # fmt: skip
C_SIZE_ALL = 24
TRIGGER_GROUP = 1  # the deadband's trigger groups: a value each (an arm's: a quantity's 3 task axes)
# S: one direction's state.
(
    S_HAS_SENT, S_SENT0, S_SENT1, S_SENT2, S_HAS_PREV, S_PREV0, S_PREV1, S_PREV2, S_PREV_NS,
    S_OFFERED, S_SENT, S_FILTERED,
    S_HAS_LAST, S_LAST_SEQ, S_LAST0, S_LAST1, S_LAST2,
    S_HAS_OLD, S_OLD_SEQ, S_OLD0, S_OLD1, S_OLD2,
    S_HAS_RATE, S_RATE0, S_RATE1, S_RATE2,
    S_RECEIVED, S_STALE, S_EXTRAPOLATED,
    S_PENDING, S_HAS_SLOT, S_SLOT, S_SLOT_N, S_PREDICTED, S_BYTES,
    S_U, S_U_END, S_BAD, S_HEAD, S_COUNT, S_RECS, S_NEWEST, S_BLACKOUT_I,
    S_LINK_SENT, S_LINK_LOST, S_DROP_BLACKOUT, S_DROP_LOSS,
) = range(47)  # fmt: skip
S_SIZE_ALL = 48
RING_WIDTH = 8  # seq, arrival_ns, payload (at most 6 values: a 3-value sample and its rate)

# FEC, ARQ (and the shared reconstruction over a sample history): constants and state after the above.
C_PARITY, C_K, C_WAIT, C_TIMEOUT_NS, C_NU, C_ACK_SIZE = range(24, 30)
# HLI: N_HLI1, predictor, warm-up, threshold, rate window, budget, bits and sizes by class, the
# decoder's delay
(
    C_HN, C_HLINEAR, C_HWARMUP, C_HTHRESH, C_HWIN, C_HBUDGET, C_HBITS1, C_HBITS2, C_HSIZE1, C_HSIZE2,
    C_HDELAY,
) = range(30, 41)  # fmt: skip
C_M_TICKS = 41  # ARQ: m = ceil(mu / period), the ticks between a sample's tries
# ARQ's cumulative ACKs: k (ack_every_ticks; 1: an ACK per data packet), the capacity of the list
# of seqs below the window (k (1 + nu): the data packets of k ticks)
C_ACK_EVERY, C_ACK_CAP = 42, 43
# ARQ with an ACK per data packet: D = max(1, ceil(ACK link delay / period)), the ticks after
# its sending that the sender takes an ACK (`codec_arq.arq_block`)
C_ACK_TICKS = 44
# A deadband direction's link with jitter (core/delay.Delay: uncorrelated or netem-correlated, no
# time-varying part, no reordering): the jitter distribution's table length in W (0: uniform,
# 2 u - 1), the delay and the jitter (ns, as Delay keeps them), whether arrivals keep their order
# (1.0) or not
C_JIT, C_JN, C_JBASE_NS, C_JSIGMA_NS, C_JKEEP = range(45, 50)
C_JRHO = 50  # netem's correlation of the jitter's uniform numbers (0: none)
C_PLAN = 51  # ARQ: where its plan starts in W (`codec_arq.arq_block`)
C_LRHO = 52  # netem's correlation of a Bernoulli loss's uniform numbers (0: none)
# The loss's parameters: Bernoulli's probability (C_LP); Gilbert-Elliott's p, r, 1-h, 1-k (C_LP,
# C_LR, C_LBAD, C_LGOOD); the 4-state chain's p13, p31, p32, p23 there and p14 (C_LP14), its state
# in S_BAD; a trace's pattern in U (0/1, a packet each) and whether it repeats (C_LP), S_U the
# packets so far
C_LP14 = 53
# FEC: where its packet's payload and the log of the samples a packet recovered start in W
# (`core.fec.fec_receive`)
C_WPAY, C_WLOG = 54, 55
C_SIZE_X = 56  # C's length with these
(
    S_HAS_HELD, S_MAXHELD, S_HAS_FRESH, S_NEWEST_FRESH, S_HAS_PLAYED, S_LAST_PLAYED, S_LATE,
    S_RECOVERED, S_RECOVERED_LATE, S_DUPLICATES,
    S_ACKED, S_ACKS_STALE, S_GAVE_UP, S_RETRANSMITTED, S_ACKS_SENT, S_ACK_PACKETS, S_ACK_BYTES, S_PEND_LO,
) = range(48, 66)  # fmt: skip
# (S_PEND_LO, ARQ's sender: every seq below it was acknowledged or given up)
# HLI: the encoder's mirrored track, counters and rate window; the decoder's track, lag, cursor
(
    S_ET1H, S_ET1, S_ET1B, S_ET1C, S_ET2H, S_ET2, S_ET2B, S_ET2C, S_ESEEN, S_ESINCE,
    S_EH2, S_EH2B, S_EH2C, S_EPREVH, S_EPREV, S_EPREVB, S_EPREVC, S_WIN_HEAD, S_WIN_COUNT, S_WIN_BITS,
    S_HLI0, S_HLI1, S_HLI2, S_FILT0, S_FILT1, S_WIRE_BITS, S_OVER, S_LAST_CLASS,
    S_DT1H, S_DT1, S_DT1B, S_DT1C, S_DT2H, S_DT2, S_DT2B, S_DT2C,
    S_LAGH, S_LAG, S_CURH, S_CUR, S_MINH, S_MIN, S_FRH, S_FRMAX,
    S_REBUILT, S_DPREDICTED, S_PLAYED, S_DLATE,
) = range(66, 114)  # fmt: skip
# ARQ's cumulative ACKs (core/arq.ArqDecoder): the newest seq received, the window's bitmaps of
# the seqs received ever and since the last ACK (53 bits: exact in a float64), an ACK due, the
# tick of the last ACK, the number of seqs below the window to name (listed in W from W_OLD)
S_AK_NEWEST, S_AK_BITS, S_AK_NEW, S_AK_DUE, S_AK_LAST_N, S_AK_OLD = range(114, 120)
# and the sender's: the newest seq of the last cumulative ACK it took and the window of the seqs
# the ACKs it took named (bit i: that newest - i), which it need not look up again
S_FB_N, S_FB_BITS = 120, 121
# the jitter's uniform numbers in W (the next, the end) and the last arrival kept in order
S_JU, S_JU_END, S_LAST_ARRIVAL = 122, 123, 124
S_JLAST = 125  # netem's last correlated uniform number
S_PLAN_N0, S_PLAN_END = 126, 127  # ARQ: the ticks its plan in W covers (from, to)
S_LLAST = 128  # netem's last correlated uniform number of a Bernoulli loss
# FEC's sender: whether it sent, its first and its last seq (`core.fec.fec_sent`)
S_FHAS, S_FFIRST, S_FLAST = 129, 130, 131
S_SIZE_X = 132  # S's length with these
# X: a codec's sample history, a row per seq modulo its (power-of-two) length: the decoder's held
# sample (seq, values), a parity sum received (seq, values) or ARQ's pending sample (seq,
# retransmissions, last sent, the tick its first ACK to arrive is taken: X_NO_ACK while none is
# on its way), the sender's sample of that tick.
X_HELD, X_VALUE, X_SUM_SEQ, X_SUM, X_SENT, X_WIDTH = 0, 1, 4, 5, 8, 11
X_PEND, X_TRIES, X_LAST_NS, X_ACK_AT = 4, 5, 6, 7
X_NO_ACK = 1e18
# ARQ's data packets in flight: the ring's attempt and send tick columns
RING_ATTEMPT, RING_SENT = 6, 7
# W: a codec's scratch: partial sums, a value, the terms of a sum, the recovery worklist (FEC:
# then a packet's payload from C_WPAY, the samples it recovered from C_WLOG: their count, seqs).
W_VALUE, W_TERMS, W_STACK = 200, 204, 280  # the partial sums from 0
# ARQ's cumulative ACKs: the seqs below the window (C_ACK_CAP of them at most), then the ACK's
# message size by that count (0 .. C_ACK_CAP); the ACK link's ring: seq (the newest), arrival,
# bitmap, count, the seqs below the window
W_OLD = W_STACK
ACK_RING_BITS, ACK_RING_COUNT, ACK_RING_OLD = 2, 3, 4
# ARQ's plan (`codec_arq.arq_block`), in W from C_PLAN: PLAN_TICKS rows of P_WIDTH values, a
# tick each: the received column's seq, the decoder's choice (`codec_fec.rec_choose`: the held
# seq it gives, -1 none; the one before it to extrapolate from, -1 none; the ticks ahead and the
# span), and how many seqs the decoder took in the plan's ticks up to this one; then those seqs,
# in the order taken (at most the packets that arrive in a tick, 1 + nu over a constant delay, a
# tick).
PLAN_TICKS = 100  # (windows.CHUNK_TICKS: a chunk's ticks planned at once)
P_RX, P_LAST, P_PREV, P_AHEAD, P_SPAN, P_TAKEN, P_WIDTH = range(7)
# HLI's X: the packet of a tick (its payload from H_PAY in the wire's order: x..., class, offset,
# previous x...[, copy of the HLI2 sample...], 3 dim + 2 values at most: the sender's, which the
# compiled loop's receiver reads, or the one the Python decoder received), the decoder's received
# mark and rebuilt sample (a tag: the seq it holds, H_NONE when none; core/hli_codec.py).
H_PAY, H_RTAG, H_BTAG, H_BX, H_WIDTH = 0, 11, 12, 13, 16
H_NONE = -1e18

# An arm scene's codec directions (engine/compiled/arm_codec_kernel.py): the scalars above at the same
# places; the vectors (a sample of up to 9 values: 3 quantities of 3 task axes) after them, and
# X, the ring and W laid out for 9 values (ARM_LAYOUT: the places that differ from the 1-DoF
# layout's, by name; the kernel is compiled with them, `arm_codec_kernel.relaid`).
ARM_AXES = 3
ARM_DIM = 9
ARM_C_TRIG0 = C_SIZE_X  # 9 flags: the value is in a trigger group (the groups: 3 values each)
ARM_C_SIZE = ARM_C_TRIG0 + ARM_DIM
# S's vectors: the deadband's and prediction's (sent, previous, last, old, rate), HLI's tracks
(
    ARM_S_SENT0, ARM_S_PREV0, ARM_S_LAST0, ARM_S_OLD0, ARM_S_RATE0,
    ARM_S_ET1, ARM_S_ET2, ARM_S_EH2, ARM_S_EPREV, ARM_S_DT1, ARM_S_DT2,
) = range(S_SIZE_X, S_SIZE_X + 11 * ARM_DIM, ARM_DIM)  # fmt: skip
ARM_S_SIZE = S_SIZE_X + 11 * ARM_DIM
ARM_RING_WIDTH = 2 + 2 * ARM_DIM  # seq, arrival_ns, a 9-value sample and its rate (ARQ: no rate,
ARM_RING_ATTEMPT, ARM_RING_SENT = 2 + ARM_DIM, 3 + ARM_DIM  # its attempt and send tick there)
ARM_X_SUM_SEQ = 1 + ARM_DIM
ARM_X_SENT = 2 + 2 * ARM_DIM
ARM_H_RTAG = 3 * ARM_DIM + 2  # (after the payload)
ARM_LAYOUT = {
    "C_TRIG0": ARM_C_TRIG0,
    "TRIGGER_GROUP": ARM_AXES,
    "S_SENT0": ARM_S_SENT0,
    "S_PREV0": ARM_S_PREV0,
    "S_LAST0": ARM_S_LAST0,
    "S_OLD0": ARM_S_OLD0,
    "S_RATE0": ARM_S_RATE0,
    "S_ET1": ARM_S_ET1,
    "S_ET2": ARM_S_ET2,
    "S_EH2": ARM_S_EH2,
    "S_EPREV": ARM_S_EPREV,
    "S_DT1": ARM_S_DT1,
    "S_DT2": ARM_S_DT2,
    "RING_ATTEMPT": ARM_RING_ATTEMPT,
    "RING_SENT": ARM_RING_SENT,
    "RING_WIDTH": ARM_RING_WIDTH,
    # X: held seq, value; parity sum seq (ARQ: pending seq, tries, last sent); the sender's sample
    "X_SUM_SEQ": ARM_X_SUM_SEQ,
    "X_SUM": ARM_X_SUM_SEQ + 1,
    "X_PEND": ARM_X_SUM_SEQ,
    "X_TRIES": ARM_X_SUM_SEQ + 1,
    "X_LAST_NS": ARM_X_SUM_SEQ + 2,
    "X_ACK_AT": ARM_X_SUM_SEQ + 3,
    "X_SENT": ARM_X_SENT,
    "X_WIDTH": ARM_X_SENT + ARM_DIM,
    # W: a value of 9, then the terms of a sum (at most 65: k <= 64) before W_STACK
    "W_TERMS": W_VALUE + ARM_DIM,
    # HLI's X
    "H_RTAG": ARM_H_RTAG,
    "H_BTAG": ARM_H_RTAG + 1,
    "H_BX": ARM_H_RTAG + 2,
    "H_WIDTH": ARM_H_RTAG + 2 + ARM_DIM,
}
