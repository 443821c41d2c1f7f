"""The compiled arm loop with the codec stage (numba), imported only when an arm scene with a
codec runs compiled (`arm_host.codec_kernel`), so codec-less arm runs never compile or
load it (docs/codec_compiled_arm.md).

The tick is the driver's (engine/compiled/driver.py) composed of `arm_kernel`'s sides (`ARM_SIDES`)
and the channels below; a direction with a
codec replaces its schedule lookup by `CodecChannel.step` for an arm scene's sample
(assembly.channel.LAYOUT_ARM: forward x, v; backward x, v, f; 3 task axes each): the 1-DoF codec
kernel's ticks (engine/compiled/codec_kernel.py: `deadband_prediction_tick` and `arq_tick` inlined
into `arm_codec_step`, which both directions call; `fec_tick`, `hli_tick` and ARQ's plan,
`arq_block`, compiled once each) with their encoders,
links, decoders and helpers,
compiled from their one definition with the arm layout's places (`relaid`: codec_layout's
ARM_LAYOUT, the vectors of S, X's, the ring's, W's and HLI's columns for 9 values, and the
deadband's 3-value trigger groups). The decoded sample goes
through the receiving side's guard every tick the decoder gives one, as in the Python arm loop.
"""

from __future__ import annotations

import types as pytypes
from typing import Any

import numba
import numpy as np

from haptic_teleop.core import codec_layout as L
from haptic_teleop.engine.compiled import codec_arq, codec_deadband, codec_fec, codec_hli, codec_link, driver
from haptic_teleop.engine.compiled.arm_kernel import (
    ARM_SIDES,
    arm_schedule_backward,
    arm_schedule_forward,
    arm_schedule_open,
    backward_sample,
    borrowed,
    forward_sample,
    guarded,
    loop_jit,
)

inline = numba.njit(cache=True, nogil=True, inline="always")
part_jit = codec_link.part_jit  # compiled once, without reference counting

# The places of the arm layout that differ from the 1-DoF layout's (by codec_layout name).
ARM_PLACES: dict[str, Any] = dict(L.ARM_LAYOUT)
# The modules of the 1-DoF loop's codec stage, whose functions `relaid` compiles again.
_CODEC_MODULES = {m.__name__ for m in (codec_link, codec_deadband, codec_fec, codec_arq, codec_hli)}


def relaid(f: Any, places: dict[str, Any], _done: dict[Any, Any] | None = None) -> Any:
    """The codec stage's function `f` (a function of `_CODEC_MODULES`) compiled from its own
    definition with the layout constants of `places` (ints: in place of codec_layout's, which `f`
    reads as `L.NAME`) and the callees of `places` (functions) in place of its module's; every
    other function of the codec stage it calls
    (inlined or not: `arq_tick`'s `arq_block`) is relaid the same way (its other globals,
    compiled callees of other modules included, are their module's). Compiled as `f` is
    (inlined, or compiled once without reference counting) but not cached: the kernel calling
    it is."""
    done: dict[Any, Any] = {} if _done is None else _done
    if f in done:
        return done[f]
    py = f.py_func
    layout = pytypes.ModuleType(L.__name__ + "_relaid")
    layout.__dict__.update(vars(L))
    glob = dict(py.__globals__)
    for name, value in places.items():
        if isinstance(value, int):
            setattr(layout, name, value)
    glob["L"] = layout
    for name in py.__code__.co_names:
        g = glob.get(name)
        if name in places and not isinstance(places[name], int):
            glob[name] = places[name]
        elif isinstance(g, numba.core.registry.CPUDispatcher) and g.py_func.__module__ in _CODEC_MODULES:
            glob[name] = relaid(g, places, done)
    fn = pytypes.FunctionType(py.__code__, glob, py.__name__, py.__defaults__, py.__closure__)
    fn.__qualname__ = py.__qualname__
    fn.__module__ = py.__module__
    options = {k: v for k, v in f.targetoptions.items() if k not in ("nopython", "boundscheck")}
    done[f] = out = numba.njit(**options)(fn)
    return out


# CodecChannel.step of an arm scene's direction: codec_kernel's ticks with the arm layout's places
# (one relaying: the helpers they share are compiled once).
_relaid: dict[Any, Any] = {}
_ARM = ARM_PLACES
arm_codec_tick = relaid(codec_deadband.deadband_prediction_tick, _ARM, _relaid)
arm_fec_tick = relaid(codec_fec.fec_tick, _ARM, _relaid)
arm_arq_tick = relaid(codec_arq.arq_tick, _ARM, _relaid)
arm_hli_tick = relaid(codec_hli.hli_tick, _ARM, _relaid)


# The channels of the compiled tick (engine/compiled/driver.py) for an arm scene with a codec: a
# direction is its codec's arrays (C, S, U, B, ring, rec, X, W, A) as `borrowed` views, whether it
# has a codec (else it runs on its schedule: `arm_kernel.arm_schedule_forward`), `now`'s period,
# the scratch rows of the sample, its rate and the decoder's output, and the schedule's direction.


@inline  # type: ignore[misc]
def arm_codec_open(net: Any) -> Any:
    codec, scratch, sched = net
    C, S, U, B, ring, rec, X, W, A = codec
    a = (borrowed(A[0]), borrowed(A[1]), borrowed(A[2]), borrowed(A[3]), borrowed(A[4]), borrowed(A[5]))
    arrays = (borrowed(C), borrowed(S), borrowed(U), borrowed(B), borrowed(ring), borrowed(rec))
    return (
        (*arrays, borrowed(X), borrowed(W), a), C[L.C_KIND] != L.NO_CODEC, int(C[L.C_PERIOD_NS]),
        borrowed(scratch[0]), borrowed(scratch[1]), borrowed(scratch[2]), arm_schedule_open(sched),
    )  # fmt: skip


@part_jit  # type: ignore[misc]
def arm_codec_step(
    net: Any, n: int, n1: int, now: int, smp: np.ndarray, rate: np.ndarray, dec: np.ndarray
) -> tuple[int, bool]:
    """CodecChannel.step of a direction whose sample is in `smp`, whatever its kind: the row's
    `received` seq (-1: none) and whether the decoder gave a sample (in `dec`). Compiled once and
    called by both directions (inlined into each, it would be compiled twice: compile time)."""
    C, S, U, B, ring, rec, X, W, A = net
    kind = C[L.C_KIND]
    if kind == L.FEC:
        return arm_fec_tick(C, S, U, B, ring, rec, X, W, n, now, smp, rate, dec)  # type: ignore[no-any-return]
    if kind == L.ARQ:
        return arm_arq_tick(C, S, U, B, ring, rec, X, W, A, n, n1, smp, dec)  # type: ignore[no-any-return]
    if kind == L.HLI:
        return arm_hli_tick(C, S, U, B, ring, rec, X, W, n, now, smp, rate, dec)  # type: ignore[no-any-return]
    return arm_codec_tick(C, S, U, B, ring, rec, X, W, n, now, smp, rate, dec)  # type: ignore[no-any-return]


@inline  # type: ignore[misc]
def codec_delivered(
    side: Any, net: Any, n: int, n1: int, now: int, smp: np.ndarray, rate: np.ndarray, dec: np.ndarray
) -> int:
    """CodecChannel.step of a direction (`arm_codec_step`) with the decoded sample through the
    receiving `side`'s guard. Returns the row's `received` seq (-1: none)."""
    rx, got = arm_codec_step(net, n, n1, now, smp, rate, dec)
    if got:
        guarded(side, dec)
    return rx


@inline  # type: ignore[misc]
def arm_codec_forward(run: Any, f: Any, t: int, n: int, n1: int) -> tuple[int, float]:
    net, has_codec, period_ns, smp, rate, dec, sched = f
    if not has_codec:
        return arm_schedule_forward(run, sched, t, n, n1)
    forward_sample(smp, run[8], run[0])
    return codec_delivered(run[1], net, n, n1, n * period_ns, smp, rate, dec), 0.0


@inline  # type: ignore[misc]
def arm_codec_backward(run: Any, b: Any, t: int, n: int, n1: int) -> tuple[int, float]:
    net, has_codec, period_ns, smp, rate, dec, sched = b
    if not has_codec:
        return arm_schedule_backward(run, sched, t, n, n1)
    backward_sample(smp, run[8], run[1])
    return codec_delivered(run[0], net, n, n1, n * period_ns, smp, rate, dec), 0.0


# The arm sides with these channels
drive_arm_codec = driver.compose(
    **ARM_SIDES,
    open_forward=arm_codec_open,
    open_backward=arm_codec_open,
    forward=arm_codec_forward,
    backward=arm_codec_backward,
)


@loop_jit  # type: ignore[misc]
def run_ticks_codec(
    n0: int,
    n1: int,
    ms_own: Any,
    ss_own: Any,
    mw_own: Any,
    sw_own: Any,
    ov: np.ndarray,
    cols: np.ndarray,
    own: np.ndarray,
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
    fX: np.ndarray,
    fW: np.ndarray,
    fA: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    bX: np.ndarray,
    bW: np.ndarray,
    bA: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> int:
    """`arm_kernel.run_ticks` with a codec on the directions whose C_KIND is not NO_CODEC (the
    others read their window of the schedule as there). fC ... frec, bC ... brec: each
    direction's codec arrays (codec_host.CodecNet.args, the arm layout); scratch: 3 rows of
    9 (the sample, its rate, the decoder's output), shared by the directions; fX, fW, fA, bX, bW,
    bA: each direction's sample history, scratch and ACK link (CodecNet.history)."""
    world = (ms_own, ss_own, mw_own, sw_own, ov, cols, data, d0, own)
    fnet = ((fC, fS, fU, fB, fring, frec, fX, fW, fA), scratch, (fwd_rel, fwd_occ, fwd_hist, w0))
    bnet = ((bC, bS, bU, bB, bring, brec, bX, bW, bA), scratch, (bwd_rel, bwd_occ, bwd_hist, w0))
    return drive_arm_codec(n0, n1, world, fnet, bnet)  # type: ignore[no-any-return]
