"""`haptic-teleop experiment hli-filtering` (studies/replications/codec.py): seed 000's simulation end to end
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


EC_CLI = [sys.executable, "-m", "haptic_teleop.cli", "experiment", "error-control"]


def test_error_control_runs_and_shows_what_each_error_control_does(tmp_path: Path) -> None:
    """`experiment error-control` on a short run: each row's rate and error ordering follow from what
    its error control does (docs/codec_error_control.md, "Seed 000's experiment")."""
    out = tmp_path / "e"
    r = subprocess.run(
        [*EC_CLI, "--out", str(out), "--duration-s", "6", "--quiet"], capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr
    for name in ("error_control.csv", "error_control.md", "error_control.png"):
        assert (out / name).stat().st_size > 100
    with (out / "error_control.csv").open() as fh:
        rows = {row["scheme"]: {k: float(v) for k, v in row.items() if k != "scheme"} for row in csv.DictReader(fh)}
    none, fec, fec_wait = (
        rows["prediction-based filtering only"],
        rows["+ FEC (k = 2)"],
        rows["+ FEC (k = 2), playing 50 ms later"],
    )
    arq25, arq4 = rows["+ ARQ (mu = 25 ms, nu = 4)"], rows["+ ARQ (mu = 4 ms, nu = 1)"]
    prio = rows["priority-based, 70 kbit/s"]
    rms, peak, rate, acks = "RMS force error [N]", "peak force error [N]", "packets/s", "acks kbit/s (ROS)"
    rms_now = "RMS force error incl. latency [N]"
    # FEC sends the same events (so meets the same losses) with bigger packets; its copies come with
    # the next event, which re-anchors the receiver anyway: without waiting it plays the same
    assert fec[rate] == none[rate] and fec["wire kbit/s (ROS)"] > none["wire kbit/s (ROS)"]
    assert fec[rms] == none[rms] and fec[peak] == none[peak]
    # waiting for the copies: a smaller error against the delayed object, a larger one against the present
    assert fec_wait[rms] < fec[rms] and fec_wait[rms_now] > fec[rms_now]
    assert fec_wait["latency [ms]"] == none["latency [ms]"] + 50
    # ARQ: only it sends ACKs; with 5 ms each way (RTT 10 ms) mu = 4 ms retransmits every event once
    assert none[acks] == fec[acks] == prio[acks] == 0 < arq25[acks]
    assert arq4[rate] == pytest.approx(2 * none[rate], rel=0.01)
    assert none[rate] < arq25[rate] < arq4[rate]
    # retransmissions re-base the receiver: a smaller error than no error control; and priority-based
    # filtering (followers with copies of the event) the smallest RMS of all
    assert arq25[rms] < none[rms] and arq4[rms] < none[rms]
    assert prio[rms] < min(none[rms], arq25[rms], arq4[rms], fec_wait[rms])
    # the table ends with the ranking by peak error (the seed's measure), smallest first
    ranking = (out / "error_control.md").read_text().splitlines()[-1]
    assert ranking.startswith("By peak force error (seed 000's measure)")
    order = sorted(rows, key=lambda k: (rows[k][peak], rows[k][rms]))
    positions = [ranking.index(f"{i}. {name} ") for i, name in enumerate(order, start=1)]
    assert positions == sorted(positions)


@pytest.mark.parametrize("argv", [["--fec-k", "0"], ["--fec-wait-s", "-1"], ["--loss", "2"], ["--fec-k", "x"]])
def test_error_control_bad_arguments_are_one_line_exit_2(tmp_path: Path, argv: list[str]) -> None:
    r = subprocess.run([*EC_CLI, "--out", str(tmp_path / "x"), *argv], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not (tmp_path / "x").exists()
