"""`haptic-teleop bench effects`: the engine's cost per tick with no effects and with each effect alone.

"bare" is the scene with its network effects taken out (both directions) and no plant effects:
plants, controllers, operator, links that deliver at once, buffers. Every other row names exactly
one effect on top of that, by scene override (`--set` syntax), so the table shows that a tick's
cost grows only with what the scene names. The figure is the CPU time of the thread running
`Engine.run` divided by the ticks (engine construction excluded). Each case runs back to back
with a bare run, `--repeat` times (alternating which goes first); the delta printed is the median
of the paired differences, so load from other processes, which changes over seconds, mostly
cancels, and half their interquartile range shows what is left of it.

Every row runs the Python loop (`--loop python`): effects with a per-tick wrapper run only there,
so the bare scene is measured in it too; the compiled loop's cost is in `bench speed`.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from typing import Any

from haptic_teleop.studies.benchmarks import add_scene_argument, positive

HELP = "per-tick cost of the bare engine loop and of each effect alone (physical, sensing, network)"

NO_NETWORK = ("network.forward.effects=", "network.backward.effects=")
FWD = "network.forward.effects"

# (label, overrides naming one effect)
CASES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("bare (no effects)", ()),
    ("master gravity, 10 deg incline", ("master.effects.gravity.incline_deg=10",)),
    ("slave gravity, -10 deg incline", ("slave.effects.gravity.incline_deg=-10",)),
    ("master friction, Coulomb 0.2 N", ("master.effects.friction.coulomb_n=0.2",)),
    ("master friction, viscous 0.5 N s/m", ("master.effects.friction.viscous_n_s_per_m=0.5",)),
    ("slave friction, Coulomb 0.5 N", ("slave.effects.friction.coulomb_n=0.5",)),
    ("master position noise 10 um", ("master.effects.noise.position_std_m=1e-5",)),
    ("master velocity noise 1 mm/s", ("master.effects.noise.velocity_std_m_per_s=1e-3",)),
    ("slave force noise 0.1 N", ("slave.effects.noise.force_std_n=0.1",)),
    ("master encoder 10 um", ("master.effects.encoder.resolution_m=1e-5",)),
    ("slave force low-pass 50 Hz", ("slave.effects.force_filter.cutoff_hz=50",)),
    (
        "slave force moving average 10",
        ("slave.effects.force_filter={type: moving_average, window_samples: 10}",),
    ),
    ("master saturation 10 N", ("master.effects.saturation.force_limit_n=10",)),
    ("master slew limit 2000 N/s", ("master.effects.saturation.slew_rate_n_per_s=2000",)),
    ("forward delay 50 ms", (f"{FWD}.delay.delay_s=0.05",)),
    ("forward delay 50 ms + 5 ms jitter", (f"{FWD}.delay={{delay_s: 0.05, jitter_s: 0.005}}",)),
    ("forward loss bernoulli 5 %", (f"{FWD}.loss.probability=0.05",)),
    (
        "forward loss gilbert-elliott",
        (f"{FWD}.loss={{model: gilbert_elliott, p: 0.01, r: 0.25, one_minus_h: 0.7, one_minus_k: 0.001}}",),
    ),
    ("forward duplicate 1 %", (f"{FWD}.duplicate.probability=0.01",)),
    ("forward corrupt 1 %", (f"{FWD}.corrupt.probability=0.01",)),
    ("forward rate limit 2 Mbit/s", (f"{FWD}.rate_limit.rate_bps=2e6",)),
    ("forward blackout 0.2 s", (f"{FWD}.blackout={{starts_s: [1.0], ends_s: [1.2]}}",)),
    (
        "forward reorder 5 % (+ delay 50 ms)",
        (f"{FWD}.delay.delay_s=0.05", f"{FWD}.reorder.probability=0.05"),
    ),
)


def _engine(scene_name: str, overrides: tuple[str, ...]) -> Any:
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.scene.load import find_scene, load_scene

    # The Python loop throughout: effects with per-tick wrappers only run there, so the bare loop
    # is measured in it too (the compiled loop's cost is `bench speed`'s).
    return Engine(load_scene(find_scene(scene_name), overrides), loop="python")


def _run_us(engine: Any) -> float:
    """CPU microseconds per tick of one `Engine.run`."""
    t0 = time.thread_time()
    result = engine.run(handle_sigint=False)
    ticks: int = result.ticks
    return (time.thread_time() - t0) / ticks * 1e6


def calls_per_tick(scene_name: str, overrides: tuple[str, ...], ticks: int = 500) -> float:
    """Function calls (Python and C, as `sys.setprofile` sees them) per tick: runs of `ticks` and
    `2 * ticks` are counted and differenced, so what a run does once drops out. Deterministic, so
    it shows what an effect adds when the CPU time is too noisy to."""
    _engine(scene_name, (*overrides, "scene.duration_s=0.01")).run(handle_sigint=False)  # one-time work
    counts = []
    for n in (ticks, 2 * ticks):
        engine = _engine(scene_name, (*overrides, f"scene.duration_s={n / 1000}", "scene.period_s=0.001"))
        calls = 0

        def count(frame: Any, event: str, arg: Any) -> None:
            nonlocal calls
            if event in ("call", "c_call"):
                calls += 1

        sys.setprofile(count)
        try:
            engine.run(handle_sigint=False)
        finally:
            sys.setprofile(None)
        counts.append(calls)
    return (counts[1] - counts[0]) / ticks


def bench(scene_name: str, duration_s: float, repeat: int) -> int:
    base = (*NO_NETWORK, f"scene.duration_s={duration_s}")
    bare_label, bare_overrides = CASES[0]
    for _, overrides in CASES:  # warm-up, not counted: imports, first-call paths, caches
        _run_us(_engine(scene_name, (*NO_NETWORK, "scene.duration_s=0.2", *overrides)))
    bare: list[float] = []
    cost: dict[str, list[float]] = {label: [] for label, _ in CASES[1:]}
    delta: dict[str, list[float]] = {label: [] for label, _ in CASES[1:]}
    # Paired runs: both engines are built first, then run back to back (alternating which goes
    # first), so load from other processes, which changes over seconds, mostly cancels in the
    # difference.
    for r in range(repeat):
        for label, overrides in CASES[1:]:
            engines = [_engine(scene_name, (*base, *bare_overrides)), _engine(scene_name, (*base, *overrides))]
            if r % 2:
                c_us = _run_us(engines[1])
                b_us = _run_us(engines[0])
            else:
                b_us = _run_us(engines[0])
                c_us = _run_us(engines[1])
            bare.append(b_us)
            cost[label].append(c_us)
            delta[label].append(c_us - b_us)
    calls = {label: calls_per_tick(scene_name, (*NO_NETWORK, *overrides)) for label, overrides in CASES}
    bare_us = statistics.median(bare)
    print(f"scene {scene_name}, network effects removed, {duration_s:g} s at 1 kHz, {repeat} paired runs per row")
    print("CPU time of Engine.run per tick; delta = median of (case - bare) over pairs of runs made back to")
    print("back; +- = half the interquartile range of those differences (the run-to-run noise);")
    print("calls = function calls per tick (Python and C, counted with sys.setprofile: exact, load-free)")
    print(f"{'effect (alone)':40s} {'us/tick':>8s} {'delta us':>9s} {'+-':>6s} {'delta %':>8s}", end="")
    print(f" {'calls':>6s} {'delta':>6s}")
    c0 = calls[bare_label]
    print(f"{bare_label:40s} {bare_us:8.2f} {0.0:+9.2f} {'':>6s} {0.0:+7.1f}% {c0:6.1f} {0.0:+6.1f}")
    for label, _ in CASES[1:]:
        d = statistics.median(delta[label])
        q = statistics.quantiles(delta[label], n=4) if len(delta[label]) > 1 else [d, d, d]
        print(
            f"{label:40s} {statistics.median(cost[label]):8.2f} {d:+9.2f} {(q[2] - q[0]) / 2:6.2f} "
            f"{100 * d / bare_us:+7.1f}% {calls[label]:6.1f} {calls[label] - c0:+6.1f}"
        )
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scene_argument(p)
    p.add_argument("--duration-s", type=positive(float), default=1.0, help="simulated seconds per run")
    p.add_argument("--repeat", type=positive(int), default=15, help="paired runs per row")


def main(args: argparse.Namespace) -> int:
    return bench(args.scene, args.duration_s, args.repeat)
