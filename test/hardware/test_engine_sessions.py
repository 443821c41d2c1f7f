"""Whole teleoperation sessions (the engine, `haptic-teleop run` as a subprocess) with one side on
the Dynamixel bus emulator, spoken to by the unmodified dynamixel_sdk (docs/hardware_emulate.md).

The test starts the emulator (its own process, a pseudo-terminal) from the scene
(`haptic_teleop.assembly.emulation.bus_config`: the same ids, models, signs and offsets, the arm's MJCF, true
viscous friction = the damping the scene lets EBA assume, the wall for a slave, the operator's
hand for a master, lockstep time), runs the real command line against its port, then analyses the
bag as a simulated run is analysed and reads Torque Enable(64) of every servo through the SDK: 0
after every way the run can end (normal, a servo fault, SIGTERM, SIGINT, an exception, a refused
start).
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from haptic_teleop.assembly.emulation import bus_config
from haptic_teleop.emulators.dynamixel.config import FaultConfig
from haptic_teleop.emulators.dynamixel.process import DynamixelBus, start_bus
from haptic_teleop.plants.dynamixel.registers import read_byte_each
from haptic_teleop.plants.dynamixel.tables import ADDR_TORQUE_ENABLE
from haptic_teleop.scene.load import find_scene, load_scene

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT_S = 240.0  # a safety net only (the runs take seconds)


def _scene(name: str, side: str, sets: list[str]) -> Any:
    return load_scene(find_scene(name), [f"{side}.backend=dynamixel", *sets], emulate=True)


@pytest.fixture
def emulator() -> Iterator[Any]:
    """emulator(scene, side, sets, faults=()) -> a running bus for that side; all stopped after."""
    buses: list[DynamixelBus] = []

    def start(name: str, side: str, sets: list[str], faults: tuple[FaultConfig, ...] = ()) -> DynamixelBus:
        cfg = bus_config(_scene(name, side, sets).config, side)
        bus = start_bus(dataclasses.replace(cfg, faults=faults))
        buses.append(bus)
        return bus

    yield start
    for bus in buses:
        bus.stop()


def torque_enable(bus: DynamixelBus, ids: list[int], baud_bps: int = 4_000_000) -> list[int]:
    """Torque Enable(64) of each servo, read through the SDK on the emulator's port."""
    return read_byte_each(bus.port, ids, ADDR_TORQUE_ENABLE, baud_bps)


def run_cli(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    full = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "haptic_teleop.cli", "run", *args],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        env=full,
        cwd=ROOT,
    )


def _run(name: str, side: str, bus: DynamixelBus, out: Path, *sets: str) -> subprocess.CompletedProcess[str]:
    on = (f"{side}.backend=dynamixel", f"{side}.hardware.port={bus.port}", f"{side}.hardware.device_clock=lockstep")
    # the emulated bus's replies under load: --emulate's 0.5 s (EMULATED_READ_TIMEOUT_S; a loaded CI
    # run saw 3 late replies in a row with the SDK's default); a test's own value comes later and wins
    on = (*on, f"{side}.hardware.read_timeout_s=0.5")
    flags = [a for s in (*on, *sets) for a in ("--set", s)]
    return run_cli(name, *flags, "--out", str(out), "--quiet")


SLAVE = ("touch_dynamixel_wall", "slave", [1, 2, 3])
MASTER = ("dxl_leader_wall", "master", [11, 12, 13])


@pytest.mark.parametrize("case", [SLAVE, MASTER], ids=["slave_on_servos", "master_on_servos"])
def test_a_session_with_one_side_on_the_emulator_is_recorded_analysed_and_passive(
    case: tuple[str, str, list[int]], emulator: Any, tmp_path: Path
) -> None:
    name, side, ids = case
    bus = emulator(name, side, [])
    proc = _run(name, side, bus, tmp_path / "run")
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "run"
    summary = json.loads((out / "summary.json").read_text())
    assert list((out / "plots").glob("*.png"))
    scene = load_scene(out / "scene.yaml")
    # The analysis' margins use the damping the scene lets EBA assume for the real side (the run
    # facts), which the emulated arm really has: every port passive.
    assumed = list(getattr(scene.config, side).damping_nm_s_per_rad)
    assert summary[f"{side}_joint_damping_simulator"] == assumed
    for s in ("master", "slave"):
        assert summary[f"{s}_energy_margin_simulator_min_j"] >= 0.0, (s, summary)
    # The tool reached the wall and was pushed back out of it (the slave's contact: the MuJoCo
    # wall's, or the quasi-static estimate from the servos' currents on a real slave).
    assert summary["penetration_max_m"] > 0.0
    assert summary["contact_force_max_n"] > 2.0
    timing = json.loads((out / "timing.json").read_text())
    assert timing["realtime"] is True and timing["paced_ticks"] == 4000
    assert timing["loop"] == "python"
    assert f"{side}_stale_reads" in timing
    assert torque_enable(bus, ids) == [0, 0, 0]


TDPA_ZOH = (
    "controllers.master.eba.law=tdpa",
    "controllers.slave.eba.law=tdpa",
    "controllers.master.eba.tdpa_controller=zoh",
    "controllers.slave.eba.tdpa_controller=zoh",
)


@pytest.mark.parametrize("case", [SLAVE, MASTER], ids=["slave_on_servos", "master_on_servos"])
def test_tdpa_on_a_side_on_the_emulator_keeps_the_two_port_passive_from_what_the_servos_reported(
    case: tuple[str, str, list[int]], emulator: Any, tmp_path: Path
) -> None:
    """TDPA (zoh) with one side on the emulated servos, on the wall clock (lockstep device clock):
    the side's observer books the torque the servos reported (its measured effort), its damping
    credit is stretched over each hold's real length; the two-port margin the analysis takes from
    the bag (the measured effort on the servos' side, the damping the emulated arm really has) stays
    >= 0, the run reaches the wall, and the servos end with torque off."""
    name, side, ids = case
    bus = emulator(name, side, [])
    proc = _run(name, side, bus, tmp_path / "run", *TDPA_ZOH)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary[f"{side}_energy_torque_topic"] == f"/{side}/measured_effort"
    assert summary["two_port_energy_margin_min_j"] >= 0.0, summary
    assert summary["contact_force_max_n"] > 2.0
    assert torque_enable(bus, ids) == [0, 0, 0]


# test_hard_cases_arm.py's dxl_delay_200ms_bursty_loss: 100 ms each way, 10 % Gilbert-Elliott loss,
# stiff coupling; the unprotected arms make energy there.
GE_10 = "{model: gilbert_elliott, p: 0.02, r: 0.16, one_minus_h: 0.9, one_minus_k: 0.0}"
HARD = (
    "operator.start_s=0.1", "operator.speed_m_per_s=0.1", "operator.distance_m=0.06",
    *(f"network.{d}.effects.{k}" for d in ("forward", "backward") for k in ("delay.delay_s=0.1", f"loss={GE_10}")),
    *(f"controllers.{s}.{k}" for s in ("master", "slave") for k in ("stiffness_n_per_m=3000", "damping_n_s_per_m=2")),
)  # fmt: skip


@pytest.mark.parametrize("variant", ["tdpa_zoh", "unprotected"])
def test_on_a_hard_network_tdpa_on_the_emulated_servos_is_passive_where_the_unprotected_arms_are_not(
    variant: str, emulator: Any, tmp_path: Path
) -> None:
    """The arm hard case with the slave on the emulated servos: with TDPA (zoh) the two-port margin
    from the bag (the servos' reported torque) stays >= 0; without a stabilizer it goes below 0 (the
    check can fail)."""
    name, side, ids = SLAVE
    bus = emulator(name, side, ["scene.duration_s=4.0"])
    off = ("controllers.master.eba.enabled=false", "controllers.slave.eba.enabled=false")
    sets = TDPA_ZOH if variant == "tdpa_zoh" else off
    proc = _run(name, side, bus, tmp_path / "run", "scene.duration_s=4.0", *HARD, *sets)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    margin = summary["two_port_energy_margin_min_j"]
    assert (margin >= 0.0) if variant == "tdpa_zoh" else (margin < 0.0), summary
    assert torque_enable(bus, ids) == [0, 0, 0]


def test_the_slave_contact_estimate_points_out_of_the_wall(emulator: Any, tmp_path: Path) -> None:
    """The quasi-static estimate f = -(J^T)^+ (tau_measured - g) at rest against the wall: along the
    wall's normal, and the servos hold it against the coupling's push."""
    from haptic_teleop.engine.run import record_run

    bus = emulator(*SLAVE[:2], ["scene.duration_s=2.5"])
    scene = load_scene(
        find_scene("touch_dynamixel_wall"),
        [
            "slave.backend=dynamixel",
            f"slave.hardware.port={bus.port}",
            "slave.hardware.device_clock=lockstep",
            "scene.duration_s=2.5",
        ],
    )
    engine, _ = record_run(scene, tmp_path / "bag", parallel=False, handle_sigint=False, keep=True)
    f = engine.data[-1, engine.schema.group("s_contact_n")]
    n = np.array(scene.config.slave.wall.normal)
    assert f @ n > 2.0
    assert f @ n > 0.95 * np.linalg.norm(f)
    assert engine.slave.contact_estimated
    assert torque_enable(bus, SLAVE[2]) == [0, 0, 0]


def test_the_same_scene_and_seed_give_the_same_bag_with_the_lockstep_emulator(emulator: Any, tmp_path: Path) -> None:
    bags = []
    for run in ("a", "b"):
        bus = emulator(*SLAVE[:2], [])
        # A read that times out repeats the last sample (a stale tick) and changes the run: a
        # generous read timeout keeps the emulator's replies on time under this machine's load.
        proc = _run(*SLAVE[:2], bus, tmp_path / run, "scene.duration_s=1.5", "slave.hardware.read_timeout_s=2.0")
        assert proc.returncode == 0, proc.stderr
        timing = json.loads((tmp_path / run / "timing.json").read_text())
        assert timing["slave_stale_reads"] == 0
        bags.append(_tick_topics(tmp_path / run / "bag"))
    # Every tick topic the same, value for value (the bags' bytes differ only in the scene they
    # carry: each emulator has its own pseudo-terminal, hardware.port).
    assert bags[0].keys() == bags[1].keys() and len(bags[0]) >= 8
    for topic, values in bags[0].items():
        assert values.shape[0] >= 1400, topic  # every tick (a received topic: all but the first 50 ms)
        assert np.array_equal(values, bags[1][topic], equal_nan=True), topic


def _tick_topics(bag: Path) -> dict[str, np.ndarray]:
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag) as r:
        return {t: np.column_stack((r.read(t).log_ns, r.read(t).values)) for t in r.specs() if r.has(t)}


def _bag_ticks(out: Path) -> int:
    from haptic_teleop.analysis.stream import summarize_bag

    return int(summarize_bag(out / "bag")["ticks"])


def test_a_servo_fault_mid_run_ends_the_run_with_one_line_a_readable_bag_and_torque_off(
    emulator: Any, tmp_path: Path
) -> None:
    fault = FaultConfig(servo_id=2, kind="hardware_error", bits=32, at_time_s=1.0)  # overload, 1 s in
    bus = emulator(*SLAVE[:2], [], (fault,))
    proc = _run(*SLAVE[:2], bus, tmp_path / "run")
    assert proc.returncode == 1, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("haptic-teleop:") and "latency" not in ln]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "servo 2" in lines[0] and "overload" in lines[0].lower(), lines[0]
    assert 500 < _bag_ticks(tmp_path / "run") < 1500  # the ticks before the fault, in a closed bag
    assert (tmp_path / "run" / "summary.json").exists()
    assert torque_enable(bus, SLAVE[2]) == [0, 0, 0]


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_stops_the_run_at_a_tick_writes_the_outputs_and_turns_the_torque_off(
    sig: int, code: int, emulator: Any, tmp_path: Path
) -> None:
    bus = emulator(*SLAVE[:2], [])
    out = tmp_path / "run"
    on = ("slave.backend=dynamixel", f"slave.hardware.port={bus.port}", "slave.hardware.device_clock=lockstep")
    flags = [a for s in on for a in ("--set", s)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "haptic_teleop.cli", "run", SLAVE[0], *flags, "--out", str(out), "--quiet"],
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT), "HAPTIC_TELEOP_TEST_PAUSE": "loop"},
        cwd=ROOT,
    )
    assert proc.stderr is not None
    for line in proc.stderr:  # the loop has run its first 100 ticks and waits for the signal there
        if "phase loop" in line:
            break
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=TIMEOUT_S)
    assert proc.returncode == code, err
    assert 100 <= _bag_ticks(out) < 4000
    assert (out / "summary.json").exists()
    assert json.loads((out / "timing.json").read_text())["interrupted"] is True
    assert torque_enable(bus, SLAVE[2]) == [0, 0, 0]


def test_an_exception_in_the_loop_turns_the_torque_off_and_leaves_a_readable_bag(emulator: Any, tmp_path: Path) -> None:
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.record.reader import BagReader

    bus = emulator(*SLAVE[:2], [])
    scene = load_scene(
        find_scene(SLAVE[0]),
        ["slave.backend=dynamixel", f"slave.hardware.port={bus.port}", "slave.hardware.device_clock=lockstep"],
    )

    def progress(done: int) -> None:
        if done >= 300:
            raise RuntimeError("a bug in a progress callback")

    with pytest.raises(RuntimeError, match="a bug"):
        record_run(scene, tmp_path / "bag", progress=progress, parallel=False, handle_sigint=False)
    BagReader(tmp_path / "bag")  # opens: the summary section and footer are there
    assert torque_enable(bus, SLAVE[2]) == [0, 0, 0]


def test_a_start_pose_too_far_from_the_scene_is_refused_with_the_distance_and_torque_off(
    emulator: Any, tmp_path: Path
) -> None:
    bus = emulator(*SLAVE[:2], [])  # the emulated arm stands at the scene's start_q_rad
    proc = _run(*SLAVE[:2], bus, tmp_path / "run", "slave.start_q_rad=[0.0, 0.7, -1.2]")
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "shoulder" in proc.stderr and "-0.100 rad" in proc.stderr and "start_tolerance_rad" in proc.stderr
    assert torque_enable(bus, SLAVE[2]) == [0, 0, 0]


def test_run_emulate_starts_the_emulator_from_the_scene(tmp_path: Path) -> None:
    proc = run_cli(
        "dxl_leader_wall",
        "--set",
        "master.backend=dynamixel",
        "--set",
        "scene.duration_s=0.5",
        "--emulate",
        "--out",
        str(tmp_path / "run"),
        "--quiet",
        "--no-plots",
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "run" / "timing.json").read_text())["paced_ticks"] == 500


def test_run_emulate_without_a_side_on_servos_is_a_usage_error(tmp_path: Path) -> None:
    proc = run_cli("touch_dynamixel_wall", "--emulate", "--out", str(tmp_path / "run"), "--quiet")
    assert proc.returncode == 2
    assert "no side is on hardware --emulate serves" in proc.stderr and "Traceback" not in proc.stderr
    assert "slave.backend=ur" in proc.stderr  # what is allowed names both backends
    assert not (tmp_path / "run").exists()


def test_run_emulate_serves_a_ur_slave_from_the_bundled_scene(tmp_path: Path) -> None:
    """`run touch_ur5e_wall --set slave.backend=ur --emulate`, the README's UR line: the UR emulator
    is started from the scene (its model, start pose, wall), the unmodified ur_rtde drives it in the
    scene's control mode, the run ends 0 and reports a real-time run; the emulator is gone after."""
    from haptic_teleop.emulators.ur.process import LOCK_PATH

    out = tmp_path / "run"
    proc = run_cli(
        "touch_ur5e_wall", "--set", "slave.backend=ur", "--set", "scene.duration_s=1.0", "--emulate",
        # the hold guard (tested in test_late_holds_emulated.py) budgets 0.5 s: a 210.8 ms hold stopped
        # this run once in an idle CI run
        "--set", "slave.hardware.max_hold_s=0.5", "--set", "slave.hardware.rtde_watchdog_s=0.5",
        "--out", str(out), "--quiet", "--no-plots",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    timing = json.loads((out / "timing.json").read_text())
    assert timing["realtime"] is True  # the UR emulator runs on the wall clock
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ticks"] == 1000
    scene = (out / "scene.yaml").read_text()
    assert "backend: ur" in scene and "host: 127.0.0.1" in scene  # the resolved scene names the emulator
    import fcntl

    with open(LOCK_PATH, "a") as lock:  # released: no emulator left running
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)


def test_the_ur_emulator_stands_in_for_a_slave_only() -> None:
    from haptic_teleop.assembly.emulation import ur_config
    from haptic_teleop.errors import ConfigError

    config = load_scene(find_scene("touch_ur5e_wall")).config
    assert ur_config(config, "slave").start_q_rad == tuple(config.slave.start_q_rad or ())
    with pytest.raises(ConfigError, match="stands in for a slave") as exc:
        ur_config(config, "master")
    assert exc.value.key_path == "master.backend"


@pytest.mark.parametrize("stop_at", [None, 200], ids=["last_tick", "stop_request"])
def test_the_engine_itself_turns_the_torque_off_when_the_run_ends(
    stop_at: int | None, emulator: Any, tmp_path: Path
) -> None:
    """In this process (the driver's atexit has not run): the engine stops the servos at the end of
    the run, and when a stop request (Ctrl-C, SIGTERM through interrupt.py) ends it at a tick."""
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.engine.run import record_run

    bus = emulator(*SLAVE[:2], [])
    scene = load_scene(
        find_scene(SLAVE[0]),
        [
            "slave.backend=dynamixel",
            f"slave.hardware.port={bus.port}",
            "slave.hardware.device_clock=lockstep",
            "scene.duration_s=0.5",
        ],
    )
    engines: list[Engine] = []

    def progress(done: int) -> None:
        if stop_at is not None and done >= stop_at:
            engines[0].request_stop()

    engine, _ = record_run(
        scene, tmp_path / "bag", progress=progress, parallel=False, handle_sigint=False, on_engine=engines.append
    )
    assert engine.ticks_done == (500 if stop_at is None else stop_at)
    assert torque_enable(bus, SLAVE[2]) == [0, 0, 0]


def test_a_session_with_the_slave_on_the_ur_emulator_in_direct_torque_mode(tmp_path: Path) -> None:
    """`slave.backend: ur`, control_mode torque: the UR driver's JointDriver (ur_rtde, unmodified)
    against the UR emulator's UR5e with the scene's wall; recorded, analysed, both ports passive
    with the damping the emulated arm has (ur5e.xml's), the contact from the TCP wrench; the
    control script stopped at the end."""
    from haptic_teleop.emulators.ur.config import URConfig
    from haptic_teleop.emulators.ur.config import WallConfig as URWall
    from haptic_teleop.emulators.ur.process import start_ur

    c = load_scene(find_scene("touch_ur5e_wall")).config
    w = c.slave.wall
    assert w.point_m is not None and w.normal is not None and c.slave.start_q_rad is not None
    wall = URWall(tuple(w.point_m), tuple(w.normal), w.stiffness_n_per_m, w.damping_n_s_per_m)
    # direct_torque() is in ur_rtde 1.6.5's control script from PolyScope 5.26 on
    cfg = URConfig(controller_version=(5.0, 26.0, 0.0, 0.0), start_q_rad=tuple(c.slave.start_q_rad), wall=wall)
    with start_ur(cfg) as ur:
        sets = [
            "slave.backend=ur",
            "slave.hardware.host=127.0.0.1",
            "slave.hardware.control_mode=torque",
            "slave.damping_nm_s_per_rad=[3.0, 3.0, 3.0, 0.5, 0.5, 0.5]",  # ur5e.xml's dof_damping
            "slave.hardware.max_hold_s=0.5",  # holds of tens of ms, 210 ms once in CI (docs/eba_many_joints.md)
            "slave.hardware.rtde_watchdog_s=0.5",  # the same stalls over ur_rtde's 0.1 s stop the script (docs/ur.md)
        ]
        out = tmp_path / "run"
        proc = run_cli("touch_ur5e_wall", *[a for s in sets for a in ("--set", s)], "--out", str(out), "--quiet")
        assert proc.returncode == 0, proc.stderr
        assert ur.state()["program_running"] is False
    summary = json.loads((out / "summary.json").read_text())
    for s in ("master", "slave"):
        assert summary[f"{s}_energy_margin_simulator_min_j"] >= 0.0, (s, summary)
    assert summary["slave_joint_damping_simulator"] == [3.0, 3.0, 3.0, 0.5, 0.5, 0.5]
    assert summary["penetration_max_m"] > 0.0 and summary["contact_force_max_n"] > 5.0
    # the torque the joints reported (actual_current_as_torque) is recorded beside the command and booked
    assert summary["slave_energy_torque_topic"] == "/slave/measured_effort"
    from haptic_teleop.record.reader import BagReader

    with BagReader(out / "bag") as r:
        measured = r.read("/slave/measured_effort").values
        info = json.loads(r.string("/haptic_teleop/run_info"))
    assert measured.shape[0] == summary["ticks"] and np.any(measured != 0.0)
    # Reads without a report happen only before the emulator's first torque report arrived (how many
    # depends on the machine's timing, so only their place is asserted): after it, every read is measured.
    assert 0 <= info["slave_unmeasured_torque_reads"] < summary["ticks"]
    assert info["slave_unmeasured_torque_reads_after_first_report"] == 0
    assert json.loads((out / "timing.json").read_text())["realtime"] is True


def test_a_ur_side_needs_a_control_mode_and_a_ur_master_only_direct_torque() -> None:
    from haptic_teleop.errors import ConfigError

    base = ["slave.backend=ur", "slave.hardware.host=127.0.0.1", "slave.damping_nm_s_per_rad=[3, 3, 3, 0.5, 0.5, 0.5]"]
    with pytest.raises(ConfigError, match="required for backend ur; allowed: force_mode") as exc:
        load_scene(find_scene("touch_ur5e_wall"), [*base, "slave.hardware.control_mode=null"])
    assert exc.value.key_path == "slave.hardware.control_mode"
    for mode in ("force_mode", "admittance", "torque"):  # every mode runs a slave
        load_scene(find_scene("touch_ur5e_wall"), [*base, f"slave.hardware.control_mode={mode}"])
    with pytest.raises(ConfigError, match=r"a key of backend dynamixel, and slave\.backend is ur") as exc:
        load_scene(
            find_scene("touch_ur5e_wall"), [*base, "slave.hardware.control_mode=torque", "slave.hardware.ids=[1]"]
        )


def test_a_real_clock_stretches_the_ledger_over_the_time_each_tick_took(emulator: Any, tmp_path: Path) -> None:
    """device_clock real (a real arm): the slave's ledger credits its damping over the wall time
    between reads (CoupledEnergyBound.stretch), never more than over one period, so its reservoir
    ends lower than the same run's on the emulator's lockstep clock (one period per command)."""
    from haptic_teleop.engine.run import record_run

    ends = {}
    for clock in ("lockstep", "real"):
        bus = emulator(*SLAVE[:2], [])
        sets = ["slave.backend=dynamixel", f"slave.hardware.port={bus.port}", f"slave.hardware.device_clock={clock}"]
        # this machine's holds: tens of ms, 109 ms once in CI (docs/eba_many_joints.md): the guard is not tested here
        sets.append("slave.hardware.max_hold_s=0.5")
        scene = load_scene(find_scene(SLAVE[0]), [*sets, "scene.duration_s=1.0"])
        engine, _ = record_run(scene, tmp_path / clock, parallel=False, handle_sigint=False, keep=True)
        assert engine.slave.read_interval_s >= (0.0 if clock == "real" else 0.001)
        ends[clock] = engine.data[:, engine.schema.group("s_energy_j")][-1, 0]
    assert ends["real"] < ends["lockstep"]
