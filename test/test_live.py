"""Live mode: real processes over real DDS on localhost, as launch_testing would run them.

Each test starts `haptic-teleop launch` (every node its own process), watches the topics from
this process with an independent rclpy subscriber, and checks exit codes and the recorded bag.
DDS stays on this host (conftest: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, own ROS_DOMAIN_ID).
"""

from __future__ import annotations

import itertools
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from launched import Launch

from haptic_teleop.nodes import WATCHDOG_FADE_S, WATCHDOG_TIMEOUT_S

rclpy = pytest.importorskip("rclpy")

CLI = [sys.executable, "-m", "haptic_teleop.cli"]
PERIOD_S = 0.001
DELAY_S = 0.05  # wall_contact: one-way delay each way


class Watcher:
    """An independent subscriber in the test process: arrival time, stamp and one value of each
    sample on the master and slave topics.

    Raw subscriptions with a deep reader history, taken by a polling thread and decoded later: a
    Python executor callback per message falls behind 3 kHz on a loaded 2-core machine, and then
    the test would measure itself rather than the nodes."""

    TOPICS: ClassVar[dict[str, str]] = {
        "/master/joint_states": "effort",
        "/slave/joint_states": "position",
        "/backward/received": "effort",
    }

    def __init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState

        from haptic_teleop.nodes.messages import _polled_group_class
        from haptic_teleop.nodes.topics import DIAGNOSTICS, reliable_qos, stream_qos

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("test_watcher", context=self.context)
        group = _polled_group_class()()
        self.subs = {
            t: self.node.create_subscription(JointState, t, lambda m: None, stream_qos(1000), callback_group=group,
                                             raw=True)
            for t in self.TOPICS
        }  # fmt: skip
        self.subs[DIAGNOSTICS] = self.node.create_subscription(
            DiagnosticArray, DIAGNOSTICS, lambda m: None, reliable_qos(1000), callback_group=group, raw=True
        )
        from std_msgs.msg import Float64MultiArray

        from haptic_teleop.nodes.topics import playout_topic

        for d in ("forward", "backward"):  # the sync buffers' decisions, as the recorder takes them
            self.subs[playout_topic(d)] = self.node.create_subscription(
                Float64MultiArray, playout_topic(d), lambda m: None, reliable_qos(1000), callback_group=group, raw=True
            )
        self.lock = threading.Lock()
        self.raw: dict[str, list[tuple[int, bytes]]] = {t: [] for t in self.subs}
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._poll, daemon=True)
        self.thread.start()

    def _poll(self) -> None:
        from haptic_teleop.nodes.messages import take_all

        while not self._stop.is_set():
            for topic, sub in self.subs.items():
                got = take_all(sub)
                if got:
                    now = time.time_ns()
                    with self.lock:
                        self.raw[topic].extend((now, r) for r in got)
            time.sleep(0.002)

    def reset(self) -> None:
        with self.lock:
            for rows in self.raw.values():
                rows.clear()

    def array(self, topic: str, last: int | None = None) -> np.ndarray:
        """Rows (arrival ns, stamp ns, value), of the `last` samples only if given."""
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import JointState

        with self.lock:
            items = list(self.raw[topic][-last:] if last else self.raw[topic])
        field = self.TOPICS[topic]
        rows = []
        for arrival, r in items:
            m = deserialize_message(r, JointState)
            v = getattr(m, field)
            rows.append((arrival, m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec,
                         float(v[0]) if len(v) else float("nan")))  # fmt: skip
        return np.array(rows, dtype=np.float64).reshape(-1, 3)

    def samples(self, topic: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arrival ns, stamp ns (int64: exact, unlike `array`'s float64) and value of every sample
        seen on `topic`, in arrival order."""
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import JointState

        with self.lock:
            items = list(self.raw[topic])
        field = self.TOPICS[topic]
        arrival, stamp, value = [], [], []
        for t, r in items:
            m = deserialize_message(r, JointState)
            v = getattr(m, field)
            arrival.append(t)
            stamp.append(m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec)
            value.append(float(v[0]) if len(v) else float("nan"))
        return np.array(arrival, dtype=np.int64), np.array(stamp, dtype=np.int64), np.array(value)

    def late_scene(self, timeout_s: float) -> str | None:
        """Subscribe to /haptic_teleop/scene now, as a late joiner would (transient local, the
        durability a latched topic is read with), and return the scene received, or None."""
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String

        from haptic_teleop.nodes.messages import take_all
        from haptic_teleop.nodes.topics import SCENE_TOPIC

        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        sub = self.node.create_subscription(String, SCENE_TOPIC, lambda m: None, qos,
                                            callback_group=_polled_group(self))  # fmt: skip
        try:
            end = time.monotonic() + timeout_s
            while time.monotonic() < end:
                got = take_all(sub)
                if got:
                    return str(got[-1].data)
                time.sleep(0.05)
            return None
        finally:
            self.node.destroy_subscription(sub)

    def diagnostics(self) -> dict[str, list[dict[str, str]]]:
        """The loop reports received on /diagnostics, per node (hardware_id), in arrival order."""
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.serialization import deserialize_message

        from haptic_teleop.nodes.topics import DIAGNOSTICS

        with self.lock:
            items = list(self.raw[DIAGNOSTICS])
        out: dict[str, list[dict[str, str]]] = {}
        for _, r in items:
            for st in deserialize_message(r, DiagnosticArray).status:
                out.setdefault(st.hardware_id, []).append({kv.key: kv.value for kv in st.values})
        return out

    def late_decisions(self, direction: str) -> set[int]:
        """The seqs the direction's sync buffer decided late (fate 4) on its playout topic (the last
        batch, sent as the node closes, may not reach this subscriber)."""
        from rclpy.serialization import deserialize_message
        from std_msgs.msg import Float64MultiArray

        from haptic_teleop.nodes.topics import playout_topic

        with self.lock:
            items = list(self.raw[playout_topic(direction)])
        late: set[int] = set()
        for _, r in items:
            m = deserialize_message(r, Float64MultiArray)
            labels = m.layout.dim[1].label.split(",")
            rows = np.asarray(m.data, dtype=np.float64).reshape(-1, len(labels))
            seq, fate = rows[:, labels.index("seq")], rows[:, labels.index("fate")]
            late.update(int(q) for q in seq[(seq >= 0) & (fate == 4.0)])
        return late

    def close(self) -> None:
        self._stop.set()
        self.thread.join(2.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _polled_group(w: Watcher):
    from haptic_teleop.nodes.messages import _polled_group_class

    return _polled_group_class()()


@pytest.fixture(scope="module")
def watcher():
    w = Watcher()
    yield w
    w.close()


@pytest.fixture(scope="module")
def default_run(tmp_path_factory, watcher):
    """The default scene, live for 5 s of scene time, recorded. Shared by the checks below.

    Composed in one process (`--single-process`, one shared loop thread): with one process per
    node the set needs about 1.8 of this VM's 2 vCPUs and the loops reach 81 to 92 % of 1 kHz
    (docs/live_measured.md, "CPU per node"); composed it needs 0.75 and keeps its rate. The tests below
    with signals and a killed slave run one process per node."""
    out = tmp_path_factory.mktemp("live") / "run"
    temp = tmp_path_factory.mktemp("tmpdir")  # the launcher's temporary folders go here
    watcher.reset()
    launch = Launch("wall_contact", "--duration", "5", "--record", str(out), "--no-plots", "--single-process",
                    cwd=out.parent, env={"TMPDIR": str(temp)})  # fmt: skip
    stamp0 = int(launch.wait_for(r"scene time 0 at stamp (\d+) ns", 60).group(1))
    scene_yaml = watcher.late_scene(30)  # subscribed after the recorder published it
    code = launch.finish(120)
    t0, t1 = stamp0, stamp0 + 5_000_000_000  # the scene's 5 s, on the nodes' clock (stamps)
    return {
        "code": code,
        "launch": launch,
        "out": out,
        "window_ns": (t0, t1),
        "master": watcher.array("/master/joint_states"),
        "slave": watcher.array("/slave/joint_states"),
        "samples": {side: watcher.samples(f"/{side}/joint_states") for side in ("master", "slave")},
        "diagnostics": watcher.diagnostics(),
        "late_decisions": {d: watcher.late_decisions(d) for d in ("forward", "backward")},
        "scene_yaml": scene_yaml,
        "temp": temp,
    }


def test_default_scene_runs_live_and_ends_cleanly(default_run):
    launch = default_run["launch"]
    assert default_run["code"] == 0, launch.failure
    assert "scene duration reached (5000 ticks)" in launch.text
    assert not list(default_run["temp"].glob("haptic_teleop_params_*"))  # its parameter files removed
    assert "bag written" in launch.text
    assert "Traceback" not in launch.text
    assert "[launcher] started" not in launch.text  # composed: no child process per node


def test_default_scenes_live_reservoirs_are_what_the_sides_booked_row_by_row(default_run):
    """Each row of each side's reservoir in the live bag of the default scene is the row before
    booked over the bag's own motion and applied force (analysis/ledgers.py, `reservoir_residuals`,
    with one joint `reservoir1`'s bits): the bag holds each side's reservoir at each tick. With the
    recorder placing the unstamped EBA arrays by write time (before 2026-12-03) a late tick moved
    them by rows, and an arm bag failed this (2.1e-4 J)."""
    from haptic_teleop.analysis.ledgers import read_signals, reservoir_residuals
    from haptic_teleop.assembly.parts import side_controller
    from haptic_teleop.scene.load import find_scene, load_scene

    assert default_run["code"] == 0, default_run["launch"].failure
    config = load_scene(find_scene("wall_contact")).config
    sides = ("master", "slave")
    gains = {s: np.asarray(side_controller(config, s, None).bound.params.reservoir_gains()) for s in sides}
    signals = read_signals(default_run["out"] / "bag")
    for side, r in reservoir_residuals(signals, gains).items():
        assert r.size > 4000 and np.max(np.abs(r)) <= 1e-12, (side, np.max(np.abs(r)), np.argmax(np.abs(r)))
    assert np.ptp(signals["master"][2]) > 1e-3  # the master's reservoir moves


@pytest.mark.parametrize("side", ["master", "slave"])
def test_independent_subscriber_sees_grid_stamps_in_order_and_the_bag_holds_them(default_run, side):
    """What load cannot change (no rate is asserted: `bench live` measures rates). This test's own
    subscriber sees the master and slave streams with stamps on the 1 ms grid, distinct and in
    order; the bag holds every value it saw at the same stamp, except the samples the recorder
    itself missed and filled (counted in live_run.json)."""
    from haptic_teleop.record.reader import BagReader

    topic = f"/{side}/joint_states"
    _, stamps, values = default_run["samples"][side]
    assert stamps.size > 0, f"{side}: nothing seen"
    assert np.all(stamps % round(PERIOD_S * 1e9) == 0), "stamps off the tick grid"
    assert np.all(np.diff(stamps) > 0), "stamps repeated or out of order"
    out = default_run["out"]
    info = json.loads((out / "live_run.json").read_text())
    with BagReader(out / "bag") as r:
        data = r.read(topic)
    field = Watcher.TOPICS[topic]
    bag_stamps = np.asarray(data.stamp_ns, dtype=np.int64) + int(info["start_stamp_ns"])
    assert np.all(np.diff(bag_stamps) == round(PERIOD_S * 1e9)), "the bag's grid has a gap or a repeat"
    seen = {int(s): float(v) for s, v in zip(stamps.tolist(), values.tolist(), strict=True)}
    bag_values = data.field(field)
    common = [(seen[int(s)], float(v)) for s, v in zip(bag_stamps.tolist(), bag_values.tolist(), strict=True)
              if int(s) in seen]  # fmt: skip
    assert len(common) > 0.5 * len(seen), (len(common), len(seen))  # the bag covers the run the watcher saw
    differ = sum(1 for a, b in common if a != b)
    assert differ <= int(info["samples_filled"][topic]), (differ, info["samples_filled"][topic])


def test_every_loop_reports_its_figures_on_diagnostics(default_run):
    """Each node's loop publishes its report about once a second (from the loop thread); the
    cumulative counters are consistent: every tick counted is in the lateness histogram, and two
    reports give the figures between them (what `bench live` uses)."""
    from haptic_teleop.studies.benchmarks.live import window_figures

    reports = default_run["diagnostics"]
    nodes = ("operator_source", "master_eba", "slave_eba", "forward_relay", "backward_relay",
             "forward_buffer", "backward_buffer", "recorder")  # fmt: skip
    for name in nodes:
        got = reports.get(name, [])
        assert len(got) >= 3, (name, len(got))
        for r in got:
            assert sum(int(v) for v in r["lateness_hist"].split()) == int(r["ticks"]), (name, r)
            assert int(r["late_ticks"]) <= int(r["ticks"])
            assert int(r["max_catch_up_periods"]) == 10
        ticks = [int(r["ticks"]) for r in got]
        assert ticks == sorted(ticks) and ticks[-1] > ticks[0]
        f = window_figures([(float(i), r) for i, r in enumerate(got)], 0.0, float(len(got)))
        assert f is not None and f["ticks"] == ticks[-1] - ticks[0] and f["loop_rate_hz"] > 0


def test_scene_topic_is_latched_for_a_late_subscriber(default_run):
    """/haptic_teleop/scene is published once, transient local: this test subscribes after scene
    time 0 and still gets the resolved scene."""
    import yaml

    text = default_run["scene_yaml"]
    assert text is not None, "a late subscriber got no scene"
    scene = yaml.safe_load(text)
    assert scene["scene"]["name"] == "wall_contact" and scene["scene"]["duration_s"] == 5.0


def test_buffer_skips_count_as_late_packets_as_the_engine_counts_them(default_run):
    """The engine marks a packet its playout buffer skipped with fate 4 (late) in the packet
    records, which packets_late_* and late_loss_* count. Live, the sync buffers report their
    decisions and the recorder applies them: every packet of the recorded window that this
    test's own subscriber saw the buffer decide late is late in the bag (the bag may hold more:
    the batch a buffer sends as it closes may not reach that subscriber, and a late packet is
    decided after newer ones), never more than the buffer skipped, one record per late packet,
    each one that arrived.
    (Lateness here is this machine's, so there may be none; test_live_engine's jitter case makes
    late packets by reordering and compares them with the engine's, record by record.)"""
    from haptic_teleop.record.reader import BagReader

    out, text = default_run["out"], default_run["launch"].text
    summary = json.loads((out / "summary.json").read_text())
    with BagReader(out / "bag") as r:
        packets = {d: r.packets(f"/{d}/packets") for d in ("forward", "backward")}
    for d in ("forward", "backward"):
        m = re.search(rf"{d}_buffer .* (\d+) released, (\d+) late", text)
        assert m, text[-3000:]
        buffer_late = int(m.group(2))
        bag_late = summary[f"packets_late_{d}"]
        assert bag_late == summary[f"late_loss_{d}"]
        assert bag_late <= buffer_late, (d, bag_late, buffer_late)
        rows = packets[d]
        late = rows[rows[:, 3] == 4.0]
        seen = default_run["late_decisions"][d]
        decided = seen & {int(q) for q in rows[:, 0]}
        in_bag = {int(q) for q in late[:, 0]}
        assert decided <= in_bag, (d, sorted(decided - in_bag)[:10], late.shape[0])
        assert late.shape[0] == bag_late
        assert np.all(np.isfinite(late[:, 2])), "a late packet without an arrival time"
        assert np.unique(late[:, 0]).size == late.shape[0], "a packet counted late twice"


def test_every_played_packet_is_in_the_bag_at_the_tick_its_buffer_took_it(default_run):
    """The bag is what happened (docs/live_network.md, "Deliveries on the stamp grid"): with playout
    `none` a buffer plays a packet at the tick it takes it, and the bag's release column and packet
    records come from the same buffer rows, so every packet recorded as played is released in the
    bag at the tick its record says it arrived (as delivered: a packet taken late carries the tick
    it was taken), no release is missing or overwritten, and the records moved that way are the
    ones counted as late by scheduling. Before, the recorder filed releases under the millisecond
    their message was written in and lost 1.5 to 6.8 % of them; the records kept the network's time."""
    from haptic_teleop.record.reader import BagReader

    out = default_run["out"]
    info = json.loads((out / "live_run.json").read_text())
    p_ns = 1_000_000
    with BagReader(out / "bag") as r:
        t0 = r.read("/master/joint_states").log_ns[0]
        n = r.read("/master/joint_states").log_ns.size
        for d in ("forward", "backward"):
            rx = r.read(f"/{d}/received")
            released = dict(
                zip(((rx.log_ns - t0) // p_ns).tolist(), ((rx.stamp_ns - t0) // p_ns).tolist(), strict=True)
            )
            pk = r.packets(f"/{d}/packets")
            played = pk[pk[:, 3] == 0]
            due = -(-np.round(played[:, 2] * 1e9).astype(np.int64) // p_ns)  # the tick it was taken at
            inside = due < n
            assert np.count_nonzero(inside) > 1000, d
            got = [released.get(t) for t in due[inside].tolist()]
            assert got == played[inside, 0].astype(np.int64).tolist(), d
            assert len(released) == np.count_nonzero(inside), d  # and nothing else released
            moved = np.count_nonzero(~np.isclose(pk[:, 2] - pk[:, 1], 0.05, rtol=0, atol=1e-9) & (pk[:, 3] != 1))
            assert moved == info["packets_late_by_scheduling"][d], d


def test_contact_force_reaches_the_master(default_run):
    """The operator pushes into the wall: the master renders a force against the push (negative)."""
    effort = default_run["master"][:, 2]
    assert effort.size and np.nanmin(effort) < -1.0, f"master force min {np.nanmin(effort):.3f} N"


def test_live_bag_is_readable_and_analyze_works(default_run):
    out = default_run["out"]
    bag = out / "bag"
    assert (bag / "metadata.yaml").is_file()
    # The QoS the topics were published with, as rosbag2 records it.
    import yaml

    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    qos = {
        t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
        for t in meta["topics_with_message_count"]
    }
    assert qos["/slave/joint_states"][0]["reliability"] == "best_effort"
    assert qos["/forward/packets"][0]["reliability"] == "reliable"
    assert qos["/haptic_teleop/scene"][0]["durability"] == "transient_local"
    r = subprocess.run([*CLI, "analyze", str(bag), "--out", str(out / "again"), "--no-plots"],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "again" / "summary.json").read_text())
    assert summary["ticks"] >= 0.95 * 5000
    assert summary["contact_force_max_n"] > 1.0
    assert summary["all_finite"] is True
    assert summary["master_energy_margin_min_j"] >= -1e-9
    assert summary["slave_energy_margin_min_j"] >= -1e-9


def test_cross_mode_live_and_engine_agree_on_force_tracking(default_run, tmp_path):
    """The same scene in the deterministic engine and live: force-tracking metrics within the
    tolerance documented in docs/live_measured.md (live timing is not lockstep: samples can be taken one
    tick apart and the operator's hand reaches the master over DDS)."""
    from haptic_teleop.analysis.metrics import analyze_bag
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.scene.load import find_scene, load_scene

    live = json.loads((default_run["out"] / "summary.json").read_text())
    scene = load_scene(find_scene("wall_contact"), overrides=["scene.duration_s=5"])
    record_run(scene, tmp_path / "bag", handle_sigint=False)
    sim, _ = analyze_bag(tmp_path / "bag")
    tol = CROSS_MODE_TOLERANCE
    assert (
        abs(live["contact_force_max_n"] - sim["contact_force_max_n"])
        <= tol["contact_force_max_n"] * sim["contact_force_max_n"]
    ), (live["contact_force_max_n"], sim["contact_force_max_n"])
    assert abs(live["force_rms_error_n"] - sim["force_rms_error_n"]) <= tol["force_rms_error_n"], (
        live["force_rms_error_n"],
        sim["force_rms_error_n"],
    )


# Documented in docs/live_measured.md: relative tolerance on the peak wall force, absolute (N) on
# the aligned RMS force error.
CROSS_MODE_TOLERANCE = {"contact_force_max_n": 0.10, "force_rms_error_n": 0.25}


@pytest.mark.parametrize(
    ("sig", "composed"),
    [(signal.SIGINT, False), (signal.SIGTERM, False), (signal.SIGTERM, True)],
    ids=["SIGINT", "SIGTERM", "SIGTERM-composed"],
)
def test_signal_stops_every_process_cleanly_and_the_launch_exits_128_plus_signal(tmp_path, watcher, sig, composed):
    out = tmp_path / "run"
    launch = Launch("wall_contact", "--duration", "60", "--record", str(out), "--no-plots",
                    *(["--single-process"] if composed else []), cwd=tmp_path)  # fmt: skip
    stamp0 = int(launch.wait_for(r"scene time 0 at stamp (\d+) ns", 60).group(1))
    seen = _wait_for_stamp(watcher, "/slave/joint_states", stamp0 + 2_000_000_000, 60)
    launch.proc.send_signal(sig)
    code = launch.finish(120)
    assert code == 128 + sig, launch.failure  # 130 (SIGINT), 143 (SIGTERM)
    if not composed:
        codes = launch.exit_codes()
        expected = {"operator_source", "master_eba", "slave_eba", "forward_relay", "backward_relay",
                    "forward_buffer", "backward_buffer", "recorder"}  # fmt: skip
        assert set(codes) == expected and all(c == 0 for c in codes.values()), codes
    assert "Traceback" not in launch.text
    from haptic_teleop.analysis.metrics import analyze_bag

    summary, _ = analyze_bag(out / "bag")
    assert summary["interrupted"] is True  # stopped before the scene's 60 s
    info = json.loads((out / "live_run.json").read_text())
    assert info["ticks"] == summary["ticks"]
    # Everything this test saw published before the signal is in the bag: its ticks reach past it.
    assert info["start_stamp_ns"] + summary["ticks"] * round(PERIOD_S * 1e9) > seen
    assert json.loads((out / "summary.json").read_text())["ticks"] == summary["ticks"]  # the summary was written
    assert "loops (whole run):" in launch.text


def _wait_for_stamp(watcher: Watcher, topic: str, stamp_ns: int, timeout_s: float) -> int:
    """Wait until this test's subscriber has seen a sample stamped at or after `stamp_ns` (the
    run has got that far); returns the newest stamp seen."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        rows = watcher.array(topic, last=50)
        if rows.size and rows[:, 1].max() >= stamp_ns:
            return int(rows[:, 1].max())
        time.sleep(0.05)
    raise AssertionError(f"no sample on {topic} stamped at or after {stamp_ns} within {timeout_s} s")


def test_killing_the_slave_fades_the_master_force_and_fails_the_launch(tmp_path, watcher):
    """SIGKILL the slave while in contact: the master's rendered force reaches zero within the
    watchdog bound after the last backward sample arrives, and the launcher exits non-zero."""
    watcher.reset()
    launch = Launch("wall_contact", "--duration", "60", cwd=tmp_path)
    slave_pid = launch.pid_of("slave_eba")
    launch.wait_for(r"scene time 0 at stamp", 60)
    # Wait for contact: the master renders more than 1 N.
    end = time.monotonic() + 30
    while time.monotonic() < end:
        m = watcher.array("/master/joint_states", last=200)
        if m.size and np.nanmin(m[:, 2]) < -1.0:
            break
        time.sleep(0.1)
    else:
        raise AssertionError("no contact force at the master within 30 s")
    os.kill(slave_pid, signal.SIGKILL)
    code = launch.finish(60)
    assert code != 0
    assert launch.exit_codes()["slave_eba"] == -signal.SIGKILL
    assert "slave_eba exited with code" in launch.text

    master = watcher.array("/master/joint_states")
    received = watcher.array("/backward/received")
    last_arrival_ns = received[:, 0].max()  # the last backward sample anyone saw released
    bound_ns = (WATCHDOG_TIMEOUT_S + WATCHDOG_FADE_S + PERIOD_S) * 1e9
    slack_ns = 0.05e9  # the master takes a sample at its next tick; this process sees it some time apart
    after = master[master[:, 1] >= last_arrival_ns + bound_ns + slack_ns]
    assert after.shape[0] > 10, "the master stopped publishing before the watchdog bound passed"
    assert np.all(np.abs(after[:, 2]) < 1e-9), f"force after the bound: {np.abs(after[:, 2]).max():.3g} N"
    before = master[(master[:, 1] < last_arrival_ns) & (master[:, 1] > last_arrival_ns - 0.2e9)]
    assert np.nanmax(np.abs(before[:, 2])) > 1.0  # it was rendering contact until then


def test_a_node_dying_in_native_code_prints_its_stack_and_the_launcher_says_what_to_check(tmp_path):
    """SIGSEGV to one node (what a crash inside Fast DDS or MuJoCo delivers): the node's log holds
    its Python stack (the launcher runs nodes with the fault handler on), the launcher names the
    crash, adds the hint for stale shared-memory segments and exits 1; the others exit 0."""
    launch = Launch("wall_contact", "--duration", "60", cwd=tmp_path)
    pid = launch.pid_of("forward_relay")
    launch.wait_for(r"scene time 0 at stamp", 60)
    os.kill(pid, signal.SIGSEGV)
    assert launch.finish(60) == 1, launch.failure
    codes = launch.exit_codes()
    assert codes.pop("forward_relay") == -signal.SIGSEGV, launch.failure
    assert all(c == 0 for c in codes.values()), (codes, launch.text[-6000:])
    relay_lines = [line for line in launch.lines if line.startswith("[forward_relay] ")]
    assert any("Fatal Python error: Segmentation fault" in line for line in relay_lines), launch.failure
    assert any("most recent call first" in line for line in relay_lines)
    assert "Native crashes at start" in launch.text


def _recorder_story(out: Path, launch: Launch, rows: int, seen_ns: int) -> str:
    """What a short bag's recorder said about itself: its counts and the launcher's loop table."""
    facts = json.loads((out / "live_run.json").read_text()) if (out / "live_run.json").is_file() else {}
    keys = ("ticks", "samples_filled", "samples_after_written", "messages_received")
    told = {k: facts.get(k) for k in keys}
    return f"{rows} rows, {seen_ns * 1e-9:.3f} s seen before the kill; {told}\n{launch.text[-3000:]}"


def _read_killed_bag(bag: Path) -> np.ndarray:
    """The tick stamps (ns from scene time 0) of /operator/joint_states in a bag whose recorder was
    killed, rebuilt with `haptic-teleop bag recover`."""
    r = subprocess.run([*CLI, "bag", "recover", str(bag)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag) as reader:
        return np.asarray(reader.read("/operator/joint_states").stamp_ns, dtype=np.int64)


@pytest.mark.parametrize(
    ("victim", "period_s"),
    [("recorder", 0.001), ("recorder", 0.01), ("master_eba", 0.001), ("forward_relay", 0.001),
     ("backward_buffer", 0.001)],
)  # fmt: skip
def test_sigkill_of_one_process_leaves_a_readable_bag_and_the_others_exit_cleanly(tmp_path, watcher, victim, period_s):
    """SIGKILL one process of a recorded launch 2.5 s (of stamps) into the scene: the others are
    stopped and exit 0, the launcher exits 1; the bag is complete (another node killed: the
    recorder closes it) or recoverable (the recorder killed: what it had flushed, at least the
    ticks up to 1.5 s before the kill), and holds a prefix of the scene's ticks, each stamp once,
    in order. At 100 Hz the data of 2.5 s fill no 1 MiB chunk: only the recorder's flushes (at
    least every 0.5 s) put them on disk."""
    out = tmp_path / "run"
    launch = Launch("wall_contact", "--duration", "60", "--record", str(out), "--no-plots",
                    "--set", f"scene.period_s={period_s}", cwd=tmp_path)  # fmt: skip
    pid = launch.pid_of(victim)
    stamp0 = int(launch.wait_for(r"scene time 0 at stamp (\d+) ns", 60).group(1))
    seen = _wait_for_stamp(watcher, "/slave/joint_states", stamp0 + 2_500_000_000, 60)
    os.kill(pid, signal.SIGKILL)
    code = launch.finish(120)
    assert code == 1, launch.failure
    codes = launch.exit_codes()
    assert codes.pop(victim) == -signal.SIGKILL
    # a str message: pytest shows it whole (a tuple's repr is cut to a line, hiding the stack a
    # node that missed the stop bound prints as it is aborted)
    assert codes and all(c == 0 for c in codes.values()), f"exit codes {dict(codes)}\n{launch.text[-12000:]}"
    bag = out / "bag"
    period = round(period_s * 1e9)
    if victim == "recorder":
        assert not (bag / "metadata.yaml").exists()  # the kill left it unfinished
        assert f"haptic-teleop bag recover {bag}" in launch.text  # the launcher says how to rebuild it
        stamps = _read_killed_bag(bag)
        # Flushed at least once a second: the ticks up to a second before the kill are there.
        assert stamps.size * period >= seen - stamp0 - 1_500_000_000, (stamps.size, (seen - stamp0) * 1e-9)
    else:
        from haptic_teleop.record.reader import BagReader

        assert (bag / "metadata.yaml").is_file()
        with BagReader(bag) as reader:
            stamps = np.asarray(reader.read("/operator/joint_states").stamp_ns, dtype=np.int64)
        assert json.loads((out / "summary.json").read_text())["ticks"] == stamps.size  # summary written
        # It ran past what this test saw before the kill.
        assert stamps.size * period >= seen - stamp0, _recorder_story(out, launch, stamps.size, seen - stamp0)
    assert np.array_equal(stamps, np.arange(stamps.size, dtype=np.int64) * period), "not a prefix of the ticks"
    assert "Traceback" not in launch.text


def test_bad_parameter_stops_the_node_and_names_it(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "haptic_teleop.nodes.master_eba", "--ros-args",
         "-p", "controllers.master.stiffness_n_per_m:=-5.0"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    assert "controllers.master.stiffness_n_per_m" in r.stderr
    r = subprocess.run(
        [sys.executable, "-m", "haptic_teleop.nodes.sync_buffer", "--ros-args", "-p", "no_such.key:=1.0"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert r.returncode == 2
    assert "no_such.key" in r.stderr and "unknown parameter" in r.stderr
    r = subprocess.run(
        [sys.executable, "-m", "haptic_teleop.nodes.sync_buffer", "--ros-args", "-p", "loop.max_catch_up_periods:=-1"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    assert "loop.max_catch_up_periods" in r.stderr


def test_simulated_time_follows_clock(tmp_path):
    """--sim-time-rate 0.5: a clock_source publishes /clock at half real time and every node
    follows it; the bag holds the scene on the simulated grid."""
    out = tmp_path / "run"
    launch = Launch("wall_contact", "--duration", "2", "--record", str(out), "--no-plots",
                    "--sim-time-rate", "0.5", cwd=tmp_path)  # fmt: skip
    launch.finish(180)
    codes = launch.exit_codes()
    # Known open bug (docs/live_launch.md, "Simulated time"): once in a clean-clone CI run, slave_eba
    # started late, fell behind /clock, and did not stop within 10 s of SIGINT, so the launcher
    # killed it and exited 1; not reproduced in the runs since. Until it is found, this test holds
    # what it is about, the time base, and that the clock and the recorder end cleanly.
    assert codes.get("clock_source") == 0 and codes.get("recorder") == 0, launch.failure
    from haptic_teleop.analysis.metrics import analyze_bag

    summary, _ = analyze_bag(out / "bag")
    # Nodes that fall behind /clock catch up rather than skip ticks, but the run ends when the
    # operator's 2 simulated seconds are over: a node still behind then leaves the bag short (seen
    # from 89 to 1982 ticks here, docs/live_launch.md "Simulated time"). What must hold is the time base.
    assert summary["ticks"] >= 2
    assert summary["all_finite"] is True
    info = json.loads((out / "live_run.json").read_text())
    # Scene time starts at the operator's first simulated tick: a small number of simulated
    # seconds after the clock started at 1 s, not the wall clock's ~1.8e9 s since 1970.
    assert 1.0 <= info["start_stamp_ns"] * 1e-9 < 120.0


def test_blackout_window_is_in_scene_time_and_drops_exactly_the_packets_sent_inside_it(tmp_path):
    """The relays run their links in scene time (0 at the operator's scene start), as the engine
    does: a blackout window of scene time loses every packet sent inside it and no other. Before,
    the links ran on the node clock (~1.8e9 s since 1970), so a window of [0.3, 0.5) s never
    opened and every packet was delivered."""
    from haptic_teleop.core.link import DELIVERED, LOST_LATE, LOST_NETWORK
    from haptic_teleop.record.reader import BagReader

    window = (0.3, 0.5)
    sets = [f"network.{d}.effects.blackout.{k}=[{t}]" for d in ("forward", "backward")
            for k, t in zip(("starts_s", "ends_s"), window, strict=True)]  # fmt: skip
    out = tmp_path / "run"
    launch = Launch("blackout", "--duration", "1", "--record", str(out), "--no-plots", "--single-process",
                    *itertools.chain.from_iterable(("--set", s) for s in sets), cwd=tmp_path)  # fmt: skip
    code = launch.finish(180)
    assert code == 0, launch.failure
    summary = json.loads((out / "summary.json").read_text())
    assert summary["packets_lost_forward"] > 0, summary
    with BagReader(out / "bag") as r:
        packets = {d: r.packets(f"/{d}/packets") for d in ("forward", "backward")}
    for d, rows in packets.items():
        send = rows[:, 1]
        fate = rows[:, 3]
        inside = (send >= window[0]) & (send < window[1])
        assert np.any(inside), (d, send.min() if send.size else None, send.max() if send.size else None)
        assert np.all(fate[inside] == LOST_NETWORK), (d, np.unique(fate[inside], return_counts=True))
        # Outside the window nothing else drops (a 20 ms delay, no loss): delivered, or played too late.
        assert np.all(np.isin(fate[~inside], (DELIVERED, LOST_LATE))), (d, np.unique(fate[~inside]))
        assert summary[f"packets_lost_{d}"] == int(np.count_nonzero(inside))
        # Scene time (the relay's clock - the scene start): from 0, not ~1.8e9 s of the epoch; the
        # upper bound is loose (a sample of the last tick may reach a busy relay late).
        assert send.min() >= 0.0 and send.max() < 5.0, (d, send.min(), send.max())


# ---------------------------------------------------------------------------------------------
# The loop's timing logic: real LoopThread and SharedLoop objects on a made-up clock, so what they
# do is fixed by their code, not by this machine's load (no timing is asserted).

P_NS = 1_000_000


def test_next_tick_runs_late_ticks_up_to_the_bound_then_skips_to_the_newest():
    from haptic_teleop.nodes.rtloop import next_tick

    assert next_tick(10, 10 * P_NS + 5, P_NS, 0, 10) == (10, 0)  # on time
    assert next_tick(10, 17 * P_NS, P_NS, 0, 10) == (10, 0)  # 7 periods late: still run, late
    assert next_tick(10, 21 * P_NS + 3, P_NS, 0, 10) == (21, 11)  # 11 late: the newest deadline, 11 skipped
    assert next_tick(10, 11 * P_NS - 1, P_NS, 0, 0) == (10, 0)  # bound 0: skip once a whole period is missed
    assert next_tick(10, 11 * P_NS, P_NS, 0, 0) == (11, 1)
    assert next_tick(10, 10**6 * P_NS, P_NS, 0, None) == (10, 0)  # simulated time: never skip
    phase = P_NS // 4  # deadlines k * period + phase
    assert next_tick(10, 12 * P_NS + phase, P_NS, phase, 2) == (10, 0)
    assert next_tick(10, 13 * P_NS + phase, P_NS, phase, 2) == (13, 3)


def test_a_check_every_50_ticks_keeps_its_turn_when_the_loop_skips_the_multiples_of_50():
    from haptic_teleop.nodes.rtloop import Every

    every = Every(50)
    # A busy loop that runs only odd indices (every 50th index skipped): the check still comes,
    # once per 50 ticks run or skipped.
    due = [i for i in range(1, 400, 3) if every(i)]
    assert due == [1, 52, 103, 154, 205, 256, 307, 358]


def test_a_failed_launchs_output_shows_the_first_crash_report_the_tail_would_cut():
    from launched import failure_text

    crash = "Fatal Python error: Aborted\n  File recorder.py, line 765 in main\n"
    text = "start\n" + crash + "x" * 5000 + "\nthe loop table"
    shown = failure_text(text)
    assert shown.startswith(crash) and shown.endswith("the loop table")
    assert failure_text("no crash " + "y" * 5000) == ("no crash " + "y" * 5000)[-4000:]
    assert failure_text(crash + "short tail") == crash + "short tail"  # already in the tail: once


def test_member_ticks_between_counts_a_slower_members_own_deadlines():
    from haptic_teleop.nodes.rtloop import member_ticks_between

    for k0, k1, every in [(5, 13, 4), (4, 8, 4), (3, 4, 4), (7, 30, 1), (0, 250, 7)]:
        assert member_ticks_between(k0, k1, every) == sum(1 for k in range(k0, k1) if k % every == 0)


class _MadeUpClock:
    """A clock that moves a quarter period at every reading; a tick can make it jump (a stall)."""

    def __init__(self) -> None:
        self.t = 10**12
        self.lock = threading.Lock()

    def __call__(self) -> int:
        with self.lock:
            self.t += P_NS // 4
            return self.t

    def stall(self, periods: int) -> None:
        with self.lock:
            self.t += periods * P_NS


def _run_loop_thread(max_catch_up: int, stall_periods: int, n: int = 60):
    from haptic_teleop.nodes.rtloop import LoopThread

    clock = _MadeUpClock()
    ran: list[int] = []
    done = threading.Event()

    def tick(k: int, stamp_ns: int) -> None:
        assert stamp_ns == k * P_NS
        ran.append(k)
        if len(ran) == 10:
            clock.stall(stall_periods)
        if len(ran) >= n:
            done.set()

    loop = LoopThread("test", P_NS, tick, now_ns=clock, max_catch_up=max_catch_up)
    loop.start()
    assert done.wait(60), "the loop did not run"
    loop.stop()
    return ran[:n], loop.stats


def test_loop_thread_runs_the_ticks_of_a_stall_late_within_the_bound():
    ran, stats = _run_loop_thread(max_catch_up=10, stall_periods=6)
    assert ran == list(range(ran[0], ran[0] + len(ran)))  # every deadline of the grid, none skipped
    assert stats.overruns == 0
    assert stats.late_ticks >= 5  # the stall's backlog ran a period or more late


def test_a_tick_held_inside_its_work_reports_how_late_it_ended():
    """The loop's "latest end" (LoopStats.end_late_max_ns) counts a tick preempted inside its work,
    which its wake-up lateness does not see: the stall here happens inside the 10th tick."""
    from haptic_teleop.nodes.rtloop import SharedLoop

    _, stats = _run_loop_thread(max_catch_up=10, stall_periods=6)
    woke_late = np.frombuffer(stats.lateness_ns, dtype=np.int64)[:10]
    assert woke_late.max() < P_NS  # the stalled tick woke on time ...
    assert stats.end_late_max_ns >= 6 * P_NS  # ... and ended 6 periods late
    assert stats.report()["end_late_max_us"] >= 6000.0
    clock = _MadeUpClock()
    group = SharedLoop(now_ns=clock)
    done = threading.Event()
    seen: list[int] = []

    def tick(k: int, stamp_ns: int) -> None:
        seen.append(k)
        if len(seen) == 5:
            clock.stall(3)
        if len(seen) >= 20:
            done.set()

    member = group.add("m", P_NS, 0.0, tick, None, None, 10)
    group.start()
    assert done.wait(60)
    group.stop()
    assert member.stats.end_late_max_ns >= 3 * P_NS


def test_loop_thread_skips_beyond_the_bound_and_counts_what_it_skipped():
    for bound, stall in [(0, 6), (10, 30)]:
        ran, stats = _run_loop_thread(max_catch_up=bound, stall_periods=stall)
        gaps = [b - a - 1 for a, b in itertools.pairwise(ran) if b - a > 1]
        assert len(gaps) == 1 and gaps[0] >= stall - bound - 1, (bound, gaps)
        assert stats.overruns == sum(gaps)
        assert stats.ticks + stats.overruns >= ran[-1] - ran[0] + 1


def test_shared_loop_catches_up_every_member_and_counts_skips_per_member():
    from haptic_teleop.nodes.rtloop import SharedLoop

    for bound, stall in [(10, 6), (0, 6)]:
        clock = _MadeUpClock()
        group = SharedLoop(now_ns=clock)
        ran: dict[str, list[int]] = {"fast": [], "slow": []}
        order: list[str] = []
        done = threading.Event()

        def ticker(name: str, period: int):
            def tick(k: int, stamp_ns: int) -> None:
                assert stamp_ns == k * period
                ran[name].append(k)
                order.append(name)
                if name == "fast" and len(ran["fast"]) == 10:
                    clock.stall(stall)
                if len(ran["fast"]) >= 80:
                    done.set()

            return tick

        slow = group.add("slow", 4 * P_NS, 0.5, ticker("slow", 4 * P_NS), None, None, bound)
        fast = group.add("fast", P_NS, 0.0, ticker("fast", P_NS), None, None, bound)
        group.start()
        assert done.wait(60)
        group.stop()
        fast_gaps = sum(b - a - 1 for a, b in itertools.pairwise(ran["fast"]))
        slow_gaps = sum(b - a - 1 for a, b in itertools.pairwise(ran["slow"]))
        assert fast.stats.overruns == fast_gaps and slow.stats.overruns == slow_gaps
        if bound == 10:
            assert fast_gaps == 0 and slow_gaps == 0 and fast.stats.late_ticks >= 5
        else:
            assert fast_gaps >= stall - 1
        # Pipeline order: in a pass the member with the earlier phase ticks first.
        pairs = [(a, b) for a, b in itertools.pairwise(order) if "slow" in (a, b)]
        assert all(a == "fast" for a, b in pairs if b == "slow")


def test_simulated_shared_loop_waits_for_the_clock_and_runs_every_pass_in_phase_order():
    """Composed nodes on simulated time share one loop on their ROS clock: nothing runs before the
    first /clock (time 0), and a clock that jumps 50 periods ahead (a loop behind /clock) gets every
    pass run, none skipped, each member in phase order, so relays and buffers stay in step with
    the sides whatever /clock does (docs/live_network.md, "Deliveries on the stamp grid")."""
    from haptic_teleop.nodes.rtloop import SharedLoop

    t = [0]  # no /clock yet
    group = SharedLoop(now_ns=lambda: t[0], simulated=True)
    order: list[tuple[str, int]] = []
    done = threading.Event()

    def ticker(name: str):
        def tick(k: int, stamp_ns: int) -> None:
            order.append((name, k))
            if name == "buffer" and len(order) == 2 * 4:
                t[0] += 50 * P_NS  # /clock jumps ahead
            if len(order) >= 2 * 50:
                done.set()

        return tick

    buffer = group.add("buffer", P_NS, 0.5, ticker("buffer"), None, None, 10)
    relay = group.add("relay", P_NS, 0.25, ticker("relay"), None, None, 10)
    group.start()
    time.sleep(0.05)
    assert order == []  # waits for the first /clock
    t[0] = 1000 * P_NS + 1  # the loop's first deadline: 1001 periods
    time.sleep(0.05)
    assert order == []  # not due yet
    t[0] = 1005 * P_NS  # passes 1001 to 1005 due; at the 4th, /clock jumps to 1055
    assert done.wait(30)
    group.stop()
    ks = [k for name, k in order if name == "relay"]
    assert ks == list(range(ks[0], ks[0] + len(ks)))  # every pass, none skipped
    # relay before buffer in every pass
    assert all(
        order[i] == ("relay", k) and order[i + 1] == ("buffer", k) for i, k in zip(range(0, len(order) - 1, 2), ks)
    )
    assert ks[-1] - ks[0] >= 49  # the 50 periods /clock jumped, all run
    assert relay.stats.overruns == 0 and buffer.stats.overruns == 0


def test_loop_stats_reports_give_exact_figures_between_two_reports():
    """What `bench live` computes from two diagnostics reports: ticks run per second of wall time,
    late ticks and lateness percentiles of exactly the ticks in between."""
    from haptic_teleop.nodes.rtloop import LoopStats
    from haptic_teleop.studies.benchmarks.live import window_figures

    st = LoopStats(P_NS)
    lateness = [(i * 7919) % 2500 * 1000 + 100 for i in range(3000)]  # 0.1 us to 2.5 ms, fixed
    t0 = 10**12
    reports = []
    for i, late in enumerate(lateness):
        st.record(t0 + i * P_NS + late, t0 + i * P_NS)
        if i in (999, 2999):
            reports.append((float(i), {k: str(v) for k, v in {**st.report(), "period_s": 1e-3}.items()}))
    f = window_figures(reports, 0.0, 1e9)
    window = np.array(lateness[1000:], dtype=np.float64)
    assert f is not None and f["ticks"] == 2000
    span = 2000 * P_NS + lateness[2999] - lateness[999]
    assert f["loop_rate_hz"] == pytest.approx(2000 / (span * 1e-9), rel=1e-12)
    assert f["late_ticks"] == int(np.count_nonzero(window >= P_NS))
    for key, q in (("lateness_p50_us", 50), ("lateness_p99_us", 99)):
        exact = float(np.percentile(window * 1e-3, q))
        assert abs(f[key] - exact) <= 0.1 * exact, (key, f[key], exact)  # within its 9 % bin
    assert f["lateness_max_us"] == pytest.approx(window.max() * 1e-3)


def test_lateness_histogram_bins_are_an_eighth_of_an_octave():
    from haptic_teleop.nodes.rtloop import LATENESS_BINS, lateness_bins

    us = np.array([0.0, 0.5, 1.0, 2 ** (1 / 8) * 1.0001, 2.0001, 1000.0, 1e9])
    assert lateness_bins(us * 1e3).tolist() == [0, 0, 0, 1, 8, int(8 * np.log2(1000.0)), LATENESS_BINS - 1]


def test_wrench_and_eba_bytes_deserialize_to_the_values_given():
    from geometry_msgs.msg import WrenchStamped
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64MultiArray

    from haptic_teleop.nodes.cdr import multiarray_codec, wrench_codec
    from haptic_teleop.nodes.topics import EBA_LABELS

    stamp = 1_795_000_000_123_456_789
    w = deserialize_message(wrench_codec("wall").encode(stamp, (-3.25,)), WrenchStamped)
    assert w.header.frame_id == "wall"
    assert w.header.stamp.sec * 1_000_000_000 + w.header.stamp.nanosec == stamp
    assert (w.wrench.force.x, w.wrench.force.y, w.wrench.torque.z) == (-3.25, 0.0, 0.0)
    a = deserialize_message(multiarray_codec(EBA_LABELS).encode(None, (0.5, -2.0)), Float64MultiArray)
    assert [d.label for d in a.layout.dim] == list(EBA_LABELS)
    assert [(d.size, d.stride) for d in a.layout.dim] == [(1, 1), (1, 1)]
    assert list(a.data) == [0.5, -2.0]


# ---------------------------------------------------------------------------------------------
# An unusable --record directory stops the launch before any node starts.


def _unwritable_dirs(tmp_path: Path) -> dict[str, Path]:
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    full = tmp_path / "full"
    full.mkdir()
    (full / "something").write_text("x")
    if os.geteuid() == 0:
        read_only = Path("/proc/haptic_teleop_record")  # root writes through permissions; not into /proc
    else:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        read_only = ro / "run"
    return {"file": a_file, "not empty": full, "read-only": read_only}


@pytest.mark.parametrize("case", ["file", "not empty", "read-only"])
def test_unusable_record_dir_fails_before_anything_starts(tmp_path, case):
    path = _unwritable_dirs(tmp_path)[case]
    r = subprocess.run([*CLI, "launch", "wall_contact", "--duration", "1", "--record", str(path)],
                       capture_output=True, text=True, timeout=60, cwd=tmp_path)  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "allowed:" in lines[0], r.stderr
    assert "started" not in r.stdout and "Traceback" not in r.stderr, r.stdout
    if case == "file":
        assert path.read_text() == "x"  # left as it was


# ---------------------------------------------------------------------------------------------
# The hardware variant's force command: QoS from parameters, reliable by default.


@pytest.mark.parametrize("reliability", [None, "best_effort"], ids=["default", "best_effort"])
def test_force_command_reaches_reliable_and_best_effort_drivers(tmp_path, reliability):
    """master_eba with device.source topic, driven by a fake device driver in this process: with
    the default QoS (reliable) a driver subscribing with ROS's default QoS (reliable) and one
    subscribing best effort both receive commands; with best_effort, only the best-effort one."""
    from geometry_msgs.msg import WrenchStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState

    from haptic_teleop.nodes.topics import stream_qos

    state_topic, command_topic = "/qos_test/joint_states", "/qos_test/force_command"
    cmd = [sys.executable, "-m", "haptic_teleop.nodes.master_eba", "--ros-args",
           "-p", "device.source:=topic", "-p", f"device.state_topic:={state_topic}",
           "-p", f"device.command_topic:={command_topic}", "-p", "loop.realtime_priority:=0"]  # fmt: skip
    if reliability is not None:
        cmd += ["-p", f"device.command_reliability:={reliability}"]
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("fake_driver", context=context)
    got = {"reliable": [], "best_effort": []}
    node.create_subscription(WrenchStamped, command_topic, got["reliable"].append, QoSProfile(depth=10))
    node.create_subscription(WrenchStamped, command_topic, got["best_effort"].append, stream_qos(10))
    state = node.create_publisher(JointState, state_topic, stream_qos())
    msg = JointState(name=["device_x"], position=[0.01], velocity=[0.0], effort=[0.0])
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # Wait for the readers that should receive (the reliable one never does with best_effort:
        # waiting on it too ran to the timeout, a minute).
        waiting = ["best_effort"] if reliability == "best_effort" else list(got)
        end = time.monotonic() + 60
        while time.monotonic() < end and min(len(got[k]) for k in waiting) < 50:
            state.publish(msg)
            executor.spin_once(timeout_sec=0.002)
            if proc.poll() is not None:
                break
        if reliability == "best_effort":  # give the reliable reader time to (not) receive
            end = time.monotonic() + 3
            while time.monotonic() < end:
                state.publish(msg)
                executor.spin_once(timeout_sec=0.002)
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert proc.returncode == 0, out
    assert len(got["best_effort"]) >= 50, (len(got["best_effort"]), out[-2000:])
    if reliability == "best_effort":
        assert got["reliable"] == []  # incompatible QoS: what the default used to do to a default driver
    else:
        assert len(got["reliable"]) >= 50, (len(got["reliable"]), out[-2000:])


# ---------------------------------------------------------------------------------------------
# The recorder's pure parts: late marks on packet records, the grid across written blocks.


def test_mark_late_marks_the_first_delivered_copy_of_each_late_packet():
    from haptic_teleop.nodes.recorder import mark_late
    from haptic_teleop.record.layouts import PACKET_FIELDS

    f = {name: i for i, name in enumerate(PACKET_FIELDS)}
    nan = float("nan")
    rows = np.array(
        [  # seq, send, arrival, fate, duplicate, size
            [1, 0.001, 0.051, 0, 0, 60],
            [2, 0.002, 0.060, 0, 0, 60],  # original, arrived second
            [2, 0.002, 0.055, 0, 1, 60],  # its duplicate arrived first: that is the copy the buffer skipped
            [3, 0.003, nan, 1, 0, 60],  # lost in the network: not late
            [4, 0.004, 0.054, 0, 0, 60],
        ]
    )
    assert mark_late(rows, {2, 3, 9}, f) == 1
    assert rows[:, f["fate"]].tolist() == [0, 0, 4, 1, 0]
    assert mark_late(rows, set(), f) == 0


def test_on_grid_holds_values_across_blocks_and_counts_the_filled_ticks():
    from haptic_teleop.nodes.recorder import _on_grid

    grid, filled, carry = _on_grid(np.array([1, 3]), np.array([[10.0], [30.0]]), 5, None)
    assert grid[:, 0].tolist() == [10.0, 10.0, 10.0, 30.0, 30.0] and filled == 3  # before the first: the first
    grid, filled, carry = _on_grid(np.array([2]), np.array([[40.0]]), 4, carry)
    assert grid[:, 0].tolist() == [30.0, 30.0, 40.0, 40.0] and filled == 3  # the previous block's last held
    grid, filled, carry = _on_grid(np.zeros(0, dtype=np.int64), np.zeros((0, 1)), 2, carry)
    assert grid[:, 0].tolist() == [40.0, 40.0] and filled == 2 and carry is not None and carry[0] == 40.0
