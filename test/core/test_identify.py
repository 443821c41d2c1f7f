"""The friction estimator and the excitation profile (core/friction.py), on synthetic data."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.core.friction import (
    FIT_SHARE,
    Excitation,
    Pass,
    Window,
    brake_speed,
    choose_direction,
    fit_friction,
    plan_passes,
    reposition,
    usable_span,
)

SPEEDS = np.array([0.2, 0.4, 0.7, 1.0, 1.5])


def _samples(b: float, c: float, noise: float, rng: np.random.Generator, repeats: int = 4, offset: float = 0.0):
    v = np.concatenate([SPEEDS, -SPEEDS] * repeats)
    v = v * (1.0 + 0.02 * rng.standard_normal(v.size))  # the speeds reached, not quite the targets
    tau = b * v + c * np.sign(v) + offset + noise * rng.standard_normal(v.size)
    return v, tau


@settings(max_examples=200, deadline=None)
@given(
    b=st.floats(0.001, 5.0),
    c=st.floats(0.0, 2.0),
    rel_noise=st.floats(0.0, 0.1),
    seed=st.integers(0, 2**32 - 1),
)
def test_recovers_b_and_c_within_the_interval(b: float, c: float, rel_noise: float, seed: int) -> None:
    """From samples of known b and c with noise, the fit's b and c are within 6 standard errors
    of the truth (probability of a miss about 2e-9 per value), and the safe damping is at most b
    unless b itself lies above its bound (probability about 1e-3 for z = 3)."""
    rng = np.random.default_rng(seed)
    noise = rel_noise * (b * 1.5 + c) + 1e-12
    v, tau = _samples(b, c, noise, rng)
    fit = fit_friction(v, tau)
    tol = 1e-9 * (b + c)
    assert abs(fit.viscous_nm_s_per_rad - b) <= 6.0 * fit.se_viscous + tol
    assert abs(fit.coulomb_nm - c) <= 6.0 * fit.se_coulomb + tol
    assert 0.0 <= fit.safe_damping_nm_s_per_rad
    assert fit.safe_damping_nm_s_per_rad == max(0.0, fit.viscous_nm_s_per_rad - 3.0 * fit.se_viscous)
    assert fit.n == v.size


@pytest.mark.parametrize("z", [1.0, 2.0])
def test_coverage_rate(z: float) -> None:
    """Over 2000 synthetic experiments the interval b +- z se holds the true b at the normal rate
    (68.3 % for z = 1, 95.4 % for z = 2; the t distribution with 37 degrees of freedom is a little
    wider: 67.6 %, 94.7 %); the one-sided bound b - z se is below the truth at the matching rate."""
    rng = np.random.default_rng(11)
    b, c, noise = 0.1, 0.15, 0.01
    inside = below = 0
    trials = 2000
    for _ in range(trials):
        v, tau = _samples(b, c, noise, rng)
        fit = fit_friction(v, tau, z=z)
        inside += abs(fit.viscous_nm_s_per_rad - b) <= z * fit.se_viscous
        below += fit.viscous_nm_s_per_rad - z * fit.se_viscous <= b
    two_sided = math.erf(z / math.sqrt(2.0))
    one_sided = 0.5 * (1.0 + two_sided)
    sd = math.sqrt(two_sided * (1.0 - two_sided) / trials)
    assert abs(inside / trials - two_sided) < 4.0 * sd + 0.01
    assert abs(below / trials - one_sided) < 4.0 * sd + 0.01


def test_no_coulomb_term() -> None:
    """Data with viscous friction only: c comes out within its interval of 0, b as given."""
    rng = np.random.default_rng(5)
    v, tau = _samples(0.05, 0.0, 0.002, rng)
    fit = fit_friction(v, tau)
    assert abs(fit.coulomb_nm) <= 3.0 * fit.se_coulomb
    assert abs(fit.viscous_nm_s_per_rad - 0.05) <= 3.0 * fit.se_viscous
    assert fit.se_coulomb < 0.01 * 0.05 * 1.5 + 0.002  # and the interval is narrow: c is known to be small


def test_offset() -> None:
    """An unmodelled bias d: fitted with `offset`, b and c come back; without, the residuals grow."""
    rng = np.random.default_rng(9)
    v, tau = _samples(0.1, 0.15, 0.002, rng, offset=0.05)
    with_d = fit_friction(v, tau, offset=True)
    assert abs(with_d.offset_nm - 0.05) <= 4.0 * with_d.se_offset
    assert abs(with_d.viscous_nm_s_per_rad - 0.1) <= 4.0 * with_d.se_viscous
    assert abs(with_d.coulomb_nm - 0.15) <= 4.0 * with_d.se_coulomb
    without = fit_friction(v, tau)
    assert without.residual_std_nm > 5.0 * with_d.residual_std_nm


def test_safe_damping_never_negative() -> None:
    """Noise far above the viscous torque: the bound goes below 0, the safe damping stays 0."""
    rng = np.random.default_rng(1)
    v, tau = _samples(0.001, 0.1, 0.05, rng, repeats=1)
    fit = fit_friction(v, tau)
    assert fit.viscous_nm_s_per_rad - 3.0 * fit.se_viscous < 0.0
    assert fit.safe_damping_nm_s_per_rad == 0.0


@pytest.mark.parametrize(
    ("v", "tau", "offset", "match"),
    [
        ([0.1, 0.2], [1.0, 2.0], False, "at least 3 samples"),
        ([0.1, 0.2, 0.3, 0.4], [1.0, 2.0, 3.0, 4.0], False, "both directions"),
        ([0.1, 0.0, -0.3, 0.4], [1.0, 2.0, 3.0, 4.0], False, "zero velocity"),
        ([0.5, -0.5, 0.5, -0.5], [1.0, -1.0, 1.1, -0.9], True, "do not determine"),
        ([0.5, -0.5, math.nan], [1.0, -1.0, 1.0], False, "finite"),
    ],
)
def test_unusable_samples(v, tau, offset, match) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=match):
        fit_friction(v, tau, offset=offset)


def test_window_takes_the_inertial_residual_out() -> None:
    """A window whose velocity rises linearly at a: the sample's torque is the mean torque minus
    M a (the inertia row times every joint's velocity slope), its velocity the mean velocity."""
    w = Window()
    a = np.array([0.5, -0.2])
    m_row = np.array([0.04, 0.01])
    rng = np.random.default_rng(0)
    taus = []
    for k in range(200):
        t = 1.0 + k * 0.001
        qd = np.array([1.0, 0.0]) + a * (t - 1.0)
        tau = 0.2 + float(m_row @ a) + 0.001 * rng.standard_normal()
        taus.append(tau)
        w.add(t, float(qd[0]), tau, qd)
    np.testing.assert_allclose(w.mean_acceleration(), a, rtol=1e-9)
    v, tau_f = w.sample(m_row)
    assert v == pytest.approx(1.0 + 0.5 * 0.199 / 2.0 * 1.0, rel=1e-9)
    assert tau_f == pytest.approx(np.mean(taus) - float(m_row @ a), rel=1e-12)
    with pytest.raises(ValueError, match="empty"):
        Window().sample(m_row)


# ------------------------------------------------------------------------------- the profile


def test_pass_trapezoid() -> None:
    p = Pass(1.0, 5.0, 0.25, 0.5, 0.05, 1)
    assert p.ramp_s == pytest.approx(0.2)
    assert p.duration_s == pytest.approx(0.2 + 0.25 + 0.5 + 0.2 + 0.05)
    # travel: integral of the speed over the pass
    ts = np.arange(0.0, p.duration_s, 1e-5)
    assert np.sum([p.velocity(t) for t in ts]) * 1e-5 == pytest.approx(p.travel_rad, rel=1e-3)
    assert p.velocity(0.1) == pytest.approx(0.5)
    assert p.velocity(0.3) == 1.0
    assert p.velocity(p.duration_s - 0.01) == 0.0
    assert not p.in_window(0.44) and p.in_window(0.46) and p.in_window(0.94) and not p.in_window(0.96)


@settings(max_examples=200, deadline=None)
@given(
    lo=st.floats(-3.0, 0.0),
    width=st.floats(0.3, 6.0),
    speeds=st.lists(st.floats(0.05, 3.0), min_size=1, max_size=6),
    measure=st.floats(0.1, 2.0),
)
def test_plan_fits_the_range(lo: float, width: float, speeds: list[float], measure: float) -> None:
    """Every planned pass fits in FIT_SHARE of the usable span and has at least the shortest
    window; each kept speed gets at least the measure time in each direction (split into
    back-and-forth passes, the windows rounded up to the shortest one); the speeds dropped are
    exactly those whose shortest pass cannot fit."""
    exc = Excitation(speeds_rad_per_s=tuple(speeds), measure_s=measure, repeats=1)
    rng = (lo, lo + width)
    plan = plan_passes(exc, rng)
    span = FIT_SHARE * usable_span(rng, exc.margin_rad)
    for p in plan.passes:
        assert p.travel_rad <= span + 1e-9
        assert p.measure_s >= exc.min_measure_s - 1e-12
    for v in set(speeds):
        mine = [p for p in plan.passes if p.speed_rad_per_s == v]
        fixed = v * (v / exc.accel_rad_per_s2 + exc.settle_s)
        if span - fixed < v * exc.min_measure_s:
            assert v in plan.dropped_speeds_rad_per_s and not mine
        else:
            up = sum(p.measure_s for p in mine if p.prefer > 0)
            down = sum(p.measure_s for p in mine if p.prefer < 0)
            n = len(mine) // (2 * speeds.count(v))  # passes per direction and repeat
            want = measure * speeds.count(v)
            assert want - 1e-9 <= up <= want + n * speeds.count(v) * exc.min_measure_s + 1e-9
            assert down == pytest.approx(up)
    signs = [p.prefer for p in plan.passes]
    assert all(a == -b for a, b in itertools.pairwise(signs))


def test_small_range_goes_back_and_forth() -> None:
    """A joint with 0.5 rad of usable range: a fast speed's half second is split into passes."""
    exc = Excitation(speeds_rad_per_s=(1.0,), measure_s=0.5, settle_s=0.1, repeats=1, margin_rad=0.1)
    plan = plan_passes(exc, (-0.35, 0.35))
    assert len(plan.passes) > 2
    assert [p.prefer for p in plan.passes][:4] == [1, -1, 1, -1]


def test_unlimited_joint_one_pass_each_way() -> None:
    plan = plan_passes(Excitation(speeds_rad_per_s=(3.0,), repeats=1), (-math.inf, math.inf))
    assert [p.prefer for p in plan.passes] == [1, -1]
    assert plan.passes[0].measure_s == Excitation().measure_s


def test_direction_and_reposition() -> None:
    rng = (-1.0, 1.0)
    assert choose_direction(0.0, rng, 0.1, 0.8, 1) == 1
    assert choose_direction(0.5, rng, 0.1, 0.8, 1) == -1  # no room up: reversed at the end
    assert choose_direction(0.0, rng, 0.1, 1.0, -1) == 0  # no room either way
    move = reposition(0.0, rng, 0.1, 1.0, 0.5, 5.0)
    assert move is not None and not move.measure
    # after the move a pass of 1.0 rad fits: the move's travel puts q where one direction has room
    q = 0.0 + move.prefer * move.travel_rad
    assert choose_direction(q, rng, 0.1, 1.0, 1) != 0
    assert -0.9 <= q <= 0.9
    assert reposition(0.0, rng, 0.1, 0.5, 0.5, 5.0) is None  # fits already
    assert reposition(0.0, rng, 0.1, 2.0, 0.5, 5.0) is None  # never fits
    assert brake_speed(0.1, 5.0) == pytest.approx(1.0)
    assert brake_speed(-0.1, 5.0) == 0.0


def test_bad_settings() -> None:
    with pytest.raises(ValueError, match="torque_fraction"):
        Excitation(torque_fraction=1.5)
    with pytest.raises(ValueError, match="speeds_rad_per_s"):
        Excitation(speeds_rad_per_s=(0.5, -1.0))
    with pytest.raises(ValueError, match="min_measure_s"):
        Excitation(measure_s=0.05)
