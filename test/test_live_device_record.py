"""A recorded device session live: the hardware variant of the node set (`node_plan(..., device="topic")`,
what teleop_hardware_launch.py starts) with a recorder, driven by a fake haptic device driver in this
process (its own rclpy context: sensor_msgs/JointState out, geometry_msgs/WrenchStamped force commands
in), every node its own process through the project's launcher (`haptic-teleop launch --device
topic`), stopped with SIGINT as Ctrl-C stops it.

There is no operator source: the recorder takes the tick master_eba announces (1 s after the
recorder said it takes every stream of its grid) as scene time 0, leaves the operator's columns
NaN and records until it is stopped, past the scene's duration (docs/live_recording.md,
"Recording a device session"); `haptic-teleop analyze` works on the bag. DDS stays on this host,
in this module's own ROS domain (conftest). Nothing here depends on wall-clock rates: the session
lasts until the driver has received commands stamped over SPAN_S of the master's clock from scene
time 0.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from launched import CLI, Launch

rclpy = pytest.importorskip("rclpy")

STATE_TOPIC = "/device_record_test/joint_states"
COMMAND_TOPIC = "/device_record_test/force_command"
# The driver's trajectory: held at START_M until the master answers, then a slow ramp in steps of
# STEP_M, one every STEP_S of the driver's clock, up to END_M (1 cm into wall_contact's wall, at 2 cm).
START_M, END_M, STEP_M, STEP_S = 0.015, 0.030, 1e-5, 0.002
DURATION_S = 1.0  # the scene's duration: a device session is recorded past it
SPAN_S = 2.5  # the session: until the driver got commands stamped over this much of the master's clock
NODES = {"master_eba", "slave_eba", "forward_relay", "backward_relay", "forward_buffer", "backward_buffer",
         "recorder"}  # fmt: skip

# The launch: `haptic-teleop launch --device topic` (the hardware variant through the project's
# launcher), in a process of its own: SIGINT to it is Ctrl-C, forwarded to the nodes (the recorder
# last); with --record it then analyses the bag as `run` does.


def _launch(tmp: Path) -> Launch:
    return Launch("wall_contact", "--duration", str(DURATION_S), "--device", "topic", "--state-topic", STATE_TOPIC,
                  "--command-topic", COMMAND_TOPIC, "--record", str(tmp / "run"), "--params-dir", str(tmp / "params"),
                  "--no-plots", cwd=tmp)  # fmt: skip


def _drive(launch: Launch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fake device driver: publishes the trajectory (START_M; once the master answers and the
    slave runs, the ramp) and takes the force commands until they span SPAN_S of stamps from the
    ramp's start; then the launch gets SIGINT. Returns the positions it published, and the commands'
    stamps (ns) and force.x.

    The master starts at the driver's first message, the slave when its process is up, scene time 0
    once the recorder takes every stream: on a busy machine seconds apart, hence the ramp starts at
    the first command stamped at or after scene time 0 (read from /haptic_teleop/scene_start)."""
    from geometry_msgs.msg import WrenchStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Header

    from haptic_teleop.nodes.topics import SCENE_START_TOPIC, latched_qos, scene_start_ns, stream_qos

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("fake_device_driver", context=context)
    got: list[tuple[int, float]] = []
    slave_up: list[bool] = []

    def on_command(m: WrenchStamped) -> None:
        got.append((m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, m.wrench.force.x))

    node.create_subscription(WrenchStamped, COMMAND_TOPIC, on_command, QoSProfile(depth=1000))
    slave = node.create_subscription(JointState, "/slave/joint_states", lambda m: slave_up.append(True),
                                     stream_qos(1), raw=True)  # fmt: skip
    start: list[int] = []
    node.create_subscription(Header, SCENE_START_TOPIC, lambda m: start.append(scene_start_ns(m, 1)), latched_qos())
    state = node.create_publisher(JointState, STATE_TOPIC, stream_qos())
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    published: list[float] = []
    ramp: list[tuple[float, int]] = []  # its start: the driver's clock, the newest command's stamp
    stopped = False

    def publish() -> None:
        if got and slave_up and start and got[-1][0] >= start[0] and not ramp:
            ramp.append((time.monotonic(), got[-1][0]))
            node.destroy_subscription(slave)
        steps = int((time.monotonic() - ramp[0][0]) / STEP_S) if ramp else 0
        x = min(START_M + steps * STEP_M, END_M)
        state.publish(JointState(name=["device_x"], position=[x], velocity=[0.0], effort=[0.0]))
        published.append(x)
        executor.spin_once(timeout_sec=0.001)

    def done() -> bool:
        return bool(ramp) and got[-1][0] - ramp[0][1] >= SPAN_S * 1e9

    try:
        end = time.monotonic() + 600  # discovery and start on a busy machine; a bound, not a rate
        while time.monotonic() < end and launch.proc.poll() is None and not done():
            publish()
        assert done(), f"{len(got)} commands, slave up: {bool(slave_up)}; launch output:\n{launch.failure}"
        launch.proc.send_signal(signal.SIGINT)
        stopped = True
        stop = time.monotonic() + 1.0  # keep publishing while the nodes stop (a driver does not stop with them)
        while time.monotonic() < stop:
            publish()
    finally:
        if not stopped and launch.proc.poll() is None:
            launch.proc.send_signal(signal.SIGINT)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    commands = np.array(got, dtype=np.float64).reshape(-1, 2)
    return np.unique(published), commands[:, 0].astype(np.int64), commands[:, 1]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("device_session")
    launch = _launch(tmp)
    try:
        published, stamps, forces = _drive(launch)
    finally:
        code = launch.finish(240)  # _drive sent SIGINT, whatever happened
    return {"code": code, "launch": launch, "out": tmp / "run", "published": published,
            "command_stamps": stamps, "command_forces": forces}  # fmt: skip


def test_every_node_stops_cleanly_on_sigint(session):
    launch = session["launch"]
    assert session["code"] == 130, launch.failure  # 128 + SIGINT: a clean stop asked by a signal
    codes = launch.exit_codes()
    assert set(codes) == NODES and all(c == 0 for c in codes.values()), (codes, launch.failure)
    assert "Traceback" not in launch.text
    assert "nothing to record" not in launch.text
    assert "bag written" in launch.text
    # ... and the launch command analysed it: the run's own summary
    summary = json.loads((session["out"] / "summary.json").read_text())
    assert summary["interrupted"] is False and summary["all_finite"] is True


def test_the_bag_reads_and_holds_the_device_session(session):
    """Scene time 0 is a tick of the master's; the master's positions are the driver's ramp, the
    operator's columns NaN, and the bag goes past the scene's duration (recorded until stopped)."""
    from haptic_teleop.record.reader import BagReader

    out = session["out"]
    bag = out / "bag"
    r = subprocess.run([*CLI, "bag", "info", str(bag)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    info = json.loads((out / "live_run.json").read_text())
    with BagReader(bag) as reader:
        facts = json.loads(reader.string("/haptic_teleop/run_info"))
        master = reader.read("/master/joint_states")
        operator = reader.read("/operator/joint_states").values
        slave = reader.read("/slave/joint_states").values
        packets = {d: reader.packets(f"/{d}/packets") for d in ("forward", "backward")}
    assert facts["ticks"] == info["ticks"] == len(master.log_ns) > round(DURATION_S / 0.001)
    assert facts["interrupted"] is False  # a device session ends by being stopped
    assert operator.shape[0] == info["ticks"] and np.all(np.isnan(operator))
    assert np.all(np.isfinite(master.values)) and np.all(np.isfinite(slave))
    x = master.field("position")
    # Every position is one the driver published, exactly (the master passes the driver's value on),
    # in the ramp's order; the ramp went on during the session.
    assert np.all(np.isin(x, session["published"])), x[~np.isin(x, session["published"])][:10]
    assert np.all(np.diff(x) >= 0.0)
    assert round((x.max() - x.min()) / STEP_M) >= 100
    assert "/operator/joint_states" not in info["messages_received"]  # not subscribed
    # The force commands the driver received are the master's effort at the same stamps (a row the
    # recorder missed holds the previous value: counted in samples_filled).
    stamps = np.asarray(master.stamp_ns, dtype=np.int64) + int(info["start_stamp_ns"])
    effort = dict(zip(stamps.tolist(), master.field("effort").tolist(), strict=True))
    common = [(effort[s], f) for s, f in zip(session["command_stamps"].tolist(), session["command_forces"].tolist(),
                                             strict=True) if s in effort]  # fmt: skip
    # a count, not a rate: the driver took 397 commands in all once, with a CI job and two busy loops beside it
    assert len(common) >= 20, (len(common), session["command_stamps"].size)
    differ = sum(1 for a, b in common if a != b)
    assert differ <= info["samples_filled"]["/master/joint_states"], differ
    assert any(f != 0.0 for _, f in common)  # the slave met the wall: a force came back
    # The packet records' times are in the bag's scene time (the relays took master_eba's scene start):
    # a packet sent on time has its tick's time as send time (a late one a later time).
    for d, rows in packets.items():
        assert rows.shape[0] > 0, d
        ahead = rows[:, 0] * 0.001 - rows[:, 1]
        assert abs(float(np.max(ahead))) < 1e-6, (d, np.percentile(ahead, [0, 50, 100]))


def test_analyze_works_on_the_device_bag(session, tmp_path):
    out = tmp_path / "analysis"
    r = subprocess.run([*CLI, "analyze", str(session["out"] / "bag"), "--out", str(out)],
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is False and summary["ticks"] > round(DURATION_S / 0.001)
    assert summary["all_finite"] is True
    assert list((out / "plots").glob("*.png")), sorted(p.name for p in out.rglob("*"))


def test_a_bad_device_source_stops_the_recorder_with_one_line(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "haptic_teleop.nodes.recorder", "--ros-args", "-p", f"output_dir:={tmp_path / 'run'}",
         "-p", "device.source:=usb"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    lines = [ln for ln in r.stderr.splitlines() if "device.source" in ln]
    assert len(lines) == 1 and "allowed: one of plant, topic" in lines[0], r.stderr
    assert "Traceback" not in r.stderr
