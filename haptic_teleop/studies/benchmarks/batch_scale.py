"""`haptic-teleop bench sweep`: how a sweep scales with worker processes, and what it costs per run
over a bare `run` (docs/sweep.md).

In one bench run, on the same scene:

1. bare run: `load_scene`, `record_run`, `write_outputs` (no plots) in this process, what
   `haptic-teleop run --no-plots` does once its imports are done; one warm-up, then the median of
   `--runs` runs (seeds 1..N);
2. a sweep of N points (seeds) on 1 local worker process, then of 2N points on 2, through the
   sweep's own code (plan, `LocalPool`, the ledger): wall time from the plan to the last point
   stored, and the steady rate (points after the first one per worker, over the time they took:
   without the workers' start-up, the interpreter and imports of a spawned process).

Prints runs per second on 1 and 2 processes (overall and steady), their ratio (linear: 2.0; the
target: within 10 %, at least 1.8) and the per-run overhead over the bare run: the steady time
per point on 1 process minus the bare run's. With each phase: the load average before it and the
CPU time the sweep's own process spent per point (the part that does not scale with workers): on a
machine with other load, the ratio shows the load, not the sweep.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from haptic_teleop.studies.benchmarks import add_scene_argument, positive

HELP = "sweep throughput on 1 and 2 worker processes (ratio) and the per-run overhead over a bare run"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scene_argument(p)
    p.add_argument("--duration-s", type=positive(float), default=2.0, help="simulated seconds per run (default 2)")
    p.add_argument("--runs", type=positive(int), default=8, help="runs per worker process (default 8)")


def bare_runs(scene_name: str, duration_s: float, seeds: list[int], out: Path) -> list[float]:
    """Wall time of each bare run (scene loaded, recorded, analysed without plots), in this process."""
    from haptic_teleop.analysis.outputs import write_outputs
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.scene.load import find_scene, load_scene

    times = []
    for seed in seeds:
        t0 = time.perf_counter()
        scene = load_scene(find_scene(scene_name), overrides=[f"scene.duration_s={duration_s}"], seed=seed)
        run_dir = out / f"bare-{seed}"
        record_run(scene, run_dir / "bag", handle_sigint=False)
        write_outputs(run_dir / "bag", run_dir, plots=False)
        times.append(time.perf_counter() - t0)
    return times


def sweep_runs(scene_name: str, duration_s: float, seeds: list[int], workers: int, out: Path) -> dict[str, Any]:
    """A sweep over `seeds` on `workers` local processes: wall time, and when each point was stored."""
    from haptic_teleop.studies.batch.plan import resolve, spec_from_flags
    from haptic_teleop.studies.batch.runner import RUNS, LocalPool, Task
    from haptic_teleop.studies.batch.store import Store, record

    load = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    spec = spec_from_flags(scene_name, [f"scene.duration_s={duration_s}"])
    points = resolve(spec, seeds)
    store = Store(out, parquet=False)
    pool = LocalPool(workers)
    done_at: list[tuple[int, float]] = []
    try:
        pool.submit([Task(p.run_hash, p.scene.to_yaml(), str(out / RUNS / p.run_hash)) for p in points])
        by_hash = {p.run_hash: p for p in points}
        for task, result, exc in pool.results(lambda: False):
            if exc is not None:
                raise exc
            assert result is not None
            p = by_hash[task.run_hash]
            store.append(record(p.run_hash, p.seed, p.keys, result["summary"], None))
            done_at.append((int(result["pid"]), time.perf_counter()))
    finally:
        pool.close()
        store.close()
    store.write_tables()
    wall = time.perf_counter() - t0
    # Steady: for each worker, its points after its first, over the time from its first to its last.
    steady_n, steady_t = 0, 0.0
    for pid in {pid for pid, _ in done_at}:
        ts = [t for q, t in done_at if q == pid]
        if len(ts) > 1:
            steady_n += len(ts) - 1
            steady_t = max(steady_t, ts[-1] - ts[0])
    return {
        "wall_s": wall,
        "rate": len(points) / wall,
        "steady_rate": steady_n / steady_t if steady_t > 0 else float("nan"),
        "processes": len({pid for pid, _ in done_at}),
        "first_s": done_at[0][1] - t0 if done_at else float("nan"),
        "parent_cpu_per_point_s": (time.process_time() - c0) / len(points),
        "load_before": load,
    }


def bench(scene_name: str, duration_s: float, runs: int) -> int:
    seeds = list(range(1, runs + 1))
    with tempfile.TemporaryDirectory(prefix="bench-sweep-") as tmp:
        base = Path(tmp)
        bare_runs(scene_name, duration_s, [runs + 1], base / "warm")  # compiled loop loaded, caches warm
        bare = bare_runs(scene_name, duration_s, seeds, base / "bare")
        one = sweep_runs(scene_name, duration_s, seeds, 1, base / "w1")
        two = sweep_runs(scene_name, duration_s, list(range(1, 2 * runs + 1)), 2, base / "w2")
    t_bare = statistics.median(bare)
    ratio = two["rate"] / one["rate"]
    steady_ratio = two["steady_rate"] / one["steady_rate"]
    overhead = 1.0 / one["steady_rate"] - t_bare
    print(f"scene {scene_name}, {duration_s:g} s simulated per run, {runs} runs per process")
    print(f"bare run (in process):       {t_bare * 1e3:8.1f} ms median ({min(bare) * 1e3:.1f}..{max(bare) * 1e3:.1f})")
    for n, r in ((1, one), (2, two)):
        print(
            f"sweep, {n} process{'es' if n > 1 else '  '}:         {r['rate']:8.2f} runs/s overall "
            f"({r['wall_s']:.1f} s with start-up), {r['steady_rate']:.2f} runs/s steady; "
            f"load average before {r['load_before']:.1f}, "
            f"this process {r['parent_cpu_per_point_s'] * 1e3:.0f} ms CPU/point"
        )
    print(
        f"2 processes / 1 process:     {ratio:8.2f} overall, {steady_ratio:.2f} steady (linear: 2.00; target >= 1.80)"
    )
    print(
        f"per-run overhead over bare:  {overhead * 1e3:8.1f} ms steady "
        f"({overhead / t_bare * 100:+.0f} %); first point stored after {one['first_s']:.1f} s "
        "(plan, spawn, imports, one run)"
    )
    if steady_ratio < 1.8:
        print(
            "note: below 1.8 the second core was not free (other processes: see the load average); the "
            "sweep's own process spends the CPU per point above, the workers share nothing else"
        )
    return 0


def main(args: argparse.Namespace) -> int:
    return bench(args.scene, args.duration_s, args.runs)
