"""`haptic-teleop bench memory`: peak memory of a recorded run against its length.

For each duration (default 10 s, 100 s and 1000 s of simulated time) and each tick loop, in a
fresh process each time:
- `record`: what `haptic-teleop run` does up to a closed bag (`engine.record_run`: the engine, the
  tick loop and the bag writer process), nothing after it;
- `run`: the whole `haptic-teleop run` command: recording, then the analysis of the bag
  (summary.json, streamed: `analysis/stream.py`) and the plots (streamed and decimated:
  `analysis/plotdata.py`);
- `summary`: the same without the plots (`run --no-plots`).
A figure is the peak resident set (VmHWM, `ru_maxrss`) of the largest process of the command (the
loop's process or the bag writer), read by a small wrapper process with
`getrusage(RUSAGE_CHILDREN)` once the command has exited, so no earlier run can inflate it. The
ratio of the longest to the shortest run says whether memory grows with duration (target: at
most 1.2, for `record` and for the whole `run`). Figures only: nothing here is asserted by a test (the machine's memory
use moves with its load; tests check the buffers' sizes instead).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# Runs the command given as arguments, then prints its largest process's peak RSS in kB.
_WRAPPER = (
    "import json, resource, subprocess, sys, time\n"
    "t0 = time.perf_counter()\n"
    "r = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)\n"
    "wall = time.perf_counter() - t0\n"
    "peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
    "print(json.dumps({'rc': r.returncode, 'peak_kb': peak, 'wall_s': wall, 'err': r.stderr[-2000:]}))\n"
)


def record_only(scene_name: str, duration_s: float, loop: str, out: str) -> int:
    """The `record` stage: load the scene and record it as `haptic-teleop run` does, then exit."""
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.scene.load import find_scene, load_scene

    scene = load_scene(find_scene(scene_name), overrides=[f"scene.duration_s={duration_s:g}"])
    record_run(scene, Path(out) / "bag", handle_sigint=False, loop=loop)
    return 0


def measure(stage: str, scene: str, duration_s: float, loop: str) -> dict[str, float]:
    """Peak RSS (MB) and wall time of one stage in a fresh process."""
    with tempfile.TemporaryDirectory(prefix="haptic-bench-memory-") as tmp:
        out = str(Path(tmp) / "out")
        if stage == "record":
            cmd = [sys.executable, "-m", "haptic_teleop.studies.benchmarks.memory", scene, f"{duration_s:g}", loop, out]
        else:
            cmd = [
                sys.executable, "-m", "haptic_teleop.cli", "run", scene, "--out", out, "--quiet",
                "--loop", loop, "--set", f"scene.duration_s={duration_s:g}",
            ]  # fmt: skip
            if stage == "summary":
                cmd.append("--no-plots")
        r = subprocess.run([sys.executable, "-c", _WRAPPER, *cmd], capture_output=True, text=True, env=os.environ)
        if r.returncode != 0 or not r.stdout.strip():
            raise SystemExit(f"bench memory: the wrapper failed: {r.stderr.strip()[-500:]}")
        res = json.loads(r.stdout.strip().splitlines()[-1])
        if res["rc"] != 0:
            raise SystemExit(f"bench memory: {' '.join(cmd[2:5])} exited {res['rc']}: {res['err'].strip()[-500:]}")
        return {"peak_mb": res["peak_kb"] / 1024.0, "wall_s": res["wall_s"]}


def memory(scene: str, durations: list[float], loops: list[str], stages: list[str]) -> int:
    print(f"scene {scene}: peak RSS of the largest process, each run in a fresh process")
    print(f"{'stage':<8} {'loop':<9} " + " ".join(f"{d:>9g} s" for d in durations) + f"  {'ratio':>6}")
    for stage in stages:
        for loop in loops:
            measure("record", scene, 0.01, loop)  # fills numba's cache: no run below compiles
            t0 = time.perf_counter()
            figs = [measure(stage, scene, d, loop) for d in durations]
            peaks = [f["peak_mb"] for f in figs]
            ratio = peaks[-1] / peaks[0]
            walls = ", ".join(f"{f['wall_s']:.0f}" for f in figs)
            print(
                f"{stage:<8} {loop:<9} "
                + " ".join(f"{p:>8.0f}MB" for p in peaks)
                + f"  {ratio:6.2f}   (wall {walls} s; {time.perf_counter() - t0:.0f} s in all)",
                flush=True,
            )
    print(f"ratio: longest / shortest run ({durations[-1]:g} s / {durations[0]:g} s); target <= 1.2")
    return 0


HELP = "peak memory (RSS) of recorded runs of 10, 100 and 1000 s: does it grow with duration?"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scene", default="wall_contact", help="scene YAML path or bundled name")
    p.add_argument(
        "--durations", default="10,100,1000", help="simulated seconds, comma separated (default 10,100,1000)"
    )
    p.add_argument("--loops", default="compiled,python", help="tick loops, comma separated (compiled, python)")
    p.add_argument(
        "--stages",
        default="record,run",
        help="record (engine and bag writer), run (the whole command), summary (run --no-plots)",
    )


def main(args: argparse.Namespace) -> int:
    try:
        durations = [float(d) for d in args.durations.split(",")]
    except ValueError:
        raise SystemExit(f"--durations must be numbers separated by commas, got {args.durations!r}") from None
    if not durations or min(durations) <= 0:
        raise SystemExit(f"--durations must be positive, got {args.durations!r}")
    loops = [x for x in args.loops.split(",") if x]
    stages = [x for x in args.stages.split(",") if x]
    bad = [x for x in loops if x not in ("compiled", "python")]
    bad += [x for x in stages if x not in ("record", "run", "summary")]
    if bad or not loops or not stages:
        raise SystemExit(
            f"--loops takes compiled, python and --stages record, run, summary; got {', '.join(bad) or 'none'}"
        )
    return memory(args.scene, durations, loops, stages)


if __name__ == "__main__":  # the `record` stage's process (see `measure`)
    sys.exit(record_only(sys.argv[1], float(sys.argv[2]), sys.argv[3], sys.argv[4]))
