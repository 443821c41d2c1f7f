"""`haptic-teleop experiment all`: every experiment behind a table or figure in docs/, run fresh,
its figures and tables gathered, a manifest written beside them, and every documented number
checked against the fresh run (docs/experiments_all.md).

Each job (`JOBS`) is one experiment command with the arguments the docs name. A documented number
is either a cell of a CSV the docs ship (docs/*.csv: compared cell by cell, numbers within the
job's relative tolerance, text equal) or a number a docs page states (`Check`: one cell of the
fresh CSV, the value the page gives, the tolerance its rounding allows). The command exits 1 when
any moved (each named in one line on stderr and in all.md), 0 when every one held.

Writes under --out: one folder per job (the experiment's own outputs), figures/ (the docs' figure
and table files, named as in docs/; `--docs DIR` also copies them there, e.g. `--docs docs` in a
clone), manifest.json (version, Python, platform, per job: its command, seconds, the bundled scenes
it runs with their SHA-256, the seeds) and all.md (every check: documented, fresh, tolerance, held).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import platform
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from haptic_teleop.studies.replications.args import subset

HELP = (
    "run every experiment behind docs/ afresh, gather its figures and tables, write a manifest (version, scene "
    "hashes, seeds) and check every documented number against the fresh runs; exit 1 if one moved"
)


@dataclass(frozen=True)
class Check:
    """A number a docs page states: one cell of a fresh CSV (the row whose `key` column is `row`)."""

    csv: str
    row: dict[str, str]
    column: str
    documented: float
    tolerance: float  # absolute: what the page's rounding allows
    page: str


@dataclass(frozen=True)
class Job:
    name: str  # the experiment's subcommand
    folder: str  # its output folder under --out
    args: tuple[str, ...] = ()
    figures: tuple[tuple[str, str], ...] = ()  # (its output file, the docs file)
    shipped: tuple[tuple[str, str], ...] = ()  # (its CSV, the docs CSV it must reproduce)
    rel_tol: float = 1e-9  # for the shipped CSVs' numbers (the runs are deterministic)
    checks: tuple[Check, ...] = ()
    scenes: tuple[str, ...] = ()
    seeds: str = "1"
    minutes: float = 1.0  # about how long it runs here (the progress bar's weight)


def _c(csv_name: str, row: dict[str, str], column: str, documented: float, tolerance: float, page: str) -> Check:
    return Check(csv_name, row, column, documented, tolerance, page)


_EC = _HLI = "codec_error_control.md"  # both codec experiments' page
_RMS, _PEAK = "RMS force error [N]", "peak force error [N]"
_PRIO = {"scheme": "priority-based, 70 kbit/s"}
_NVE = "nve_experiments.md"
_ST = "stabilizers_compared.md"
_DB = "codec_deadband_experiments.md"

# Every experiment behind a docs table or figure, with the arguments the docs name, and the numbers
# the docs state (their rounding is the tolerance).
JOBS: tuple[Job, ...] = (
    Job(
        "transparency", "transparency",
        figures=(("transparency.png", "transparency.png"),
                 *((f"transparency_{t}.csv", f"transparency_{t}.csv") for t in ("delay", "loss", "free_start"))),
        shipped=tuple((f"transparency_{t}.csv", f"transparency_{t}.csv") for t in ("delay", "loss", "free_start")),
        scenes=("seed_contact",), minutes=0.3,
    ),
    Job(
        "playout", "playout",
        figures=(("playout.png", "playout.png"),
                 *((f"playout{t}.csv", f"playout{t}.csv") for t in ("", "_paired", "_runs"))),
        shipped=tuple((f"playout{t}.csv", f"playout{t}.csv") for t in ("", "_paired", "_runs")),
        scenes=("seed_contact_playout",), seeds="1-20", minutes=1.5,
    ),
    Job(
        "hli-filtering", "hli-filtering",
        figures=(("hli_filtering.png", "codec_hli_filtering.png"),),
        checks=(
            _c("hli_filtering.csv", _PRIO, _RMS, 0.021, 0.0005, _HLI),
            _c("hli_filtering.csv", {"scheme": "deadband 0.7 mm"}, _RMS, 0.106, 0.0005, _HLI),
            _c("hli_filtering.csv", {"scheme": "deadband 2.5 mm"}, _RMS, 0.262, 0.0005, _HLI),
            _c("hli_filtering.csv", {"scheme": "prediction-based filtering"}, _PEAK, 0.58, 0.005, _HLI),
        ),
        minutes=0.1,
    ),
    Job(
        "error-control", "error-control",
        figures=(("error_control.png", "codec_error_control.png"),),
        checks=(
            _c("error_control.csv", _PRIO, _RMS, 0.021, 0.0005, _EC),
            _c("error_control.csv", _PRIO, _PEAK, 0.36, 0.005, _EC),
            _c("error_control.csv", {"scheme": "+ ARQ (mu = 25 ms, nu = 4)"}, _PEAK, 0.27, 0.005, _EC),
            _c("error_control.csv", {"scheme": "+ ARQ (mu = 4 ms, nu = 1)"}, _PEAK, 0.39, 0.005, _EC),
            _c("error_control.csv", {"scheme": "+ FEC (k = 2), playing 50 ms later"}, _PEAK, 0.31, 0.005, _EC),
            _c("error_control.csv", {"scheme": "prediction-based filtering only"}, _PEAK, 0.58, 0.005, _EC),
        ),
        minutes=0.1,
    ),
    Job(
        "nve-analysis", "nve-analysis",
        figures=(("nve_analysis.png", "nve_experiment_analysis.png"),),
        checks=(
            _c("nve_analysis.csv", {"run": "(0) no delay, original m, b, k_h"}, "rms_error_n", 0.01808, 5e-6, _NVE),
            _c("nve_analysis.csv", {"run": "(2) no delay, m_h = 0.2732 kg, b_h = 0.1525 N s/m"}, "rms_error_n",
               0.01698, 5e-6, _NVE),
        ),
        scenes=("nve_push",), minutes=0.2,
    ),
    Job(
        "nve-analysis", "nve-analysis-ramp", args=("--ramp-s", "6", "--duration-s", "20"),
        figures=(("nve_analysis.png", "nve_experiment_analysis_ramp.png"),),
        checks=(
            _c("nve_analysis.csv", {"run": "(2) no delay, m_h = 0.2732 kg, b_h = 0.1525 N s/m"}, "relative_rms_error",
               0.18, 0.005, _NVE),
        ),
        scenes=("nve_push",), minutes=0.3,
    ),
    Job(
        "nve-compensation", "nve-compensation", args=("--rtt-sweep",),
        figures=(("nve_compensation.png", "nve_experiment_compensation.png"),
                 ("nve_compensation_rtt.png", "nve_experiment_compensation_rtt.png")),
        checks=(
            _c("nve_compensation.csv", {"run": "(2) no compensation"}, "rms_error_n", 0.01808, 5e-6, _NVE),
            _c("nve_compensation.csv", {"run": "(3) Fujimoto04, alpha = 0.25 N/m/s"}, "rms_error_n", 0.01616, 5e-6,
               _NVE),
            _c("nve_compensation.csv", {"run": "(4) Fujimoto04, alpha = 1.5 N/m/s"}, "rms_error_n", 0.02220, 5e-6,
               _NVE),
            _c("nve_compensation.csv", {"run": "(5) proposed (transparency)"}, "rms_error_n", 0.01678, 5e-6, _NVE),
            _c("nve_compensation_rtt.csv", {"rtt_s": "0.5"}, "proposed_rms_error_n", 0.02423, 5e-6, _NVE),
        ),
        scenes=("nve_push",), minutes=0.9,
    ),
    Job(
        "deadband", "deadband",
        figures=(("deadband.png", "codec_deadband_rate.png"),),
        checks=(
            _c("deadband.csv", {"stream": "force", "p [%]": "5.0"}, "packets saved [%]", 88.7, 0.05, _DB),
            _c("deadband.csv", {"stream": "force", "p [%]": "5.0"}, "RMS error", 0.228, 0.0005, _DB),
            _c("deadband.csv", {"stream": "velocity", "p [%]": "20.0"}, "packets saved [%]", 91.5, 0.05, _DB),
        ),
        scenes=("touch_ur5e_wall",), minutes=0.2,
    ),
    Job(
        "deadband-loop", "deadband-loop",
        figures=(("deadband_loop.png", "codec_deadband_loop.png"),),
        checks=(
            _c("deadband_loop.csv", {"coded": "forward", "p [%]": "20.0"}, "forward saved [%]", 88.1, 0.05, _DB),
            _c("deadband_loop.csv", {"coded": "backward", "p [%]": "5.0"}, "backward saved [%]", 57.4, 0.05, _DB),
            _c("deadband_loop.csv", {"coded": "backward", "p [%]": "5.0"}, "master force RMS diff [N]", 1.30,
               0.005, _DB),
        ),
        scenes=("touch_ur5e_wall",), minutes=1.8,
    ),
    Job(
        "stabilizers", "stabilizers",
        figures=(
            ("stabilizers.png", "stabilizers.png"),
            ("stabilizers_arm.png", "stabilizers_arm.png"),
            ("zwidth.png", "zwidth.png"),
            ("zwidth_arm.png", "zwidth_arm.png"),
        ),
        checks=(
            _c("stabilizers.csv", {"law": "reservoir", "delay_s": "0.5", "loss": "none"},
               "force_rms_error_vs_wall_n_mean", 2.35, 0.005, _ST),
            _c("stabilizers_arm.csv", {"law": "reservoir", "delay_s": "0.5", "loss": "none"},
               "force_rms_error_vs_wall_n_mean", 13.6, 0.05, _ST),
            _c("stabilizers_arm.csv", {"law": "tdpa_zoh", "delay_s": "0.5", "loss": "none"},
               "force_rms_error_vs_wall_n_mean", 11.0, 0.05, _ST),
            _c("zwidth_runs.csv", {"law": "wave", "delay_s": "0.1", "wall_stiffness_n_per_m": "100000.0",
                                   "wall_damping_n_s_per_m": "0.0"}, "felt_static_stiffness_n_per_m", 142, 0.5, _ST),
            _c("zwidth_runs.csv", {"law": "reservoir", "delay_s": "0.1", "wall_stiffness_n_per_m": "100000.0",
                                   "wall_damping_n_s_per_m": "0.0"}, "felt_static_stiffness_n_per_m", 498, 0.5, _ST),
            _c("stabilizers.csv", {"law": "tdpa_zoh", "delay_s": "0.2", "loss": "none"},
               "force_rms_error_vs_wall_n_mean", 7.59, 0.005, _ST),
            _c("stabilizers.csv", {"law": "tdpa_velocity", "delay_s": "0.5", "loss": "none"},
               "two_port_margin_min_j_mean", -0.197, 0.0005, _ST),
            _c("stabilizers_arm.csv", {"law": "two_condition", "delay_s": "0.5", "loss": "none"},
               "force_rms_error_vs_wall_n_mean", 16.2, 0.05, _ST),
            _c("stabilizers_arm.csv", {"law": "wave", "delay_s": "0.1", "loss": "none"},
               "force_rms_error_vs_wall_n_mean", 1.44, 0.005, _ST),
            _c("zwidth_arm_runs.csv", {"law": "wave", "delay_s": "0.1", "wall_stiffness_n_per_m": "100000.0",
                                       "wall_damping_n_s_per_m": "0.0"},
               "felt_static_stiffness_n_per_m", 181, 0.5, _ST),
        ),
        scenes=("wall_contact", "touch_ur5e_wall"), seeds="1-2", minutes=2.6,
    ),
)  # fmt: skip


def _checks_table(results: Sequence[tuple[str, Check | str, float, bool]]) -> str:
    lines = ["| job | what | documented | fresh | tolerance | held |", "|---|---|---|---|---|---|"]
    for job, what, fresh, ok in results:
        if isinstance(what, Check):
            where = ", ".join(f"{k} = {v}" for k, v in what.row.items())
            desc = f"{what.csv}: {where}: {what.column} ({what.page})"
            lines.append(
                f"| {job} | {desc} | {what.documented:g} | {fresh:.6g} | {what.tolerance:g} | {'yes' if ok else 'NO'} |"
            )
        else:
            lines.append(f"| {job} | {what} | | | | {'yes' if ok else 'NO'} |")
    return "\n".join(lines) + "\n"


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def compare_shipped(fresh: Path, shipped: Path, rel_tol: float) -> list[str]:
    """Every cell of the shipped CSV against the fresh one: numbers within `rel_tol` (and 1e-12
    absolute), text equal, the same header and row count. The differences, one line each."""
    a, b = _rows(fresh), _rows(shipped)
    if not b:
        return [f"{shipped.name}: the shipped CSV has no rows"]
    if len(a) != len(b) or list(a[0]) != list(b[0]):
        fresh_cols = list(a[0]) if a else []
        return [f"{shipped.name}: {len(a)} fresh rows with columns {fresh_cols}, shipped {len(b)} with {list(b[0])}"]
    out = []
    for i, (ra, rb) in enumerate(zip(a, b, strict=True)):
        for col, vb in rb.items():
            va = ra[col]
            na, nb = _number(va), _number(vb)
            if na is None or nb is None:
                if va != vb:
                    out.append(f"{shipped.name} row {i + 1} {col}: {va!r} fresh, {vb!r} shipped")
            elif not ((math.isnan(na) and math.isnan(nb)) or math.isclose(na, nb, rel_tol=rel_tol, abs_tol=1e-12)):
                out.append(f"{shipped.name} row {i + 1} {col}: {na:.10g} fresh, {nb:.10g} shipped")
    return out


def evaluate(check: Check, folder: Path) -> float:
    """The fresh value of a check (NaN when its row is not in the CSV)."""
    for row in _rows(folder / check.csv):
        if all(row.get(k) == v for k, v in check.row.items()):
            v = _number(row[check.column])
            return math.nan if v is None else v
    return math.nan


def scene_hashes(names: Sequence[str]) -> dict[str, str]:
    from haptic_teleop.scene.load import find_scene

    return {n: hashlib.sha256(Path(find_scene(n)).read_bytes()).hexdigest() for n in names}


def run_job(job: Job, out: Path, keep_bags: bool = False) -> tuple[float, int, str]:
    """The experiment, as its command runs it: (seconds, exit code, the end of its stderr)."""
    cmd = [sys.executable, "-m", "haptic_teleop.cli", "experiment", job.name, "--out", str(out / job.folder)]
    cmd += [*_args(job, keep_bags), "--quiet"]
    t0 = time.monotonic()
    r = subprocess.run(cmd, capture_output=True, text=True)
    return time.monotonic() - t0, r.returncode, r.stderr.strip()[-2000:]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="output directory, new or empty (default runs/all-NNN)")
    p.add_argument("--only", help="a comma-separated subset of the jobs (see --list)")
    p.add_argument("--list", action="store_true", help="print the jobs and their commands, run nothing")
    p.add_argument("--docs", help="also copy the regenerated figures and tables into this folder (e.g. docs)")
    p.add_argument(
        "--keep-bags",
        action="store_true",
        help="keep every run's bag (about 1.6 GB for all jobs; default: each experiment measures its bags, "
        "then deletes them)",
    )
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def _args(job: Job, keep_bags: bool) -> tuple[str, ...]:
    """The job's arguments: every experiment records its runs as bags; `--discard-bags` unless kept."""
    return job.args if keep_bags else (*job.args, "--discard-bags")


def _command(job: Job, keep_bags: bool = False) -> str:
    return " ".join(["haptic-teleop experiment", job.name, *_args(job, keep_bags)])


def main(args: argparse.Namespace) -> int:
    from haptic_teleop import __version__
    from haptic_teleop.analysis.outputs import check_out_dir, default_out
    from haptic_teleop.errors import InputError
    from haptic_teleop.resources import docs_dir

    jobs = list(JOBS)
    if args.only:
        names = subset(args.only, [j.folder for j in JOBS], "--only")
        jobs = [j for j in JOBS if j.folder in names]
    if args.list:
        for j in jobs:
            sys.stdout.write(f"{j.folder:22s} {_command(j, args.keep_bags)}  (about {j.minutes:g} min)\n")
        return 0
    docs_src = docs_dir()
    shipped_needed = [s for j in jobs for _, s in j.shipped]
    if shipped_needed and docs_src is None:
        raise InputError("experiment all compares with the CSVs shipped in docs/, which this install does not have")
    target = Path(args.docs) if args.docs else None
    if target is not None and not target.is_dir():
        raise InputError(f"--docs {args.docs}: not a directory; allowed: an existing folder (docs in a clone)")
    out = Path(args.out) if args.out else default_out("all")
    check_out_dir(out)
    figures = out / "figures"
    figures.mkdir()
    manifest: dict[str, Any] = {
        "version": __version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "jobs": {},
    }
    results: list[tuple[str, Check | str, float, bool]] = []
    failures: list[str] = []
    from tqdm import tqdm

    total = sum(j.minutes for j in jobs)
    with tqdm(
        total=total,
        unit="min",
        disable=args.quiet,
        desc="experiments",
        bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} est. min",
    ) as bar:
        for j in jobs:
            bar.set_postfix_str(j.folder)
            seconds, code, err = run_job(j, out, args.keep_bags)
            bar.update(j.minutes)
            manifest["jobs"][j.folder] = {
                "command": _command(j, args.keep_bags),
                "seconds": round(seconds, 1),
                "exit_code": code,
                "scenes": scene_hashes(j.scenes),
                "seeds": j.seeds,
            }
            folder = out / j.folder
            if code != 0:
                failures.append(f"{j.folder}: the experiment exited {code}: {err.splitlines()[-1] if err else ''}")
                results.append((j.folder, "the experiment ran", math.nan, False))
                continue
            for made, doc in j.figures:
                shutil.copy2(folder / made, figures / doc)
                if target is not None:
                    shutil.copy2(folder / made, target / doc)
            for made, doc in j.shipped:
                assert docs_src is not None
                diffs = compare_shipped(folder / made, docs_src / doc, j.rel_tol)
                failures += [f"{j.folder}: {d}" for d in diffs]
                results.append((j.folder, f"{doc}: every cell (relative tolerance {j.rel_tol:g})", math.nan, not diffs))
            for c in j.checks:
                fresh = evaluate(c, folder)
                ok = math.isfinite(fresh) and abs(fresh - c.documented) <= c.tolerance
                results.append((j.folder, c, fresh, ok))
                if not ok:
                    failures.append(
                        f"{j.folder}: {c.page} says {c.column} = {c.documented:g} "
                        f"(+-{c.tolerance:g}) for {c.row}; fresh {fresh:.6g}"
                    )
    manifest["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    table = _checks_table(results)
    (out / "all.md").write_text(table)
    for line in failures:
        sys.stderr.write(f"haptic-teleop: experiment all: {line}\n")
    if not args.quiet:
        held = sum(1 for r in results if r[3])
        sys.stdout.write(table + f"\n{held} of {len(results)} checks held; {out / 'manifest.json'}\n")
    return 1 if failures else 0
