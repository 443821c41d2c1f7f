"""The Python tick loop: one loop for every teleoperation scene, one-axis or arm, with or without a
codec, over the stages of assembly/stages.py (docs/architecture.md, "One tick").

Per tick n (period T, scene time n T):

  1. the master's tick: its plant's state at t_n, its control law and energy bound on the newest
     backward sample it took, its sample;
  2. the forward channel: the master's sample sent, the slave takes what is released (or decoded);
  3. the slave's tick (its state, the wall force over the last period, its law and bound);
  4. the backward channel: the slave's sample sent, the master takes what is released;
  5. the operator's hand from the master's state, both sides actuate (the plants step one period
     with the forces held; the ledgers book what was applied), the operator finishes (an imposed
     trajectory), and the tick's row goes into the block.

Rows fill blocks of the output (engine/output.py), handed over when full with the packet records
settled by then; progress is reported and a stop request honoured every 100 ticks (and after
every tick for a stop). A real device on a side paces each tick to the wall clock.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from haptic_teleop.engine.output import Output


@dataclass
class Stages:
    """What one run's tick is made of (assembly/stages.py)."""

    operator: Any
    master: Any
    slave: Any
    forward: Any
    backward: Any
    row: Any


class LoopState:
    """What the loop and the engine tell each other as it goes: the ticks done (a failing tick
    leaves the ticks before it), read by the engine when the loop ends or raises; `stop`, set by a
    stop request (Ctrl-C), read after every tick."""

    ticks_done = 0
    stop = False


def run_ticks(
    stages: Stages,
    n_ticks: int,
    period_ns: int,
    output: Output,
    progress: Callable[[int], None] | None,
    state: LoopState,
    pace: Any = None,
) -> int:
    """Ticks from 0 until `n_ticks` or a stop request (`state.stop`); returns the ticks done (also
    in `state`)."""
    op, master, slave = stages.operator, stages.master, stages.slave
    fwd, bwd, row = stages.forward, stages.backward, stages.row
    m_tick, s_tick, m_take, s_take = master.tick, slave.tick, master.take, slave.take
    m_actuate, s_actuate = master.actuate, slave.actuate
    f_step, b_step = fwd.step, bwd.step
    hand, finish, write = op.hand, op.finish, row.write  # finish: None when the operator has nothing to do
    block = output.block
    rows = block.shape[0]
    base = 0  # tick of the block's first row
    done = 0
    for n in range(n_ticks):
        now_ns = n * period_ns
        if pace is not None:
            pace.wait(n)
        payload, frx = f_step(n, now_ns, m_tick(n))
        if payload is not None:
            s_take(payload)
        payload, brx = b_step(n, now_ns, s_tick(n))
        if payload is not None:
            m_take(payload)
        h = hand(n, master)
        m_actuate(n, h)
        s_actuate(n, None)
        if finish is not None:
            finish(n, master)
        write(block, n - base, op, master, slave, frx, brx, fwd.occupancy, bwd.occupancy)
        done = state.ticks_done = n + 1
        if done % 100 == 0:
            if progress is not None:
                progress(done)
            if done - base == rows:
                output.block_done(done)
                base = done
        if state.stop:
            break
    return done
