"""Applied, not commanded (docs/hardware_plant.md): a side on hardware records the port torque its device
reported (/<side>/measured_effort, `s_tau_measured_nm`) beside the torque commanded
(/<side>/joint_states effort), its energy ledger books the reported one, and the analysis does too;
a simulated side records nothing new.

The Dynamixel session runs against the bus emulator in lockstep time (deterministic: the same scene
gives the same bag), spoken to by the unmodified dynamixel_sdk. A servo whose torque is turned off
mid-run (the emulator's `torque_off` fault) reports Present Current 0 while the driver keeps
commanding it until its applied check stops the run: those ticks show what the servo really did in
the measured topic, and the command in joint_states effort. Row n of the measured topic is the
hold that ended at read n: the reported motor torque minus the gravity compensation written with
the command at tick n - 1 (the arm's model at q[n - 1], recomputed here from the bag's q).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from haptic_teleop.assembly.emulation import bus_config
from haptic_teleop.emulators.dynamixel.config import FaultConfig
from haptic_teleop.emulators.dynamixel.process import start_bus
from haptic_teleop.plants.dynamixel import tables
from haptic_teleop.plants.hardware import HardwareError
from haptic_teleop.record.columns import TickSchema
from haptic_teleop.record.reader import BagReader
from haptic_teleop.scene.load import find_scene, load_scene

SCENE = "touch_dynamixel_wall"  # the slave on three servos, ids 1, 2, 3
SETS = ["slave.backend=dynamixel", "scene.duration_s=1.0"]
FAULT_S = 0.5  # emulator time at which servo 2 (the shoulder, which holds the arm up) turns its torque off
SHOULDER = 1


@dataclasses.dataclass
class Session:
    bag: Path
    scene: Any
    error: str
    q: np.ndarray  # (N, 3) s_q
    effort: np.ndarray  # (N, 3) /slave/joint_states effort: the port torque commanded at each tick
    measured: np.ndarray  # (N, 3) /slave/measured_effort
    reservoir_j: np.ndarray  # (N,) /slave/eba's reservoir
    topics: dict[str, str]
    first_message: Any
    run_info: dict[str, Any]
    tick_schema: TickSchema


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Session]:
    from rosbags.rosbag2 import Reader

    from haptic_teleop.engine.run import record_run
    from haptic_teleop.record.layouts import typestore

    out = tmp_path_factory.mktemp("measured") / "bag"
    cfg = bus_config(load_scene(find_scene(SCENE), SETS, emulate=True).config, "slave")
    fault = FaultConfig(servo_id=2, kind="torque_off", at_time_s=FAULT_S)
    bus = start_bus(dataclasses.replace(cfg, faults=(fault,)))
    try:
        on = [f"slave.hardware.port={bus.port}", "slave.hardware.device_clock=lockstep"]
        # a read that times out repeats the last sample (a stale tick): generous under this machine's load
        scene = load_scene(find_scene(SCENE), [*SETS, *on, "slave.hardware.read_timeout_s=2.0"])
        with pytest.raises(HardwareError) as exc:  # the driver's applied check ends the run
            record_run(scene, out, parallel=False, handle_sigint=False)
    finally:
        bus.stop()
    with BagReader(out) as r:
        js = r.read("/slave/joint_states").values
        measured = r.read("/slave/measured_effort")
        assert measured.fields == ("effort[base_yaw]", "effort[shoulder]", "effort[elbow]")
        eba = r.read("/slave/eba").values
        topics = dict(r.topics)
        run_info = json.loads(r.string("/haptic_teleop/run_info"))
        schema = r.schema
    with Reader(out) as raw:
        conn = [c for c in raw.connections if c.topic == "/slave/measured_effort"]
        _, _, data = next(raw.messages(connections=conn))
        first = typestore().deserialize_cdr(data, conn[0].msgtype)
    yield Session(
        out, scene, str(exc.value), js[:, :3], js[:, 6:9], measured.values, eba[:, 0], topics, first, run_info, schema
    )


def gravity_written(scene: Any, q: np.ndarray) -> np.ndarray:
    """The gravity compensation the plant wrote with each tick's command: the arm's model at that
    tick's q (HardwareArm.gravity_torque)."""
    from haptic_teleop.plants.kinematics import ArmKinematics

    c = scene.config.slave
    kin = ArmKinematics(c.model, c.joints, "tool")
    out = []
    for qk in q:
        kin.set_q(qk)
        out.append(kin.gravity_torque())
    return np.array(out)


def units_per_nm(scene: Any) -> np.ndarray:
    """Present/Goal Current units per N m of joint torque, per joint (the datasheet k_t, the sign)."""
    hw = scene.config.slave.hardware
    kt = np.array([tables.model(m).torque_constant_nm_per_a for m in hw.models])
    return np.array(hw.signs, dtype=float) / (kt * tables.CURRENT_UNIT_A)


def test_the_bag_carries_the_current_the_servos_reported_and_the_fault_only_there(session: Session) -> None:
    s = session
    assert "servo 2 (shoulder)" in s.error and "Torque Enable(64) is 0" in s.error
    assert s.topics["/slave/measured_effort"] == "sensor_msgs/msg/JointState"
    assert "/master/measured_effort" not in s.topics  # the master is simulated
    assert s.tick_schema.slave_measured and not s.tick_schema.master_measured
    assert s.run_info["tick_schema"]["slave_measured"] is True
    assert s.run_info["slave_unmeasured_torque_reads"] == 0  # every read carried a report
    msg = s.first_message  # the joint names and effort only
    assert list(msg.name) == ["base_yaw", "shoulder", "elbow"]
    assert len(msg.position) == 0 and len(msg.velocity) == 0 and len(msg.effort) == 3
    n = s.q.shape[0]
    assert 400 < n < 600  # the ticks before the applied check stopped the run, 20 reads after the fault
    g = gravity_written(s.scene, s.q)
    k = units_per_nm(s.scene)
    # What each servo reported at read n (Present Current, in its units) and the Goal Current
    # written at tick n - 1: whole units both.
    reported = (s.measured[1:] + g[:-1]) * k
    goal = (s.effort[:-1] + g[:-1]) * k
    assert np.allclose(reported, np.rint(reported), atol=1e-6)
    assert np.allclose(goal, np.rint(goal), atol=1e-6)
    reported, goal = np.rint(reported), np.rint(goal)
    fault = int(round(FAULT_S / s.scene.config.scene.period_s)) - 5  # lockstep: emulator time = ticks
    assert np.array_equal(reported[:fault], goal[:fault])  # a healthy servo applies its command
    assert np.abs(goal[:fault, SHOULDER]).max() > 20  # ... which is not nothing
    # The shoulder after its torque went off: it reports no current, the command goes on.
    off = np.flatnonzero(reported[:, SHOULDER] != goal[:, SHOULDER])
    assert off.size >= 15 and off[0] >= fault and off[-1] == n - 2
    assert np.all(reported[off, SHOULDER] == 0.0)
    assert np.all(np.abs(goal[off, SHOULDER]) > 20)
    # joint_states effort still says what was commanded; the measured port torque is what the servo
    # did: it no longer carries the arm's weight (-g).
    assert np.all(np.abs(s.effort[off, SHOULDER] - s.measured[off + 1, SHOULDER]) > 0.1)
    assert np.allclose(s.measured[off + 1, SHOULDER], -g[off, SHOULDER], rtol=0.0, atol=1e-12)
    assert np.array_equal(reported[off][:, [0, 2]], goal[off][:, [0, 2]])  # the other servos: healthy


def test_the_ledger_books_the_torque_the_servos_reported(session: Session) -> None:
    """The slave's reservoir (the bag's /slave/eba) is the ledger with row n + 1's measured torque
    held over q[n] -> q[n + 1] (lockstep: each hold is one period), not with the command."""
    s = session
    c = s.scene.config
    d = np.array(c.slave.damping_nm_s_per_rad)
    period = c.scene.period_s
    dq = np.diff(s.q, axis=0)

    def ledger(held: np.ndarray) -> np.ndarray:
        return s.reservoir_j[0] + np.cumsum(np.sum((d / period) * dq * dq - held * dq, axis=1))

    booked = ledger(s.measured[1:])
    commanded = ledger(s.effort[:-1])
    assert np.allclose(booked, s.reservoir_j[1:], rtol=0.0, atol=1e-12)
    assert np.abs(commanded - s.reservoir_j[1:]).max() > 1e-5  # the fault's ticks tell the two apart


def test_the_analysis_of_the_session_names_the_torque_it_booked(session: Session) -> None:
    from haptic_teleop.analysis.stream import summarize_bag
    from haptic_teleop.analysis.summary_table import format_summary

    summary = summarize_bag(session.bag)
    assert summary["slave_energy_torque_topic"] == "/slave/measured_effort"
    assert summary["master_energy_torque_topic"] == "/master/joint_states"
    assert summary["slave_unmeasured_torque_reads"] == 0 and "master_unmeasured_torque_reads" not in summary
    assert "slave energy booked on" in format_summary(summary) and "master energy booked" not in format_summary(summary)


def test_a_measured_side_adds_its_group_last_and_its_topic_after_its_joint_states() -> None:
    from haptic_teleop.record.columns import SchemaError, tick_topics

    plain = TickSchema(JOINTS["master"], JOINTS["slave"], 3)
    both = TickSchema(JOINTS["master"], JOINTS["slave"], 3, True, True)
    assert both.columns[: plain.width] == plain.columns  # every other column where it was
    assert both.columns[plain.width :] == tuple(
        f"{p}_tau_measured_nm[{j}]" for p, side in (("m", "master"), ("s", "slave")) for j in JOINTS[side]
    )
    topics = [t.topic for t in tick_topics(both)]
    assert [t.topic for t in tick_topics(plain)] == [t for t in topics if "measured" not in t]
    assert topics.index("/master/measured_effort") == topics.index("/master/joint_states") + 1
    assert topics.index("/slave/measured_effort") == topics.index("/slave/joint_states") + 1
    assert TickSchema.from_facts(both.facts()) == both and "slave_measured" not in plain.facts()
    with pytest.raises(SchemaError, match="1-axis"):
        TickSchema(("master_x",), ("slave_x",), 1, slave_measured=True)


# ------------------------------------------------------------------------------------------------
# A simulated scene records nothing new.


def test_a_simulated_arm_scene_records_no_measured_torque(tmp_path: Path) -> None:
    from haptic_teleop.engine.run import record_run

    scene = load_scene(find_scene("touch_ur5e_wall"), ["scene.duration_s=0.05"])
    engine, _ = record_run(scene, tmp_path / "bag", loop="python", parallel=False, handle_sigint=False)
    assert not engine.schema.master_measured and not engine.schema.slave_measured
    assert not any("measured" in c for c in engine.schema.columns)
    with BagReader(tmp_path / "bag") as r:
        assert not any("measured" in t for t in r.topics), list(r.topics)
        info = json.loads(r.string("/haptic_teleop/run_info"))
        assert set(info["tick_schema"]) == {"master_joints", "slave_joints", "task_axes"}
        assert not any("measured" in k for k in info)
        assert r.schema == TickSchema(engine.schema.master_joints, engine.schema.slave_joints, 3)


# ------------------------------------------------------------------------------------------------
# The analysis books the measured torque when the bag has it: a synthetic bag (the real recorder)
# whose slave commands one torque and reports another, alternating, so that pairing the motion
# q[n] -> q[n + 1] with row n + 1's report, row n's report or the command gives three answers.

T = 0.001
N = 1200  # an odd number of steps (N - 1): the two pairings of the alternating report sum differently
JOINTS = {"master": ("yaw", "shoulder", "elbow"), "slave": ("base_yaw", "shoulder", "elbow")}
RATES = {"master": np.array([0.2, -0.1, 0.3]), "slave": np.array([0.1, 0.2, -0.3])}
COMMAND = {"master": np.array([0.5, 0.5, 0.5]), "slave": np.array([0.4, -0.2, 0.6])}
# the slave's report, row n: REPORT (1 + n % 2); it does work on every joint's motion (REPORT . RATES > 0)
REPORT = np.array([1.0, 2.0, -3.0])
DAMPING = {"master": [0.01, 0.02, 0.03], "slave": [0.1, 0.1, 0.04]}
E0 = {"master": 1.5, "slave": 0.5}
SYNTHETIC = TickSchema(JOINTS["master"], JOINTS["slave"], 3, slave_measured=True)


def synthetic_rows(schema: TickSchema) -> np.ndarray:
    n = np.arange(N)
    t = n * T
    rows = np.zeros((N, schema.width))
    for side in ("master", "slave"):
        p = side[0]
        rows[:, schema.group(f"{p}_q")] = RATES[side] * t[:, None]
        rows[:, schema.group(f"{p}_qd")] = RATES[side]
        rows[:, schema.group(f"{p}_tau_nm")] = COMMAND[side]
        rows[:, schema.group(f"{p}_energy_j")] = E0[side]
    if schema.slave_measured:
        rows[:, schema.group("s_tau_measured_nm")] = REPORT * (1 + n % 2)[:, None]
    rows[:, schema.index("fwd_rx_seq")] = n
    rows[:, schema.index("bwd_rx_seq")] = n
    return rows


def write_bag(out: Path, schema: TickSchema) -> Path:
    from haptic_teleop.record.recorder import RunRecorder

    scene = {
        "scene": {"name": "synthetic_measured", "seed": 1, "period_s": T},
        "controllers": {side: {"eba": {"initial_energy_j": E0[side]}} for side in ("master", "slave")},
        "network": {},
    }
    info = {"ticks": N, "interrupted": False, **{f"{s}_joint_damping": DAMPING[s] for s in ("master", "slave")}}
    rec = RunRecorder(out, yaml.safe_dump(scene), round(T * 1e9), True, True, schema.width, schema=schema)
    rows = synthetic_rows(schema)
    for a in range(0, N, 500):
        rec.append(rows[a : a + 500])
    rec.close(info)
    return out


def port_energy(side: str, held: np.ndarray) -> tuple[float, np.ndarray]:
    """(the pooled minimum, each port's minimum) of the energy absorbed since tick 0, with
    `held[k]` the torque over step k (q[k] -> q[k + 1])."""
    dq = RATES[side] * T
    step = (np.array(DAMPING[side]) / T) * dq * dq - held * dq
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(step, axis=0)])
    return float(np.min(np.sum(cum, axis=1))), np.min(cum, axis=0)


@pytest.mark.parametrize("path", ["streamed", "whole"])
def test_the_analysis_books_row_n_plus_one_of_the_measured_torque(path: str, tmp_path: Path) -> None:
    from haptic_teleop.analysis.stream import summarize_bag
    from haptic_teleop.analysis.taskmetrics import compute_task_summary, load_task_signals

    bag = write_bag(tmp_path / "bag", SYNTHETIC)
    with BagReader(bag) as r:
        assert r.schema == SYNTHETIC  # the measured topic names the side
    summary = summarize_bag(bag) if path == "streamed" else compute_task_summary(load_task_signals(bag))
    assert summary["slave_energy_torque_topic"] == "/slave/measured_effort"
    assert summary["master_energy_torque_topic"] == "/master/joint_states"
    k = np.arange(N - 1)[:, None]
    report_next = REPORT * (1 + (k + 1) % 2)  # row k + 1's report, held over step k
    pooled, ports = port_energy("slave", report_next)
    assert summary["slave_port_energy_min_j"] == pytest.approx(pooled, rel=1e-9, abs=1e-12)
    assert list(summary["slave_joint_energy_min_j"].values()) == pytest.approx(ports.tolist(), rel=1e-9, abs=1e-12)
    for wrong in (REPORT * (1 + k % 2), np.broadcast_to(COMMAND["slave"], (N - 1, 3))):  # row k's, the command
        assert abs(port_energy("slave", wrong)[0] - pooled) > 1e-6
    m_pooled, _ = port_energy("master", np.broadcast_to(COMMAND["master"], (N - 1, 3)))
    assert summary["master_port_energy_min_j"] == pytest.approx(m_pooled, rel=1e-9, abs=1e-12)


def test_without_a_measured_topic_the_analysis_books_the_joint_states_effort(tmp_path: Path) -> None:
    from haptic_teleop.analysis.stream import summarize_bag

    plain = TickSchema(JOINTS["master"], JOINTS["slave"], 3)
    summary = summarize_bag(write_bag(tmp_path / "bag", plain))
    assert summary["slave_energy_torque_topic"] == "/slave/joint_states"
    pooled, _ = port_energy("slave", np.broadcast_to(COMMAND["slave"], (N - 1, 3)))
    assert summary["slave_port_energy_min_j"] == pytest.approx(pooled, rel=1e-9, abs=1e-12)
