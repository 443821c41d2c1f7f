"""The Python loop around every compiled kernel (1-DoF and arm, with or without the codec stage).

The network's decisions are made a window of ticks ahead of the kernel (`axis_host.schedule`:
nothing a schedule decides depends on what packets carry); a direction whose codec runs in the
kernel (`codec_host.CodecNet`) has no schedule: its arrays (random numbers, room for records)
are made ready READY_TICKS ahead, and the kernel's codec arguments are built again only then. The
kernel runs CHUNK_TICKS at a time, so progress, full blocks of rows and a stop are seen between
chunks. (Readying the nets and building the arguments every chunk was about 3 us of Python a
chunk, and the loop after it ran slower on cold caches: 1 to 6 points of a codec run's real-time
factor, docs/codec_cost.md.)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from haptic_teleop.engine.compiled.codec_host import no_codec, no_history
from haptic_teleop.plants.mujoco_native import mujoco_timers_off

CHUNK_TICKS = 100  # the compiled loop returns to Python this often (progress, blocks, Ctrl-C)
READY_TICKS = 1000  # the codec nets' arrays are made ready this far ahead (a multiple of CHUNK_TICKS)

# call(c0, c1, fwd_rel, fwd_occ, bwd_rel, bwd_occ, fwd_ring, bwd_ring, w0, codec): ticks [c0, c1)
# of the kernel, with the window of the schedules' decisions from tick w0 on, the sent payloads'
# rings and the codec kernel's trailing arguments (`codec_tail`; empty when no direction has a
# codec).
KernelCall = Callable[
    [int, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, tuple[Any, ...]], Any
]


def run_windows(
    engine: Any,
    call: KernelCall,
    schedules: tuple[Any, Any],
    nets: Sequence[Any],
    rings: Any,
    output: Any,
    window: int,
    progress: Callable[[int], None] | None,
    scratch: np.ndarray | None = None,
) -> int:
    """Ticks from 0 until `engine.ticks` or `engine.stop_requested` (a stop requested before the
    loop still runs one chunk): window by window each direction's schedule (None: its net's
    codec runs in the kernel), `rings` fitted to the window, then `call` chunk by chunk, each net
    made `ready` up to READY_TICKS ahead; `engine.ticks_done` follows, `progress` every 100
    ticks, `output`'s block handed over when full. The nets' state is stored back however the
    loop ends. `scratch`: the codec kernel's scratch rows (needed when a net is given). Returns
    the ticks done."""
    fwd, bwd = schedules
    codec = any(net is not None for net in nets)
    idle = no_codec(engine.period_ns)
    tail: tuple[Any, ...] = ()
    ready_to = 0
    n_ticks = engine.ticks
    block_ticks = output.block.shape[0]
    done = 0
    engine.ticks_done = 0
    try:
        with mujoco_timers_off():
            while done < n_ticks:
                w0, w1 = done, min(done + window, n_ticks)
                if fwd is None or bwd is None:
                    none = np.full(w1 - w0, -1, dtype=np.int64), np.zeros(w1 - w0)
                frel, focc = none if fwd is None else fwd.window(w0, w1)
                brel, bocc = none if bwd is None else bwd.window(w0, w1)
                rings.fit(frel, brel, w0, w1)
                for c0 in range(w0, w1, CHUNK_TICKS):
                    c1 = min(c0 + CHUNK_TICKS, w1)
                    if codec and c1 > ready_to:
                        ready_to = min(c0 + READY_TICKS, w1)
                        for net in nets:
                            if net is not None:
                                net.ready(ready_to - c0)
                        assert scratch is not None
                        tail = codec_tail(nets, idle, scratch)  # (`ready` may replace arrays)
                    call(c0, c1, frel, focc, brel, bocc, rings.fwd, rings.bwd, w0, tail)
                    done = engine.ticks_done = c1
                    if progress is not None and done % 100 == 0:
                        progress(done)
                    if done - output.start == block_ticks:
                        output.block_done(done)
                    if engine.stop_requested:
                        break
                if engine.stop_requested:
                    break
    finally:
        for net in nets:
            if net is not None:
                net.store()
    return done


def codec_tail(nets: Sequence[Any], idle: tuple[np.ndarray, ...], scratch: np.ndarray) -> tuple[Any, ...]:
    """The codec kernels' trailing arguments: each direction's codec arrays (`idle`, those of no
    codec, where it has no net), the scratch rows, then each direction's sample history, scratch
    and ACK link (X, W, A; FEC, ARQ, HLI)."""
    fnet, bnet = nets
    no_x = no_history()
    return (
        *(idle if fnet is None else fnet.args()),
        *(idle if bnet is None else bnet.args()),
        scratch,
        *(no_x if fnet is None else fnet.history()),
        *(no_x if bnet is None else bnet.history()),
    )
