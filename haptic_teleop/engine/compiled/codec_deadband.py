"""The deadband (seed 001) and prediction codecs inside the compiled loops (numba):
`CodecChannel.step`'s order for these kinds; the deadband's encoder (rate, trigger) and decoder
(receive, hold or extrapolate) and the per-sample formulas are core/deadband.py's and
core/prediction.py's, compiled from their one definition.
"""

from __future__ import annotations

import numpy as np

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import codec_layout as L
from haptic_teleop.core import deadband as db
from haptic_teleop.core import prediction as pr
from haptic_teleop.engine.compiled.codec_link import inline, jit, link_send, packet_send

extrapolate1 = jit(pr.extrapolate1)


# GroupedDeadbandEncoder's send and DeadbandDecoder's receive and sample, one definition
# (core/deadband.py): the places of their vectors are passed (a relaid arm tick passes the arm
# layout's, and its 3-value trigger groups).
encoder_send = compile_tree(db.encoder_send, inline=True)


decoder_receive = compile_tree(db.decoder_receive, inline=True)


decoder_sample = compile_tree(db.decoder_sample, inline=True)


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
    deadband = C[L.C_KIND] == L.DEADBAND
    if deadband:  # GroupedDeadbandEncoder.send
        if encoder_send(C, S, smp, rate, now, L.S_SENT0, L.S_PREV0, L.C_TRIG0, L.TRIGGER_GROUP):
            link_send(C, S, U, B, ring, rec, n, now, smp, rate, C[L.C_SENDS_RATE] != 0.0, True, True, W)
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
            decoder_receive(C, S, seq, ring, head, L.S_LAST0, L.S_OLD0, L.S_RATE0)
        else:
            prediction_receive(C, S, seq, ring, head)
        if seq > S[L.S_NEWEST]:
            S[L.S_NEWEST] = seq
            rx = seq
    if deadband:
        return rx, decoder_sample(C, S, n, out, L.S_LAST0, L.S_RATE0)
    return rx, prediction_sample(C, S, n, out)
