"""`haptic-teleop bench speed`: what a simulated second costs, against a bare MuJoCo step."""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path


def bare_mj_step_us(scene_path: Path, steps: int = 20000) -> tuple[float, float]:
    """Time per bare `mujoco.mj_step` of the scene's master and slave models (us), no Python around it."""
    import mujoco

    from haptic_teleop.engine import Engine
    from haptic_teleop.scene import load_scene

    engine = Engine(load_scene(scene_path))
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


def speed(scene_name: str, repeat: int) -> int:
    from haptic_teleop.engine import Engine, record_run
    from haptic_teleop.scene import find_scene, load_scene

    path = find_scene(scene_name)
    scene = load_scene(path)
    rtf, per_tick, loop_only = [], [], []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as tmp:
            engine, timing = record_run(scene, Path(tmp) / "bag", handle_sigint=False)
            rtf.append(timing.realtime_factor)
        e = Engine(scene)
        r = e.run(handle_sigint=False)
        loop_only.append(r.loop_wall_s / r.ticks * 1e6)
        per_tick.append(timing.record_wall_s / max(1, engine.ticks_done) * 1e6)
    m_us, s_us = bare_mj_step_us(path)
    bare = m_us + s_us
    tick = statistics.median(loop_only)
    run = scene.config.scene
    print(f"scene {run.name}: {run.duration_s:g} s at {1 / run.period_s:g} Hz, median of {repeat}")
    print(f"  real-time factor, loop + bag recording   {statistics.median(rtf):8.1f}   (target >= 50)")
    print(f"  wall time per tick, loop + recording     {statistics.median(per_tick):8.2f} us")
    print(f"  wall time per tick, loop alone           {tick:8.2f} us")
    print(f"  bare mj_step, master + slave models      {bare:8.2f} us  ({m_us:.2f} + {s_us:.2f})")
    print(f"  engine tick / bare mj_step               {tick / bare:8.1f} x")
    return 0


HELP = "real-time factor of a scene and the engine's cost per tick against a bare mj_step"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scene", default="wall_contact", help="scene YAML path or bundled name")
    p.add_argument("--repeat", type=int, default=3, help="runs; the median is printed")


def main(args: argparse.Namespace) -> int:
    return speed(args.scene, args.repeat)
