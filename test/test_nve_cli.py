"""`haptic-teleop run` and `analyze` on NVE scenes: outputs from the bag, the same seed the same
bag bytes, Ctrl-C mid-loop leaves a closed bag and an interrupted summary, bad keys exit 2."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from haptic_teleop.analysis.nve_summary import PLOT_FILES
from haptic_teleop.interrupt import TEST_PAUSE_ENV
from haptic_teleop.record.reader import BagReader

CLI = [sys.executable, "-m", "haptic_teleop.cli"]


def _run(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=300, env=env, check=False)


def test_run_nve_push_writes_summary_plots_and_bag(tmp_path: Path) -> None:
    out = tmp_path / "push"
    r = _run("run", "nve_push", "--out", str(out), "--set", "scene.duration_s=3", "--quiet")
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["kind"] == "nve" and summary["ticks"] == 3000 and not summary["interrupted"]
    client = summary["clients"]["client"]
    assert client["round_trip_s"]["median"] == pytest.approx(0.301, abs=1e-9)
    assert summary["server_energy"]["passive"]
    for name in PLOT_FILES:
        assert (out / "plots" / name).stat().st_size > 10_000
    with BagReader(out / "bag") as reader:
        assert reader.nve_schema is not None and reader.nve_schema.clients == ("client",)
    # `analyze` recomputes the same summary from the bag alone
    again = tmp_path / "again"
    r2 = _run("analyze", str(out / "bag"), "--out", str(again), "--no-plots", "--quiet")
    assert r2.returncode == 0, r2.stderr
    assert json.loads((again / "summary.json").read_text())["clients"] == summary["clients"]


def test_nve_same_seed_same_bag_other_seed_other_bag(tmp_path: Path) -> None:
    def digest(name: str, seed: int) -> str:
        out = tmp_path / name
        r = _run(
            "run", "nve_two_clients", "--out", str(out), "--seed", str(seed),
            "--set", "scene.duration_s=1.5", "--quiet", "--no-plots",
        )  # fmt: skip
        assert r.returncode == 0, r.stderr
        return hashlib.sha256((out / "bag" / "bag.mcap").read_bytes()).hexdigest()

    a, b, c = digest("a", 1), digest("b", 1), digest("c", 2)
    assert a == b != c


def test_ctrl_c_mid_loop_closes_the_bag(tmp_path: Path) -> None:
    out = tmp_path / "stopped"
    env = {**os.environ, TEST_PAUSE_ENV: "loop"}
    p = subprocess.Popen(
        [*CLI, "run", "nve_push", "--out", str(out), "--set", "scene.duration_s=600", "--quiet", "--no-plots"],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert p.stderr is not None
    line = p.stderr.readline()
    assert "phase loop" in line, line
    p.send_signal(signal.SIGINT)
    assert p.wait(timeout=120) == 130
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] and 0 < summary["ticks"] < 600_000
    with BagReader(out / "bag") as reader:
        assert reader.nve_schema is not None


@pytest.mark.parametrize(
    "setting",
    ["nve.clients.0.coupling.client_stiffness_n_per_m=-1", "nve.axes=2", "master.mass_kg=1"],
)
def test_bad_nve_input_is_one_line_and_exit_2(tmp_path: Path, setting: str) -> None:
    r = _run("run", "nve_push", "--out", str(tmp_path / "x"), "--set", setting)
    assert r.returncode == 2
    lines = [x for x in r.stderr.strip().splitlines() if x]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "x").exists()
