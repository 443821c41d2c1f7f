"""`haptic-teleop bench recording`: what CRCs and chunk compression cost (docs/recording_costs.md).

Runs the scene once, then writes its bag in process (`write_run`) and reads every topic back
(`BagReader`), round after round, the variants alternating: without CRCs (the CRC fields 0, as a
writer that does not compute them leaves them), with CRCs (the default), and with zstd and lz4
chunk compression. Prints, per variant, the range of write and read times over the rounds and the
file size.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from haptic_teleop.studies.benchmarks import add_scene_argument, positive

HELP = "cost of CRCs and zstd/lz4 chunk compression: write and read times of a run's bag, file size"

# "CRC" is the recorder's own (record/crc.py: ISA-L's when installed), "CRC (zlib)" the standard
# library's: the same values, at the speed of each.
VARIANTS = ("no CRC", "CRC (zlib)", "CRC", "CRC + zstd", "CRC + lz4")


def _no_crc(data: Any, value: int = 0) -> int:
    """Stands in for the CRC in the writer and reader: every CRC is 0 (not computed, not checked)."""
    return 0


@contextmanager
def _crc(variant: str) -> Iterator[None]:
    from haptic_teleop.record import crc, mcap, mcapread

    use = {"no CRC": _no_crc, "CRC (zlib)": zlib.crc32}.get(variant, crc.crc32)
    mcap.crc32 = mcapread.crc32 = use  # type: ignore[attr-defined]
    try:
        yield
    finally:
        mcap.crc32 = mcapread.crc32 = crc.crc32  # type: ignore[attr-defined]


def _read_all(bag: Path) -> None:
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag) as r:
        for topic in r.topics:
            if topic.endswith("/packets"):
                r.packets(topic)
            elif topic.startswith("/haptic_teleop/"):
                r.string(topic)
            else:
                r.read(topic)


def crc_implementation() -> str:
    from haptic_teleop.record.crc import CRC_IMPLEMENTATION

    hint = " (pip install isal: 4 to 5 times faster)" if CRC_IMPLEMENTATION == "zlib" else ""
    return f"the recorder's is {CRC_IMPLEMENTATION}'s{hint}"


def bench(scene_name: str, duration_s: float, rounds: int) -> int:
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.record.recorder import write_run
    from haptic_teleop.scene.load import find_scene, load_scene

    scene = load_scene(find_scene(scene_name), overrides=[f"scene.duration_s={duration_s}"])
    run = Engine(scene).run(handle_sigint=False)
    times: dict[str, list[tuple[float, float]]] = {v: [] for v in VARIANTS}
    sizes: dict[str, int] = {}
    work = Path(tempfile.mkdtemp(prefix="bench-recording-"))
    try:
        for _ in range(rounds):
            for v in VARIANTS:
                bag = work / "bag"
                shutil.rmtree(bag, ignore_errors=True)
                comp = v.split(" + ")[1] if " + " in v else "none"
                with _crc(v):
                    t0 = time.perf_counter()
                    write_run(run, bag, {}, compression=comp)
                    t1 = time.perf_counter()
                    _read_all(bag)
                    t2 = time.perf_counter()
                times[v].append((t1 - t0, t2 - t1))
                sizes[v] = sum(p.stat().st_size for p in bag.glob("*.mcap"))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"{scene_name}, {duration_s:g} s ({run.ticks} ticks), {rounds} rounds; median [min .. max] over the rounds")
    print(f"CRC: {crc_implementation()}")
    print(f"{'variant':12s} {'write (ms)':>18s} {'read all (ms)':>20s} {'file (MiB)':>11s}")
    for v in VARIANTS:
        w = [a * 1e3 for a, _ in times[v]]
        r = [b * 1e3 for _, b in times[v]]
        print(
            f"{v:12s} {statistics.median(w):5.0f} [{min(w):4.0f} .. {max(w):4.0f}]"
            f" {statistics.median(r):6.0f} [{min(r):5.0f} .. {max(r):5.0f}] {sizes[v] / 2**20:11.1f}"
        )
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scene_argument(p)
    p.add_argument("--duration-s", type=positive(float), default=10.0, help="simulated seconds of the run")
    p.add_argument("--rounds", type=positive(int), default=5, help="rounds of all variants")


def main(args: argparse.Namespace) -> int:
    return bench(args.scene, args.duration_s, args.rounds)
