"""EBA invariants: reservoir >= 0 and a passive port for any motion; the 2b/T force slope."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.analysis.metrics import port_energy
from haptic_teleop.core.controller import ControllerParams, TeleopController
from haptic_teleop.core.eba import EnergyBound
from haptic_teleop.core.eba_state import EnergyBoundParams

T = 0.001
finite = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False)


def _drive(bound: EnergyBound, xs: list[float], fds: list[float]) -> tuple[list[float], list[float]]:
    applied, energy = [], []
    for x, fd in zip(xs, fds, strict=True):
        applied.append(bound.step([x], [fd])[0])
        energy.append(bound.energy_j[0])
    return applied, energy


@settings(max_examples=300, deadline=None)
@given(
    steps=st.lists(st.tuples(st.floats(-1e-2, 1e-2), st.floats(-500.0, 500.0)), min_size=2, max_size=200),
    damping=st.floats(0.01, 50.0),
    e0=st.floats(0.0, 1.0),
)
def test_reservoir_and_port_margin_never_negative(steps, damping, e0):
    """Any displacement sequence, any desired force: the bounded port never delivers net energy."""
    b = EnergyBound(EnergyBoundParams(period_s=T, damping_n_s_per_m=(damping,), initial_energy_j=e0))
    xs = list(np.cumsum([dx for dx, _ in steps]))
    applied, energy = _drive(b, xs, [f for _, f in steps])
    tol = 1e-9 * max(1.0, e0)
    assert min(energy) >= -tol
    margin = e0 + port_energy(np.array(xs), np.array(applied), damping, T)
    assert margin.min() >= -tol
    # The controller's reservoir is exactly the margin computed from the port's signals.
    assert np.allclose(margin, energy, atol=1e-9)


def test_unprotected_port_delivers_energy():
    """The same motion with the bound off: a force pushing along the motion drains the port."""
    xs = [i * 1e-4 for i in range(100)]
    fds = [5.0] * 100
    off = EnergyBound(EnergyBoundParams(period_s=T, damping_n_s_per_m=(1.0,), enabled=False))
    on = EnergyBound(EnergyBoundParams(period_s=T, damping_n_s_per_m=(1.0,)))
    a_off, _ = _drive(off, xs, fds)
    a_on, _ = _drive(on, xs, fds)
    assert port_energy(np.array(xs), np.array(a_off), 1.0, T).min() < -0.04
    assert port_energy(np.array(xs), np.array(a_on), 1.0, T).min() >= 0.0


def test_bounded_force_grows_with_stiffness_2b_over_t():
    """Pushing into a spring far stiffer than 2b/T: the bounded force rises at (2b/T) per metre."""
    b = 2.0
    bound = EnergyBound(EnergyBoundParams(period_s=T, damping_n_s_per_m=(b,)))
    v = 0.01
    xs = [v * T * i for i in range(2000)]
    forces = [bound.step([x], [-1e6 * x])[0] for x in xs]
    slope = (forces[1500] - forces[500]) / (xs[1500] - xs[500])
    assert slope == pytest.approx(-2 * b / T, rel=0.01)
    assert bound.params.max_stiffness_n_per_m()[0] == pytest.approx(2 * b / T)


def test_soft_spring_is_not_bounded():
    """A spring softer than 2b/T, loaded from rest, passes the bound unchanged."""
    bound = EnergyBound(EnergyBoundParams(period_s=T, damping_n_s_per_m=(2.0,)))
    k = 1000.0  # < 2b/T = 4000
    for i in range(1, 500):
        x = 1e-5 * i
        f = bound.step([x], [-k * x])[0]
    assert f == pytest.approx(-k * x)


def test_bound_is_per_axis():
    params = EnergyBoundParams(period_s=T, damping_n_s_per_m=(1.0, 4.0), initial_energy_j=0.01)
    bound = EnergyBound(params)
    out = bound.step([0.0, 0.0], [100.0, 100.0])
    assert out == pytest.approx([2 * math.sqrt(1.0 * 0.01 / T), 2 * math.sqrt(4.0 * 0.01 / T)])


def test_position_law_and_saturation():
    c = TeleopController(
        ControllerParams(role="slave", stiffness_n_per_m=100.0, damping_n_s_per_m=2.0, force_limit_n=3.0),
        EnergyBoundParams(period_s=T, damping_n_s_per_m=(1.0,), enabled=False),
    )
    assert c.step([0.0], [0.0]) == [0.0]  # nothing received yet: no force
    c.set_remote((0.01, 0.5))  # master x, v
    assert c.desired_force([0.0], [0.0]) == pytest.approx([100.0 * 0.01 + 2.0 * 0.5])
    c.set_remote((1.0, 0.0))
    assert c.step([0.0], [0.0]) == [3.0]  # saturated


def test_master_laws_use_slave_position_or_force():
    bound = EnergyBoundParams(period_s=T, damping_n_s_per_m=(1.0,), enabled=False)
    pos = TeleopController(ControllerParams(role="master", stiffness_n_per_m=10.0, damping_n_s_per_m=0.0), bound)
    pos.set_remote((-4.0, 0.2, 0.0))  # slave: f_env, x, v
    assert pos.desired_force([0.5], [0.0]) == pytest.approx([10.0 * (0.2 - 0.5)])
    frc = TeleopController(ControllerParams(role="master", law="force", force_gain=0.5), bound)
    frc.set_remote((-4.0, 0.2, 0.0))
    assert frc.desired_force([0.5], [0.0]) == pytest.approx([-2.0])


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(role="x"),
        dict(role="slave", law="force"),
        dict(role="master", law="spring"),
        dict(role="master", force_limit_n=0.0),
    ],
)
def test_bad_controller_params(kwargs):
    with pytest.raises(ValueError):
        ControllerParams(**kwargs)


@pytest.mark.parametrize("kwargs", [dict(period_s=0.0), dict(damping_n_s_per_m=(0.0,)), dict(initial_energy_j=-1.0)])
def test_bad_bound_params(kwargs):
    base = dict(period_s=T, damping_n_s_per_m=(1.0,))
    base.update(kwargs)
    with pytest.raises(ValueError):
        EnergyBoundParams(**base)


@settings(max_examples=100, deadline=None)
@given(
    steps=st.lists(
        st.tuples(st.floats(-1e-2, 1e-2), st.floats(-1.0, 1.0), st.floats(-0.05, 0.05), st.floats(-50.0, 50.0)),
        min_size=1,
        max_size=60,
    ),
    role_law=st.sampled_from([("master", "position"), ("slave", "position"), ("master", "force")]),
    enabled=st.booleans(),
    e0=st.floats(0.0, 0.5),
)
def test_scalar_path_equals_the_general_path(steps, role_law, enabled, e0):
    """One axis runs `step1` (floats); two axes run the list path. Axis 0 of a two-axis controller
    fed the same data must give the same bits: force, desired force and reservoir, every tick."""
    role, law = role_law
    params = ControllerParams(role=role, law=law, stiffness_n_per_m=800.0, damping_n_s_per_m=15.0, force_limit_n=7.0)
    one = TeleopController(params, EnergyBoundParams(T, (1.5,), e0, enabled))
    two = TeleopController(params, EnergyBoundParams(T, (1.5, 3.0), e0, enabled))
    x = 0.0
    for n, (dx, v, remote_x, remote_f) in enumerate(steps):
        x += dx
        if n % 3 != 2:  # some ticks bring no new sample
            if role == "master":
                one.set_remote((remote_f, remote_x, -v))
                two.set_remote((remote_f, 0.1, remote_x, 0.2, -v, 0.0))
            else:
                one.set_remote((remote_x, -v))
                two.set_remote((remote_x, 0.3, -v, 0.1))
        f1 = one.step([x], [v])
        f2 = two.step([x, -x], [v, 0.5 * v])
        assert f1[0] == f2[0]
        assert one.force_desired[0] == two.force_desired[0]
        assert one.bound.energy_j[0] == two.bound.energy_j[0]
        assert one.force_applied == f1


def test_step1_and_step_share_state():
    """The list API on one axis goes through the scalar path: mixing the two keeps one state."""
    params = ControllerParams(role="slave", stiffness_n_per_m=500.0, damping_n_s_per_m=5.0)
    bound = EnergyBoundParams(T, (2.0,), 0.01)
    a, b = TeleopController(params, bound), TeleopController(params, bound)
    for c in (a, b):
        c.set_remote((0.01, 0.0))
    for i in range(50):
        x = 1e-4 * i
        fa = a.step([x], [0.1])[0] if i % 2 else a.step1(x, 0.1)
        fb = b.step1(x, 0.1)
        assert fa == fb
        assert a.bound.energy_j == b.bound.energy_j


def test_the_compiled_loop_composes_cores_law_and_bound() -> None:
    # the 1-DoF kernel's control is core's command1 and bound1, compiled: no copy of their steps
    from haptic_teleop.core import eba
    from haptic_teleop.engine.compiled import axis_kernel

    for name in ("command1", "bound1"):
        assert getattr(axis_kernel, name).py_func.__code__ is getattr(eba, name).__code__, name
    assert {"command1", "bound1"} <= set(axis_kernel.control.py_func.__code__.co_names)
    # and so do the Python objects
    from haptic_teleop.core import controller

    assert "command1" in controller.TeleopController.step1.__code__.co_names
    assert "bound1" in eba.EnergyBound.step1.__code__.co_names
