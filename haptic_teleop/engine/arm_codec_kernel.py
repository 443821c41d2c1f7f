"""The compiled arm loop with the codec stage (numba), imported only when an arm scene with a
codec runs compiled (`compiled_arm_loop.codec_kernel`), so codec-less arm runs never compile or
load it (docs/codec.md, "Compiled", "Arm scenes").

The tick is `arm_kernel.run_ticks`'s, from the same inlined parts (`sense`, `side_torque`,
`forward_sample`, `backward_sample`, `released`, `guarded`, `finish_tick`); a direction with a
codec replaces its schedule lookup by `arm_codec_tick`, which is `CodecChannel.step` for an arm
scene's sample (codec_channel.LAYOUT_ARM: forward x, v; backward x, v, f; 3 task axes each): the
1-DoF codec kernel's `deadband_prediction_tick` (engine/codec_kernel.py) and its encoder, link
and decoders, compiled from their one definition with the arm layout's places of the vectors
(`relaid`: codec_layout's ARM_S_* instead of S_SENT0, S_LAST0, ...) and the grouped deadband's
test on 3-value groups (`arm_deadband_triggered`). The decoded sample goes through the receiving side's guard every tick
the decoder gives one, as in the Python arm loop.
"""

from __future__ import annotations

import math
import types as pytypes
from typing import Any

import numba
import numpy as np

from haptic_teleop.engine import codec_kernel as ck
from haptic_teleop.engine import codec_layout as L
from haptic_teleop.engine.arm_kernel import (
    V_QDM,
    V_QDS,
    V_QM,
    V_QS,
    V_TAU_M,
    V_TAU_S,
    V_VM,
    V_VS,
    V_XM,
    V_XS,
    backward_sample,
    borrowed,
    finish_tick,
    forward_sample,
    guarded,
    released,
    run_start,
    sense,
    side_torque,
)

jit = numba.njit(cache=True, nogil=True)
inline = numba.njit(cache=True, nogil=True, inline="always")

# Where the vectors of a direction's state are in the arm layout (the 1-DoF names they replace).
ARM_PLACES = {
    "S_SENT0": L.ARM_S_SENT0,
    "S_PREV0": L.ARM_S_PREV0,
    "S_LAST0": L.ARM_S_LAST0,
    "S_OLD0": L.ARM_S_OLD0,
    "S_RATE0": L.ARM_S_RATE0,
}


def relaid(f: Any, places: dict[str, Any]) -> Any:
    """The inlined codec_kernel function `f` compiled from its own definition with the layout
    constants of `places` (ints: in place of codec_layout's, which `f` reads as `L.NAME`) and
    the inlined callees of `places` (functions) in place of its module's (its other globals,
    compiled callees included, are its module's)."""
    py = f.py_func
    layout = pytypes.ModuleType(L.__name__ + "_relaid")
    layout.__dict__.update(vars(L))
    glob = dict(py.__globals__)
    for name, value in places.items():
        if isinstance(value, int):
            setattr(layout, name, value)
        else:
            glob[name] = value
    glob["L"] = layout
    fn = pytypes.FunctionType(py.__code__, glob, py.__name__, py.__defaults__, py.__closure__)
    fn.__qualname__ = py.__qualname__
    fn.__module__ = py.__module__
    return numba.njit(nogil=True, inline="always")(fn)


@inline  # type: ignore[misc]
def arm_deadband_triggered(C: np.ndarray, S: np.ndarray, smp: np.ndarray) -> bool:
    # codec_kernel.deadband_triggered on 3-value groups (GroupedDeadbandEncoder: the distance and
    # the norm of a group summed in order as core/deadband.vector_norm; p(|v|) likewise).
    p = C[L.C_P0]
    if C[L.C_GAIN] > 0.0:
        vel = int(C[L.C_VEL])
        s2 = 0.0
        for i in range(vel, vel + L.ARM_AXES):
            s2 += smp[i] * smp[i]
        p = ck.deadband_p(C[L.C_P0], C[L.C_GAIN], C[L.C_PMAX], math.sqrt(s2))
    for g in range(0, int(C[L.C_DIM]), L.ARM_AXES):
        if C[L.ARM_C_TRIG0 + g] != 0.0:  # violates(last[g], sample[g], p, min_threshold)
            d2 = 0.0
            l2 = 0.0
            for i in range(g, g + L.ARM_AXES):
                last = S[L.ARM_S_SENT0 + i]
                d = last - smp[i]
                d2 += d * d
                l2 += last * last
            if ck.outside(math.sqrt(d2), math.sqrt(l2), p, C[L.C_MIN]):
                return True
    return False


# CodecChannel.step of an arm scene's direction: codec_kernel's deadband/prediction tick with the
# arm layout's places and the group trigger (link_send uses scalars of the state only: the same).
arm_codec_tick = relaid(
    ck.deadband_prediction_tick,
    {
        **ARM_PLACES,
        "deadband_triggered": arm_deadband_triggered,
        "deadband_receive": relaid(ck.deadband_receive, ARM_PLACES),
        "deadband_sample": relaid(ck.deadband_sample, ARM_PLACES),
        "prediction_receive": relaid(ck.prediction_receive, ARM_PLACES),
        "prediction_sample": relaid(ck.prediction_sample, ARM_PLACES),
    },
)


@inline  # type: ignore[misc]
def delivered(
    codec: bool, side: Any, n: int, now: int, w0: int, rel: np.ndarray, occ: np.ndarray, hist: np.ndarray,
    mask: int, net: Any, smp: np.ndarray, rate: np.ndarray, dec: np.ndarray,
) -> tuple[int, float]:  # fmt: skip
    """A direction's network at tick n after its sample was written (`smp` with a codec, else the
    sender's ring): the codec's tick (`net`: C, S, U, B, ring, rec) with the decoded sample through
    the receiving `side`'s guard, or the schedule's release. Returns the row's `received` seq (-1:
    none) and buffer occupancy (0 with a codec)."""
    if codec:
        C, S, U, B, ring, rec = net
        rx, got = arm_codec_tick(C, S, U, B, ring, rec, n, now, smp, rate, dec)
        if got:
            guarded(side, dec)
        return rx, 0.0
    return released(side, rel[n - w0], hist, mask), occ[n - w0]


@jit  # type: ignore[misc]
def run_ticks_codec(
    n0: int,
    n1: int,
    ms_own: Any,
    ss_own: Any,
    mw_own: Any,
    sw_own: Any,
    ov: np.ndarray,
    cols: np.ndarray,
    fwd_rel: np.ndarray,
    fwd_occ: np.ndarray,
    bwd_rel: np.ndarray,
    bwd_occ: np.ndarray,
    fwd_hist: np.ndarray,
    bwd_hist: np.ndarray,
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
) -> int:
    """`arm_kernel.run_ticks` with a codec on the directions whose C_KIND is not NO_CODEC (the
    others read their window of the schedule as there). fC ... frec, bC ... brec: each
    direction's codec arrays (compiled_codec.CodecNet.args, the arm layout); scratch: 3 rows of
    9 (the sample, its rate, the decoder's output)."""
    ms, ss, mw, sw, ov, cols, fwd_rel, fwd_occ, bwd_rel, bwd_occ, fwd_hist, bwd_hist, data, own, v, c = run_start(
        ms_own, ss_own, mw_own, sw_own, ov, cols, fwd_rel, fwd_occ, bwd_rel, bwd_occ, fwd_hist, bwd_hist, data
    )
    fnet = (borrowed(fC), borrowed(fS), borrowed(fU), borrowed(fB), borrowed(fring), borrowed(frec))
    bnet = (borrowed(bC), borrowed(bS), borrowed(bU), borrowed(bB), borrowed(bring), borrowed(brec))
    smp, rate, dec = borrowed(scratch[0]), borrowed(scratch[1]), borrowed(scratch[2])
    fcodec = fC[L.C_KIND] != L.NO_CODEC
    bcodec = bC[L.C_KIND] != L.NO_CODEC
    period_ns = int(fC[L.C_PERIOD_NS])
    fmask = fwd_hist.shape[0] - 1
    bmask = bwd_hist.shape[0] - 1
    for n in range(n0, n1):
        now = n * period_ns
        sense(ms, ss, mw, sw, v, c)  # 1. both arms
        side_torque(ms, v[V_QM], v[V_QDM], v[V_XM], v[V_VM], v[V_TAU_M], mw)  # 2. master
        # 3. forward packet (the codec's, or the schedule's release)
        forward_sample(smp if fcodec else fwd_hist[n & fmask], v)
        frx, focc = delivered(fcodec, ss, n, now, w0, fwd_rel, fwd_occ, fwd_hist, fmask, fnet, smp, rate, dec)
        side_torque(ss, v[V_QS], v[V_QDS], v[V_XS], v[V_VS], v[V_TAU_S], sw)  # 4. slave
        # 5. backward packet
        backward_sample(smp if bcodec else bwd_hist[n & bmask], v)
        brx, bocc = delivered(bcodec, ms, n, now, w0, bwd_rel, bwd_occ, bwd_hist, bmask, bnet, smp, rate, dec)
        # 6. operator, plants, the row
        finish_tick(n, ms, ss, mw, sw, ov, cols, v, c, data[n - d0], frx, brx, focc, bocc)
    own[0, 0] = 0.0  # `own` lives until here, past every use of its views
    return n1
