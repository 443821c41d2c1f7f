"""`haptic-teleop experiment all` (studies/replications/all_experiments.py, docs/experiments_all.md):
the shipped-CSV comparison, a short run of two real jobs with their manifest and figures, and a
documented number that moved failing the command."""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest

from haptic_teleop.studies.replications import all_experiments as ae

CLI = [sys.executable, "-m", "haptic_teleop.cli", "experiment", "all"]


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_the_shipped_comparison_names_every_cell_that_moved(tmp_path: Path) -> None:
    shipped = _write(tmp_path / "doc.csv", "name,x,y\na,1.0,2.0\nb,3.0,text\n")
    same = _write(tmp_path / "same.csv", "name,x,y\na,1.0000000000001,2.0\nb,3.0,text\n")
    assert ae.compare_shipped(same, shipped, 1e-9) == []
    moved = _write(tmp_path / "moved.csv", "name,x,y\na,1.001,2.0\nb,3.0,other\n")
    diffs = ae.compare_shipped(moved, shipped, 1e-9)
    assert len(diffs) == 2 and "row 1 x" in diffs[0] and "row 2 y" in diffs[1]
    short = _write(tmp_path / "short.csv", "name,x,y\na,1.0,2.0\n")
    assert "1 fresh rows" in ae.compare_shipped(short, shipped, 1e-9)[0]


def test_two_jobs_run_write_their_manifest_and_figures_and_every_documented_number_holds(tmp_path: Path) -> None:
    out, docs = tmp_path / "all", tmp_path / "docs"
    docs.mkdir()
    r = subprocess.run(
        [*CLI, "--only", "hli-filtering,error-control", "--out", str(out), "--docs", str(docs)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert set(manifest["jobs"]) == {"hli-filtering", "error-control"}
    for job in manifest["jobs"].values():
        assert job["exit_code"] == 0 and job["seconds"] > 0 and job["command"].startswith("haptic-teleop experiment")
        assert job["command"].endswith("--discard-bags")  # each experiment measured its bags, then deleted them
    assert not (out / "hli-filtering" / "bags").exists() and (out / "hli-filtering" / "hli_filtering.csv").is_file()
    assert manifest["version"]
    for name in ("codec_hli_filtering.png", "codec_error_control.png"):
        assert (out / "figures" / name).stat().st_size > 10_000
        assert (docs / name).read_bytes() == (out / "figures" / name).read_bytes()
    table = (out / "all.md").read_text()
    n_checks = sum(len(j.checks) for j in ae.JOBS if j.folder in ("hli-filtering", "error-control"))
    assert table.count("| yes |") == n_checks and "| NO |" not in table
    assert f"{n_checks} of {n_checks} checks held" in r.stdout


def test_a_documented_number_that_moved_fails_the_command_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    job = next(j for j in ae.JOBS if j.folder == "error-control")
    wrong = dataclasses.replace(job.checks[0], documented=0.5)  # the page would say 0.5 N
    monkeypatch.setattr(ae, "JOBS", (dataclasses.replace(job, checks=(wrong,)),))
    args = argparse.Namespace(out=str(tmp_path / "o"), only=None, list=False, docs=None, quiet=True, keep_bags=False)
    assert ae.main(args) == 1
    err = capsys.readouterr().err
    assert "error-control: codec_error_control.md says RMS force error [N] = 0.5" in err
    assert "| NO |" in (tmp_path / "o" / "all.md").read_text()


BAD = [
    (["--only", "nothing"], "--only nothing: allowed"),
    (["--docs", "/no/such/dir"], "--docs /no/such/dir: not a directory"),
]


@pytest.mark.parametrize(("argv", "words"), BAD)
def test_bad_arguments_exit_2_in_one_line(tmp_path: Path, argv: list[str], words: str) -> None:
    r = subprocess.run([*CLI, *argv, "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and words in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "o").exists()
