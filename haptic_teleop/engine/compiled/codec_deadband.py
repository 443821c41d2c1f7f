"""The deadband (seed 001) and prediction codecs inside the compiled loops (numba):
`CodecChannel.step`'s order for these kinds; the deadband's encoder (rate, trigger) and decoder
(receive, hold or extrapolate), prediction's reconstruction over its sample history and the
per-sample formulas are core/deadband.py's and core/prediction.py's, compiled from their one
definition.
"""

from __future__ import annotations

import numpy as np

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import codec_layout as L
from haptic_teleop.core import deadband as db
from haptic_teleop.core import prediction as pr
from haptic_teleop.engine.compiled.codec_link import inline, jit, link_send, packet_send

extrapolate1 = jit(pr.extrapolate1)


# Prediction's reconstruction over its sample history, one definition (core/prediction.py, as
# FEC's and ARQ's: codec_fec.py).
rec_take = compile_tree(pr.rec_take, inline=True)


rec_sample = compile_tree(pr.rec_sample, inline=True)


# GroupedDeadbandEncoder's send and DeadbandDecoder's receive and sample, one definition
# (core/deadband.py): the places of their vectors are passed (a relaid arm tick passes the arm
# layout's, and its 3-value trigger groups).
encoder_send = compile_tree(db.encoder_send, inline=True)


decoder_receive = compile_tree(db.decoder_receive, inline=True)


decoder_sample = compile_tree(db.decoder_sample, inline=True)


@inline  # type: ignore[misc]
def deadband_prediction_tick(
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
    # CodecChannel.step with deadband or prediction (X: prediction's sample history):
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
        else:  # PredictionDecoder.receive: Reconstructor.add, fresh
            S[L.S_RECEIVED] += 1.0
            if rec_take(C, S, X, seq, True):
                j = seq & (X.shape[0] - 1)
                for i in range(int(C[L.C_DIM])):
                    X[j, L.X_VALUE + i] = ring[head, 2 + i]
            else:
                S[L.S_DUPLICATES] += 1.0
        if seq > S[L.S_NEWEST]:
            S[L.S_NEWEST] = seq
            rx = seq
    if deadband:
        return rx, decoder_sample(C, S, n, out, L.S_LAST0, L.S_RATE0)
    return rx, rec_sample(C, S, X, n, out)
