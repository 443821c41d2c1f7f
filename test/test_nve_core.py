"""The NVE's core objects (core/nve.py): the server's object against the exact solution, observers,
echoes and the round trip a client measures, the spring schedules as the clients apply them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.core.nve import (
    Coupling,
    Fujimoto04,
    NoCompensation,
    NveClient,
    ObjectServer,
    TransparencyCompensation,
    expm,
)
from haptic_teleop.core.nve_transparency import NveModel, mass_based_spring_n_per_m

SPRING = Coupling(0.5, 0.0, 0.5, 0.0)


def _series_expm(a: np.ndarray) -> np.ndarray:
    """A second method for small norms: the plain Taylor series, no scaling and squaring."""
    out, term = np.eye(len(a)), np.eye(len(a))
    for k in range(1, 120):
        term = term @ a / k
        out = out + term
    return out


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-3.0, 3.0), min_size=9, max_size=9))
def test_expm_equals_the_plain_series(values: list[float]) -> None:
    a = np.array(values).reshape(3, 3)
    ref = _series_expm(a)
    assert np.allclose(expm(a), ref, rtol=1e-10, atol=1e-12 * max(1.0, float(np.abs(ref).max())))


@pytest.mark.parametrize("wt", [0.01, 1.0, 7.5, 300.0])
def test_expm_of_an_oscillator_is_a_rotation(wt: float) -> None:
    """exp([[0, 1], [-w^2, 0]] t) = [[cos wt, sin wt / w], [-w sin wt, cos wt]], also far past the
    series' own range (the scaling and squaring)."""
    w = 3.0
    got = expm(np.array([[0.0, 1.0], [-w * w, 0.0]]) * (wt / w))
    ref = np.array([[math.cos(wt), math.sin(wt) / w], [-w * math.sin(wt), math.cos(wt)]])
    assert np.allclose(got, ref, rtol=0, atol=1e-9 * max(1.0, wt))


def _oscillator(m: float, b: float, k: float, x0: float, target: float, t: np.ndarray) -> np.ndarray:
    """x(t) of m x'' + b x' + k (x - target) = 0, x(0) = x0, x'(0) = 0, underdamped."""
    wn = math.sqrt(k / m)
    z = b / (2.0 * math.sqrt(k * m))
    wd = wn * math.sqrt(1.0 - z * z)
    a = x0 - target
    return target + np.exp(-z * wn * t) * (a * np.cos(wd * t) + (z * wn * a / wd) * np.sin(wd * t))


def test_object_follows_the_exact_solution_for_a_held_hip() -> None:
    """Zero-order hold is exact for a held HIP: the samples equal the continuous solution."""
    m, b, k, T = 0.25, 0.0025, 0.5, 0.001
    server = ObjectServer(m, b, [Coupling(0.5, 0.0, k, 0.0)], T, [0.0])
    server.receive(0, [0.1], [0.0], 0.0)
    xs = []
    for _ in range(5000):
        xs.append(float(server.x[0]))
        server.step()
    ref = _oscillator(m, b, k, 0.0, 0.1, np.arange(5000) * T)
    assert np.max(np.abs(np.array(xs) - ref)) < 1e-12


def test_explicit_euler_would_not_be_exact() -> None:
    """The same check fails for the simplest explicit integrator (the check can fail)."""
    m, b, k, T = 0.25, 0.0025, 0.5, 0.001
    x, v, xs = 0.0, 0.0, []
    for _ in range(5000):
        xs.append(x)
        a = (-b * v + k * (0.1 - x)) / m
        x, v = x + T * v, v + T * a
    ref = _oscillator(m, b, k, 0.0, 0.1, np.arange(5000) * T)
    assert np.max(np.abs(np.array(xs) - ref)) > 1e-6


@pytest.mark.parametrize(("k", "m"), [(1e6, 1e-4), (1e4, 1e-3), (5.0, 1e-6)])
def test_a_stiff_spring_on_a_light_object_stays_bounded(k: float, m: float) -> None:
    """omega T up to 1e5: the exact step never makes energy (the explicit one would explode)."""
    server = ObjectServer(m, 0.0, [Coupling(0.5, 0.0, k, 0.0)], 0.001, [0.0])
    server.receive(0, [0.01], [0.0], 0.0)
    bound = 0.5 * k * 0.01**2  # the spring's energy at the start: no more can ever appear
    for _ in range(20000):
        server.step()
        e = server.energy_j() + 0.5 * k * float((server.x[0] - 0.01) ** 2)
        assert math.isfinite(e) and e <= bound * (1 + 1e-6)


def test_a_client_pulls_only_once_its_hip_arrived_and_observers_never() -> None:
    a = ObjectServer(0.25, 0.0025, [SPRING, Coupling(0.5, 0.0, 0.0, 0.0)], 0.001, [0.0])
    b = ObjectServer(0.25, 0.0025, [SPRING], 0.001, [0.0])
    for _ in range(10):
        a.step()
    assert a.x[0] == 0.0 and math.isnan(a.echo_s[0])  # nothing arrived: nothing pulls
    a = ObjectServer(0.25, 0.0025, [SPRING, Coupling(0.5, 0.0, 0.0, 0.0)], 0.001, [0.0])
    for n in range(2000):
        hip = 0.05 * n * 0.001
        a.receive(0, [hip], [0.05], n * 0.001)
        a.receive(1, [-3.0], [0.0], n * 0.001)  # an observer far away: no pull
        b.receive(0, [hip], [0.05], n * 0.001)
        a.step()
        b.step()
    assert a.x[0] == b.x[0] and a.v[0] == b.v[0]
    assert a.echo_s[0] == pytest.approx(1.999)


def test_two_pushing_clients_pull_with_their_sum() -> None:
    """Two springs k to the same HIP are one spring 2k (the sum of the clients' couplings)."""
    two = ObjectServer(0.25, 0.0025, [SPRING, SPRING], 0.001, [0.0])
    one = ObjectServer(0.25, 0.0025, [Coupling(0.5, 0.0, 1.0, 0.0)], 0.001, [0.0])
    for s in (two, one):
        s.receive(0, [0.1], [0.0], 0.0)
    two.receive(1, [0.1], [0.0], 0.0)
    for _ in range(3000):
        two.step()
        one.step()
    assert two.x[0] == pytest.approx(one.x[0], abs=1e-13)


def test_the_client_measures_the_round_trip_from_the_echo() -> None:
    c = NveClient(SPRING, NoCompensation(0.5), 1)
    assert c.force(np.array([0.1]), np.array([0.0]))[0] == 0.0  # nothing received yet
    c.receive([0.02], [0.0], echo_s=1.25, now_s=1.55)
    assert c.rtt_s == pytest.approx(0.3)
    assert c.force(np.array([0.1]), np.array([0.0]))[0] == pytest.approx(0.5 * 0.08)
    c.receive([0.03], [0.0], echo_s=math.nan, now_s=1.6)  # no echo yet: R kept
    assert c.rtt_s == pytest.approx(0.3)


def test_the_clients_schedule_sets_its_spring_from_the_measured_round_trip() -> None:
    model = NveModel(0.25, 0.0025, 0.5, 0.5)
    comp = TransparencyCompensation.build(model, "auto", 1.0, 0.26, 0.1, 0.0)
    assert comp.distortion == "mass"
    c = NveClient(SPRING, comp, 1)
    assert c.spring_n_per_m == 0.5
    c.receive([0.0], [0.0], echo_s=0.0, now_s=0.1)  # within the allowable delay: unchanged
    assert c.spring_n_per_m == 0.5
    c.receive([0.0], [0.0], echo_s=0.0, now_s=0.3)
    assert c.spring_n_per_m == pytest.approx(0.5 - (mass_based_spring_n_per_m(model, 0.3) - 0.5))
    f = Fujimoto04(0.5, 1.0, 0.1, 0.05)
    assert f.spring_n_per_m(math.nan) == 0.5
    assert f.spring_n_per_m(0.3) == pytest.approx(0.3)
    assert f.spring_n_per_m(5.0) == 0.05


def test_the_damping_rule_needs_a_damped_object() -> None:
    with pytest.raises(ValueError, match="damping"):
        TransparencyCompensation.build(NveModel(0.25, 0.0, 0.5, 0.5), "damping", 1.0, 1.0, 1.0, 0.0)
