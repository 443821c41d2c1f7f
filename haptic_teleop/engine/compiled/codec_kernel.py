"""The compiled 1-DoF loop with the codec stage (numba), imported only when a scene with a codec
runs compiled, so codec-less runs never compile or load it (engine/compiled/codec_host.py has the
design, engine/compiled/codec_layout.py the arrays' layouts).

The tick is `axis_kernel.run_ticks`'s (the same helpers: `control`, `forward_released`,
`backward_released`, `accept2`, `accept3`, `finish_tick`); a direction with a codec replaces
its schedule lookup by `codec_tick`, which is
`CodecChannel.step` line for line: encoder, link (blackout, loss, constant delay; a deadband's
jitter), deliveries, decoder. `codec_tick` is compiled once and called by both directions (inlined
into each, numba would copy its IR at every level: cold compile 230 s against about 90;
docs/architecture.md, "Inlined or called"); it dispatches on the kind: deadband and prediction
inlined into it (`deadband_prediction_tick`),
FEC and HLI compiled once each (`fec_tick`, `hli_tick`), ARQ (with its ACK link) planned ahead
a chunk at a time by `arq_block`, compiled once, and its samples moved by `arq_tick`. The
per-sample formulas are compiled from their one definition in core/deadband.py,
core/prediction.py, core/loss.py, core/hli_codec.py; the parity sums (`math.fsum` in core/fec.py's classes) from
`fec.rounded_sum`, which gives the same value.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

from haptic_teleop.core import codec_layout as L
from haptic_teleop.engine.compiled import driver
from haptic_teleop.engine.compiled.axis_kernel import (
    AXIS_SIDES,
    accept2,
    accept3,
    schedule_backward,
    schedule_forward,
    schedule_open,
)
from haptic_teleop.engine.compiled.codec_arq import arq_tick
from haptic_teleop.engine.compiled.codec_deadband import deadband_prediction_tick
from haptic_teleop.engine.compiled.codec_fec import fec_tick
from haptic_teleop.engine.compiled.codec_hli import hli_tick
from haptic_teleop.engine.compiled.codec_link import inline, part_jit

# The loop itself without numba's reference counting (NRT): it allocates nothing, and every
# array handed to an inlined part would otherwise be counted in and out with atomic operations,
# which cost ten times the codec's own work (180 against 15 ns a tick for `prediction`).
loop_jit = numba.njit(cache=True, nogil=True, _nrt=False)


@part_jit  # type: ignore[misc]
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


# The channels of the compiled tick (engine/compiled/driver.py) with a codec: a direction is its
# codec's arrays (C, S, U, B, ring, rec, X, W, A), whether it has a codec (else it runs on its
# schedule: `axis_kernel.schedule_forward`), `now`'s period, the scratch rows of the sample, its
# rate and the decoder's output, and the schedule's direction.


@inline  # type: ignore[misc]
def codec_open(net: Any) -> Any:
    codec, scratch, sched = net
    C = codec[0]
    return (
        codec, C[L.C_KIND] != L.NO_CODEC, int(C[L.C_PERIOD_NS]), scratch[0], scratch[1], scratch[2],
        schedule_open(sched),
    )  # fmt: skip


@inline  # type: ignore[misc]
def codec_forward(run: Any, f: Any, t: Any, n: int, n1: int) -> tuple[int, float]:
    # CodecChannel.step of the forward direction: the master's (x, v) in, the slave's remote
    # sample out through its guard.
    codec, has_codec, period_ns, smp, rate, out, sched = f
    if not has_codec:
        return schedule_forward(run, sched, t, n, n1)
    C, S, U, B, ring, rec, X, W, A = codec
    smp[0] = t[0]
    smp[1] = t[1]
    rx, got = codec_tick(C, S, U, B, ring, rec, X, W, A, n, n1, n * period_ns, smp, rate, out)
    if got:
        accept2(run[8], run[9], out[0], out[1])
    return rx, 0.0


@inline  # type: ignore[misc]
def codec_backward(run: Any, b: Any, t: Any, n: int, n1: int) -> tuple[int, float]:
    # The backward direction: the slave's (f_env, x, v) in, the master's remote sample out.
    codec, has_codec, period_ns, smp, rate, out, sched = b
    if not has_codec:
        return schedule_backward(run, sched, t, n, n1)
    C, S, U, B, ring, rec, X, W, A = codec
    smp[0] = t[4]
    smp[1] = t[2]
    smp[2] = t[3]
    rx, got = codec_tick(C, S, U, B, ring, rec, X, W, A, n, n1, n * period_ns, smp, rate, out)
    if got:
        accept3(run[8], run[9], out[0], out[1], out[2])
    return rx, 0.0


# The one-axis sides with these channels
drive_axis_codec = driver.compose(
    **AXIS_SIDES, open_forward=codec_open, open_backward=codec_open, forward=codec_forward, backward=codec_backward
)


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
    # others read their window of the schedule as there). The directions share the scratch rows.
    run = (models, mq, mv, mctrl, sq, sv, sctrl, sqfrc, P, S, data, d0)
    fnet = ((fC, fS, fU, fB, fring, frec, fX, fW, fA), scratch, (fwd_rel, fwd_occ, fwd_hist, w0))
    bnet = ((bC, bS, bU, bB, bring, brec, bX, bW, bA), scratch, (bwd_rel, bwd_occ, bwd_hist, w0))
    return drive_axis_codec(n0, n1, run, fnet, bnet)  # type: ignore[no-any-return]


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
