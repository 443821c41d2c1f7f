"""Safety guards of a hardware arm side (core/safety.py): start-pose check and ramp-in, joint-limit
guard, stale reads; and a closed loop on the Dynamixel arm's MuJoCo model with guard and bound."""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.core.safety import (
    SafetyGuard,
    SafetyParams,
    StartPoseError,
    check_start_pose,
    ramp_gain,
)
from haptic_teleop.errors import PlantError

T = 0.001
NAMES = ("base_yaw", "shoulder", "elbow")
LOW = (-3.14159, -1.5, -2.4)
HIGH = (3.14159, 1.9, 2.4)


def _params(**kw):
    base = dict(joint_names=NAMES, period_s=T, limit_low_rad=LOW, limit_high_rad=HIGH)
    base.update(kw)
    return SafetyParams(**base)


def _started(q0=(0.0, 0.6, -1.2), **kw):
    g = SafetyGuard(_params(**kw))
    g.start(0.0, np.array(q0), q0)
    return g


# ------------------------------------------------------------------------------------- start


def test_start_beyond_the_tolerance_is_refused_naming_each_distance_in_rad_and_deg():
    with pytest.raises(StartPoseError) as info:
        check_start_pose([0.02, 0.95, -1.2], [0.0, 0.6, -1.2], [0.1] * 3, NAMES)
    msg = str(info.value)
    assert isinstance(info.value, PlantError) and "\n" not in msg
    # the far joint: 0.35 rad = 20.1 deg, named with the tolerance and the fix
    assert "shoulder +0.350 rad (+20.1 deg) > 0.1 rad" in msg
    assert "base_yaw +0.020 rad (+1.1 deg)" in msg and "elbow +0.000 rad" in msg
    assert "Move the arm to the start pose" in msg and "start_tolerance_rad" in msg


def test_start_within_the_tolerance_passes_and_the_guard_refuses_through_start():
    check_start_pose([0.05, 0.55, -1.25], [0.0, 0.6, -1.2], [0.1] * 3, NAMES)
    g = SafetyGuard(_params(start_tolerance_rad=(0.1, 0.1, 0.01)))
    with pytest.raises(StartPoseError, match=r"elbow -0.050 rad \(-2.9 deg\) > 0.01 rad"):
        g.start(0.0, np.array([0.0, 0.6, -1.25]), (0.0, 0.6, -1.2))
    assert not g.started
    with pytest.raises(RuntimeError, match="before start"):
        g.step(0.0, np.zeros(3), np.ones(3))


def test_start_outside_the_range_or_not_a_number_is_refused():
    g = SafetyGuard(_params(start_tolerance_rad=(1.0, 1.0, 1.0)))
    with pytest.raises(StartPoseError, match=r"elbow.*outside its range"):
        g.start(0.0, np.array([0.0, 0.6, 2.6]), (0.0, 0.6, 2.0))
    with pytest.raises(StartPoseError, match=r"shoulder.*not a number"):
        g.start(0.0, np.array([0.0, math.nan, 0.0]), (0.0, 0.6, 0.0))


@settings(max_examples=200, deadline=None)
@given(ramp=st.floats(0.001, 5.0), ts=st.lists(st.floats(-1.0, 10.0), min_size=2, max_size=50))
def test_ramp_is_monotone_bounded_and_one_from_ramp_in_s(ramp, ts):
    ts = sorted(ts)
    gains = [ramp_gain(t, ramp) for t in ts]
    assert all(0.0 <= g <= 1.0 for g in gains)
    assert all(b >= a for a, b in itertools.pairwise(gains))
    assert ramp_gain(ramp, ramp) == 1.0 and ramp_gain(0.0, ramp) == 0.0
    assert all(g == 1.0 for t, g in zip(ts, gains, strict=True) if t >= ramp)
    assert all(g < 1.0 for t, g in zip(ts, gains, strict=True) if t < ramp)


def test_ramp_is_continuous_with_no_step_larger_than_its_slope_allows():
    ramp = 0.5
    ts = np.arange(0, 600) * T
    gains = np.array([ramp_gain(t, ramp) for t in ts])
    # the raised cosine's largest slope is pi / (2 ramp): per period at most that times T
    assert np.max(np.diff(gains)) <= math.pi / (2 * ramp) * T * (1 + 1e-9)
    assert gains[0] == 0.0 and gains[500] == 1.0 and np.all(gains[500:] == 1.0)


def test_guard_ramps_the_torque_in_from_zero_over_ramp_in_s():
    g = _started(ramp_in_s=0.2)
    tau = np.array([1.0, -2.0, 0.5])
    outs = [g.step(k * T, np.array([0.0, 0.6, -1.2]), tau)[0].copy() for k in range(300)]
    assert np.all(outs[0] == 0.0)
    mags = [float(np.abs(o).sum()) for o in outs]
    assert all(b >= a for a, b in itertools.pairwise(mags))
    assert np.array_equal(outs[200], tau) and np.array_equal(outs[299], tau)
    assert np.max(np.abs(np.diff(np.array(outs), axis=0))) < 0.02  # never a jump (2 N m * pi/0.4 * 1 ms = 0.016)


# ------------------------------------------------------------------------------------- limits

joint_q = st.floats(-3.5, 3.5)
joint_tau = st.floats(-20.0, 20.0)


@settings(max_examples=300, deadline=None)
@given(
    q=st.lists(joint_q, min_size=3, max_size=3),
    tau=st.lists(joint_tau, min_size=3, max_size=3),
    t=st.floats(0.0, 2.0),
    stale=st.booleans(),
)
def test_guard_never_increases_any_joints_torque_nor_flips_its_sign(q, tau, t, stale):
    g = _started(ramp_in_s=0.5, overshoot_tolerance_rad=10.0, max_stale_s=100.0)
    out, fault = g.step(t, np.array(q), np.array(tau), stale)
    assert fault is None
    tau = np.array(tau)
    assert np.all(np.abs(out) <= np.abs(tau))
    assert np.all(out * tau >= 0.0)


@settings(max_examples=300, deadline=None)
@given(
    joint=st.integers(0, 2),
    depth=st.floats(-0.05, 1.2),  # how far into the zone (in margins); > 1: past the limit
    tau=st.floats(0.01, 20.0),
    upper=st.booleans(),
)
def test_in_the_margin_zone_the_outward_torque_fades_to_zero_at_the_limit_and_inward_passes(joint, depth, tau, upper):
    margin = 0.2
    g = _started(ramp_in_s=0.0, limit_margin_rad=(margin,) * 3, overshoot_tolerance_rad=1.0)
    q = np.array([0.0, 0.6, -1.2])
    end = HIGH[joint] if upper else LOW[joint]
    inward = -1.0 if upper else 1.0
    q[joint] = end + inward * margin * (1.0 - depth)  # depth 0: the zone's edge, 1: the limit
    out_t = -inward * tau  # pushing outward
    torque = np.zeros(3)
    torque[joint] = out_t
    out, _ = g.step(0.0, q, torque)
    room = max(0.0, 1.0 - depth)
    assert abs(out[joint]) <= abs(out_t) * min(1.0, room) * (1 + 1e-9) + 1e-12
    if depth >= 1.0:
        assert out[joint] == 0.0
    torque[joint] = inward * tau  # pointing back in: passes whole
    out, _ = g.step(0.0, q, torque)
    assert out[joint] == torque[joint]


def test_past_the_limit_by_more_than_the_overshoot_is_a_latched_fault_naming_joint_position_and_limit():
    g = _started(ramp_in_s=0.0, overshoot_tolerance_rad=0.05)
    q = np.array([0.0, 0.6, 2.44])
    out, fault = g.step(0.001, q, np.ones(3))
    assert fault is None  # 0.04 past: within the tolerance, outward torque 0, the others whole
    assert out[2] == 0.0 and out[0] == 1.0
    q[2] = 2.46
    out, fault = g.step(0.002, q, np.ones(3))
    assert fault is not None and fault.kind == "limit" and fault.joint == "elbow"
    assert "joint 'elbow' at 2.460 rad" in fault.message and "limit 2.400 rad" in fault.message
    assert np.all(out == 0.0)
    q[2] = 0.0  # back inside: the fault stays
    out, again = g.step(2.0, q, np.ones(3))
    assert again is fault and np.all(out == 0.0) and g.fault is fault


def test_a_position_that_is_not_a_number_is_a_fault_and_nan_torque_gives_zero():
    g = _started(ramp_in_s=0.0)
    out, fault = g.step(0.001, np.array([0.0, 0.6, -1.2]), np.array([math.nan, 1.0, math.inf]))
    assert fault is None and out[0] == 0.0 and out[1] == 1.0 and out[2] == 0.0
    _, fault = g.step(0.002, np.array([0.0, math.nan, -1.2]), np.ones(3))
    assert fault is not None and fault.kind == "position" and fault.joint == "shoulder"


# ------------------------------------------------------------------------------------- stale


def test_stale_reads_hold_zero_torque_and_the_nth_consecutive_one_is_a_fault():
    g = _started(ramp_in_s=0.0, max_stale_reads=4, max_stale_s=1.0)
    q, tau = np.array([0.0, 0.6, -1.2]), np.array([1.0, 1.0, 1.0])
    t = 0.0
    # isolated stale reads: zero torque on each, full torque back on the next fresh read, no fault
    for pattern in ([True, False], [True, True, True, False]):
        for stale in pattern:
            t += T
            out, fault = g.step(t, q, tau, stale)
            assert fault is None
            assert np.all(out == 0.0) if stale else np.array_equal(out, tau)
    for k in range(1, 5):
        t += T
        out, fault = g.step(t, q, tau, True)
        assert np.all(out == 0.0)
        if k < 4:
            assert fault is None and g.state().stale_reads == k
    assert fault is not None and fault.kind == "stale" and "4 consecutive stale reads" in fault.message


def test_stale_for_longer_than_max_stale_s_is_a_fault_even_with_fewer_reads():
    g = _started(ramp_in_s=0.0, max_stale_reads=100, max_stale_s=0.02)
    q, tau = np.array([0.0, 0.6, -1.2]), np.ones(3)
    g.step(0.001, q, tau)
    _, fault = g.step(0.015, q, tau, True)  # a slow tick: 14 ms since the last good read
    assert fault is None
    _, fault = g.step(0.0215, q, tau, True)
    assert fault is not None and fault.kind == "stale" and "20.5 ms since the last good one" in fault.message


def test_stale_fade_fades_out_and_back_in_with_the_watchdog():
    g = _started(ramp_in_s=0.0, stale_fade_s=0.004, max_stale_reads=50, max_stale_s=1.0)
    q, tau = np.array([0.0, 0.6, -1.2]), np.ones(3)
    gains = []
    for k in range(1, 21):
        stale = 5 <= k < 12
        out, fault = g.step(k * T, q, tau, stale)
        assert fault is None
        gains.append(out[0])
    assert gains[:4] == [1.0] * 4
    assert gains[4:8] == pytest.approx([0.75, 0.5, 0.25, 0.0])  # fades out by T / fade per tick
    assert gains[8:11] == [0.0] * 3
    assert gains[11:15] == pytest.approx([0.25, 0.5, 0.75, 1.0])  # and back in


@pytest.mark.parametrize(
    "kw",
    [
        dict(limit_low_rad=(0.0, 0.0, 0.0), limit_high_rad=(1.0, 1.0, -1.0)),
        dict(limit_margin_rad=(0.1, 0.0, 0.1)),
        dict(limit_margin_rad=(0.1, 0.1, 3.0)),
        dict(start_tolerance_rad=(0.1, -0.1, 0.1)),
        dict(max_stale_reads=0),
        dict(ramp_in_s=math.nan),
        dict(period_s=0.0),
        dict(joint_names=("a", "b")),
    ],
)
def test_bad_settings_name_what_is_allowed(kw):
    with pytest.raises(ValueError, match=r"must|allowed|low < high"):
        _params(**kw)


# ------------------------------------------------------------------------------------- closed loop


def _arm_run(guarded, tau_const, ticks=3000, e0=0.5, margin=0.3, bound_on=True):
    """The touch_dynamixel_wall scene's slave (MuJoCo, gravity compensated), a constant torque through
    the guard, then the pooled energy bound with the model's damping, into the plant; the plant's
    applied torques and positions per tick."""
    from haptic_teleop.assembly.plants import build_slave_arm
    from haptic_teleop.core.eba_coupled import CoupledEnergyBound, CoupledEnergyBoundParams
    from haptic_teleop.scene.load import find_scene, load_scene

    config = load_scene(find_scene("touch_dynamixel_wall")).config
    arm = build_slave_arm(config)
    names = arm.joints
    ranges = np.array([arm.model.joint(n).range for n in names])
    period = config.scene.period_s
    bound = CoupledEnergyBound(
        CoupledEnergyBoundParams(
            period,
            tuple(arm.damping_nm_s_per_rad),
            e0,
            bound_on,
            torque_limit_nm=tuple(arm.torque_hi),
            joint_names=names,
        )
    )
    guard = SafetyGuard(
        SafetyParams(
            names,
            period,
            tuple(ranges[:, 0]),
            tuple(ranges[:, 1]),
            ramp_in_s=0.2,
            limit_margin_rad=(margin,) * 3,
        )
    )
    q, _ = arm.read()
    guard.start(0.0, q.copy(), config.slave.start_q_rad)
    qs, applied = [], []
    for k in range(ticks):
        q, _ = arm.read()
        q = q.copy()
        tau = np.asarray(tau_const, dtype=float)
        if guarded:
            tau, fault = guard.step(k * period, q, tau)
            assert fault is None, fault.message
        lo, hi = arm.torque_room()
        out = bound.step(q, tau, np.minimum(lo, 0.0), np.maximum(hi, 0.0))
        done = arm.step(out)
        bound.applied(done)
        qs.append(q)
        applied.append(done.copy())
    return np.array(qs), np.array(applied), arm.damping_nm_s_per_rad, ranges, period


def test_closed_loop_arm_driven_at_its_limit_stops_short_with_the_guard():
    """A constant -0.1 N m on the elbow drives it toward its lower end (-2.4 rad) from the scene's
    start pose (-1.2), the bound with the scene's E0 = 0.5 J (it never binds here: the stop is the
    guard's). With the guard it stops short of the end; without it, it runs into the model's joint
    limit."""
    qs, _, _, ranges, _ = _arm_run(True, [0.0, 0.0, -0.1])
    elbow_low = ranges[2, 0]
    assert qs[:, 2].min() > elbow_low + 0.02  # stopped short of the end
    assert qs[-1, 2] < -1.2 - 0.9  # and it did travel most of the way
    qs_off, _, _, _, _ = _arm_run(False, [0.0, 0.0, -0.1])
    assert qs_off[:, 2].min() < elbow_low  # unguarded: into the limit stop


@pytest.mark.parametrize("tau", [[0.0, 0.0, -0.1], [0.4, -0.6, -0.3]])
def test_closed_loop_with_the_guard_inside_stays_passive_judged_from_plant_signals(tau):
    """Guard then bound (E0 = 0.05 J: the bound binds) on the same arm: the energy margin recomputed
    from the plant's applied torques, its positions and the model's dof_damping
    (analysis/energy.py) stays >= 0; without the bound the same drive makes it negative, so the
    check can fail."""
    from haptic_teleop.analysis.energy import energy_margins

    qs, applied, damping, _, period = _arm_run(True, tau, e0=0.05)
    assert energy_margins(qs, applied, damping, period, 0.05).pooled_min_j >= -1e-12  # 0 up to rounding
    qs, applied, damping, _, period = _arm_run(True, tau, e0=0.05, bound_on=False)
    assert energy_margins(qs, applied, damping, period, 0.05).pooled_min_j < -0.005
