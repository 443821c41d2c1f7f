"""The engine's tick for arm scenes (Python loop; docs/arms.md, "The tick").

One tick (period T), in this order, every task-space value in the task frame (the slave's world
frame; the master's handle is mapped with the WorkspaceMapping):
  1. read both arms (MuJoCo's mj_step1: q, qd, the point, its Jacobian, gravity torques, one
     instant); the wall's wrench on the tool is MuJoCo's over the last period;
  2. master: task-space law on the newest backward sample -> force F (saturated in norm) ->
     tau = J^T F through the mapped Jacobian -> brought within each motor's room left by gravity
     compensation (one factor: direction kept) -> pooled joint energy bound (one lambda);
  3. master packet (handle x, v) into the forward link; arrivals by t_n go to the slave's buffer;
  4. slave: the same on the released sample, with the orientation held (6-DoF) and null-space
     damping; 5. slave packet (tool x, v, contact force) into the backward link;
  6. the operator's hand force (a 3-D spring-damper in the device frame) and both arms step one
     period; the bounds' ledgers take the torques the plants applied.
The row's columns follow the scene's TickSchema (record/columns.py).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_teleop.assembly.side import operator_hand
from haptic_teleop.core.link import Packet

if TYPE_CHECKING:
    from haptic_teleop.assembly.parts import ArmParts


class Pacer:
    """Absolute deadlines for a loop that drives real devices: tick n starts no earlier than
    t0 + n T on `time.perf_counter`. The first tick starts the devices (connecting, checking,
    configuring: a long tick), so the clock is anchored at the start of the second: t0 = its start
    minus T. A tick that starts more than one period after its deadline is late: counted, never made
    up (the loop does not drop ticks to catch up; scene time stays n T, so the bag is the same
    however late the ticks were). An overrun is a tick that took longer than one period. The
    counts go into timing.json, never into the bag."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self._stall = stall_for_test()
        self.t0 = 0.0
        self.late_ticks = 0
        self.overrun_ticks = 0
        self.max_late_s = 0.0
        self.ticks = 0
        self._last = 0.0

    def wait(self, n: int) -> None:
        every, stall_s = self._stall
        if every and n >= 2 and n % every == 0:
            time.sleep(stall_s)  # tests: a stalled host, the torque held on (docs/eba.md, "Late ticks")
        now = time.perf_counter()
        if n >= 2 and now - self._last > self.period_s:
            self.overrun_ticks += 1
        if n <= 1:
            self.t0 = now - n * self.period_s
        deadline = self.t0 + n * self.period_s
        if now < deadline:
            time.sleep(deadline - now)
            now = time.perf_counter()
        else:
            late = now - deadline
            if late > self.period_s:
                self.late_ticks += 1
            self.max_late_s = max(self.max_late_s, late)
        self._last = now
        self.ticks = n + 1

    def facts(self) -> dict[str, float | int]:
        """What timing.json gets: ticks paced, late ticks, overruns and the largest lateness (s)."""
        return {
            "paced_ticks": self.ticks,
            "late_ticks": self.late_ticks,
            "overrun_ticks": self.overrun_ticks,
            "max_late_s": self.max_late_s,
        }


STALL_ENV = "HAPTIC_TELEOP_TEST_STALL"


def stall_for_test() -> tuple[int, float]:
    """With HAPTIC_TELEOP_TEST_STALL=EVERY:SECONDS in the environment the paced loop sleeps SECONDS
    before every EVERY-th tick (a host that stalls while the devices hold their torque); (0, 0)
    otherwise."""
    every, _, seconds = os.environ.get(STALL_ENV, "").partition(":")
    return (int(every), float(seconds)) if every else (0, 0.0)


def run_arm_loop(engine: Any, parts: ArmParts, progress: Callable[[int], None] | None, output: Any) -> int:
    """Run the arm scene's ticks into `output` (the engine's output.Output); returns the ticks done.
    `engine`: the Engine running the scene (engine/lockstep.py: its ticks, period, network and pacing)."""
    n_ticks = engine.ticks
    period_ns = engine.period_ns
    period_s = engine.period_s
    schema = parts.schema
    g = schema.group
    maps = parts.maps
    m_side, s_side = parts.master, parts.slave
    master, slave = m_side.plant, s_side.plant
    mt, st = engine.arm_ticks
    m_guard, s_guard = m_side.guard, s_side.guard
    fwd, bwd = engine.forward, engine.backward
    fbuf, bbuf = engine.forward_buffer, engine.backward_buffer
    fwd_size, bwd_size = engine._sizes
    # The codec stage of a direction that names one (assembly/channel.py): its decoder's
    # sample for the tick replaces the buffer's release (docs/codec.md, "In the channels").
    fcodec, bcodec = getattr(engine, "codecs", (None, None))
    block = output.block
    cols = {
        name: g(name)
        for name in (
            "op_x_m", "op_v_m_per_s", "op_force_n",
            "m_q", "m_qd", "m_tau_nm", "m_x_m", "m_v_m_per_s", "m_force_n", "m_force_desired_n", "m_energy_j",
            "s_q", "s_qd", "s_tau_nm", "s_x_m", "s_v_m_per_s", "s_force_n", "s_force_desired_n", "s_energy_j",
            "s_contact_n", "s_contact_torque_nm", "fwd_rx_seq", "bwd_rx_seq", "fwd_occupancy", "bwd_occupancy",
        )
    }  # fmt: skip
    m_remote: tuple[float, ...] | None = None  # the master's newest accepted backward sample
    s_remote: tuple[float, ...] | None = None
    base = 0
    done = 0
    engine.ticks_done = 0
    pace = engine.pacer  # a real device on a side: each tick starts at its deadline (wall clock)
    m_hand = not engine.hardware_master  # a real master's operator is a real hand: nothing commanded
    # A real arm's ledger credits the damping over the time the tick's motion really took
    # (CoupledEnergyBound.stretch; one period for a device on a lockstep clock: the emulator).
    m_real, s_real = engine.hardware_master, engine.hardware_slave
    # A side with its own period (<side>.period_s = k scene periods) ticks (read, law, bound, write)
    # every k-th scene tick and holds its command in between: a simulated arm is stepped with the
    # held torque every scene tick, a real one is left alone; its packets and rows carry its last values.
    km, ks = engine.side_every
    tau_m = tau_s = applied_m = applied_s = None
    for n in range(n_ticks):
        now_ns = n * period_ns
        if pace is not None:
            pace.wait(n)
        row = block[n - base]
        m_due = n % km == 0
        s_due = n % ks == 0
        # 1. both arms
        if m_due:
            qm, qdm = master.read()
            if m_real:  # a real arm: the motion since the last read took its own time (Pacer: late ticks)
                mt.bound.stretch(master.read_interval_s)
            xm_dev, vm_dev = master.point()
            xh_dev, vh_dev = xm_dev, vm_dev
            x_m = maps.to_task_x(xm_dev)
            v_m = maps.to_task_v(vm_dev)
        elif not m_real:  # the operator's hand meets the simulated handle where it is now
            xh_dev, vh_dev = master.point()
        if s_due:
            qs, qds = slave.read()
            if s_real:
                st.bound.stretch(slave.read_interval_s)
            xs, vs = slave.point()
            f_env, t_env = slave.contact_wrench()
        # 2. master
        if m_due:
            tau_m = mt.torque(x_m, v_m, m_remote)
        # 3. forward packet
        if fcodec is None:
            fwd.send(Packet(n, now_ns, (*x_m.tolist(), *v_m.tolist()), fwd_size))
            for p in fwd.deliver(now_ns):
                fbuf.push(p, now_ns)
            rel = fbuf.release(now_ns)
            if rel is not None:
                if s_guard.accept(rel.payload):
                    s_remote = rel.payload
                frx = rel.seq
            else:
                frx = -1
        else:
            decoded, frx = fcodec.step(n, now_ns, (*x_m.tolist(), *v_m.tolist()))
            if decoded is not None and s_guard.accept(decoded):
                s_remote = decoded
        # 4. slave
        if s_due:
            tau_s = st.torque(xs, vs, s_remote)
        # 5. backward packet
        if bcodec is None:
            bwd.send(Packet(n, now_ns, (*xs.tolist(), *vs.tolist(), *f_env.tolist()), bwd_size))
            for p in bwd.deliver(now_ns):
                bpush = bbuf.push
                bpush(p, now_ns)
            rel = bbuf.release(now_ns)
            if rel is not None:
                if m_guard.accept(rel.payload):
                    m_remote = rel.payload
                brx = rel.seq
            else:
                brx = -1
        else:
            decoded, brx = bcodec.step(n, now_ns, (*xs.tolist(), *vs.tolist(), *f_env.tolist()))
            if decoded is not None and m_guard.accept(decoded):
                m_remote = decoded
        # 6. operator and plants
        xd_t, vd_t, f_hand = operator_hand(parts, n * period_s, xh_dev, vh_dev)
        if m_due:
            applied_m = master.step(tau_m, f_hand if m_hand else None)
            mt.bound.held[:] = applied_m  # the ledger: the torques the plants applied
        elif not m_real:
            master.step(tau_m, f_hand if m_hand else None)
        if s_due:
            applied_s = slave.step(tau_s)
            st.bound.held[:] = applied_s
        elif not s_real:
            slave.step(tau_s)
        row[cols["op_x_m"]] = xd_t
        row[cols["op_v_m_per_s"]] = vd_t
        row[cols["op_force_n"]] = maps.force_to_task(f_hand) if m_hand else np.nan
        row[cols["m_q"]] = qm
        row[cols["m_qd"]] = qdm
        row[cols["m_tau_nm"]] = applied_m
        row[cols["m_x_m"]] = x_m
        row[cols["m_v_m_per_s"]] = v_m
        row[cols["m_force_n"]] = mt.ratio * mt.force
        row[cols["m_force_desired_n"]] = mt.force
        row[cols["m_energy_j"]] = mt.bound.energy_j
        row[cols["s_q"]] = qs
        row[cols["s_qd"]] = qds
        row[cols["s_tau_nm"]] = applied_s
        row[cols["s_x_m"]] = xs
        row[cols["s_v_m_per_s"]] = vs
        row[cols["s_force_n"]] = st.ratio * st.force
        row[cols["s_force_desired_n"]] = st.force
        row[cols["s_energy_j"]] = st.bound.energy_j
        row[cols["s_contact_n"]] = f_env
        row[cols["s_contact_torque_nm"]] = t_env
        row[cols["fwd_rx_seq"]] = frx
        row[cols["bwd_rx_seq"]] = brx
        row[cols["fwd_occupancy"]] = fbuf.occupancy if fcodec is None else 0.0
        row[cols["bwd_occupancy"]] = bbuf.occupancy if bcodec is None else 0.0
        done = engine.ticks_done = n + 1  # a failing tick leaves the ticks before it
        if done % 100 == 0:
            if progress is not None:
                progress(done)
            if done - base == block.shape[0]:
                output.block_done(done)
                base = done
        if engine.stop_requested:
            break
    engine.ticks_done = done
    engine.joint_limit_ticks = {"master": mt.limited_ticks, "slave": st.limited_ticks}
    return done
