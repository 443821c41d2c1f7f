"""The compiled 1-DoF loop with the codec stage (numba), imported only when a scene with a codec
runs compiled, so codec-less runs never compile or load it (engine/compiled/codec_host.py has the
design, engine/compiled/codec_layout.py the arrays' layouts).

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

import numba
import numpy as np

from haptic_teleop.core import codec_layout as L
from haptic_teleop.engine.compiled.axis_kernel import (
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
from haptic_teleop.engine.compiled.codec_arq import arq_tick
from haptic_teleop.engine.compiled.codec_deadband import deadband_prediction_tick
from haptic_teleop.engine.compiled.codec_fec import fec_tick
from haptic_teleop.engine.compiled.codec_hli import hli_tick
from haptic_teleop.engine.compiled.codec_link import inline

# The loop itself without numba's reference counting (NRT): it allocates nothing, and every
# array handed to an inlined part would otherwise be counted in and out with atomic operations,
# which cost ten times the codec's own work (180 against 15 ns a tick for `prediction`).
loop_jit = numba.njit(cache=True, nogil=True, _nrt=False)


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
    return deadband_prediction_tick(C, S, U, B, ring, rec, X, W, n, now, smp, rate, out)


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
