"""TDPA on the arm scenes (core/tdpa_coupled.py, docs/stabilizers_arms.md, "Pooled joints"): the pooled rules,
and the arm hard cases of test_hard_cases_arm.py run with TDPA on both sides, recorded to real
bags and judged from the plant signals: the two-port's energy margin (both sides' joints, the
damping the simulator really has) stays >= 0 with the "zoh" controller in every case, falls below
with the controller off where the unprotected arms fail, and the field's "velocity" controller
makes energy over the zero-order hold in the cases that say so.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from haptic_teleop.analysis.energy import energy_margins
from haptic_teleop.analysis.stream import summarize_bag
from haptic_teleop.core.eba_coupled import CoupledEnergyBoundParams
from haptic_teleop.core.tdpa import velocity_pc1
from haptic_teleop.core.tdpa_coupled import CoupledTdpaBound, joint_power, velocity_scaled
from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.engine.run import record_run
from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.load import find_scene, load_scene

sys.path.insert(0, str(Path(__file__).parent))
import test_hard_cases_arm as ha

TDPA = ("controllers.master.eba.law=tdpa", "controllers.slave.eba.law=tdpa")
ZOH = (*TDPA, "controllers.master.eba.tdpa_controller=zoh", "controllers.slave.eba.tdpa_controller=zoh")
REFLECT = tuple(f"controllers.{side}.eba.tdpa_reflection=0.5" for side in ("master", "slave"))
ADMITTANCE = ("controllers.slave.eba.tdpa_placement=admittance", "controllers.slave.eba.tdpa_drift_gain_per_s=2")
VARIANTS = {
    "zoh": ZOH,
    "zoh_reflect": (*ZOH, *REFLECT),
    "zoh_admittance": (*ZOH, *ADMITTANCE),
    "velocity": TDPA,
    "off": ZOH + ha.UNPROTECTED,
}
# Where the field's controller makes more than 0.5 J on the arms (docs/stabilizers_arms.md, "Pooled joints").
VELOCITY_FAILS = ("dxl_operator_fast", "ur5e_stiff_wall")
SIDES = ("master", "slave")

torques = st.lists(st.floats(-50.0, 50.0, allow_nan=False), min_size=3, max_size=3)
motions = st.lists(st.floats(-0.01, 0.01, allow_nan=False), min_size=3, max_size=3)


def _params(damping: tuple[float, ...] = (0.5, 1.0, 2.0), e0: float = 0.0) -> CoupledEnergyBoundParams:
    return CoupledEnergyBoundParams(period_s=0.001, damping_nm_s_per_rad=damping, initial_energy_j=e0)


# --------------------------------------------------------------------------------------------
# The rules.


@settings(max_examples=200, deadline=None)
@given(torques, motions, st.floats(0.0, 1.0))
def test_the_zoh_controller_bounds_what_any_joint_motion_over_the_hold_releases(
    tau: list[float], dq_probe: list[float], budget: float
) -> None:
    """Whatever the joints do over the next hold, the held torques release at most the budget
    beyond what the joints' damping takes: sum tau_i dq_i - (d_i/T) dq_i^2 <= W."""
    b = CoupledTdpaBound(_params(e0=budget), "zoh")
    out = b.step(np.zeros(3), np.array(tau)).copy()
    d = np.array(b.params.damping_nm_s_per_rad) / b.params.period_s
    worst_dq = out / (2.0 * d)  # the motion that maximises the release
    for dq in (worst_dq, np.array(dq_probe)):
        release = joint_power(out, dq) - float(np.sum(d * dq * dq))
        assert release <= budget * (1.0 + 1e-12) + 1e-15


@settings(max_examples=200, deadline=None)
@given(torques, motions, st.floats(-1.0, 1.0))
def test_the_velocity_controller_adds_a_damper_whose_prediction_is_the_budget(
    tau: list[float], dq: list[float], budget: float
) -> None:
    """Beyond the budget, tau + beta dq (beta < 0: a damper along the last motion) whose
    predicted release is the budget; within it (or with no motion) the torque passes."""
    out = np.zeros(3)
    lim = np.full(3, 1e15)  # a room that never binds here
    t, d = np.array(tau), np.array(dq)
    p, dd = joint_power(t, d), joint_power(d, d)
    assume(dd == 0.0 or dd > 1e-12)
    beta = velocity_scaled(out, t, budget, d, -lim, lim)
    if dd == 0.0 or p <= budget:
        assert beta == 0.0 and np.array_equal(out, t)
    else:
        assert beta < 0.0
        assert np.allclose(out, t + beta * d, rtol=1e-12, atol=1e-12)
        assert joint_power(out, d) == pytest.approx(budget, rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("dq", [2e-162, 1e-160, 1e-155])
def test_a_tiny_motion_gives_the_room_against_it_not_an_overflow(dq: float) -> None:
    """(W - P) / |dq|^2 overflows on a tiny motion: the torque is the motors' room against the
    motion, finite, never NaN (0 times inf) on a joint that did not move. (A motion whose |dq|^2
    underflows to 0, below 1e-162 rad, is no motion: the torque passes.)"""
    out = np.zeros(3)
    low, high = np.array([-5.0, -5.0, -5.0]), np.array([5.0, 5.0, 5.0])
    velocity_scaled(out, np.array([0.0, 1.0, 0.0]), -1.0, np.array([0.0, dq, 0.0]), low, high)
    assert np.array_equal(out, [0.0, -5.0, 0.0])


@given(st.floats(-20.0, 20.0, allow_nan=False), st.floats(-0.01, 0.01, allow_nan=False), st.floats(-1.0, 1.0))
def test_one_joint_runs_the_one_axis_velocity_rule_bit_for_bit(f: float, dx: float, budget: float) -> None:
    out = np.zeros(1)
    velocity_scaled(out, np.array([f]), budget, np.array([dx]), np.array([-30.0]), np.array([30.0]))
    assert out[0] == min(max(velocity_pc1(f, budget, dx, np.inf), -30.0), 30.0)


def test_the_observer_books_the_pooled_joint_power_and_the_budget_spends_what_the_remote_put_in() -> None:
    b = CoupledTdpaBound(_params(e0=0.1), "velocity")
    b.step(np.zeros(3), np.array([1.0, -2.0, 0.5]))
    b.step(np.array([0.01, 0.01, 0.0]), np.zeros(3))  # held (1, -2, 0.5) over dq: w = 0.01 - 0.02 = -0.01
    assert (b.energy_in_j, b.energy_out_j) == pytest.approx((0.01, 0.0))
    b.applied(np.array([3.0, 0.0, 0.0]))
    b.receive(0.2)
    b.receive(0.05)  # an older sample released later: the larger cumulative value stays
    b.step(np.array([0.02, 0.01, 0.0]), np.zeros(3))  # w = 3 * 0.01 = 0.03 out
    assert b.energy_out_j == pytest.approx(0.03)
    assert b.energy_j == pytest.approx(0.1 + 0.2 - 0.03)


def test_a_hold_stretched_over_several_periods_credits_the_damping_over_its_real_length() -> None:
    """A real arm's late tick: the hold the next step books took 4 periods, so the zoh credit is
    d dq^2 / (4 T) (the least the damping dissipated over that time), not d dq^2 / T; the observer's
    booking, tau . dq, is the same; the step after it is back to one period."""
    d = np.array([0.5, 1.0, 2.0])
    b = CoupledTdpaBound(_params(damping=tuple(d), e0=0.1), "zoh")
    b.step(np.zeros(3), np.zeros(3))
    dq = np.array([0.01, -0.02, 0.005])
    b.stretch(0.004)
    b.step(dq, np.zeros(3))
    assert b.credit_j == pytest.approx(float(np.sum(d / 0.001 * dq * dq)) / 4.0, rel=1e-12)
    before = b.credit_j
    b.stretch(0.0005)  # shorter than a period: T stays the conservative one
    b.step(2 * dq, np.zeros(3))
    assert b.credit_j - before == pytest.approx(float(np.sum(d / 0.001 * dq * dq)), rel=1e-12)


@pytest.mark.parametrize("controller", ["zoh", "velocity"])
def test_a_restart_starts_a_new_ledger_from_the_energy_it_is_given(controller: str) -> None:
    """`restart(e)` (a live side at scene time 0, with min(budget, E0)): every count at 0, the
    budget e, and the next step takes its q as the first (the motion before it is not booked); from
    there the ledger runs as a new bound with E0 = e would."""
    b = CoupledTdpaBound(_params(e0=0.1), controller)
    b.step(np.zeros(3), np.array([1.0, -2.0, 0.5]))
    b.receive(0.2)
    b.step(np.array([0.01, 0.01, 0.0]), np.array([0.5, 0.0, 0.0]))
    assert b.energy_in_j > 0.0 and b.remote_in_j == 0.2
    b.restart(0.05)
    assert (b.energy_in_j, b.energy_out_j, b.remote_in_j, b.credit_j, b.sent_j) == (0.0, 0.0, 0.0, 0.0, 0.0)
    assert b.energy_j == 0.05 and b.initial_energy_j == 0.05
    fresh = CoupledTdpaBound(_params(e0=0.05), controller)
    for q, tau in ((np.array([0.5, 0.2, 0.1]), np.array([3.0, 1.0, 0.0])), (np.array([0.51, 0.2, 0.1]), np.zeros(3))):
        out, want = b.step(q, tau).copy(), fresh.step(q, tau).copy()
        b.applied(out)
        fresh.applied(want)
        assert np.array_equal(out, want)
        assert (b.energy_j, b.energy_in_j, b.energy_out_j) == (fresh.energy_j, fresh.energy_in_j, fresh.energy_out_j)


# --------------------------------------------------------------------------------------------
# The scene: samples carry the energy, what cannot run is refused.


def test_each_arm_sample_carries_the_senders_pooled_input_energy_last(tmp_path: Path, monkeypatch: Any) -> None:
    from haptic_teleop.assembly.stages import ArmSideStage

    sent: dict[bool, list[tuple[float, ...]]] = {True: [], False: []}
    tick = ArmSideStage.tick

    def spy(self: ArmSideStage, n: int) -> Any:
        p = tick(self, n)
        assert p[-1] == self.side_tick.bound.sent_j == self.side_tick.bound.energy_in_j  # nothing kept
        sent[self.master].append(p)
        return p

    monkeypatch.setattr(ArmSideStage, "tick", spy)
    scene = load_scene(find_scene("touch_ur5e_wall"), ["scene.duration_s=0.8", *ha.GEOMETRY, *ZOH])
    # the Python arm loop's stage (the compiled loop's samples: test_compiled_arm.py's TDPA cases,
    # which give the same bag bit for bit)
    record_run(scene, tmp_path / "bag", parallel=False, handle_sigint=False, loop="python")
    assert len(sent[True]) == len(sent[False]) == 800
    assert {len(p) for p in sent[True]} == {7} and {len(p) for p in sent[False]} == {10}
    assert max(p[-1] for p in sent[False]) > 0.0  # the wall pushed back: energy went in


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        (("slave.slew_nm_per_s=[100, 100, 100, 100, 100, 100]", *TDPA), "slave.slew_nm_per_s"),
        ((*TDPA, ADMITTANCE[0]), "controllers.slave.eba.tdpa_placement"),  # with the velocity controller
    ],
)
def test_what_tdpa_on_arms_cannot_run_is_refused_naming_the_key(overrides: tuple[str, ...], key: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_scene(find_scene("touch_ur5e_wall"), list(overrides))
    assert key in str(err.value) and "allowed" in str(err.value)


# --------------------------------------------------------------------------------------------
# The arm hard cases, from bags.


Runs = Callable[[str, str], tuple[dict[str, Any], Engine]]


def recorded_cases(tmp_path_factory: pytest.TempPathFactory, variants: dict[str, tuple[str, ...]]) -> Runs:
    """The arm hard cases with a variant's overrides (`variants`), each recorded once to a bag:
    (its summary, the engine), by case name and variant (the other stabilizers' test modules too)."""
    cache: dict[tuple[str, str], tuple[dict[str, Any], Engine]] = {}

    def get(name: str, variant: str) -> tuple[dict[str, Any], Engine]:
        if (name, variant) not in cache:
            case = ha.CASE[name]
            overrides = [f"scene.duration_s={case.duration_s}", *ha.GEOMETRY, *case.overrides, *variants[variant]]
            bag = tmp_path_factory.mktemp(f"{name}_{variant}") / "bag"
            engine, _ = record_run(
                load_scene(find_scene(case.scene), overrides), bag, parallel=False, handle_sigint=False, keep=True
            )
            cache[(name, variant)] = (summarize_bag(bag), engine)
        return cache[(name, variant)]

    return get


def assert_passive(summary: dict[str, Any], engine: Engine) -> None:
    """A recorded arm run's two-port stayed passive, from the bag's plant signals, and the engine's
    columns give the same margin (a second method)."""
    assert summary["all_finite"]
    assert summary["two_port_energy_margin_min_j"] >= -1e-9, summary["two_port_energy_margin_min_j"]
    assert _two_port_from_columns(engine) == pytest.approx(summary["two_port_energy_margin_min_j"], abs=1e-9)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Runs:
    return recorded_cases(tmp_path_factory, VARIANTS)


def _two_port_from_columns(engine: Engine) -> float:
    """A second method: both sides' pooled ledgers from the engine's columns and the plants' damping."""
    total = 0.0
    for side, plant in zip(SIDES, (engine.master, engine.slave), strict=True):
        e0 = getattr(engine.scene.config.controllers, side).eba.initial_energy_j
        col = engine.schema.group
        m = energy_margins(
            engine.data[:, col(f"{side[0]}_q")], engine.data[:, col(f"{side[0]}_tau_nm")],
            plant.joint_damping(), engine.period_s, e0,
        )  # fmt: skip
        total = total + m.pooled_margin_j
    return float(np.min(total))


@pytest.mark.parametrize("variant", ["zoh", "zoh_reflect", "zoh_admittance"])
@pytest.mark.parametrize("name", [c.name for c in ha.CASES])
def test_tdpa_with_the_zoh_controller_keeps_the_arms_two_port_passive(runs: Any, name: str, variant: str) -> None:
    assert_passive(*runs(name, variant))


@pytest.mark.parametrize("name", ["dxl_delay_200ms_bursty_loss", "dxl_operator_fast"])
def test_the_admittance_placement_lets_the_slaves_reference_yield_where_its_controller_cuts(
    runs: Any, name: str
) -> None:
    """On the Dynamixel arm the slave's zoh controller scales its torque down in most ticks: with the
    admittance placement its task reference slips by what was cut (recovered at 2/s), so the slave
    lags the master further (position RMS error 10.7 -> 21 mm, 13.5 -> 19.8 mm) where the impedance
    placement keeps pulling it toward the received point; passive either way (above)."""
    impedance, _ = runs(name, "zoh")
    admittance, engine = runs(name, "zoh_admittance")
    assert admittance["position_rms_error_m"] > 1.3 * impedance["position_rms_error_m"], (admittance, impedance)
    assert engine.arm.slave.bound.admittance and not engine.arm.master.bound.admittance


@pytest.mark.parametrize("name", [c.name for c in ha.CASES if c.unprotected_fails])
def test_without_its_controller_the_arms_two_port_makes_energy(runs: Any, name: str) -> None:
    summary, _ = runs(name, "off")
    assert summary["two_port_energy_margin_min_j"] < ha.FAIL_J


@pytest.mark.parametrize("name", VELOCITY_FAILS)
def test_the_fields_velocity_controller_makes_energy_on_the_arms(runs: Any, name: str) -> None:
    summary, _ = runs(name, "velocity")
    assert summary["two_port_energy_margin_min_j"] < -0.5


def test_the_velocity_controllers_felt_force_is_the_task_force_of_its_applied_torque() -> None:
    """Its torque is no scaled copy of the desired one: the recorded felt force is the least-squares
    task force F of the applied torque, J (J^T F - tau) = 0 (with EBA: ratio x desired)."""
    from haptic_teleop.assembly.parts import build_arm_parts
    from haptic_teleop.assembly.side import side_ticks

    scene = load_scene(find_scene("touch_ur5e_wall"), [*TDPA, "controllers.master.eba.initial_energy_j=0.0"])
    parts = build_arm_parts(scene.config)
    tick, _ = side_ticks(parts)
    plant = parts.master.plant
    x, v = np.asarray(plant.point()[0]), np.zeros(3)
    remote = (*(x + np.array([0.0, 0.0, -0.01])).tolist(), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    tick.torque(x, v, remote)  # the first step: no motion yet, the torque passes
    tick.bound.applied(np.array(tick.bound.held))
    plant.step(np.array(tick.bound.held), None)
    x2 = np.asarray(parts.maps.to_task_x(plant.point()[0]))
    out = tick.torque(x2, v, remote)  # the motion the held torque made: the controller acts (W = 0)
    assert tick.bound.beta < 0.0
    jac = plant.jacobian(rotational=False)
    jac[:3] = tick.jac_scale @ jac[:3]
    residual = jac.T @ tick.rendered - out
    assert np.allclose(jac @ residual, 0.0, atol=1e-9 * (1.0 + np.abs(out).max()))
    assert not np.allclose(tick.rendered, tick.ratio * tick.force)
