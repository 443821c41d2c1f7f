"""Late ticks against the Dynamixel bus emulator on its realtime clock (docs/eba_many_joints.md, "Late
ticks on a real clock"): the leader arm of `dxl_leader_wall` as the master, its servos emulated in their own
process and spoken to by the unmodified dynamixel_sdk, while the engine's paced loop stalls
deliberately (HAPTIC_TELEOP_TEST_STALL: the loop sleeps before some ticks, the servos hold their
current meanwhile, as a real host that stalls).

Judged from the plant's signals: the joint positions the driver read, the port torques the servos
applied (the bag's m_q, m_tau_nm), the real time between reads (the driver's read times), and the
damping the emulated arm really has (its viscous friction: the scene's damping; its Coulomb
friction only dissipates more). The energy the port absorbed is at least
E0 + sum_k d dq_k^2 / h_k - tau_k . dq_k over the real intervals h_k.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from haptic_teleop.assembly.emulation import bus_config
from haptic_teleop.emulators.dynamixel.process import start_bus
from haptic_teleop.plants.dynamixel.registers import read_byte_each
from haptic_teleop.plants.dynamixel.tables import ADDR_TORQUE_ENABLE
from haptic_teleop.scene.load import find_scene, load_scene

ROOT = Path(__file__).resolve().parents[2]
SCENE = "dxl_leader_wall"
IDS = [11, 12, 13]


def _bus() -> Any:
    scene = load_scene(find_scene(SCENE), ["master.backend=dynamixel"], emulate=True)
    return start_bus(bus_config(scene.config, "master", "realtime"))


def _sets(port: str, max_hold_s: float, duration_s: float) -> list[str]:
    return [
        "master.backend=dynamixel",
        f"master.hardware.port={port}",
        "master.hardware.device_clock=real",
        f"master.hardware.max_hold_s={max_hold_s}",
        "master.hardware.start_tolerance_rad=1.0",
        "master.hardware.read_timeout_s=1.0",
        "master.hardware.bus_watchdog_s=0.5",  # a loaded CI run once left the servos 100 ms without a packet
        f"scene.duration_s={duration_s}",
    ]


def torque_enable(port_name: str) -> list[int]:
    """Torque Enable(64) of each servo, read through the SDK on the emulator's port."""
    return read_byte_each(port_name, IDS, ADDR_TORQUE_ENABLE, 4_000_000)


def _true_margin(engine: Any, scene: Any) -> tuple[float, float]:
    """(min over the run of the master's true reservoir, the longest interval between reads)."""
    g = engine.schema.group
    q = engine.data[:, g("m_q")]
    tau = engine.data[:, g("m_tau_nm")]
    t = np.array(engine.master.read_times_s)
    n = min(len(t), q.shape[0])  # row k: q read at t[k], tau held from then until the next read
    q, tau, t = q[:n], tau[:n], t[:n]
    d = np.array(scene.config.master.damping_nm_s_per_rad)
    dq = np.diff(q, axis=0)
    h = np.diff(t)
    absorbed = (dq * dq) @ d / h - np.einsum("ij,ij->i", tau[:-1], dq)
    e0 = scene.config.controllers.master.eba.initial_energy_j
    return float(e0 + np.minimum.accumulate(np.concatenate(([0.0], np.cumsum(absorbed))))[-1]), float(h[1:].max())


def test_stalls_within_max_hold_keep_the_leader_port_passive(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The loop stalls 25 ms before every 150th tick; max_hold_s 250 ms (the bound budgets it; ten
    times the stall, so a busy machine's own scheduling delays on top stay within it): the
    master's true margin over the real intervals stays >= 0, the run ends normally, torque off."""
    from haptic_teleop.engine.run import record_run

    monkeypatch.setenv("HAPTIC_TELEOP_TEST_STALL", "150:0.025")
    with _bus() as bus:
        scene = load_scene(find_scene(SCENE), _sets(bus.port, 0.25, 2.0))

        def on_engine(engine: Any) -> None:
            engine.master.read_times_s = []  # the driver's read times, for the real intervals

        engine, timing = record_run(
            scene, tmp_path / "bag", parallel=False, handle_sigint=False, keep=True, on_engine=on_engine
        )
        margin, longest = _true_margin(engine, scene)
        assert longest >= 0.025  # the stalls happened, and were held through
        assert timing.pacing is not None and timing.pacing["master_longest_hold_s"] >= 0.025
        assert timing.pacing["master_long_holds"] >= 5
        assert margin >= -1e-9, margin
        assert engine.master.safety.fault is None
        assert torque_enable(bus.port) == [0, 0, 0]


def test_a_stall_past_max_hold_stops_the_run_with_one_line_and_torque_off(tmp_path: Path) -> None:
    """A stall of 80 ms with max_hold_s 30 ms, after the ramp-in: the tick after it is the guard's
    hold fault: exit 1, one line naming the hold and the key, torque off on every servo."""
    with _bus() as bus:
        sets = [a for s in _sets(bus.port, 0.03, 3.0) for a in ("--set", s)]
        proc = subprocess.run(
            [sys.executable, "-m", "haptic_teleop.cli", "run", SCENE, *sets, "--out", str(tmp_path / "run"), "--quiet"],
            capture_output=True,
            text=True,
            timeout=240.0,
            env={**os.environ, "PYTHONPATH": str(ROOT), "HAPTIC_TELEOP_TEST_STALL": "1200:0.08"},
            cwd=ROOT,
        )
        assert proc.returncode == 1, proc.stderr
        lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("haptic-teleop:") and "latency" not in ln]
        assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
        assert "the torque was held" in lines[0] and "master.hardware.max_hold_s" in lines[0], lines[0]
        assert torque_enable(bus.port) == [0, 0, 0]


def test_a_max_hold_shorter_than_the_period_is_refused_naming_the_key() -> None:
    from haptic_teleop.errors import ConfigError

    with pytest.raises(ConfigError, match=r"at least the side's period") as exc:
        load_scene(find_scene(SCENE), ["master.backend=dynamixel", "master.hardware.max_hold_s=0.0005"], emulate=True)
    assert exc.value.key_path == "master.hardware.max_hold_s"
    ok = ["master.backend=dynamixel", "master.hardware.max_hold_s=0.004"]
    scene = load_scene(find_scene(SCENE), ok, emulate=True)
    assert scene.config.master.hardware.max_hold_s == 0.004
