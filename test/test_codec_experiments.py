"""`haptic-teleop experiment hli-filtering` (experiments/codec.py): seed 000's simulation end to end
on a short run, the ordering its numbers must show, and one-line argument errors."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

CLI = [sys.executable, "-m", "haptic_teleop.cli", "experiment", "hli-filtering"]


def _rows(out: Path) -> dict[str, dict[str, float]]:
    with (out / "hli_filtering.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    return {r["scheme"]: {k: float(v) for k, v in r.items() if k != "scheme"} for r in rows}


def test_filtering_runs_and_priority_based_has_the_smallest_error_of_the_filters(tmp_path: Path) -> None:
    out = tmp_path / "f"
    r = subprocess.run(
        [*CLI, "--out", str(out), "--duration-s", "6", "--quiet"], capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr
    for name in ("hli_filtering.csv", "hli_filtering.md", "hli_filtering.png"):
        assert (out / name).stat().st_size > 100
    rows = _rows(out)
    every = rows["every sample (prediction)"]
    prio = rows["priority-based, 70 kbit/s"]
    fine, coarse = rows["deadband 0.7 mm"], rows["deadband 2.5 mm"]
    pred = rows["prediction-based filtering"]
    assert every["packets/s"] == pytest.approx(1000.0)
    # filtering sends far fewer packets than every sample
    assert max(prio["packets/s"], fine["packets/s"], coarse["packets/s"]) < 0.2 * every["packets/s"]
    # the seed's ordering of the force errors: priority-based < deadband 0.7 mm < deadband 2.5 mm
    err = "RMS force error [N]"
    assert prio[err] < fine[err] < coarse[err]
    # priority-based is prediction-based filtering plus the HLI1 followers: more packets, more latency
    assert pred["packets/s"] < prio["packets/s"] and pred["latency [ms]"] < prio["latency [ms]"]


@pytest.mark.parametrize(
    "argv", [["--loss", "1.5"], ["--duration-s", "0"], ["--filtering", "random"], ["--bandwidth-bps", "x"]]
)
def test_bad_arguments_are_one_line_exit_2(tmp_path: Path, argv: list[str]) -> None:
    r = subprocess.run([*CLI, "--out", str(tmp_path / "x"), *argv], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not (tmp_path / "x").exists()


def test_deadband_experiment_rates_grow_with_p_and_errors_with_them(tmp_path: Path) -> None:
    """`experiment deadband` on a short tapping run: every p of seed 001's list for both streams,
    packets saved and the error both grow with p, and p = 0 reconstructs exactly."""
    out = tmp_path / "d"
    r = subprocess.run(
        [sys.executable, "-m", "haptic_teleop.cli", "experiment", "deadband", "--out", str(out), "--duration-s", "3",
         "--quiet"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert (out / "deadband.png").stat().st_size > 10_000
    with (out / "deadband.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    for stream in ("force", "velocity"):
        got = [row for row in rows if row["stream"] == stream]
        assert [float(row["p [%]"]) for row in got] == [0, 2.5, 5, 7.5, 10, 12.5, 15, 20, 25, 30, 35, 40]
        saved = [float(row["packets saved [%]"]) for row in got]
        err = [float(row["RMS error"]) for row in got]
        assert saved == sorted(saved) and saved[-1] > saved[1] > saved[0]
        assert err[0] == 0.0 and err[-1] > err[1] > 0.0
