"""`haptic-teleop bench speed`: what a simulated second costs, against a bare MuJoCo step.

Prints, for the compiled loop (when the scene allows it) and the Python loop, the real-time factor
(simulated s / wall s) of a scene with bag recording (the writer in a second process; and all
pinned to one CPU, writer in the loop's process), the loop alone, the wall time per tick against
a bare `mujoco.mj_step` of the same two models (called from Python, and from compiled code), and
where a Python-loop tick's time goes, and what recording costs the loop per tick and per run
(recording_cost.py: paired rounds against the loop with its rows discarded). The breakdown replays the
recorded run through each stage on its own (fresh objects, the same inputs), so the stages can be
timed without instrumenting the loop; what the stages do not explain is the loop's own glue.
Every figure is a median over `--repeat` runs: on a shared machine single timings are noise.
"""

from __future__ import annotations

import argparse
import statistics
import struct
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.benchmarks import add_scene_argument, positive, recording_cost


def bare_mj_step_us(scene_path: Path, steps: int = 20000) -> tuple[float, float]:
    """Time per bare `mujoco.mj_step` of the scene's master and slave models called from Python
    (us), each pushed into its wall so contact is part of the cost. (From compiled code the bare
    step is paired with the tick in the same run, `tick_costs_us`.)"""
    import mujoco

    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.scene.load import load_scene

    engine = Engine(load_scene(scene_path), loop="python")
    out = []
    for plant in (engine.master, engine.slave):
        m, d = plant.model, plant.data
        d.ctrl[:] = 1.0  # push: the slave reaches its wall, so contact is part of the cost
        step = mujoco.mj_step
        for _ in range(2000):
            step(m, d)
        t0 = time.perf_counter()
        for _ in range(steps):
            step(m, d)
        out.append((time.perf_counter() - t0) / steps * 1e6)
    return out[0], out[1]


def _one_core() -> Callable[[], None] | None:
    """Pin this process (and children it starts) to one CPU; returns the undo, or None if the OS
    cannot (then "one core" means the writer runs in the loop's process, nothing more)."""
    import os

    if not hasattr(os, "sched_setaffinity"):
        return None
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(before)})
    return lambda: os.sched_setaffinity(0, before)


# --------------------------------------------------------------------------------------------
# Stage replays: each takes a fresh Engine (built outside the timing) and the recorded columns,
# runs one stage over every tick, and returns the wall seconds it took.

Columns = dict[str, list[float]]


def _stage_mj_step(e: Any, c: Columns) -> float:
    import mujoco

    step = mujoco.mj_step
    mm, md, sm, sd = e.master.model, e.master.data, e.slave.model, e.slave.data
    md.ctrl[:] = 0.5
    sd.ctrl[:] = 0.5
    t0 = time.perf_counter()
    for _ in range(len(c["m_x_m"])):
        step(mm, md)
        step(sm, sd)
    return time.perf_counter() - t0


def _stage_plants(e: Any, c: Columns) -> float:
    m_read, s_read, s_contact = e.master.read, e.slave.read, e.slave.contact_force
    m_step, s_step = e.master.step, e.slave.step
    fm, fh, fs = c["m_force_n"], c["op_force_n"], c["s_force_n"]
    t0 = time.perf_counter()
    for n in range(len(fm)):
        m_read()
        s_read()
        s_contact()
        m_step([fm[n]], [fh[n]])
        s_step([fs[n]])
    return time.perf_counter() - t0


def _stage_controllers(e: Any, c: Columns) -> float:
    mc, sc = e.master_ctrl, e.slave_ctrl
    m_control, s_control = mc.step1, sc.step1
    m_applied, s_applied = mc.bound.applied1, sc.bound.applied1
    m_set, s_set = mc.set_remote, sc.set_remote
    mx, mv, sx, sv, fe = c["m_x_m"], c["m_v_m_per_s"], c["s_x_m"], c["s_v_m_per_s"], c["s_contact_n"]
    fm, fs = c["m_force_n"], c["s_force_n"]
    # The samples each side received, from the recorded release columns.
    frx = [int(k) for k in c["fwd_rx_seq"]]
    brx = [int(k) for k in c["bwd_rx_seq"]]
    fwd = [(mx[k], mv[k]) if k >= 0 else None for k in frx]
    bwd = [(fe[k], sx[k], sv[k]) if k >= 0 else None for k in brx]
    t0 = time.perf_counter()
    for n in range(len(mx)):
        m_control(mx[n], mv[n])
        p = fwd[n]
        if p is not None:
            s_set(p)
        s_control(sx[n], sv[n])
        p = bwd[n]
        if p is not None:
            m_set(p)
        m_applied(fm[n])  # the engine reports the applied forces after the plants' step
        s_applied(fs[n])
    return time.perf_counter() - t0


def _stage_operator(e: Any, c: Columns) -> float:
    hand = e.operator.hand_force_and_intended
    mx, mv = c["m_x_m"], c["m_v_m_per_s"]
    period_s = e.period_s
    t0 = time.perf_counter()
    for n in range(len(mx)):
        hand(n * period_s, [mx[n]], [mv[n]])
    return time.perf_counter() - t0


def _stage_packets(e: Any, c: Columns) -> float:
    from haptic_teleop.core.link import Packet

    mx, mv, sx, sv, fe = c["m_x_m"], c["m_v_m_per_s"], c["s_x_m"], c["s_v_m_per_s"], c["s_contact_n"]
    period_ns = e.period_ns
    t0 = time.perf_counter()
    for n in range(len(mx)):
        now_ns = n * period_ns
        Packet(n, now_ns, (mx[n], mv[n]), 100)
        Packet(n, now_ns, (fe[n], sx[n], sv[n]), 100)
    return time.perf_counter() - t0


def _packets(e: Any, c: Columns) -> tuple[list[Any], list[Any]]:
    from haptic_teleop.core.link import Packet

    mx, mv, sx, sv, fe = c["m_x_m"], c["m_v_m_per_s"], c["s_x_m"], c["s_v_m_per_s"], c["s_contact_n"]
    period_ns = e.period_ns
    fwd = [Packet(n, n * period_ns, (mx[n], mv[n]), 100) for n in range(len(mx))]
    bwd = [Packet(n, n * period_ns, (fe[n], sx[n], sv[n]), 100) for n in range(len(mx))]
    return fwd, bwd


def _stage_links(e: Any, c: Columns) -> float:
    fwd_p, bwd_p = _packets(e, c)
    fs, fd, bs, bd = e.forward.send, e.forward.deliver, e.backward.send, e.backward.deliver
    period_ns = e.period_ns
    t0 = time.perf_counter()
    for n in range(len(fwd_p)):
        now_ns = n * period_ns
        fs(fwd_p[n])
        fd(now_ns)
        bs(bwd_p[n])
        bd(now_ns)
    return time.perf_counter() - t0


def _stage_buffers(e: Any, c: Columns) -> float:
    # The links' deliveries are computed first (untimed); the buffers then take them tick by tick.
    fwd_p, bwd_p = _packets(e, c)
    period_ns = e.period_ns
    arrivals: list[tuple[list[Any], list[Any]]] = []
    for n in range(len(fwd_p)):
        now_ns = n * period_ns
        e.forward.send(fwd_p[n])
        e.backward.send(bwd_p[n])
        arrivals.append((e.forward.deliver(now_ns), e.backward.deliver(now_ns)))
    fbuf, bbuf = e.forward_buffer, e.backward_buffer
    fpush, frelease, bpush, brelease = fbuf.push, fbuf.release, bbuf.push, bbuf.release
    t0 = time.perf_counter()
    for n in range(len(arrivals)):
        now_ns = n * period_ns
        f_in, b_in = arrivals[n]
        for p in f_in:
            fpush(p, now_ns)
        frelease(now_ns)
        for p in b_in:
            bpush(p, now_ns)
        brelease(now_ns)
        fbuf.occupancy  # noqa: B018 - recorded every tick: part of the cost
        bbuf.occupancy  # noqa: B018
    return time.perf_counter() - t0


def _stage_row(e: Any, c: Columns) -> float:
    from haptic_teleop.engine.lockstep import COLUMNS

    n_ticks = len(c["m_x_m"])
    data = np.zeros((n_ticks, len(COLUMNS)))
    pack_row = struct.Struct(f"<{len(COLUMNS)}d").pack_into
    row_bytes = 8 * len(COLUMNS)
    x = c["m_x_m"]
    t0 = time.perf_counter()
    for n in range(n_ticks):
        a = x[n]
        pack_row(data, n * row_bytes, a, a, a, a, a, a, a, a, a, a, a, a, a, a, n, n, 0, 0)
    return time.perf_counter() - t0


STAGES: tuple[tuple[str, Callable[[Any, Columns], float]], ...] = (
    ("MuJoCo mj_step, master + slave", _stage_mj_step),
    ("plants' Python (read, step, contact)", _stage_plants),  # minus mj_step below
    ("controllers: law, saturation, EBA", _stage_controllers),
    ("operator: hand force, intention", _stage_operator),
    ("Packet objects (2)", _stage_packets),
    ("network links: send, deliver", _stage_links),
    ("playout buffers: push, release", _stage_buffers),
    ("recording the row (pack_into)", _stage_row),
)


def breakdown_us(scene: Any, repeat: int) -> tuple[list[tuple[str, float]], float]:
    """Per-tick wall time of each stage (us, median of `repeat`) and of the whole loop."""
    from haptic_teleop.engine.lockstep import COLUMNS, Engine

    ref = Engine(scene, loop="python").run(handle_sigint=False)
    data = ref.data[: ref.ticks]
    cols = {name: data[:, i].tolist() for i, name in enumerate(COLUMNS)}
    ticks = ref.ticks
    rows = []
    for name, stage in STAGES:
        times = []
        for _ in range(repeat):
            times.append(stage(Engine(scene, loop="python"), cols) / ticks * 1e6)
        rows.append((name, statistics.median(times)))
    # The plant stage includes mj_step: report only the Python around it.
    mj = rows[0][1]
    rows[1] = (rows[1][0], rows[1][1] - mj)
    loop = statistics.median(
        Engine(scene, loop="python").run(handle_sigint=False).loop_wall_s / ticks * 1e6 for _ in range(repeat)
    )
    return rows, loop


def _loop_figures(scene: Any, loop: str, repeat: int) -> dict[str, float]:
    """Medians over `repeat` runs of one loop: RTF with the writer process, RTF on one core, and
    the loop alone (us per tick)."""
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.engine.run import record_run

    rtf, rtf_one_core, per_tick, loop_only = [], [], [], []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as tmp:
            engine, timing = record_run(scene, Path(tmp) / "bag", handle_sigint=False, loop=loop)
            rtf.append(timing.realtime_factor)
            per_tick.append(timing.record_wall_s / max(1, engine.ticks_done) * 1e6)
        undo = _one_core()
        try:
            with tempfile.TemporaryDirectory() as tmp:
                _, timing = record_run(scene, Path(tmp) / "bag", handle_sigint=False, parallel=False, loop=loop)
                rtf_one_core.append(timing.realtime_factor)
        finally:
            if undo is not None:
                undo()
        r = Engine(scene, loop=loop).run(handle_sigint=False)
        loop_only.append(r.loop_wall_s / r.ticks * 1e6)
    return {
        "rtf": statistics.median(rtf),
        "rtf_one_core": statistics.median(rtf_one_core),
        "per_tick_recorded_us": statistics.median(per_tick),
        "tick_us": statistics.median(loop_only),
    }


SAMPLE_STRIDE = 5  # `tick_costs_us` samples MuJoCo alone at every 5th progress call (500 ticks)


def cost_run(scene: Any, every: int, stride: int = SAMPLE_STRIDE) -> dict[str, float]:
    """One run of `tick_costs_us`, its tallies: seconds spent in the loop's timed chunks ("loop",
    over "loop_ticks"), in the chunks right after a sample ("after", over "after_ticks"), in the
    bare steps ("bare") and the tick's MuJoCo calls ("calls", arms only), over "samples" steps."""
    import mujoco

    from haptic_teleop.engine.lockstep import Engine

    e = Engine(scene, loop="compiled")
    arm = scene.config.is_arm
    if arm:
        from haptic_teleop.assembly import compiled_side
        from haptic_teleop.engine.compiled.arm_kernel import bare_steps, mujoco_steps

        mp, sp = e.arm.master.plant, e.arm.slave.plant
    else:
        from haptic_teleop.engine.compiled.axis_kernel import bare_steps

        mp, sp = e.master, e.slave
    md, sd = mujoco.MjData(mp.model), mujoco.MjData(sp.model)
    models = np.array([mp.model._address, md._address, sp.model._address, sd._address], dtype=np.int64)
    if arm:
        ms = compiled_side.side_tuple(e.arm.master, e.arm, True, md)
        ss = compiled_side.side_tuple(e.arm.slave, e.arm, False, sd)
    spent = {"bare": 0.0, "calls": 0.0, "loop": 0.0, "loop_ticks": 0, "samples": 0, "after": 0.0, "after_ticks": 0}
    steady = (0.2 * e.ticks, 0.95 * e.ticks)  # the loop's ticks timed: not its start or end
    last = [0, 0.0, 1]  # the tick and the time the last callback returned, whether it sampled

    def copy() -> None:
        mujoco.mj_copyData(md, mp.model, mp.data)
        mujoco.mj_copyData(sd, sp.model, sp.data)

    def progress(n: int) -> None:
        t0 = time.perf_counter()
        if steady[0] <= last[0] and n <= steady[1]:
            key = "after" if last[2] else "loop"
            spent[key] += t0 - last[1]
            spent[key + "_ticks"] += n - last[0]
        sample = (n // 100) % stride == 0
        if sample:
            copy()
            t1 = time.perf_counter()
            bare_steps(models, every)
            t2 = time.perf_counter()
            spent["bare"] += t2 - t1
            if arm:
                copy()
                t3 = time.perf_counter()
                mujoco_steps(ms, ss, every)
                spent["calls"] += time.perf_counter() - t3
            spent["samples"] += every
        last[0], last[1], last[2] = n, time.perf_counter(), int(sample and stride > 1)

    bare_steps(models, 0)  # compiled (or loaded) before the timing
    if arm:
        mujoco_steps(ms, ss, 0)
    # (the compiled loop turns MuJoCo's timers off around its chunks and its progress calls: the
    # bare steps run as the loop's do)
    e.run(handle_sigint=False, progress=progress, sink=recording_cost.Discard())
    return spent


def per_tick_us(spent: dict[str, float]) -> tuple[float, float, float, float]:
    """A `cost_run`'s figures, us per tick: the loop, the bare step pair, the tick's MuJoCo calls
    (NaN without them), the loop right after a sample (NaN without such chunks)."""
    nan = float("nan")

    def per(key: str, over: str) -> float:
        return spent[key] / spent[over] * 1e6 if spent[over] and spent[key] else nan

    return per("loop", "loop_ticks"), per("bare", "samples"), per("calls", "samples"), per("after", "after_ticks")


def tick_costs_us(scene: Any, repeat: int, every: int = 100, stride: int = SAMPLE_STRIDE) -> dict[str, Any]:
    """The compiled tick against MuJoCo alone, in the same run (us per tick, medians of `repeat`
    runs without recording): the loop, timed between its progress calls (every 100 ticks) from 20 %
    to 95 % of the run (its steady state: not the run's start, which builds its arrays, or its
    end); and at every `stride`-th progress call, on a copy of both plants' MjData as the loop has
    them (in contact when the loop is, the controls it holds), `every` bare `mj_step`s of both
    models and, for arms, `every` steps of the tick's own MuJoCo calls (mj_step1, mj_jacSite,
    mj_step2), all from compiled code with MuJoCo's timers off (as in the loop). The 100 ticks
    after a sample are not timed: the sample's copies and steps have pushed the loop's data out of
    the caches, a cost the bench adds and a run does not have; they are timed apart, as
    `after_ratio`."""
    runs = [per_tick_us(cost_run(scene, every, stride)) for _ in range(repeat)]
    ratios = [r[0] / r[1] for r in runs]
    return {
        "stride": stride,
        "after_ratio": statistics.median(r[3] / r[1] for r in runs),
        "tick_us": statistics.median(r[0] for r in runs),
        "bare_us": statistics.median(r[1] for r in runs),
        "calls_us": statistics.median(r[2] for r in runs),
        "ratio": statistics.median(ratios),
        "ratio_range": (min(ratios), max(ratios)),
    }


def print_tick_costs(c: dict[str, Any], arm: bool) -> None:
    lo, hi = c["ratio_range"]
    print(
        f"compiled tick against MuJoCo alone, in the same runs (state copied from the loop every {100 * c['stride']} "
        "ticks):"
    )
    print(f"  compiled tick (steady state, no bag)     {c['tick_us']:8.2f} us")
    if arm:
        print(f"  its MuJoCo calls (step1, jacSite, step2) {c['calls_us']:8.2f} us")
    print(f"  bare mj_step, master + slave, compiled   {c['bare_us']:8.2f} us  (timers off)")
    ratio = c["ratio"]
    print(f"  compiled tick / bare mj_step             {ratio:8.2f} x  (runs {lo:.2f} to {hi:.2f}; target <= 1.3)")
    print(f"  the same, 100 ticks after a sample       {c['after_ratio']:8.2f} x  (refilling caches the copies took)")


def arm_speed(scene: Any, repeat: int) -> None:
    """`speed` for arm scenes: real-time factors of both loops, the compiled tick against a bare
    mj_step of the same two models in the same run, and the part of it MuJoCo's own calls take."""
    run = scene.config.scene
    from haptic_teleop.engine.lockstep import Engine

    probe = Engine(scene)
    loops = ["compiled", "python"] if probe.loop_kind == "compiled" else ["python"]
    one_core = "pinned to one CPU" if hasattr(__import__("os"), "sched_setaffinity") else "writer in the loop's process"
    print(f"scene {run.name} (arms): {run.duration_s:g} s at {1 / run.period_s:g} Hz, median of {repeat}")
    if probe.loop_kind != "compiled":
        print(f"  (no compiled loop for this scene: {probe.compiled_reason})")
    for loop in loops:
        f = _loop_figures(scene, loop, repeat)
        print(f"{loop} loop (haptic-teleop run --loop {loop}{', the default' if loop == loops[0] else ''}):")
        print(f"  real-time factor, loop + bag recording   {f['rtf']:8.1f}   (writer process)")
        print(f"  real-time factor, the same on one core   {f['rtf_one_core']:8.1f}   ({one_core}; target >= 50)")
        print(f"  real-time factor, loop alone             {1e6 * run.period_s / f['tick_us']:8.1f}")
        print(f"  wall time per tick, loop + recording     {f['per_tick_recorded_us']:8.2f} us")
        print(f"  wall time per tick, loop alone           {f['tick_us']:8.2f} us")
    if probe.loop_kind == "compiled":
        for line in recording_cost.report(recording_cost.measure(scene, repeat), run.duration_s):
            print(line)
        print_tick_costs(tick_costs_us(scene, repeat), True)


def speed(scene_name: str, repeat: int, breakdown: bool) -> int:
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.scene.load import find_scene, load_scene

    path = find_scene(scene_name)
    scene = load_scene(path)
    if scene.config.is_arm:
        arm_speed(scene, repeat)
        return 0
    probe = Engine(scene)
    loops = ["compiled", "python"] if probe.loop_kind == "compiled" else ["python"]
    figures = {loop: _loop_figures(scene, loop, repeat) for loop in loops}
    m_us, s_us = bare_mj_step_us(path)
    bare = m_us + s_us
    run = scene.config.scene
    one_core = "pinned to one CPU" if hasattr(__import__("os"), "sched_setaffinity") else "writer in the loop's process"
    print(f"scene {run.name}: {run.duration_s:g} s at {1 / run.period_s:g} Hz, median of {repeat}")
    if probe.loop_kind != "compiled":
        print(f"  (no compiled loop for this scene: {probe.compiled_reason})")
    for loop in loops:
        f = figures[loop]
        print(f"{loop} loop (haptic-teleop run --loop {loop}{', the default' if loop == loops[0] else ''}):")
        print(f"  real-time factor, loop + bag recording   {f['rtf']:8.1f}   (writer process; target >= 50)")
        print(f"  real-time factor, the same on one core   {f['rtf_one_core']:8.1f}   ({one_core}; target >= 100)")
        print(f"  real-time factor, loop alone             {1e6 * run.period_s / f['tick_us']:8.1f}")
        print(f"  wall time per tick, loop + recording     {f['per_tick_recorded_us']:8.2f} us")
        print(f"  wall time per tick, loop alone           {f['tick_us']:8.2f} us")
    print(f"bare mj_step, master + slave, from Python  {bare:8.2f} us  ({m_us:.2f} + {s_us:.2f})")
    if "compiled" in figures:
        print_tick_costs(tick_costs_us(scene, repeat), False)
    for line in recording_cost.report(recording_cost.measure(scene, repeat, loops[0]), run.duration_s):
        print(line)
    print(f"Python tick / bare mj_step from Python     {figures['python']['tick_us'] / bare:8.2f} x")
    if breakdown and scene.config.is_arm:
        print("(no per-stage breakdown for arm scenes: the stages replay the one-axis tick; docs/arms.md)")
    elif breakdown:
        rows, loop_us = breakdown_us(scene, repeat)
        print(
            f"where a Python-loop tick's time goes (stages replayed alone, median of {repeat}; loop {loop_us:.2f} us):"
        )
        for name, us in rows:
            print(f"  {name:<40} {us:6.2f} us  {100 * us / loop_us:5.1f} %")
        rest = loop_us - sum(us for _, us in rows)
        print(f"  {'loop glue (the rest)':<40} {rest:6.2f} us  {100 * rest / loop_us:5.1f} %")
    return 0


HELP = "real-time factor of a scene and the engine's cost per tick against a bare mj_step"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scene_argument(p)
    p.add_argument("--repeat", type=positive(int), default=3, help="runs; the median is printed")
    p.add_argument("--no-breakdown", action="store_true", help="skip the per-stage table")


def main(args: argparse.Namespace) -> int:
    return speed(args.scene, args.repeat, not args.no_breakdown)
