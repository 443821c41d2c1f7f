"""HLI inside the compiled loops (numba): `CodecChannel.step`'s order for this kind; the encoder's
and decoder's steps are core/hli_codec.py's (`hli_send`, `hli_receive`, `hli_sample`:
`HliEncoder`'s and `HliDecoder`'s own functions), compiled from their one definition. The layouts'
places of S and X are passed (a relaid arm tick passes the arm layout's).
"""

from __future__ import annotations

import numpy as np

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import codec_layout as L
from haptic_teleop.core import hli_codec
from haptic_teleop.engine.compiled.codec_link import link_next, link_send, newest, part_jit

# HliEncoder's and HliDecoder's steps, one definition (core/hli_codec.py)
hli_send = compile_tree(hli_codec.hli_send, inline=True)


hli_receive = compile_tree(hli_codec.hli_receive, inline=True)


hli_sample = compile_tree(hli_codec.hli_sample, inline=True)


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
    # CodecChannel.step with HliEncoder / HliDecoder (`rate`: scratch for the encoder's
    # prediction). The link carries a packet's seq: its payload stays in the sender's row of X,
    # which is the receiver's row of that seq.
    if hli_send(C, S, W, X, n, smp, rate, L.S_ET1, L.S_ET2, L.S_EH2, L.S_EPREV):
        link_send(C, S, U, B, ring, rec, n, now, smp, rate, False)
    rx = -1
    while True:
        head = link_next(S, ring, now)
        if head < 0:
            break
        seq = int(ring[head, 0])
        rx = newest(S, seq, rx)
        hli_receive(C, S, X, seq, X, seq & (X.shape[0] - 1), L.H_RTAG, L.H_BTAG, L.H_BX)
    return rx, hli_sample(C, S, X, n, out, L.H_RTAG, L.H_BTAG, L.H_BX, L.S_DT1, L.S_DT2)
