"""The two-condition law (joint by joint) and wave variables (a port per task axis) on a live arm
scene (docs/stabilizers_arms.md): a composed run keeps the two-port passive as the engine does,
judged from the bag's plant signals, and each side's ledger (the side's /<side>/eba column: the
joints' ledgers summed, or the wave ledger) follows the engine's (no rate or duration is asserted).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from launched import Launch

rclpy = pytest.importorskip("rclpy")

LAWS = {
    law: (f"controllers.master.eba.law={law}", f"controllers.slave.eba.law={law}") for law in ("two_condition", "wave")
}
# How close the live run's peak wall force comes to the engine's (relative). Measured 2026-12-03 on
# touch_ur5e_wall, 3 s (the same figures run after run): two_condition 15.0 N in both (ledgers within
# 1e-4 J); wave 10.67 against 9.88 N (+8 %; the slave's wave ledger within 0.007 J): the waves,
# velocity-borne and used once, feel the live loop's phase (which tick a released sample reaches the
# port) more than positions do (docs/stabilizers_arms.md). The ledgers' tick-by-tick match is a
# real-time figure, measured, not asserted (TDPA's live budget missed the engine's by 217 % once).
TOLERANCE = {"two_condition": 0.10, "wave": 0.15}
SCENE = "touch_ur5e_wall"  # (on the Dynamixel scene the law stops the slave short of its wall)
DURATION_S = 3.0
CLI = [str(Path(sys.executable).parent / "haptic-teleop")]


@pytest.mark.parametrize("law", sorted(LAWS))
def test_a_live_arm_run_keeps_the_two_port_passive_as_the_engine(tmp_path: Path, law: str) -> None:
    """Composed, 3 s, the law on both arms: exits 0; the two-port energy margin from the bag's
    plant signals stays >= 0; the slave meets the wall as in the engine's run of the same scene
    (peak wall force within TOLERANCE); each side's ledger is recorded, tick by tick, and finite.
    (Broken once each: two-condition ledgers restarted at 0 instead of their share of E0 leave the
    slave without force, the wall untouched; waves not taken from the received samples leave the
    slave still.)"""
    from haptic_teleop.record.reader import BagReader

    out = tmp_path / "run"
    sets = [a for o in LAWS[law] for a in ("--set", o)]
    launch = Launch(SCENE, "--duration", str(DURATION_S), "--record", str(out), "--no-plots", "--single-process",
                    *sets, cwd=tmp_path)  # fmt: skip
    assert launch.finish(240) == 0, launch.failure
    live = json.loads((out / "summary.json").read_text())
    assert live["all_finite"] is True
    assert live["two_port_energy_margin_min_j"] >= 0.0, live
    engine = tmp_path / "engine"
    sets = [a for o in (*LAWS[law], f"scene.duration_s={DURATION_S}") for a in ("--set", o)]
    r = subprocess.run([*CLI, "run", SCENE, *sets, "--out", str(engine), "--no-plots", "--quiet"],
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    sim = json.loads((engine / "summary.json").read_text())
    assert sim["contact_force_max_n"] > 1.0  # the scene touches the wall
    peak_tol = TOLERANCE[law]
    rel = abs(live["contact_force_max_n"] - sim["contact_force_max_n"]) / sim["contact_force_max_n"]
    assert rel <= peak_tol, (live["contact_force_max_n"], sim["contact_force_max_n"])
    with BagReader(out / "bag") as b:
        live_e = {s: np.asarray(b.read(f"/{s}/eba").values)[:, 0] for s in ("master", "slave")}
    with BagReader(engine / "bag") as b:
        sim_e = {s: np.asarray(b.read(f"/{s}/eba").values)[:, 0] for s in ("master", "slave")}
    for side in ("master", "slave"):
        a, e = live_e[side], sim_e[side]
        n = min(a.size, e.size)
        assert n > 0.9 * e.size and np.all(np.isfinite(a)), side
