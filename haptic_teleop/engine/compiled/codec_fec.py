"""FEC inside the compiled loops (numba): repetition and parity recovery and the tick over the
decoder's history of samples, whose reconstruction is core/prediction.py's (`rec_take`,
`rec_sample`, ...: `Reconstructor`'s own functions); the parity sums are core/fec.py's
`rounded_sum` (the value `math.fsum` gives in the Python classes).
"""

from __future__ import annotations

import numpy as np

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import codec_layout as L
from haptic_teleop.core import fec
from haptic_teleop.core import prediction as pr
from haptic_teleop.engine.compiled.codec_link import inline, link_next, newest, packet_send, part_jit

rounded_sum = part_jit(fec.rounded_sum)


# The reconstruction over the sample history, one definition (core/prediction.py: `Reconstructor`
# calls the same functions): inlined here, and by the ARQ tick.
rec_held = compile_tree(pr.rec_held, inline=True)


rec_take = compile_tree(pr.rec_take, inline=True)


rec_choose = compile_tree(pr.rec_choose, inline=True)


rec_give = compile_tree(pr.rec_give, inline=True)


rec_sample = compile_tree(pr.rec_sample, inline=True)


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
