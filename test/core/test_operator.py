"""Operator model: intended trajectories and the hand impedance."""

import math

import pytest

from haptic_teleop.core.operator import Operator, OperatorParams


def test_push_then_hold():
    op = Operator(OperatorParams(profile="push", start_s=1.0, speed_m_per_s=0.02, distance_m=0.04))
    assert op.intended(0.5) == (0.0, 0.0)
    assert op.intended(2.0) == pytest.approx((0.02, 0.02))
    assert op.intended(10.0) == pytest.approx((0.04, 0.0))


def test_sinusoid_and_hand_force():
    p = OperatorParams(
        profile="sinusoid",
        start_s=0.0,
        amplitude_m=0.01,
        frequency_hz=1.0,
        stiffness_n_per_m=100.0,
        damping_n_s_per_m=2.0,
    )
    op = Operator(p)
    x, v = op.intended(0.25)
    assert x == pytest.approx(0.01)
    assert v == pytest.approx(0.0, abs=1e-12)
    _, vd = op.intended(0.0)
    assert vd == pytest.approx(0.01 * 2 * math.pi)
    assert op.hand_force(0.0, [0.001], [0.0]) == pytest.approx([100.0 * -0.001 + 2.0 * vd])


def test_trace_interpolates():
    op = Operator(OperatorParams(profile="trace", trace_time_s=(0.0, 1.0, 2.0), trace_position_m=(0.0, 0.1, 0.1)))
    assert op.intended(0.5) == pytest.approx((0.05, 0.1))
    assert op.intended(5.0) == pytest.approx((0.1, 0.0))


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(profile="walk"),
        dict(profile="trace"),
        dict(profile="trace", trace_time_s=(1.0, 0.5), trace_position_m=(0, 0)),
    ],
)
def test_bad_operator(kwargs):
    with pytest.raises(ValueError):
        OperatorParams(**kwargs)
