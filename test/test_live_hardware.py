"""Live mode with a real arm on a side: `haptic-teleop launch touch_dynamixel_wall --set
slave.backend=dynamixel`, the slave node driving the scene's three servos through the unmodified
dynamixel_sdk, the servos played by the Dynamixel bus emulator (its own process, a pseudo-terminal,
realtime time: the emulated arm follows the wall clock as a real one does), real rclpy nodes over
real DDS on localhost (conftest: own ROS_DOMAIN_ID), a real bag.

What must hold on every way the node ends: the servos' torque off (Torque Enable(64) = 0, read back
through the SDK from here after the launch), the bag closed and readable; a HardwareError is one line
and exit 1, and the rest of the launch stops cleanly; a SIGKILL leaves the servos to their Bus
Watchdog. No wall-clock assertion: the loops' figures are printed, not checked.

The emulated arm's Coulomb friction is raised (0.6, 0.6, 0.3 N m) so that it holds its start pose
with the torque off, as the high-ratio gearboxes of X-series servos do: in realtime time the arm
lives from the emulator's start, seconds before the node starts its driver, and with the model's
friction it would fall onto its joint limit and the start-up check would (rightly) refuse. More
friction only dissipates more: the energy margins, computed with the damping EBA assumes (the
emulator's true viscous friction), stay a lower bound.
"""

from __future__ import annotations

import dataclasses
import json
import signal
import sys
import time
from pathlib import Path

import launched
import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("dynamixel_sdk")

CLI = [sys.executable, "-m", "haptic_teleop.cli"]
SCENE = "touch_dynamixel_wall"
# The energy bound budgets holds of up to max_hold_s on a real clock, and a longer hold stops the side
# (docs/eba_many_joints.md, "Late ticks on a real clock"). On this shared machine the live node's holds reach tens of
# ms, and once 108 ms in a loaded CI run (the servos' Bus Watchdog, 0.1 s by default, stopped the session): both
# budget 0.5 s here (the watchdog's own trip: test_sigkill_of_the_node_process_leaves_the_servos_to_their_bus_watchdog).
MAX_HOLD = "0.5"
HARDWARE = ("--set", "slave.backend=dynamixel", "--set", f"slave.hardware.max_hold_s={MAX_HOLD}",
            "--set", f"slave.hardware.bus_watchdog_s={MAX_HOLD}")  # fmt: skip
DURATION = ("--set", "scene.duration_s=2")
JOINTS = ("base_yaw", "shoulder", "elbow")
HOLDING_FRICTION_NM = (0.6, 0.6, 0.3)
ADDR_TORQUE_ENABLE = 64  # X-series control table (ROBOTIS e-Manual)
ADDR_BUS_WATCHDOG = 98
SCENE_TIME_0 = r"operator_source\]: scene time 0 at stamp"  # the operator's, not the relays' (announced ahead)

# A margin a hair below zero is the rounding of products of near-zero velocities and forces (a live
# arm at rest: -1e-33 J seen), not energy created.
ROUNDING_J = 1e-12


def _scene(name: str = SCENE, side: str = "slave"):
    from haptic_teleop.scene.load import find_scene, load_scene

    return load_scene(find_scene(name), [f"{side}.backend=dynamixel"], emulate=True).config


def _start_emulator(name: str = SCENE, side: str = "slave", hand_delay_s: float = 0.0):
    """The side's bus emulator from the scene (haptic_teleop/assembly/emulation.py), realtime, with the holding
    friction; a leader's operator hand starts its push `hand_delay_s` later in emulator time."""
    from haptic_teleop.assembly.emulation import bus_config
    from haptic_teleop.emulators.dynamixel.process import start_bus

    cfg = bus_config(_scene(name, side), side, "realtime", source="test")
    physics = dataclasses.replace(cfg.physics, frictionloss_nm=HOLDING_FRICTION_NM)
    if physics.hand is not None:
        physics = dataclasses.replace(
            physics, hand=dataclasses.replace(physics.hand, start_s=physics.hand.start_s + hand_delay_s)
        )
    return start_bus(dataclasses.replace(cfg, physics=physics))


def _registers(port: str, address: int, tries: int = 50, name: str = SCENE, side: str = "slave") -> list[int]:
    """One byte of every servo's control table, read through the SDK (a dropped reply is retried)."""
    from haptic_teleop.plants.dynamixel.registers import read_byte_each

    hw = getattr(_scene(name, side), side).hardware
    return read_byte_each(port, hw.ids, address, hw.baud_bps, tries)


class Launch(launched.Launch):
    """The launch of the hardware scene (SCENE with HARDWARE, unless `scene` says otherwise); `finish`
    prints the loop table (reported, not asserted)."""

    def __init__(self, *args: str, cwd: Path, scene: tuple[str, ...] = (SCENE, *HARDWARE)) -> None:
        super().__init__(*scene, *args, cwd=cwd)

    def finish(self, timeout_s: float = 240.0) -> int:
        code = super().finish(timeout_s)
        print(self.loop_table())
        return code


def _margins_from_bag(bag: Path, name: str = SCENE, real: str = "slave") -> dict[str, float]:
    """Each side's pooled energy margin recomputed here from the bag's plant signals (joint positions,
    the torques the plants applied) and the damping the run recorded (analysis/energy.py).

    The simulated side is stepped once per tick, so its rows are one period apart. The `real` side
    lives in wall time: a tick the node skipped is a row the recorder filled with the previous
    sample, and the next sample's displacement took several periods. Its margin is taken over the
    rows that differ from the one before (a filled row repeats it exactly), each interval's damping
    credit d dq^2 / (k T) over the k periods it spanned (the least a damper dissipates over that time)."""
    from haptic_teleop.analysis.energy import energy_margins
    from haptic_teleop.record.reader import BagReader

    scene = _scene(name, real)
    period = scene.scene.period_s
    out = {}
    with BagReader(bag) as r:
        facts = json.loads(r.string("/haptic_teleop/run_info"))
        for side in ("master", "slave"):
            js = r.read(f"/{side}/joint_states").values
            d = np.array(facts[f"{side}_joint_damping"])
            n = d.size
            e0 = getattr(scene.controllers, side).eba.initial_energy_j
            if side != real:
                out[side] = energy_margins(js[:, :n], js[:, 2 * n : 3 * n], d, period, e0).pooled_min_j
                continue
            fresh = np.ones(len(js), dtype=bool)
            fresh[1:] = np.any(js[1:] != js[:-1], axis=1)
            rows = np.flatnonzero(fresh)
            q, tau = js[rows, :n], js[rows, 2 * n : 3 * n]
            dq = np.diff(q, axis=0)
            credit = (dq * dq) @ d / (np.diff(rows) * period)
            out[side] = e0 + min(0.0, float(np.min(np.cumsum(credit - np.sum(tau[:-1] * dq, axis=1)), initial=0.0)))
    return out


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """touch_dynamixel_wall live for 2 s of scene time, composed in one process, the slave on the
    emulated bus; the servos' Torque Enable read back after the launch ended."""
    tmp = tmp_path_factory.mktemp("hw_session")
    out = tmp / "run"
    with _start_emulator() as bus:
        launch = Launch("--set", f"slave.hardware.port={bus.port}", *DURATION, "--record", str(out), "--no-plots",
                        "--single-process", cwd=tmp)  # fmt: skip
        code = launch.finish()
        torque = _registers(bus.port, ADDR_TORQUE_ENABLE)
        counters = bus.counters()
    return code, launch, out, torque, counters


def test_live_session_with_the_slave_on_the_emulated_bus_ends_with_torque_off_and_a_readable_bag(session):
    code, launch, out, torque, counters = session
    assert code == 0, launch.failure
    assert "Traceback" not in launch.text
    assert torque == [0, 0, 0]  # Torque Enable(64) of every servo, read through the SDK
    ticks, _, _ = launch.loop_row("slave_eba")
    # the node read and wrote the bus on every tick it ran (the loop table's count, which a busy
    # machine's skipped ticks lower)
    assert ticks > 0 and counters["transactions"] >= 2 * ticks, (counters, ticks)
    assert counters["watchdog_trips"] == 0  # the node never left the servos alone with torque on
    assert (out / "bag" / "metadata.yaml").exists()
    from haptic_teleop.record.reader import BagReader

    with BagReader(out / "bag") as r:
        assert r.schema.slave_joints == JOINTS
        facts = json.loads(r.string("/haptic_teleop/run_info"))
        q = r.read("/slave/joint_states").values
        # the slave node publishes the port torque the servos reported (docs/hardware_plant.md, "Applied,
        # not commanded"), the recorder records it; the simulated master has no such topic
        assert r.schema.slave_measured and not r.has("/master/measured_effort")
        measured = r.read("/slave/measured_effort").values
    assert measured.shape == (q.shape[0], 3) and np.all(np.isfinite(measured)) and np.any(measured != 0.0)
    assert facts["slave_backend"] == "dynamixel" and facts["master_backend"] == "mujoco"
    assert facts["slave_joint_damping"] == list(_scene().slave.damping_nm_s_per_rad)  # what EBA assumes
    assert np.all(np.isfinite(q)) and np.ptp(q[:, :3], axis=0).max() > 1e-3  # the emulated arm moved


def test_live_session_on_the_emulated_bus_is_passive_on_both_ports(session):
    code, launch, out, _, _ = session
    assert code == 0, launch.failure
    summary = json.loads((out / "summary.json").read_text())
    assert summary["slave_joints"] == list(JOINTS) and summary["ticks"] > 0
    assert summary["slave_energy_torque_topic"] == "/slave/measured_effort"
    for side in ("master", "slave"):
        assert summary[f"{side}_energy_margin_simulator_min_j"] >= -ROUNDING_J, (side, summary)
    margins = _margins_from_bag(out / "bag")
    print("live margins (slave on servos):", margins)  # for the record (-s)
    assert margins["master"] >= -1e-9 and margins["slave"] >= -1e-9, margins


def test_live_tdpa_with_the_slave_on_the_emulated_bus_keeps_the_two_port_passive(tmp_path):
    """TDPA (zoh) live with the slave on the emulated servos: the slave's observer books the torque
    the servos reported and its damping credit stretches over each hold's real length
    (`CoupledTdpaBound.stretch`); the run ends 0 with torque off, and the two-port margin the
    analysis takes from the bag (the servos' measured effort) stays >= 0."""
    tdpa = [a for s in ("master", "slave") for k in ("law=tdpa", "tdpa_controller=zoh")
            for a in ("--set", f"controllers.{s}.eba.{k}")]  # fmt: skip
    out = tmp_path / "run"
    with _start_emulator() as bus:
        launch = Launch("--set", f"slave.hardware.port={bus.port}", *DURATION, *tdpa, "--record", str(out),
                        "--no-plots", "--single-process", cwd=tmp_path)  # fmt: skip
        code = launch.finish()
        torque = _registers(bus.port, ADDR_TORQUE_ENABLE)
    assert code == 0, launch.failure
    assert torque == [0, 0, 0]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["slave_energy_torque_topic"] == "/slave/measured_effort"
    assert summary["two_port_energy_margin_min_j"] >= -ROUNDING_J, summary


def test_a_hardware_error_mid_run_is_one_line_exit_1_torque_off_and_the_rest_stops_cleanly(tmp_path):
    """A servo stops answering after scene time 0 (the emulator drops its replies): the slave node
    stops its servos, says why in one line and ends with 1; the other nodes stop cleanly, the
    recorder closes the bag, which is analysed."""
    out = tmp_path / "run"
    with _start_emulator() as bus:
        launch = Launch("--set", f"slave.hardware.port={bus.port}", "--set", "scene.duration_s=30", "--record",
                        str(out), "--no-plots", "--single-process", cwd=tmp_path)  # fmt: skip
        launch.wait_for(SCENE_TIME_0, 180)
        launched.wait_for_bag_messages(out / "bag", 120)  # the run is under way, ticks on disk
        # The first servo of the chain: a FAST SYNC READ's one packet starts with its reply.
        bus.inject(servo_id=1, kind="drop_replies", count=20)
        code = launch.finish()
        torque = _registers(bus.port, ADDR_TORQUE_ENABLE)
    assert code == 1, launch.failure
    assert torque == [0, 0, 0]
    errors = [line for line in launch.lines if line.startswith("slave_eba: ")]
    assert len(errors) == 1 and "servo 1" in errors[0], launch.failure
    assert "Traceback" not in launch.text and "bad parameter" not in launch.text
    assert (out / "bag" / "metadata.yaml").exists()  # the recorder closed the bag
    summary = json.loads((out / "summary.json").read_text())
    assert 0 < summary["ticks"] < 30_000


@pytest.mark.parametrize(("signum", "exit_code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_sigint_or_sigterm_to_the_node_process_turns_the_torque_off_and_closes_the_bag(tmp_path, signum, exit_code):
    out = tmp_path / "run"
    with _start_emulator() as bus:
        launch = Launch("--set", f"slave.hardware.port={bus.port}", "--set", "scene.duration_s=30", "--record",
                        str(out), "--no-plots", "--single-process", cwd=tmp_path)  # fmt: skip
        launch.wait_for(SCENE_TIME_0, 180)
        launched.wait_for_bag_messages(out / "bag", 120)
        launch.proc.send_signal(signum)  # composed: the launcher's process is the node's
        code = launch.finish()
        torque = _registers(bus.port, ADDR_TORQUE_ENABLE)
        trips = bus.counters()["watchdog_trips"]
    assert code == exit_code, launch.failure
    assert torque == [0, 0, 0] and trips == 0
    assert "Traceback" not in launch.text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and 0 < summary["ticks"] < 30_000


def test_sigkill_of_the_node_process_leaves_the_servos_to_their_bus_watchdog(tmp_path):
    """Nothing in the process can run after SIGKILL: the servos' Bus Watchdog(98), armed by the driver,
    stops them once the host has been silent for bus_watchdog_s (the emulator applies no current
    from then on, and the register reads -1 until the next start clears it)."""
    out = tmp_path / "run"
    with _start_emulator() as bus:
        launch = Launch("--set", f"slave.hardware.port={bus.port}", "--set", "scene.duration_s=30", "--record",
                        str(out), "--no-plots", "--single-process", cwd=tmp_path)  # fmt: skip
        launch.wait_for(SCENE_TIME_0, 180)
        time.sleep(0.5)
        assert bus.counters()["watchdog_trips"] == 0
        launch.proc.kill()
        launch.finish()
        end = time.monotonic() + 30
        while bus.counters()["watchdog_trips"] < 3 and time.monotonic() < end:
            time.sleep(0.05)
        state = bus.state()
        watchdog = _registers(bus.port, ADDR_BUS_WATCHDOG)
    assert watchdog == [255, 255, 255]  # -1: tripped
    assert state["torque_nm"] == [0.0, 0.0, 0.0]


def test_live_session_with_a_dynamixel_leader_arm_as_master(tmp_path):
    """dxl_leader_wall with the leader (master) on the emulated bus: the master node drives its
    servos with the bounded force, the emulator's operator hand pushes the handle, the simulated
    follower follows. The hand's push runs on emulator time, from the emulator's start: delayed by
    4 s, about when the launch reaches scene time 0; on a slow start it may push the arm before the
    node reads it, so the start tolerance is wide here (the ramp-in still brings the torque in from
    zero). Torque off on every servo after the launch, both ports' margins >= 0 (the leader's over
    real intervals)."""
    name = "dxl_leader_wall"
    out = tmp_path / "run"
    with _start_emulator(name, "master", hand_delay_s=4.0) as bus:
        launch = Launch("--set", f"master.hardware.port={bus.port}", "--set", "scene.duration_s=4", "--record",
                        str(out), "--no-plots", "--single-process", "--set", "master.hardware.start_tolerance_rad=1.0",
                        cwd=tmp_path,
                        scene=(name, "--set", "master.backend=dynamixel", "--set",
                               f"master.hardware.max_hold_s={MAX_HOLD}", "--set",
                               f"master.hardware.bus_watchdog_s={MAX_HOLD}"))  # fmt: skip
        code = launch.finish()
        torque = _registers(bus.port, ADDR_TORQUE_ENABLE, name=name, side="master")
    assert code == 0, launch.failure
    assert "Traceback" not in launch.text
    assert torque == [0, 0, 0]
    from haptic_teleop.record.reader import BagReader

    with BagReader(out / "bag") as r:
        facts = json.loads(r.string("/haptic_teleop/run_info"))
        q = r.read("/master/joint_states").values
    assert facts["master_backend"] == "dynamixel" and facts["slave_backend"] == "mujoco"
    assert np.all(np.isfinite(q))
    summary = json.loads((out / "summary.json").read_text())
    for side in ("master", "slave"):
        assert summary[f"{side}_energy_margin_simulator_min_j"] >= -ROUNDING_J, (side, summary)
    margins = _margins_from_bag(out / "bag", name, real="master")
    print("live margins (leader on servos):", margins)  # for the record (-s)
    assert margins["master"] >= -1e-9 and margins["slave"] >= -1e-9, margins
