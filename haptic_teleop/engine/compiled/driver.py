"""The compiled tick: one driver, `drive`, in engine/loop.py's order, composed per kernel from
that kernel's stages (docs/architecture.md, "One tick").

`drive` is plain Python that names its stages as globals; `compose` compiles it with a kernel's
stages bound to those names (`compiling.compile_tree`), inlined into the kernel's entry point
(numba IR), so a composed driver costs nothing over a loop written out by hand. The four
kernels are four compositions of the same driver:

| kernel | sides | channels |
| --- | --- | --- |
| `axis_kernel.run_ticks` | one axis (`control`, `finish_tick`) | the schedule's releases |
| `codec_kernel.run_ticks_codec` | one axis | a codec's tick, or the schedule's releases |
| `arm_kernel.run_ticks` | two arms (`sense`, `side_torque`, `finish_tick`) | the schedule's releases |
| `arm_codec_kernel.run_ticks_codec` | two arms | a codec's tick, or the schedule's releases |

A stage is a compiled function (inlined) of this interface; the stubs below name it and say what
each does. `run` is what `begin` made of the kernel's run arguments, `f` and `b` what
`open_forward` and `open_backward` made of each direction's; `t0`, `t1`, `t2` are the tick's
values as the stages hand them on (a side that keeps them in arrays hands on anything).
Importing this module needs no numba: `compose` imports it.
"""

from __future__ import annotations

from typing import Any


def _stage(*_args: Any) -> Any:
    raise NotImplementedError("a stage of the compiled tick: bound by compose()")


# The stage interface (each bound by `compose`; these stubs are never compiled):
begin = _stage  # begin(world) -> run: the run's arrays and constants, read once
open_forward = _stage  # open_forward(fnet) -> f: the forward direction's arrays, read once
open_backward = _stage  # open_backward(bnet) -> b
sense = _stage  # sense(run, n) -> t0: both plants' state at t_n (and the wall's force of the last period)
master = _stage  # master(run, t0) -> t1: the master's law and bound on its newest remote sample
# forward(run, f, t1, n, n1) -> (rx, occupancy): the master's sample sent, the slave takes what is released
forward = _stage
slave = _stage  # slave(run, t1) -> t2: the slave's law and bound
backward = _stage  # backward(run, b, t2, n, n1) -> (rx, occupancy)
finish = _stage  # finish(run, t2, n, frx, brx, focc, bocc): operator, plants, the tick's row
end = _stage  # end(run): after the last tick (what `begin` lent is given back)

STAGES = ("begin", "open_forward", "open_backward", "sense", "master", "forward", "slave", "backward", "finish", "end")


def drive(n0: int, n1: int, world: Any, fnet: Any, bnet: Any) -> int:
    """Ticks [n0, n1): engine/loop.py's `run_ticks` order, per tick n (scene time n T): both
    plants sensed, the master's tick, the forward channel, the slave's tick, the backward
    channel, then the operator, both plants' steps and the row. Returns n1."""
    run = begin(world)
    f = open_forward(fnet)
    b = open_backward(bnet)
    for n in range(n0, n1):
        t0 = sense(run, n)
        t1 = master(run, t0)
        frx, focc = forward(run, f, t1, n, n1)
        t2 = slave(run, t1)
        brx, bocc = backward(run, b, t2, n, n1)
        finish(run, t2, n, frx, brx, focc, bocc)
    end(run)
    return n1


def compose(**stages: Any) -> Any:
    """`drive` compiled with these stages (every name of `STAGES`, each a compiled function),
    inlined into the caller: a kernel's entry point calls it with its arguments grouped."""
    missing = set(STAGES) - set(stages)
    extra = set(stages) - set(STAGES)
    if missing or extra:
        raise TypeError(f"compose: stages missing {sorted(missing)}, unknown {sorted(extra)}; the stages are {STAGES}")
    from haptic_teleop.compiling import compile_tree

    return compile_tree(drive, inline=True, bound=stages)
