"""EBA behind a limited actuator (docs/eba_actuator_limits.md, "Actuator limits inside the bound"): the reservoir
accounts with the applied force, and the bound that models a clip and a slew limit keeps the port
passive for any motion; the plain bound behind a slew limit does not."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.analysis.metrics import port_energy
from haptic_teleop.core.eba import EnergyBound, actuator_bounded1, bounded1, ramp_limit1
from haptic_teleop.core.eba_state import EnergyBoundParams
from haptic_teleop.core.sensing import ActuatorLimit

T = 0.001


def ramp_cost(force: float, step: float) -> float:
    """sum_k F_k^2 over the fastest ramp down from |force|: |F|, |F| - step, ... while > 0."""
    total, f = 0.0, abs(force)
    while f > 0.0:
        total += f * f
        f -= step
    return total


@settings(max_examples=300, deadline=None)
@given(
    energy=st.floats(1e-6, 10.0),
    damping=st.floats(0.01, 50.0),
    slew=st.floats(1.0, 1e5),
)
def test_ramp_limit_is_the_largest_force_whose_ramp_down_the_reservoir_pays(energy, damping, slew):
    """ramp_limit1 solves sum_k F_k^2 = (4 b / T) E for |F|: the ramp down from it costs at most
    E (with T F_k^2 / (4 b) per period), and from a force a millionth larger more than E."""
    gain, step = 4.0 * damping / T, slew * T
    e = gain * energy
    if e / (step * step) > 1e9:  # more than about 1400 steps: the brute-force sum gets slow
        return
    limit = ramp_limit1(energy, gain, math.inf, step)
    assert ramp_cost(limit, step) <= e * (1.0 + 1e-9)
    assert ramp_cost(limit * (1.0 + 1e-6), step) > e
    assert limit <= math.sqrt(e)  # never above the plain bound (the ramp costs at least F^2)
    assert ramp_limit1(energy, gain, 0.5 * limit, step) == 0.5 * limit  # the clip caps it


def test_ramp_limit_without_limits_is_the_plain_bound():
    """Without a slew limit and a clip, the bound is `bounded1` bit for bit (bags unchanged)."""
    rng = np.random.default_rng(3)
    for energy, gain, force in zip(rng.uniform(-1, 5, 500), rng.uniform(1, 1e5, 500), rng.normal(0, 50, 500)):
        limit = ramp_limit1(energy, gain, math.inf, math.inf)
        assert actuator_bounded1(force, limit, rng.normal(), math.inf) == bounded1(force, energy, gain)
    assert ramp_limit1(0.0, 4000.0, math.inf, 0.2) == 0.0
    assert ramp_limit1(-1e-18, 4000.0, math.inf, 0.2) == 0.0


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(force_limit_n=0.0),
        dict(force_limit_n=math.inf),
        dict(slew_rate_n_per_s=-1.0),
        dict(slew_rate_n_per_s=math.nan),
    ],
)
def test_bad_actuator_limits(kwargs):
    with pytest.raises(ValueError, match="finite and > 0"):
        EnergyBoundParams(period_s=T, damping_n_s_per_m=(1.0,), **kwargs)


def _drive(bound, actuator, xs, fds, account_applied=True):
    """One tick each: the bound's force, then the actuator's; the bound is told what was applied."""
    commanded, applied, energy = [], [], []
    for x, fd in zip(xs, fds, strict=True):
        f = bound.step([x], [fd])[0]
        a = actuator.apply([f])[0] if actuator is not None else f
        if account_applied:
            bound.applied([a])
        commanded.append(f)
        applied.append(a)
        energy.append(bound.energy_j[0])
    return np.array(commanded), np.array(applied), np.array(energy)


@settings(max_examples=300, deadline=None)
@given(
    steps=st.lists(st.tuples(st.floats(-1e-2, 1e-2), st.floats(-500.0, 500.0)), min_size=2, max_size=300),
    damping=st.floats(0.01, 50.0),
    e0=st.floats(0.0, 1.0),
    slew=st.one_of(st.none(), st.floats(1.0, 1e5)),
    clip=st.one_of(st.none(), st.floats(0.1, 100.0)),
)
def test_port_behind_a_limited_actuator_never_delivers_net_energy(steps, damping, e0, slew, clip):
    """Any motion, any desired force, an actuator that clips and slews: with the bound modelling
    both, the actuator applies exactly the bound's force, the reservoir stays >= 0, and it is the
    port's true ledger (the margin from the applied force and the positions)."""
    if slew is None and clip is None:
        clip = 10.0
    params = EnergyBoundParams(T, (damping,), e0, force_limit_n=clip, slew_rate_n_per_s=slew)
    bound = EnergyBound(params)
    actuator = ActuatorLimit(T, 1, clip, slew)
    xs = np.cumsum([dx for dx, _ in steps])
    commanded, applied, energy = _drive(bound, actuator, list(xs), [f for _, f in steps])
    assert np.array_equal(commanded, applied)  # a force the actuator applies as it is
    tol = 1e-9 * max(1.0, e0)
    margin = e0 + port_energy(xs, applied, damping, T)
    assert energy.min() >= -tol and margin.min() >= -tol
    assert np.allclose(margin, energy, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    steps=st.lists(st.tuples(st.floats(-1e-2, 1e-2), st.floats(-500.0, 500.0)), min_size=2, max_size=200),
    damping=st.floats(0.01, 50.0),
    e0=st.floats(0.0, 1.0),
    clip=st.floats(0.1, 20.0),
)
def test_reservoir_accounts_with_the_applied_force(steps, damping, e0, clip):
    """A clip the bound does not know of: the reservoir still equals the port's true ledger,
    because it accounts with what the actuator applied (`applied`), not with what it was asked."""
    bound = EnergyBound(EnergyBoundParams(T, (damping,), e0))
    xs = np.cumsum([dx for dx, _ in steps])
    _, applied, energy = _drive(bound, ActuatorLimit(T, 1, clip, None), list(xs), [f for _, f in steps])
    margin = e0 + port_energy(xs, applied, damping, T)
    assert np.allclose(margin, energy, atol=1e-9)
    assert energy.min() >= -1e-9 * max(1.0, e0)


def test_plain_bound_behind_a_slew_limit_delivers_energy():
    """The bound before the fix (blind to the slew, accounting with its own force): the port
    absorbs 20 N over 5 cm, then the motion reverses; the bound drops the force as the reservoir
    drains but the actuator can only ramp down at 200 N/s, so it keeps pushing along the motion:
    the port delivers far more than it absorbed, while the blind reservoir stays >= 0. The bound
    that models the slew keeps the true margin >= 0 on the same motion."""
    b, slew = 1.0, 200.0
    xs = [1e-3 * i for i in range(50)] + [0.049 - 1e-3 * i for i in range(1, 50)]
    fds = [-20.0] * len(xs)
    plain = EnergyBound(EnergyBoundParams(T, (b,)))
    _, applied, energy = _drive(plain, ActuatorLimit(T, 1, None, slew), xs, fds, account_applied=False)
    assert port_energy(np.array(xs), applied, b, T).min() < -0.3
    assert energy.min() >= 0.0  # the blind ledger saw nothing wrong
    fixed = EnergyBound(EnergyBoundParams(T, (b,), slew_rate_n_per_s=slew))
    _, applied, energy = _drive(fixed, ActuatorLimit(T, 1, None, slew), xs, fds)
    assert port_energy(np.array(xs), applied, b, T).min() >= -1e-12
    assert energy.min() >= -1e-12


@settings(max_examples=100, deadline=None)
@given(
    steps=st.lists(st.tuples(st.floats(-1e-2, 1e-2), st.floats(-50.0, 50.0)), min_size=1, max_size=60),
    e0=st.floats(0.0, 0.5),
    slew=st.one_of(st.none(), st.floats(1.0, 1e4)),
)
def test_limited_scalar_path_equals_the_general_path(steps, e0, slew):
    """`step1` and the n-axis path give the same bits with actuator limits too."""
    p1 = EnergyBoundParams(T, (1.5,), e0, force_limit_n=7.0, slew_rate_n_per_s=slew)
    p2 = EnergyBoundParams(T, (1.5, 3.0), e0, force_limit_n=7.0, slew_rate_n_per_s=slew)
    one, two = EnergyBound(p1), EnergyBound(p2)
    x = 0.0
    for n, (dx, fd) in enumerate(steps):
        x += dx
        f1 = one.step1(x, fd)
        f2 = two.step([x, -x], [fd, -fd])
        assert f1 == f2[0]
        assert one.energy_j[0] == two.energy_j[0]
        if n % 4 == 3:  # now and then the actuator applied less than asked
            one.applied1(0.5 * f1)
            two.applied([0.5 * f1, f2[1]])
