"""Where a run's outputs go and how they are written: summary.json and plots from a bag, files
written whole (by a rename), the default and the checks of an output directory.

Shared by `haptic-teleop run` and `analyze` (cli/main.py), `sweep` (cli/sweep.py) and `launch --record`
(live/launcher.py), which all write the same files the same way.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

from haptic_teleop import interrupt
from haptic_teleop.errors import InputError

TIMING_FILE = "timing.json"
SCENE_FILE = "scene.yaml"


def _clean(summary: dict[str, Any]) -> dict[str, Any]:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in summary.items()}


def write_atomic(path: Path, text: str) -> None:
    """Write `text` to `path` through a temporary file and a rename: a reader (or an abort) never
    sees half a file."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_outputs(bag_dir: Path, out_dir: Path, plots: bool = True) -> dict[str, Any]:
    """Analyse a bag: summary.json and plots/ in out_dir. Same code for `run` and `analyze`.

    summary.json is written (whole, by a rename) before the plots start."""
    from haptic_teleop.analysis.stream import summarize_bag

    interrupt.pause_for_test("summary")
    if _is_nve(bag_dir):
        return _write_nve_outputs(bag_dir, out_dir, plots)
    summary = summarize_bag(bag_dir)
    timing = Path(bag_dir).parent / TIMING_FILE
    if timing.is_file():
        t = json.loads(timing.read_text())
        summary["realtime_factor"] = t["realtime_factor"]
        summary["engine_loop"] = t.get("loop", "python")
    out_dir.mkdir(parents=True, exist_ok=True)
    write_atomic(out_dir / "summary.json", json.dumps(_clean(summary), indent=2, sort_keys=True) + "\n")
    if plots:
        from haptic_teleop.analysis.bag_plotdata import from_bag
        from haptic_teleop.analysis.plots import write_plots

        interrupt.pause_for_test("plots")
        write_plots(from_bag(bag_dir, summary.get("force_alignment_lag_s")), out_dir / "plots")
    return summary


def _is_nve(bag_dir: Path) -> bool:
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag_dir) as reader:
        return reader.nve_schema is not None


def _write_nve_outputs(bag_dir: Path, out_dir: Path, plots: bool) -> dict[str, Any]:
    """An NVE run's summary.json and plots (analysis/nve_summary.py)."""
    from haptic_teleop.analysis.nve_summary import summarize_nve, write_nve_plots

    summary = summarize_nve(bag_dir)
    timing = Path(bag_dir).parent / TIMING_FILE
    if timing.is_file():
        summary["realtime_factor"] = json.loads(timing.read_text())["realtime_factor"]
    out_dir.mkdir(parents=True, exist_ok=True)
    write_atomic(out_dir / "summary.json", json.dumps(_clean(summary), indent=2, sort_keys=True) + "\n")
    if plots:
        interrupt.pause_for_test("plots")
        write_nve_plots(bag_dir, out_dir / "plots")
    return summary


def default_out(scene_name: str) -> Path:
    base = Path("runs")
    i = 1
    while (base / f"{scene_name}-{i:03d}").exists():
        i += 1
    return base / f"{scene_name}-{i:03d}"


def check_out_dir(out: Path, empty: bool = True, flag: str = "--out") -> None:
    """Fail now, before anything runs, when `out` cannot take the outputs: a file, not empty (when
    `empty`), or not writable. Creates `out` (a probe file tells writable from not, also as root)."""
    if out.exists() and not out.is_dir():
        raise InputError(f"{flag} {out}: is a file; allowed: a directory that does not exist yet or is empty")
    if empty and out.is_dir() and any(out.iterdir()):
        raise InputError(f"{flag} {out}: exists and is not empty; allowed: a new or empty directory")
    existed = out.is_dir()
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as exc:
        if not existed and out.is_dir():
            with contextlib.suppress(OSError):
                out.rmdir()
        reason = exc.strerror or str(exc)
        raise InputError(f"{flag} {out}: cannot write there ({reason}); allowed: a directory you can write") from None
