"""`haptic-teleop experiment deadband-loop` (studies/replications/deadband_loop.py): seed 001's deadband in the
channels of the engine's arm loop, on a short tapping run: what each case codes, the p = 0 runs
against the reference, the reduction against `haptic-teleop run`'s summary.json, and one-line
argument errors."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

CLI = [sys.executable, "-m", "haptic_teleop.cli", "experiment", "deadband-loop"]


def _num(text: str) -> float:
    return float(text) if text != "" else math.nan


@pytest.fixture(scope="module")
def loop_rows(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, float], dict[str, float]]:
    out = tmp_path_factory.mktemp("dbl") / "out"
    r = subprocess.run(
        [*CLI, "--out", str(out), "--duration-s", "2", "--p", "20,0,5", "--jobs", "2", "--quiet"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    assert (out / "deadband_loop.png").stat().st_size > 10_000
    assert "| forward | 5 |" in (out / "deadband_loop.md").read_text()
    # every run (the uncoded one, then each coded direction at each p) is a bag, named in the index
    with (out / "bags" / "index.csv").open() as fh:
        index = [row["bag"] for row in csv.DictReader(fh)]
    assert index[:2] == ["001_uncoded", "002_forward_p0"] and len(index) == 1 + 3 * 3  # p sorted
    assert all((out / "bags" / b / "metadata.yaml").is_file() for b in index)
    with (out / "deadband_loop.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    return {(row["coded"], float(row["p [%]"])): {k: _num(v) for k, v in row.items() if k != "coded"} for row in rows}


def test_each_case_codes_its_directions_and_saves_more_with_p(
    loop_rows: dict[tuple[str, float], dict[str, float]],
) -> None:
    assert sorted(loop_rows) == sorted((c, p) for c in ("forward", "backward", "both") for p in (0.0, 5.0, 20.0))
    for case, coded in (("forward", ("forward",)), ("backward", ("backward",)), ("both", ("forward", "backward"))):
        for d in ("forward", "backward"):
            col = f"{d} saved [%]"
            got = [loop_rows[(case, p)][col] for p in (0.0, 5.0, 20.0)]
            if d in coded:
                # p = 0 sends every sample: the triggers (the handle's velocity forward; the contact
                # force and the tool's velocity backward) change every tick of this run
                assert got[0] == 0.0
                assert 0.0 < got[1] < got[2] < 100.0, (case, d, got)
            else:
                assert all(math.isnan(g) for g in got), (case, d, got)


def test_p0_runs_are_the_reference_run_and_coding_changes_the_loop(
    loop_rows: dict[tuple[str, float], dict[str, float]],
) -> None:
    diffs = [c for c in next(iter(loop_rows.values())) if "diff" in c or (c.startswith("master") and "JND" in c)]
    assert len(diffs) == 8
    for case in ("forward", "backward", "both"):
        zero = loop_rows[(case, 0.0)]
        assert all(zero[c] == 0.0 for c in diffs), (case, zero)
        coded = loop_rows[(case, 20.0)]
        for c in ("master force RMS diff [N]", "tool position RMS diff [mm]", "contact force RMS diff [N]"):
            assert coded[c] > 0.0, (case, c)
        assert coded["master force peak diff [N]"] >= coded["master force RMS diff [N]"]
        # the coded stream's own error (held against sent, in the run): zero at p = 0, growing with p;
        # none for a direction without a codec
        for d, col in (("forward", "coded velocity RMS error [m/s]"), ("backward", "coded force RMS error [N]")):
            got = [loop_rows[(case, p)][col] for p in (0.0, 5.0, 20.0)]
            if case in (d, "both"):
                assert got[0] == 0.0 and 0.0 < got[1] < got[2], (case, col, got)
            else:
                assert all(math.isnan(g) for g in got), (case, col, got)
    # every p = 0 run is the reference: the same peak contact force, the same work of EBA
    for col in ("contact force max [N]", "master EBA-scaled ticks [%]", "master force EBA removed RMS [N]"):
        assert len({loop_rows[(c, 0.0)][col] for c in ("forward", "backward", "both")}) == 1, col
    assert loop_rows[("forward", 0.0)]["contact force max [N]"] > 0.0


def test_run_case_codec_facts_and_reduction_match_run_summary(tmp_path: Path) -> None:
    """The reference run has no codec facts; a coded run's reduction (the encoder's counters) is
    summary.json's codec_packet_reduction of `haptic-teleop run` of the same scene and seed."""
    from haptic_teleop.studies.replications.deadband import TAPPING
    from haptic_teleop.studies.replications.deadband_loop import codec_overrides, run_case, saved

    base = ["scene.duration_s=1", *TAPPING]
    ref = run_case("touch_ur5e_wall", base, 3, str(tmp_path / "ref_bag"))
    assert ref["facts"] == {}
    assert math.isnan(saved(ref["facts"], "forward")) and math.isnan(saved(ref["facts"], "backward"))
    coded = codec_overrides("backward", 0.1)
    run = run_case("touch_ur5e_wall", [*base, *coded], 3, str(tmp_path / "coded_bag"))
    assert set(run["facts"]) == {"codec_backward", "codec_plain_bytes"}
    out = tmp_path / "run"
    sets = [a for s in [*base, *coded] for a in ("--set", s)]
    r = subprocess.run(
        [sys.executable, "-m", "haptic_teleop.cli", "run", "touch_ur5e_wall", "--out", str(out), "--seed", "3",
         "--no-plots", "--quiet", "--loop", "python", *sets],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["codec_kind_backward"] == "deadband" and summary["codec_kind_forward"] == "none"
    assert saved(run["facts"], "backward") == pytest.approx(summary["codec_packet_reduction_backward"], abs=1e-12)
    assert 0.0 < summary["codec_packet_reduction_backward"] < 1.0


@pytest.mark.parametrize(
    "argv",
    [
        ["--p", "5,x"],
        ["--p", "100"],
        ["--p", "5,5"],
        ["--coded", "sideways"],
        ["--reconstruction", "linear"],
        ["--jobs", "0"],
        ["--duration-s", "0.5"],
        ["--scene", "wall_contact"],
        ["--bogus"],
    ],
)
def test_bad_arguments_are_one_line_exit_2(tmp_path: Path, argv: list[str]) -> None:
    r = subprocess.run([*CLI, "--out", str(tmp_path / "x"), *argv], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not (tmp_path / "x").exists()
