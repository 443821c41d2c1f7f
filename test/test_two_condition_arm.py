"""The two-condition law on the arm scenes, joint by joint (core/eba_two_condition_coupled.py,
docs/stabilizers_arms.md, "The two conditions, joint by joint"): the rule per joint is the one-axis
rule bit for bit; every joint's port, and so the side's, delivers at most its share of E0 for any
motion (from the joints' positions and applied torques with their damping); the torque stays in
the motors' room; what cannot run is refused; and the arm hard cases of test_hard_cases_arm.py, run
with the law on both sides and recorded to real bags, keep the two-port passive, judged from the
plant signals (both sides' joints, the damping the simulator really has).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.analysis.metrics import port_energy
from haptic_teleop.core.eba_coupled import CoupledEnergyBoundParams
from haptic_teleop.core.eba_state import EnergyBoundParams
from haptic_teleop.core.eba_two_condition import TwoConditionBound, two_condition_room_interval1
from haptic_teleop.core.eba_two_condition_coupled import CoupledTwoConditionBound
from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.load import find_scene, load_scene

sys.path.insert(0, str(Path(__file__).parent))
import test_hard_cases_arm as ha
from test_stabilizers_arm import Runs, assert_passive, recorded_cases

T = 0.001
TWO_CONDITION = ("controllers.master.eba.law=two_condition", "controllers.slave.eba.law=two_condition")
DAMPING = (0.5, 1.0, 2.0)
REAL_SLAVE = (
    "slave.backend=dynamixel",
    "slave.hardware.port=/dev/ttyUSB0",
    "slave.start_q_rad=[0, 0, 0]",
    "slave.damping_nm_s_per_rad=[0.1, 0.1, 0.1]",
)

# One tick of a drive on three joints: a displacement per joint (None: the worst one for the torque
# just held, dq* = tau T / (2 d), which drains that joint most) and a desired torque per joint.
joint_tick = st.tuples(st.one_of(st.none(), st.floats(-1e-2, 1e-2)), st.floats(-50.0, 50.0))
ticks = st.lists(st.lists(joint_tick, min_size=3, max_size=3), min_size=2, max_size=80)


def _params(e0: float = 0.0, limit: tuple[float, ...] = ()) -> CoupledEnergyBoundParams:
    return CoupledEnergyBoundParams(
        period_s=T, damping_nm_s_per_rad=DAMPING, initial_energy_j=e0, torque_limit_nm=limit
    )


def _drive(bound: CoupledTwoConditionBound, steps: list[list[tuple[float | None, float]]]) -> tuple[Any, Any]:
    """Run the bound over `steps`; returns (joint positions, applied torques), one row per tick."""
    d = np.array(DAMPING)
    q, qs, taus = np.zeros(3), [], []
    for row in steps:
        if qs:
            for i, (dq, _) in enumerate(row):
                q[i] += bound.held[i] * T / (2.0 * d[i]) if dq is None else dq
        tau = bound.step(q.copy(), np.array([fd for _, fd in row])).copy()
        qs.append(q.copy())
        taus.append(tau)
    return np.array(qs), np.array(taus)


@settings(max_examples=60, deadline=None)
@given(steps=ticks, e0=st.floats(0.0, 1.0), limited=st.booleans())
def test_the_sides_joints_never_deliver_more_than_e0(steps: Any, e0: float, limited: bool) -> None:
    """Any joint motions (worst-case ones among them), any desired torques, with or without the
    motors' limits: the energy the joints delivered, from their positions and applied torques with
    the damping they have, never exceeds E0 in total nor E0 / 3 on any joint."""
    bound = CoupledTwoConditionBound(_params(e0, (20.0, 5.0, 30.0) if limited else ()))
    qs, taus = _drive(bound, steps)
    tol = 1e-9 * max(1.0, e0)
    total = np.full(len(qs), e0)
    for i, d in enumerate(DAMPING):
        margin = e0 / 3 + port_energy(qs[:, i], taus[:, i], d, T)
        assert margin.min() >= -tol, i
        total = total - e0 / 3 + margin
        if limited:
            assert np.max(np.abs(taus[:, i])) <= (20.0, 5.0, 30.0)[i]
    assert total.min() >= -tol
    assert bound.energy_j == pytest.approx(float(np.sum(bound.ledgers_j)), abs=1e-15)


def test_the_check_can_fail_without_the_law() -> None:
    """Disabled (the ledgers still kept), the same drive pushes along the motion and delivers energy."""
    steps = [[(1e-4, 5.0)] * 3] * 100
    off = CoupledTwoConditionBound(CoupledEnergyBoundParams(period_s=T, damping_nm_s_per_rad=DAMPING, enabled=False))
    qs, taus = _drive(off, steps)
    assert sum(port_energy(qs[:, i], taus[:, i], d, T).min() for i, d in enumerate(DAMPING)) < -0.04
    qs, taus = _drive(CoupledTwoConditionBound(_params()), steps)
    assert all(port_energy(qs[:, i], taus[:, i], d, T).min() >= 0.0 for i, d in enumerate(DAMPING))


@settings(max_examples=100, deadline=None)
@given(steps=st.lists(joint_tick, min_size=2, max_size=60), e0=st.floats(0.0, 1.0), clip=st.floats(0.5, 100.0))
def test_one_joint_runs_the_one_axis_law_bit_for_bit(steps: Any, e0: float, clip: float) -> None:
    """A one-joint side is the one-axis two-condition bound (core/eba_two_condition.py) with the
    same clip: the same forces and ledgers, bit for bit."""
    arm = CoupledTwoConditionBound(
        CoupledEnergyBoundParams(period_s=T, damping_nm_s_per_rad=(1.5,), initial_energy_j=e0, torque_limit_nm=(clip,))
    )
    axis = TwoConditionBound(
        EnergyBoundParams(
            period_s=T, damping_n_s_per_m=(1.5,), initial_energy_j=e0, force_limit_n=clip, law="two_condition"
        )
    )
    x = 0.0
    for dq, fd in steps:
        x += arm.held[0] * T / 3.0 if dq is None else dq
        a = float(arm.step(np.array([x]), np.array([fd]))[0])
        assert a == axis.step1(x, fd)
        assert arm.ledgers_j[0] == axis.energy_j[0]


@settings(max_examples=300, deadline=None)
@given(
    st.floats(-40.0, 40.0),
    st.floats(0.0, 1.0),
    st.floats(-1e-2, 1e-2),
    st.floats(0.0, 30.0),
    st.floats(0.0, 30.0),
    st.floats(-50.0, 50.0),
)
def test_the_torque_stays_in_the_room_and_meets_both_conditions_where_they_meet_it(
    held: float, extra: float, dq: float, low: float, high: float, desired: float
) -> None:
    """Within an asymmetric room [-low, high] (the motor's range less its gravity torque): the torque
    is always in the room, and wherever the two conditions' interval meets the room it is in both.
    They always meet when the room holds the held torque f and its mirror -f (the one-axis proof,
    docs/eba_two_condition.md); a room smaller than |f| on one side can leave none
    (docs/stabilizers_arms.md, "The two conditions, joint by joint")."""
    b = CoupledTwoConditionBound(CoupledEnergyBoundParams(period_s=T, damping_nm_s_per_rad=(2.0,)))
    g, bg = 2.0 / T, 8.0 / T
    e = held * held / bg + extra  # the reserve the law keeps for the held torque, and more
    b.set_state(b.state().__class__(e, np.array([held]), np.zeros(1), True, 1.0, (e,)))
    out = float(b.step(np.array([dq]), np.array([desired]), np.array([-low]), np.array([high]))[0])
    assert -low <= out <= high
    lo, hi = two_condition_room_interval1(e, g, bg, held, dq, -low, high)
    if abs(held) <= min(low, high):  # the room holds f and its mirror -f: they meet (the one-axis proof)
        assert lo <= hi + 1e-9 * (1.0 + abs(lo))
    if lo <= hi:
        assert lo - 1e-9 <= out <= hi + 1e-9


def test_a_restart_starts_each_joints_ledger_from_its_share() -> None:
    b = CoupledTwoConditionBound(_params(e0=0.3))
    assert np.allclose(b.ledgers_j, 0.1) and b.energy_j == pytest.approx(0.3)
    b.step(np.zeros(3), np.array([1.0, -2.0, 0.5]))
    b.step(np.array([0.01, 0.01, 0.0]), np.zeros(3))
    assert not np.allclose(b.ledgers_j, 0.1)
    b.restart(0.06)
    assert np.allclose(b.ledgers_j, 0.02) and b.energy_j == pytest.approx(0.06)
    fresh = CoupledTwoConditionBound(_params(e0=0.06))
    fresh.held[:] = b.held
    for q, tau in ((np.array([0.5, 0.2, 0.1]), np.array([3.0, 1.0, 0.0])), (np.array([0.51, 0.2, 0.1]), np.zeros(3))):
        assert np.array_equal(b.step(q, tau), fresh.step(q, tau))
        assert np.array_equal(b.ledgers_j, fresh.ledgers_j)


# --------------------------------------------------------------------------------------------
# The scene: what cannot run is refused.


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        ((*REAL_SLAVE, *TWO_CONDITION), "controllers.slave.eba.law"),
        (("slave.slew_nm_per_s=[100, 100, 100]", *TWO_CONDITION), "slave.slew_nm_per_s"),
    ],
)
def test_what_the_two_condition_law_on_arms_cannot_run_is_refused_naming_the_key(
    overrides: tuple[str, ...], key: str
) -> None:
    with pytest.raises(ConfigError) as err:
        load_scene(find_scene("touch_dynamixel_wall"), list(overrides))
    assert key in str(err.value) and "allowed" in str(err.value)


# --------------------------------------------------------------------------------------------
# The arm hard cases, from bags.


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Runs:
    return recorded_cases(tmp_path_factory, {"two_condition": TWO_CONDITION})


@pytest.mark.parametrize("name", [c.name for c in ha.CASES])
def test_the_two_condition_law_keeps_the_arms_two_port_passive(runs: Any, name: str) -> None:
    summary, engine = runs(name, "two_condition")
    assert_passive(summary, engine)
    assert engine.loop_kind == "compiled"


def test_each_joint_cut_alone_turns_the_felt_force_which_is_the_applied_torques(runs: Any) -> None:
    """Where one joint's conditions bind and another's do not, the applied torque is no scaled copy
    of the desired one: the recorded felt force is the least-squares task force of the applied
    torque (not ratio x desired, as with the pooled reservoir), and it turns away from the desired force."""
    _, engine = runs("dxl_stiff_wall", "two_condition")
    col = engine.schema.group
    felt, desired = engine.data[:, col("s_force_n")], engine.data[:, col("s_force_desired_n")]
    norms = np.linalg.norm(felt, axis=1) * np.linalg.norm(desired, axis=1)
    live = norms > 1e-6
    cos = np.sum(felt * desired, axis=1)[live] / norms[live]
    assert np.min(cos) < 0.99, np.min(cos)
