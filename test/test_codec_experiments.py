"""`haptic-teleop experiment hli-filtering` (studies/replications/codec.py): seed 000's simulation end to end
on a short run, the ordering its numbers must show, and one-line argument errors."""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from haptic_teleop.core.link import DELIVERED, LOST_LATE, Packet
from haptic_teleop.studies.replications import codec

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


def _args(**kw: object) -> argparse.Namespace:
    """The experiments' defaults (their parsers), a short run."""
    p = argparse.ArgumentParser()
    codec.add_error_control_arguments(p)
    args = p.parse_args(["--duration-s", "3"])
    for k, v in kw.items():
        setattr(args, k.replace("-", "_"), v)
    return args


def _fates(packets: list[Packet]) -> list[tuple[object, ...]]:
    """Each packet as the bag's records keep it: the arrival time only of one that arrived."""
    arrived = (DELIVERED, LOST_LATE)
    return [
        (
            p.seq,
            p.send_time_ns,
            p.payload,
            p.size_bytes,
            p.fate,
            p.duplicate,
            p.arrival_time_ns if p.fate in arrived else None,
        )
        for p in packets
    ]


@pytest.mark.parametrize("scheme", ["arq", "hli"])
def test_a_run_read_back_from_its_bag_is_the_run_and_gives_the_same_table_row(tmp_path: Path, scheme: str) -> None:
    """write_bag then read_bag returns the run as simulated: the server's and the played object
    every tick, every packet of both links with its fate and payload, the latency; so the table's
    row computed from the bag is the in-memory one, bit for bit."""
    from haptic_teleop.core.arq import SEED_000_EXPERIMENT
    from haptic_teleop.studies.replications.codec_bags import read_bag, write_bag

    args = _args()
    if scheme == "arq":
        arq = SEED_000_EXPERIMENT[0]
        made = codec.event_codec(args, "arq", timeout_s=arq.timeout_s, max_retransmissions=arq.max_retransmissions)
    else:
        made = codec.hli(args)
    (pair, extra) = made
    ran = codec.simulate(scheme, pair, args, codec._delay_ticks(args) + extra)
    assert ran.forward and (ran.reverse or scheme == "hli")
    write_bag(tmp_path / "bag", ran, "error-control", {"duration_s": 3.0})
    back, facts = read_bag(tmp_path / "bag")
    assert facts["experiment"] == "error-control" and facts["arguments"] == {"duration_s": 3.0}
    assert back.label == scheme and back.latency_ticks == ran.latency_ticks
    np.testing.assert_array_equal(back.t_s, ran.t_s)
    np.testing.assert_array_equal(back.object_m, ran.object_m)
    np.testing.assert_array_equal(back.played_m, ran.played_m)
    assert _fates(back.forward) == _fates(ran.forward) and _fates(back.reverse) == _fates(ran.reverse)
    assert codec.row(back, present=True) == codec.row(ran, present=True)


def test_the_bags_are_standard_rosbag2_that_an_independent_reader_opens(tmp_path: Path) -> None:
    """rosbags (not this package's reader) opens a scheme's bag: standard message types, one
    /server/object message per tick, /client/object's effort is k times the played penetration,
    and the packet records count what the table says went on the wire."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out = tmp_path / "e"
    r = subprocess.run(
        [*EC_CLI, "--out", str(out), "--duration-s", "3", "--fec-wait-s", "0", "--quiet"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    with (out / "error_control.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    bags = sorted(d for d in (out / "bags").iterdir() if d.is_dir())
    assert [b.name[:4] for b in bags] == [f"{i:03d}_" for i in range(1, len(rows) + 1)]
    with (out / "bags" / "index.csv").open() as fh:
        assert [r["run"] for r in csv.DictReader(fh)] == [r["scheme"] for r in rows]
    arq = next(b for b in bags if "arq_mu_25" in b.name)
    row = next(x for x in rows if x["scheme"].startswith("+ ARQ (mu = 25"))
    counts: dict[str, int] = {}
    with AnyReader([arq], default_typestore=get_typestore(Stores.LATEST)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert set(types.values()) <= {
            "sensor_msgs/msg/JointState", "std_msgs/msg/String", "std_msgs/msg/Float64MultiArray"
        }  # fmt: skip
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + (
                len(msg.data) // 6 if conn.topic.endswith("/packets") else 1
            )
            if conn.topic == "/client/object":
                assert msg.effort[0] == pytest.approx(100.0 * max(0.0, -msg.position[0]), abs=1e-12)
    assert counts["/server/object"] == 3000
    assert counts["/forward/packets"] == counts["/forward/sent"] == round(float(row["packets/s"]) * 3)
    assert counts["/backward/packets"] == counts["/backward/sent"] > 0
