"""FEC inside the compiled loops (numba): `CodecChannel.step`'s order for this kind; the encoder's and
decoder's steps are core/fec.py's (`fec_sent`, `fec_payload`, `fec_receive`: `FecEncoder`'s and
`FecDecoder`'s own functions) and the reconstruction over the decoder's history core/prediction.py's
(`rec_take`, `rec_sample`, ...: `Reconstructor`'s), compiled from their one definition. The
layouts' places of X and W are passed (a relaid arm tick passes the arm layout's).
"""

from __future__ import annotations

import numpy as np

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import codec_layout as L
from haptic_teleop.core import fec
from haptic_teleop.core import prediction as pr
from haptic_teleop.engine.compiled.codec_link import link_next, newest, packet_send, part_jit

# (the parity sums: compiled once and called, not inlined at each of their calls)
rounded_sum = part_jit(fec.rounded_sum)


# The reconstruction over the sample history, one definition (core/prediction.py: `Reconstructor`
# calls the same functions): inlined here, and by the ARQ tick.
rec_take = compile_tree(pr.rec_take, inline=True)


rec_choose = compile_tree(pr.rec_choose, inline=True)


rec_give = compile_tree(pr.rec_give, inline=True)


rec_sample = compile_tree(pr.rec_sample, inline=True)


# FecEncoder's and FecDecoder's steps, one definition (core/fec.py)
fec_sent = compile_tree(fec.fec_sent, inline=True)


fec_payload = compile_tree(fec.fec_payload, inline=True, bound={"rounded_sum": rounded_sum})


fec_receive = compile_tree(fec.fec_receive, inline=True, bound={"rounded_sum": rounded_sum})


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
    # CodecChannel.step with FecEncoder / FecDecoder. A packet's payload is the encoder's, made
    # when it arrives from the sender's rows of X (as many as the packets in flight and k need):
    # the same floats the packet carries.
    fec_sent(C, S, X, n, smp, L.X_SENT)
    S[L.S_OFFERED] += 1.0
    packet_send(C, S, U, B, ring, rec, n, now, smp, rate)
    rx = -1
    while True:
        head = link_next(S, ring, now)
        if head < 0:
            break
        seq = int(ring[head, 0])
        fec_payload(C, S, X, W, seq, L.X_SENT, L.W_TERMS)
        fec_receive(C, S, X, W, seq, L.X_SUM_SEQ, L.W_TERMS)
        rx = newest(S, seq, rx)
    return rx, rec_sample(C, S, X, n, out)
