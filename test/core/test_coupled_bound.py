"""The n-port energy bound: joints pooled into one reservoir, one scale factor on the torque vector."""

import math

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.core.eba import EnergyBound
from haptic_teleop.core.eba_coupled import (
    CoupledEnergyBound,
    CoupledEnergyBoundParams,
    coupled_demand,
    coupled_descent_cost,
    descent_cost1,
    task_demand,
)
from haptic_teleop.core.eba_state import EnergyBoundParams

T = 0.001


def _ledger(e0, d, qs, applied):
    """E0 + sum dq.T D dq / T - tau(n-1).T dq from the signals alone (what the analysis recomputes)."""
    out = [e0]
    e = e0
    for k in range(1, len(qs)):
        dq = qs[k] - qs[k - 1]
        e += float(dq @ (d * dq)) / T - float(applied[k - 1] @ dq)
        out.append(e)
    return np.array(out)


def _run(bound, rng, n, d, steps, torque_scale, adversarial_share, slew_step=None):
    """Drive `bound` with random desired torques and displacements; a share of the displacements
    is the worst case for the torque just applied, dq* = (T/2) D^-1 tau (scaled around 1)."""
    q = rng.normal(size=n)
    qs, applied = [q.copy()], []
    for _ in range(steps):
        tau_d = rng.normal(size=n) * torque_scale * 10.0 ** rng.uniform(-2, 1)
        tau = bound.step(q, tau_d).copy()
        applied.append(tau)
        if rng.random() < adversarial_share:
            dq = (T / 2.0) * tau / d * rng.uniform(0.5, 1.5)
        else:
            dq = rng.normal(size=n) * 10.0 ** rng.uniform(-6, -2)
        q = q + dq
        qs.append(q.copy())
    return qs, applied


@settings(max_examples=300, deadline=None)
@given(
    n=st.integers(1, 6),
    seed=st.integers(0, 2**32 - 1),
    e0=st.floats(0.0, 1.0),
    steps=st.integers(2, 150),
    torque_scale=st.floats(0.01, 200.0),
    adversarial_share=st.floats(0.0, 1.0),
    limits=st.booleans(),
    mode=st.sampled_from(["scale", "clip"]),
)
def test_reservoir_never_negative(n, seed, e0, steps, torque_scale, adversarial_share, limits, mode):
    """Any n, positive damping, desired torques and adversarial motion: the pooled reservoir, and the
    same ledger recomputed from the applied torques and the damping, never go below 0."""
    rng = np.random.default_rng(seed)
    d = 10.0 ** rng.uniform(-3, 1, size=n)
    lim = tuple(10.0 ** rng.uniform(-1, 2, size=n)) if limits else ()
    params = CoupledEnergyBoundParams(T, tuple(d), e0, torque_limit_nm=lim, limit_mode=mode)
    bound = CoupledEnergyBound(params)
    qs, applied = _run(bound, rng, n, d, steps, torque_scale, adversarial_share)
    ledger = _ledger(e0, d, qs, applied)
    tol = 1e-9 * max(1.0, e0)
    assert ledger.min() >= -tol
    # the bound's reservoir at its last tick (the last displacement is not accounted yet)
    assert bound.energy_j == pytest.approx(ledger[-2], abs=1e-9 * max(1.0, abs(ledger).max()))
    if lim:
        assert np.all(np.abs(np.array(applied)) <= np.array(lim))


def test_unprotected_variant_goes_negative():
    """The same drive with the bound off: adversarial motion against the held torque drains the port."""
    n = 3
    d = np.array([0.5, 0.1, 2.0])
    off = CoupledEnergyBound(CoupledEnergyBoundParams(T, tuple(d), 0.1, enabled=False))
    on = CoupledEnergyBound(CoupledEnergyBoundParams(T, tuple(d), 0.1))
    qs_off, a_off = _run(off, np.random.default_rng(1), n, d, 200, 20.0, 1.0)
    qs_on, a_on = _run(on, np.random.default_rng(1), n, d, 200, 20.0, 1.0)
    assert _ledger(0.1, d, qs_off, a_off).min() < -1.0
    assert off.energy_j < -1.0
    assert _ledger(0.1, d, qs_on, a_on).min() >= -1e-9


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(1, 6),
    seed=st.integers(0, 2**32 - 1),
    e=st.floats(0.0, 10.0),
    mode=st.sampled_from(["scale", "none"]),
)
def test_scale_keeps_the_direction(n, seed, e, mode):
    """The applied torque is lambda * desired with one lambda in [0, 1], on the bound's edge when it binds
    (with limit_mode 'scale' also when a motor limit binds)."""
    rng = np.random.default_rng(seed)
    d = 10.0 ** rng.uniform(-2, 1, size=n)
    lim = tuple(10.0 ** rng.uniform(-1, 1, size=n)) if mode == "scale" else ()
    bound = CoupledEnergyBound(CoupledEnergyBoundParams(T, tuple(d), e, torque_limit_nm=lim))
    tau_d = rng.normal(size=n) * 10.0 ** rng.uniform(-2, 2)
    out = bound.step(np.zeros(n), tau_d)
    lam = float(out @ tau_d) / float(tau_d @ tau_d)
    assert 0.0 <= lam <= 1.0
    assert out == pytest.approx(lam * tau_d, rel=1e-12, abs=1e-300)
    demand = coupled_demand(out, 4.0 * d / T)
    assert demand <= e * (1 + 1e-12) + 1e-300  # (subnormal energies round coarser)
    if lam < 1.0 - 1e-12:  # reduced: either the bound binds (demand = E) or a motor limit does
        at_limit = bool(lim) and np.any(np.abs(out) >= np.array(lim) * (1 - 1e-12))
        assert at_limit or demand == pytest.approx(e, rel=1e-9, abs=1e-300)


def test_clip_mode_clips_each_joint_then_scales():
    """'clip': each joint clipped alone (the direction turns), then one lambda on the clipped vector."""
    bound = CoupledEnergyBound(
        CoupledEnergyBoundParams(T, (1.0, 1.0), 1e-4, torque_limit_nm=(1.0, 10.0), limit_mode="clip")
    )
    out = bound.step(np.zeros(2), np.array([5.0, 5.0]))
    clipped = np.array([1.0, 5.0])
    lam = math.sqrt(1e-4 / coupled_demand(clipped, np.full(2, 4.0 / T)))
    assert out == pytest.approx(lam * clipped, rel=1e-12)
    scaled = CoupledEnergyBound(CoupledEnergyBoundParams(T, (1.0, 1.0), 100.0, torque_limit_nm=(1.0, 10.0)))
    assert scaled.step(np.zeros(2), np.array([5.0, 5.0])) == pytest.approx([1.0, 1.0])


def test_per_tick_range_leaves_room_for_gravity_compensation():
    """low/high of one tick (the motor's range minus the gravity torque added after the bound):
    the bounded torque plus gravity stays within the motor's range, direction kept."""
    lim = np.array([10.0, 10.0, 4.0])
    gravity = np.array([0.0, 7.0, -3.5])
    bound = CoupledEnergyBound(CoupledEnergyBoundParams(T, (1.0, 1.0, 1.0), 100.0, torque_limit_nm=tuple(lim)))
    tau_d = np.array([2.0, 8.0, 2.0])
    out = bound.step(np.zeros(3), tau_d, low=-lim - gravity, high=lim - gravity).copy()
    assert np.all(np.abs(out + gravity) <= lim)
    assert out == pytest.approx(tau_d * (3.0 / 8.0), rel=1e-12)  # joint 1 has 3 N m of room left


@settings(max_examples=300, deadline=None)
@given(
    steps=st.lists(st.tuples(st.floats(-1e-2, 1e-2), st.floats(-500.0, 500.0)), min_size=1, max_size=200),
    damping=st.floats(0.01, 50.0),
    e0=st.floats(0.0, 1.0),
    enabled=st.booleans(),
)
def test_one_joint_is_the_one_axis_bound_bit_for_bit(steps, damping, e0, enabled):
    """One joint: the pooled bound gives the 1-DoF EnergyBound's bits (reservoir1 / bounded1)."""
    one = EnergyBound(EnergyBoundParams(T, (damping,), e0, enabled))
    joint = CoupledEnergyBound(CoupledEnergyBoundParams(T, (damping,), e0, enabled))
    x = 0.0
    for dx, fd in steps:
        x += dx
        f1 = one.step1(x, fd)
        f2 = joint.step(np.array([x]), np.array([fd]))[0]
        assert f1 == f2
        assert one.energy_j[0] == joint.energy_j


@settings(max_examples=300, deadline=None)
@given(
    steps=st.lists(st.tuples(st.floats(-1e-2, 1e-2), st.floats(-500.0, 500.0)), min_size=1, max_size=200),
    damping=st.floats(0.01, 50.0),
    e0=st.floats(0.0, 1.0),
    limit=st.floats(0.5, 100.0),
    slew=st.floats(10.0, 1e5),
)
def test_one_joint_with_limit_and_slew_is_the_one_axis_actuator_bound(steps, damping, e0, limit, slew):
    """One joint with a torque limit and a slew limit: the bits of the 1-DoF bound that models the
    actuator's clip and slew (EnergyBoundParams force_limit_n / slew_rate_n_per_s)."""
    one = EnergyBound(EnergyBoundParams(T, (damping,), e0, force_limit_n=limit, slew_rate_n_per_s=slew))
    joint = CoupledEnergyBound(
        CoupledEnergyBoundParams(T, (damping,), e0, torque_limit_nm=(limit,), slew_nm_per_s=(slew,))
    )
    x = 0.0
    for dx, fd in steps:
        x += dx
        f1 = one.step1(x, fd)
        f2 = joint.step(np.array([x]), np.array([fd]))[0]
        assert f1 == f2
        assert one.energy_j[0] == joint.energy_j


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.sampled_from([3, 6]), n=st.integers(1, 6), e=st.floats(0.0, 5.0))
def test_task_space_form_equals_joint_form(seed, m, n, e):
    """(T/4) F.T B^-1 F with B^-1 = J D^-1 J.T is (T/4) tau.T D^-1 tau for tau = J.T F, and bounding
    F in task space by the same lambda gives the joint form's torque."""
    rng = np.random.default_rng(seed)
    d = 10.0 ** rng.uniform(-2, 1, size=n)
    jac = rng.normal(scale=0.4, size=(m, n))
    f = rng.normal(size=m) * 10.0 ** rng.uniform(-1, 2)
    bg = 4.0 * d / T
    b_inv = jac @ np.diag(1.0 / d) @ jac.T
    assert task_demand(jac, f, bg) == pytest.approx((T / 4.0) * f @ b_inv @ f, rel=1e-9)
    assert task_demand(jac, f, bg) == pytest.approx(coupled_demand(jac.T @ f, bg), rel=1e-12)
    bound = CoupledEnergyBound(CoupledEnergyBoundParams(T, tuple(d), e))
    tau = bound.step(np.zeros(n), jac.T @ f).copy()
    demand = bound.task_demand(jac, f)
    lam = 1.0 if demand <= e else math.sqrt(e / demand)
    assert tau == pytest.approx(jac.T @ (lam * f), rel=1e-9, abs=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        (dict(damping_nm_s_per_rad=(1.0, 0.0), joint_names=("shoulder", "elbow")), "joint 'elbow': damping must be"),
        (dict(damping_nm_s_per_rad=(math.nan,)), "joint 'joint 0': damping must be finite and > 0"),
        (dict(damping_nm_s_per_rad=()), "one value per joint"),
        (dict(period_s=0.0), "period_s"),
        (dict(initial_energy_j=-1.0), "initial_energy_j"),
        (dict(limit_mode="box"), "limit_mode"),
        (dict(torque_limit_nm=(1.0,)), "torque_limit_nm must have one value per joint"),
        (dict(slew_nm_per_s=(1.0, 0.0)), "joint 'joint 1': slew_nm_per_s must be > 0"),
        (dict(joint_names=("a",)), "joint_names"),
    ],
)
def test_bad_params_name_the_joint(kwargs, words):
    base = dict(period_s=T, damping_nm_s_per_rad=(1.0, 2.0))
    base.update(kwargs)
    with pytest.raises(ValueError, match=words):
        CoupledEnergyBoundParams(**base)


# --------------------------------------------------------------------------------------------
# Slew limit: the torque can change by at most S T per period.


def test_descent_cost_is_the_sum_of_the_descent_demands():
    rng = np.random.default_rng(0)
    for _ in range(2000):
        a = rng.uniform(-10, 10)
        h = rng.uniform(0.01, 3)
        if rng.random() < 0.2:
            a = h * rng.integers(0, 20)  # on the grid
        bg = rng.uniform(0.1, 10)
        brute = sum(max(abs(a) - k * h, 0.0) ** 2 for k in range(2000)) / bg
        assert descent_cost1(a, h, bg) == pytest.approx(brute, rel=1e-12, abs=1e-15)
    assert descent_cost1(3.0, math.inf, 2.0) == 4.5


def _slew_limited(tau, held, step):
    return np.minimum(np.maximum(tau, held - step), held + step)


@settings(max_examples=300, deadline=None)
@given(
    n=st.integers(1, 6),
    seed=st.integers(0, 2**32 - 1),
    e0=st.floats(0.0, 1.0),
    steps=st.integers(2, 200),
    torque_scale=st.floats(0.1, 200.0),
    adversarial_share=st.floats(0.0, 1.0),
)
def test_slew_aware_bound_never_negative(n, seed, e0, steps, torque_scale, adversarial_share):
    """With a per-joint slew limit the torque cannot drop at once; the slew-aware bound keeps the
    reserve the descent needs: the ledger from the applied torques stays >= 0 and every change
    respects the slew limit."""
    rng = np.random.default_rng(seed)
    d = 10.0 ** rng.uniform(-2, 1, size=n)
    slew = 10.0 ** rng.uniform(1, 4, size=n)  # 10 to 10^4 N m/s
    bound = CoupledEnergyBound(CoupledEnergyBoundParams(T, tuple(d), e0, slew_nm_per_s=tuple(slew)))
    qs, applied = _run(bound, rng, n, d, steps, torque_scale, adversarial_share)
    ledger = _ledger(e0, d, qs, applied)
    assert ledger.min() >= -1e-9 * max(1.0, e0)
    tau = np.array([np.zeros(n), *applied])
    assert np.all(np.abs(np.diff(tau, axis=0)) <= slew * T * (1 + 1e-12))
    # the invariant: the reservoir covers the fastest descent of the torque just applied
    assert bound.energy_j + 1e-12 >= 0.0
    assert coupled_descent_cost(bound.held, slew * T, 4.0 * d / T) <= bound.energy_j * (1 + 1e-9) + 1e-15


def test_bound_then_slew_goes_negative_slew_aware_does_not():
    """The failure of issue 10 on joints: the bound computed as if the torque could drop at once,
    the motor's slew limit after it. Push the joints so the reservoir fills and the torque climbs,
    then move against the torque: the bound asks for 0, the motor can only descend, the ledger
    (with the torque really applied) goes negative. The slew-aware bound stays >= 0."""
    n = 2
    d = np.array([0.2, 0.05])
    slew = np.array([200.0, 200.0])
    unaware = CoupledEnergyBound(CoupledEnergyBoundParams(T, tuple(d), 0.0))
    aware = CoupledEnergyBound(CoupledEnergyBoundParams(T, tuple(d), 0.0, slew_nm_per_s=tuple(slew)))
    results = []
    for bound, slewed_after in ((unaware, True), (aware, False)):
        q = np.zeros(n)
        held = np.zeros(n)
        qs, applied = [q.copy()], []
        for k in range(1500):
            tau = bound.step(q, np.array([30.0, -30.0])).copy()
            if slewed_after:  # the motor: at most S T per period from what it applied last
                tau = _slew_limited(tau, held, slew * T)
                bound.applied(tau)  # the ledger uses the applied torque (the fix's first half)
            held = tau
            applied.append(tau)
            # 1 s pushed back against the torque (reservoir fills), then 0.5 s moved with it
            dq = np.array([-1e-3, 1e-3]) if k < 1000 else (T / 2.0) * tau / d
            q = q + dq
            qs.append(q.copy())
        results.append(_ledger(0.0, d, qs, applied).min())
    assert results[0] < -0.1
    assert results[1] >= -1e-9


# --------------------------------------------------------------------------------------------
# Closed loop on MuJoCo: a 3-link arm with joint damping, torques through the bound.

ARM = """
<mujoco model="three_link">
  <option timestep="0.00025" gravity="0 0 0" integrator="Euler"/>
  <worldbody>
    <body name="l1">
      <joint name="j1" type="hinge" axis="0 0 1" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="1.0"/>
      <body name="l2" pos="0.3 0 0">
        <joint name="j2" type="hinge" axis="0 1 0" damping="0.02"/>
        <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.02" mass="0.6"/>
        <body name="l3" pos="0.25 0 0">
          <joint name="j3" type="hinge" axis="0 1 0" damping="0.005"/>
          <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.015" mass="0.2"/>
          <site name="tool" pos="0.15 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="j1" joint="j1" ctrlrange="-5 5" ctrllimited="true"/>
    <motor name="j2" joint="j2" ctrlrange="-5 5" ctrllimited="true"/>
    <motor name="j3" joint="j3" ctrlrange="-2 2" ctrllimited="true"/>
  </actuator>
</mujoco>
"""


def _closed_loop(enabled, seed, substeps=4, ticks=2000, e0=0.05):
    model = mujoco.MjModel.from_xml_string(ARM)
    data = mujoco.MjData(model)
    d = model.dof_damping.copy()  # the damping the simulator really has
    period = model.opt.timestep * substeps
    lim = tuple(model.actuator_ctrlrange[:, 1])
    bound = CoupledEnergyBound(CoupledEnergyBoundParams(period, tuple(d), e0, enabled, torque_limit_nm=lim))
    rng = np.random.default_rng(seed)
    work = dissipated = 0.0
    margin = []
    tau_d = np.zeros(3)
    for k in range(ticks):
        if k % 50 == 0:
            tau_d = rng.uniform(-6.0, 6.0, size=3)
        jitter = rng.normal(size=3) * 0.5
        data.ctrl[:] = bound.step(data.qpos.copy(), tau_d + jitter)
        for _ in range(substeps):
            q0 = data.qpos.copy()
            mujoco.mj_step(model, data)
            # the simulator's own signals: actuator force, displacement, velocity, dof_damping
            work += float(data.qfrc_actuator @ (data.qpos - q0))
            dissipated += model.opt.timestep * float(d @ (data.qvel * data.qvel))
        margin.append(e0 + dissipated - work)
    return np.array(margin), bound


def test_closed_loop_mujoco_arm_never_injects_more_than_e0_plus_dissipated():
    """2000 ticks of random desired torques on a damped 3-link arm: the work the motors did on the
    joints (qfrc_actuator . dq, from the simulator) never exceeds E0 plus what the joints' damping
    (the MjModel's dof_damping) dissipated. Without the bound it does."""
    margin, bound = _closed_loop(True, seed=5)
    assert margin.min() >= -1e-9
    assert bound.energy_j <= margin[-1] + 1e-9  # the reservoir credits at most the dissipation
    off, _ = _closed_loop(False, seed=5)
    assert off.min() < -1.0


def _closed_loop_gravity(enabled, seed, substeps=4, ticks=2000, e0=0.5):
    """The arm in a vertical plane (gravity on), gravity compensation g(q) from the model added
    after the bound, held over the tick like the bounded torque; the bound gets the room g leaves."""
    # motors of 3 N m on joints 1 and 2: gravity takes up to 1.4 N m of joint 2's
    xml = ARM.replace('gravity="0 0 0"', 'gravity="0 0 -9.81"').replace('ctrlrange="-5 5"', 'ctrlrange="-3 3"')
    xml = xml.replace('integrator="Euler"/>', 'integrator="Euler"><flag energy="enable"/></option>')
    model = mujoco.MjModel.from_xml_string(xml)
    data, scratch = mujoco.MjData(model), mujoco.MjData(model)
    data.qpos[:] = [0.3, -0.4, 0.5]
    mujoco.mj_forward(model, data)
    d = model.dof_damping.copy()
    lim = model.actuator_ctrlrange[:, 1].copy()
    bound = CoupledEnergyBound(
        CoupledEnergyBoundParams(model.opt.timestep * substeps, tuple(d), e0, enabled, torque_limit_nm=tuple(lim))
    )
    rng = np.random.default_rng(seed)
    port_work = dissipated = unaccounted = 0.0
    kinetic, margin = [], []
    tau_d = np.zeros(3)
    for k in range(ticks):
        scratch.qpos[:] = data.qpos
        scratch.qvel[:] = 0.0
        mujoco.mj_forward(model, scratch)
        gravity = scratch.qfrc_bias.copy()  # g(q): the bias force at rest
        if k % 50 == 0:
            tau_d = rng.uniform(-6.0, 6.0, size=3)
        low, high = np.minimum(-lim - gravity, 0.0), np.maximum(lim - gravity, 0.0)
        bound.step(data.qpos.copy(), tau_d + rng.normal(size=3) * 0.5, low, high)
        data.ctrl[:] = bound.held + gravity
        for _ in range(substeps):
            q0 = data.qpos.copy()
            mujoco.mj_step(model, data)
            # the port's torque: what the motors applied minus the gravity compensation
            port_work += float((data.qfrc_actuator - gravity) @ (data.qpos - q0))
            unaccounted = max(unaccounted, float(np.abs(data.qfrc_actuator - gravity - bound.held).max()))
            dissipated += model.opt.timestep * float(d @ (data.qvel * data.qvel))
        mujoco.mj_forward(model, data)
        kinetic.append(data.energy[1])
        margin.append(e0 + dissipated - port_work)
    return np.array(kinetic), np.array(margin), unaccounted


def test_closed_loop_mujoco_arm_with_gravity_compensation_outside_the_port():
    """Gravity on, compensated after the bound, which leaves it room within the motor's range: the
    motors apply exactly the bounded torque plus g; the port's work (motors minus g) never exceeds
    E0 plus the dissipation, and the arm's kinetic energy (MuJoCo's) never exceeds E0
    (10 % allowed for the compensation held over a tick and the integrator); without the bound the
    arm gains joules."""
    kinetic, margin, unaccounted = _closed_loop_gravity(True, seed=2)
    assert unaccounted <= 1e-9  # the motors applied what the bound admitted (no clip of bound + g)
    assert margin.min() >= -1e-9
    assert kinetic.max() <= 1.1 * 0.5
    kinetic_off, margin_off, _ = _closed_loop_gravity(False, seed=2)
    assert margin_off.min() < -1.0
    assert kinetic_off.max() > 1.0


@pytest.mark.parametrize("k", [1.0, 2.5, 7.0])
def test_stretch_credits_the_damping_over_the_wall_time_the_motion_took(k):
    """A pure damper d qd = tau holding tau for k periods moves dq = tau k T / d and dissipates exactly
    tau dq (= d dq^2 / (k T)): the ledger stretched by k T books that and nets zero; unstretched it
    would credit d dq^2 / T, k times the dissipation. A stretch shorter than a period changes nothing."""
    d = np.array([0.1, 0.04])
    params = CoupledEnergyBoundParams(period_s=T, damping_nm_s_per_rad=tuple(d), initial_energy_j=1.0)
    stretched, plain = CoupledEnergyBound(params), CoupledEnergyBound(params)
    q0 = np.array([0.2, -0.3])
    tau = np.array([0.5, -0.2])
    for b in (stretched, plain):
        b.step(q0, tau)
        b.applied(tau)
    e0 = stretched.energy_j
    dq = tau * k * T / d
    stretched.stretch(k * T)
    stretched.step(q0 + dq, np.zeros(2))
    plain.step(q0 + dq, np.zeros(2))
    work = float(tau @ dq)
    assert stretched.energy_j == pytest.approx(e0, abs=1e-12)  # credit = dissipation = the port's work
    assert plain.energy_j == pytest.approx(e0 + (k - 1.0) * work, abs=1e-12)
    short, ref = CoupledEnergyBound(params), CoupledEnergyBound(params)
    for b in (short, ref):
        b.step(q0, tau)
    short.stretch(0.5 * T)
    assert short.step(q0 + dq, tau).tolist() == ref.step(q0 + dq, tau).tolist() and short.energy_j == ref.energy_j
