"""`haptic-teleop compile`: build the compiled tick loops into numba's on-disk cache ahead of use.

Each compiled loop is compiled on the first run on a machine that needs it and loaded from
numba's cache afterwards (docs/performance.md, "Compile once"): the 1-DoF loop (`axis`, with the
network schedule's Markov loss chains and jitter, engine/compiled/link_runs.py, and the playout
buffers' rules, engine/compiled/buffer_schedule.py), the 1-DoF
loop with the codec stage (`codec`), the arm loop (`arm`), the arm loop with the codec stage
(`arm_codec`) and the side tick the live arm nodes run (`side`). This runs a few ticks of a
bundled scene through each, so that a first real run, a launch, a benchmark, a sweep or a test
session does not pay it. A kernel that another process is compiling at the same time is waited
for and then loaded (`compiling.first_compile`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path

# name -> (bundled scene, overrides): a few ticks of each reach its kernel
KERNELS: dict[str, tuple[str, tuple[str, ...]]] = {
    "axis": ("wall_contact", ()),
    "codec": ("wall_contact", ("network.forward.codec={kind: prediction}",)),
    "arm": ("touch_ur5e_wall", ()),
    "arm_codec": ("touch_ur5e_wall", ("network.forward.codec={kind: deadband, deadband: 0.1}",)),
    "side": ("touch_ur5e_wall", ()),  # the live arm nodes' side tick (assembly/compiled_side.warm)
}


def parse_names(text: str | None) -> list[str]:
    """`axis,codec` -> ["axis", "codec"]; None: every kernel. ValueError naming the allowed ones."""
    if text is None:
        return list(KERNELS)
    names = [n.strip() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in KERNELS]
    if bad or not names:
        raise ValueError(f"unknown kernel {', '.join(bad) or repr(text)}; allowed: {', '.join(KERNELS)}")
    return names


def warm_one(name: str) -> float:
    """Run a few ticks of `name`'s scene in the compiled loop (compiling it or loading numba's
    cache); the seconds it took. RuntimeError if this machine cannot run that loop compiled."""
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.errors import ConfigError
    from haptic_teleop.scene.load import find_scene, load_scene

    scene_name, overrides = KERNELS[name]
    t0 = time.perf_counter()
    scene = load_scene(find_scene(scene_name), overrides=["scene.duration_s=0.005", *overrides])
    if name == "side":
        from haptic_teleop.assembly.compiled_side import warm as warm_side

        why = warm_side(scene.config)
        if why is not None:
            raise RuntimeError(why)
        return time.perf_counter() - t0
    try:
        engine = Engine(scene, loop="compiled")
    except ConfigError as exc:  # no numba here, or the kernel cannot load: `--loop compiled` says why
        raise RuntimeError(str(exc)) from exc
    engine.run(handle_sigint=False)
    if name == "axis":  # the link runs and the playout rules every compiled loop's schedules run
        from haptic_teleop.engine.compiled import buffer_schedule, link_runs

        link_runs.warm()
        buffer_schedule.warm()
    return time.perf_counter() - t0


def warm(names: Sequence[str], done_dir: Path | None = None, say: Callable[[str], None] = print) -> int:
    """Warm each kernel of `names` in turn, saying how long each took; with `done_dir`, touch
    `<name>.done` there as each finishes (`<name>.failed` if it cannot be built). 0 if every
    kernel was built, 1 if any failed."""
    failed = 0
    for name in names:
        try:
            seconds = warm_one(name)
        except RuntimeError as exc:
            failed += 1
            say(f"{name}: not compiled: {exc}")
            if done_dir is not None:
                (done_dir / f"{name}.failed").write_text(str(exc))
            continue
        say(f"{name}: ready in {seconds:.1f} s")
        if done_dir is not None:
            (done_dir / f"{name}.done").write_text(f"{seconds:.3f}\n")
    return 1 if failed else 0
