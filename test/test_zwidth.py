"""The Z-width part of `haptic-teleop experiment stabilizers` (studies/replications/zwidth.py): the
status of a run from its signals, the sweep's tables measured from real bags, and its options'
one-line errors.
"""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from haptic_teleop.studies.replications import zwidth as zw

PERIOD_S = 1e-3
T_S = np.arange(3000) * PERIOD_S  # a 3 s run


def _signals() -> tuple[np.ndarray, np.ndarray]:
    """A still master (it moved only before 0.8 s) in steady contact from 0.4 s."""
    v = np.where(T_S < 0.8, 0.05, 0.0)
    contact = np.where(T_S >= 0.4, 5.0, 0.0)
    return v, contact


def test_a_run_is_active_oscillating_or_ok_from_its_signals() -> None:
    v, contact = _signals()
    still = zw.judge(T_S, v, contact, margin_j=0.5, still_from_s=0.8)
    assert still["status"] == "ok" and still["contact_breaks"] == 0
    assert still["late_start_s"] == pytest.approx(2.0 - PERIOD_S)  # the last second of the run
    assert still["velocity_rms_m_per_s"] == 0.0
    # Just below the passive tolerance: active, however still.
    assert zw.judge(T_S, v, contact, margin_j=-1e-6, still_from_s=0.8)["status"] == "active"
    assert zw.judge(T_S, v, contact, margin_j=-0.5 * zw.PASSIVE_TOLERANCE_J, still_from_s=0.8)["status"] == "ok"
    # A 5 Hz velocity oscillation of 3 mm/s amplitude (RMS 2.1 mm/s) in the last second only.
    shaking = v + np.where(T_S >= 2.0, 3e-3 * np.sin(2.0 * math.pi * 5.0 * T_S), 0.0)
    judged = zw.judge(T_S, shaking, contact, margin_j=0.5, still_from_s=0.8)
    assert judged["status"] == "oscillating"
    assert judged["velocity_rms_m_per_s"] == pytest.approx(3e-3 / math.sqrt(2.0), rel=0.01)
    # The same oscillation before the late window does not count.
    early = v + np.where((T_S >= 1.0) & (T_S < 1.9), 3e-3 * np.sin(2.0 * math.pi * 5.0 * T_S), 0.0)
    assert zw.judge(T_S, early, contact, margin_j=0.5, still_from_s=0.8)["status"] == "ok"
    # Still bouncing on the wall in the late window: the contact force falls to zero twice there.
    bouncing = np.where((T_S >= 2.45) & (T_S < 2.46) | (T_S >= 2.5) & (T_S < 2.51), 0.0, contact)
    judged = zw.judge(T_S, v, bouncing, margin_j=0.5, still_from_s=0.8)
    assert judged["contact_breaks"] == 2 and judged["status"] == "oscillating"
    # The impact's bounces, before the late window, do not count.
    impact = np.where((T_S >= 0.45) & (T_S < 0.46) | (T_S >= 0.5) & (T_S < 0.51), 0.0, contact)
    judged = zw.judge(T_S, v, impact, margin_j=0.5, still_from_s=0.8)
    assert judged["contact_breaks"] == 0 and judged["status"] == "ok"
    # A run shorter than the push: the late window is its last MIN_LATE_WINDOW_S.
    short = zw.judge(T_S[:500], v[:500], contact[:500], margin_j=0.5, still_from_s=0.8)
    assert short["late_start_s"] == pytest.approx(0.499 - zw.MIN_LATE_WINDOW_S)
    assert short["status"] == "oscillating"  # the master still moves at 50 mm/s


def _float(cell: str) -> float:
    """A CSV cell: NaN is written empty."""
    return float(cell) if cell else math.nan


def _experiment(out: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(Path(sys.executable).parent / "haptic-teleop"), "experiment", "stabilizers", "--quick", "--quiet",
         "--laws", "reservoir,tdpa_zoh", "--losses", "none", *args, "--out", str(out)],
        capture_output=True, text=True, timeout=600, cwd=out.parent,
    )  # fmt: skip


def test_the_z_width_sweep_writes_a_bag_per_wall_and_tables_measured_from_them(tmp_path: Path) -> None:
    from haptic_teleop.analysis.metrics import analyze_bag
    from haptic_teleop.studies.replications.stabilizer_runs import LAWS, felt_stiffness

    kept, discarded = tmp_path / "kept", tmp_path / "discarded"
    for out, args in ((kept, ()), (discarded, ("--discard-bags",))):
        r = _experiment(out, *args)
        assert r.returncode == 0, r.stdout + r.stderr
    runs = list(csv.DictReader((kept / "zwidth_runs.csv").open()))
    # quick: walls 1000 and 30000 N/m x 0 and 10 N s/m, 100 ms one way: one run per law and wall
    assert sorted(
        (x["law"], float(x["delay_s"]), float(x["wall_stiffness_n_per_m"]), float(x["wall_damping_n_s_per_m"]))
        for x in runs
    ) == sorted((law, 0.1, k, b) for law in ("reservoir", "tdpa_zoh") for k in (1000.0, 30000.0) for b in (0.0, 10.0))
    assert {x["status"] for x in runs} <= set(zw.STATUSES)
    for x in runs:
        bag = (
            kept / "zwidth_bags" / x["law"] / "delay_100ms"
            / f"k_{float(x['wall_stiffness_n_per_m']):g}-b_{float(x['wall_damping_n_s_per_m']):g}" / "bag"
        )  # fmt: skip
        summary, sig = analyze_bag(bag)  # every run is a readable bag, and the table is what it holds
        assert sig.scene["slave"]["wall"]["stiffness_n_per_m"] == float(x["wall_stiffness_n_per_m"])
        assert sig.scene["slave"]["wall"]["damping_n_s_per_m"] == float(x["wall_damping_n_s_per_m"])
        margin = summary["two_port_energy_margin_min_j"]
        assert float(x["two_port_margin_min_j"]) == margin
        slope = felt_stiffness(sig.master_x_m, sig.master_force_n, sig.contact_n)
        assert _float(x["felt_slope_n_per_m"]) == pytest.approx(slope, rel=1e-12, nan_ok=True)
        # The push ends at 0.2 s + 3 cm / 5 cm/s = 0.8 s, in the 1.5 s run's last second.
        assert float(x["late_window_start_s"]) == pytest.approx(0.8)
        late = sig.t_s >= 0.8
        # At rest: the master's mean force over its mean depth beyond the wall (5 mm ahead).
        depth = float(np.mean(sig.master_x_m[late])) - 0.005
        static = float(np.mean(np.abs(sig.master_force_n[late]))) / depth if depth >= 1e-4 else math.nan
        assert _float(x["felt_static_stiffness_n_per_m"]) == pytest.approx(static, rel=1e-12, nan_ok=True)
        v = np.gradient(sig.master_x_m, sig.t_s)[late]  # from the positions, not the velocity signal
        rms = float(x["late_master_velocity_rms_m_per_s"])
        assert rms == pytest.approx(math.sqrt(np.mean(v * v)), rel=0.05, abs=1e-5)
        touching = (np.abs(sig.contact_n) > zw.CONTACT_N).astype(int)
        breaks = int(np.count_nonzero((np.diff(touching) == -1) & (sig.t_s[1:] >= 0.8)))
        assert int(x["contact_breaks"]) == breaks
        expected = (
            "active"
            if margin < -1e-9
            else "oscillating"
            if rms >= 2e-3 or breaks > 0
            else "ok"
        )  # fmt: skip
        assert x["status"] == expected
    # Measured, then deleted: the same table without the bags (the runs are deterministic).
    assert (discarded / "zwidth_runs.csv").read_text() == (kept / "zwidth_runs.csv").read_text()
    assert not (discarded / "zwidth_bags").exists() and not (discarded / "bags").exists()
    text = (kept / "zwidth.md").read_text()
    assert "### One-way delay 100 ms" in text and "| 1000 / 0 | 1000 / 10 | 30000 / 0 | 30000 / 10 |" in text
    for law in ("reservoir", "tdpa_zoh"):
        ok = [_float(x["felt_static_stiffness_n_per_m"]) for x in runs if x["law"] == law and x["status"] == "ok"]
        ok = [k for k in ok if math.isfinite(k)]
        span = f"{min(ok):.3g}..{max(ok):.3g}" if ok else "none"
        assert f"| {LAWS[law][0]} | {span} | {len(ok)}/4 |" in text
    assert (kept / "zwidth.png").stat().st_size > 10_000
    # The same sweep on the arm scene (the arm laws among --laws), measured along the table's normal.
    from haptic_teleop.analysis.stream import summarize_bag
    from haptic_teleop.analysis.taskmetrics import load_task_signals

    arm = list(csv.DictReader((kept / "zwidth_arm_runs.csv").open()))
    assert sorted((x["law"], float(x["wall_stiffness_n_per_m"]), float(x["wall_damping_n_s_per_m"])) for x in arm) == (
        sorted((law, k, b) for law in ("reservoir", "tdpa_zoh") for k in (1000.0, 30000.0) for b in (0.0, 10.0))
    )
    for x in arm:
        bag = (
            kept / "zwidth_arm_bags" / x["law"] / "delay_100ms"
            / f"k_{float(x['wall_stiffness_n_per_m']):g}-b_{float(x['wall_damping_n_s_per_m']):g}" / "bag"
        )  # fmt: skip
        sig = load_task_signals(bag)
        assert sig.scene["scene"]["name"] == "touch_ur5e_wall"
        assert sig.scene["slave"]["wall"]["stiffness_n_per_m"] == float(x["wall_stiffness_n_per_m"])
        assert float(x["two_port_margin_min_j"]) == summarize_bag(bag)["two_port_energy_margin_min_j"] >= 0.0
        late = sig.t_s >= float(x["late_window_start_s"])
        n = np.array([0.0, 0.0, 1.0])  # the table's normal
        depth = float(np.mean((np.asarray(sig.scene["slave"]["wall"]["point_m"]) - sig.master_x_m[late]) @ n))
        static = float(np.mean(np.abs(sig.master_force_n[late] @ n))) / depth if depth >= 1e-4 else math.nan
        assert _float(x["felt_static_stiffness_n_per_m"]) == pytest.approx(static, rel=1e-12, nan_ok=True)
        speed = np.linalg.norm(np.gradient(sig.master_x_m, sig.t_s, axis=0), axis=1)[late]
        assert float(x["late_master_velocity_rms_m_per_s"]) == pytest.approx(math.sqrt(np.mean(speed**2)), rel=0.05)
    assert "## Z-width on touch_ur5e_wall" in (kept / "zwidth_arm.md").read_text()
    assert (kept / "zwidth_arm.png").stat().st_size > 10_000
    assert (discarded / "zwidth_arm_runs.csv").read_text() == (kept / "zwidth_arm_runs.csv").read_text()
