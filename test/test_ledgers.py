"""The honest-report checks of the arms' ledgers (analysis/ledgers.py) in lockstep: an engine bag's
recorded TDPA budgets are exactly what the bag's own joint signals give (the remote energy each
tick implies is a value the other side sent, sent no later, never falling), and its EBA reservoirs
step from row to row exactly as `coupled_reservoir` books the bag's motion and torques; a column
moved by a row, as a recorder that placed it by write time did on late ticks, fails either."""

from __future__ import annotations

import numpy as np
import pytest

ZOH = (
    "controllers.master.eba.law=tdpa",
    "controllers.slave.eba.law=tdpa",
    "controllers.master.eba.tdpa_controller=zoh",
    "controllers.slave.eba.tdpa_controller=zoh",
)


def arm_gains(scene) -> dict[str, np.ndarray]:
    """Each side's d_i / T per joint, from the scene's bounds."""
    from haptic_teleop.assembly.parts import build_arm_parts

    parts = build_arm_parts(scene.config, compiled=False)
    try:
        return {s: getattr(parts, s).bound.constants().gain for s in ("master", "slave")}
    finally:
        parts.master.plant.close()
        parts.slave.plant.close()


@pytest.fixture(scope="module")
def engine_bag(tmp_path_factory):
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.scene.load import find_scene, load_scene

    scene = load_scene(find_scene("touch_ur5e_wall"), overrides=[*ZOH, "scene.duration_s=2.0"])
    out = tmp_path_factory.mktemp("ledger") / "bag"
    record_run(scene, out, parallel=False, handle_sigint=False)
    return out, arm_gains(scene)


def test_an_engine_bags_tdpa_budgets_are_what_its_signals_give(engine_bag):
    from haptic_teleop.analysis.ledgers import check_bag

    bag, gains = engine_bag
    checks = check_bag(bag, gains)
    for side, c in checks.items():
        assert c.ticks == 2000 and c.holds(1e-12), c
    # the run moves energy both ways: the check is not about zeros
    from haptic_teleop.analysis.ledgers import observed, read_signals

    signals = read_signals(bag)
    for side in ("master", "slave"):
        e_in, _, credit = observed(*signals[side][:2], gains[side])
        assert e_in[-1] > 1e-4 and credit[-1] > 1e-4, side


@pytest.mark.parametrize("side", ["master", "slave"])
def test_a_budget_a_row_late_fails_the_check(engine_bag, side):
    """Rows 1000 to 1003 of one side's budget hold row 999's value, then the column goes on (what
    a late tick's array placed by its write time looked like in a live bag): the check fails."""
    from haptic_teleop.analysis.ledgers import check_signals, read_signals

    bag, gains = engine_bag
    signals = read_signals(bag)
    q, tau, budget = signals[side]
    moved = budget.copy()
    moved[1000:1004] = budget[999]
    signals[side] = (q, tau, moved)
    checks = check_signals(signals, gains)
    assert not checks[side].holds(1e-9), checks[side]
    assert checks[side].worst_j > 1e-9
    other = "slave" if side == "master" else "master"
    assert checks[other].holds(1e-12)


@pytest.fixture(scope="module")
def reservoir_bag(tmp_path_factory):
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.scene.load import find_scene, load_scene

    scene = load_scene(find_scene("touch_ur5e_wall"), overrides=["scene.duration_s=2.0"])
    out = tmp_path_factory.mktemp("reservoir") / "bag"
    record_run(scene, out, parallel=False, handle_sigint=False)
    return out, arm_gains(scene)


def test_an_engine_bags_reservoirs_step_exactly_as_booked_and_a_late_row_does_not(reservoir_bag):
    from haptic_teleop.analysis.ledgers import read_signals, reservoir_residuals

    bag, gains = reservoir_bag
    signals = read_signals(bag)
    for side, r in reservoir_residuals(signals, gains).items():
        assert r.size == 1999 and np.all(r == 0.0), (side, np.abs(r).max())
        assert np.ptp(signals[side][2]) > 1e-3, side  # the reservoir moves
    q, tau, energy = signals["slave"]
    moved = energy.copy()
    moved[1000:1004] = energy[999]
    signals["slave"] = (q, tau, moved)
    r = reservoir_residuals(signals, gains)["slave"]
    assert np.count_nonzero(np.abs(r) > 1e-9) >= 1, np.abs(r).max()
