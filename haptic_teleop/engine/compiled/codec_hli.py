"""HLI inside the compiled loops (numba): the sender's classes and rate window, the receiver N_HLI1
ticks behind its newest packet, its rebuild of a lost HLI2 event (core/hli_codec.py's `linear1`,
compiled from its one definition).
"""

from __future__ import annotations

import math

import numpy as np

from haptic_teleop.core import codec_layout as L
from haptic_teleop.core import hli_codec
from haptic_teleop.engine.compiled.codec_link import inline, jit, link_next, link_send, newest, part_jit

linear1 = jit(hli_codec.linear1)


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
