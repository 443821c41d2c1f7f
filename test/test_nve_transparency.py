"""The NVE transparency analysis (core/nve_transparency.py, docs/nve.md) against independent
computations: the impedance against a time-domain simulation of the delayed loop written here
(one or several clients, any split of the round trip), the distorted mass and damping against the
exact impedance (the residual of the formulas shrinks as w^2; wrong formulas' residuals do not) and
against a least-squares fit, the spring distortions and the rule against the exact impedance on
both sides of the crossover, the allowable delays against bisection, the two spring schedules
against their formulas (hypothesis)."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.core.nve_transparency import (
    NveModel,
    allowable_rtt_damping_s,
    allowable_rtt_mass_s,
    damping_based_spring_n_per_m,
    damping_gradient,
    distorted_damping_n_s_per_m,
    distorted_mass_kg,
    distortion_crossover_rad_per_s,
    dominant_distortion,
    fujimoto04_spring_n_per_m,
    impedance,
    mass_based_spring_n_per_m,
    mass_gradient,
    matching_distortion,
    proposed_spring_n_per_m,
    spring_distortion_n_per_m,
    with_partners,
)

SEED = NveModel(mass_kg=0.25, damping_n_s_per_m=0.0025, client_stiffness_n_per_m=0.5, server_stiffness_n_per_m=0.5)
MODELS = {
    "seed": SEED,
    "seed_de": NveModel(0.25, 0.0025, 0.5, 0.5, server_damping_n_s_per_m=0.05),
    "kh_ne_ke": NveModel(0.25, 0.0025, 2.0, 0.5),
    "dh_de": NveModel(1.5, 0.3, 40.0, 10.0, client_damping_n_s_per_m=0.4, server_damping_n_s_per_m=0.2),
    "stiff_light": NveModel(0.05, 0.01, 300.0, 800.0),
}
RTTS = (0.01, 0.05, 0.3, 1.0)
W_LOW = np.logspace(-6, -1, 21)


def undelayed(model: NveModel, w: np.ndarray, mass_kg: float, damping_n_s_per_m: float) -> np.ndarray:
    """Z of the undelayed loop with the object (mass_kg, damping_n_s_per_m), written out from the
    equations: (m s^2 + (b + D) s + K + C_e) X_o = C_e X_h, F = C_h (X_h - X_o), Z = F / (s X_h),
    so X_h - X_o = (m s^2 + (b + D) s + K) X_h / (...) (written so, 1 - X_o/X_h would cancel at low w)."""
    s = 1j * w
    ch = model.client_stiffness_n_per_m + model.client_damping_n_s_per_m * s
    ce = model.server_stiffness_n_per_m + model.server_damping_n_s_per_m * s
    rest = mass_kg * s * s + (damping_n_s_per_m + model.partner_damping_n_s_per_m) * s + model.partner_stiffness_n_per_m
    return ch * rest / (s * (rest + ce))


def residual(model: NveModel, rtt_s: float, mass_kg: float, damping_n_s_per_m: float, w: np.ndarray = W_LOW):
    z = impedance(model, w, rtt_s)
    return np.abs(z - undelayed(model, w, mass_kg, damping_n_s_per_m)) / np.abs(z)


def slopes(w: np.ndarray, r: np.ndarray) -> np.ndarray:
    """d log r / d log w between neighbouring frequencies."""
    return np.diff(np.log(r)) / np.diff(np.log(w))


FLOOR = 1e-13  # relative residuals below this are rounding (Z itself is good to ~1e-16)


def clean_slopes(w: np.ndarray, r: np.ndarray, w_max: float = 1e-3) -> np.ndarray:
    """The slopes between neighbours above the rounding floor, up to w_max; at least three."""
    keep = (r[:-1] > FLOOR) & (r[1:] > FLOOR) & (w[1:] <= w_max)
    assert keep.sum() >= 3, r
    return slopes(w, r)[keep]


def leading_coefficient(w: np.ndarray, r: np.ndarray, order: float) -> float:
    """r / w^order at the lowest frequency where r is well above rounding (1e-9)."""
    i = int(np.argmax(r > 1e-9))
    assert 1e-9 < r[i] < 1e-5, r
    return float(r[i] / w[i] ** order)


def third_order_coefficient(model: NveModel, rtt_s: float) -> float:
    """c3 of D e^{sR} - D_h = c3 s^3 + ...: m R + (b + D + d_e) R^2/2 + (k_e + K) R^3/6 (docs/nve.md)."""
    c0 = model.damping_n_s_per_m + model.partner_damping_n_s_per_m + model.server_damping_n_s_per_m
    k = model.server_stiffness_n_per_m + model.partner_stiffness_n_per_m
    return model.mass_kg * rtt_s + c0 * rtt_s**2 / 2 + k * rtt_s**3 / 6


# --- the impedance itself, against a time-domain simulation of the delayed loop -------------------


def simulate_force(
    model: NveModel,
    w: float,
    up_s: float,
    down_s: float,
    partners: list[tuple[float, float, float, float]],
    dt: float = 1e-3,
    duration_s: float = 40.0,
) -> complex:
    """Client 0 moves its HIP as sin(w t); each partner (k_e, d_e, one-way up delay, held position)
    pushes the object toward its HIP as the server received it. The object ODE is integrated with
    RK4 (the delayed HIPs are known functions of time); client 0's force uses the object as it
    left the server down_s ago. Returns the force's complex amplitude at w over the HIP velocity's
    (least squares over the last 4 periods; the constant offset from the held partners fitted too)."""
    m, b = model.mass_kg, model.damping_n_s_per_m
    ke, de = model.server_stiffness_n_per_m, model.server_damping_n_s_per_m
    kh, dh = model.client_stiffness_n_per_m, model.client_damping_n_s_per_m

    def accel(t: float, x: float, v: float) -> float:
        tu = t - up_s
        xh, vh = (math.sin(w * tu), w * math.cos(w * tu)) if tu >= 0.0 else (0.0, 0.0)
        f = -b * v + ke * (xh - x) + de * (vh - v)
        for kj, dj, _, hold in partners:
            f += kj * (hold - x) + dj * (0.0 - v)
        return f / m

    n = round(duration_s / dt)
    lag = round(down_s / dt)
    assert abs(lag * dt - down_s) < 1e-12
    xs = np.zeros(n + 1)
    vs = np.zeros(n + 1)
    x = v = 0.0
    for i in range(n):
        t = i * dt
        a1 = accel(t, x, v)
        a2 = accel(t + dt / 2, x + dt / 2 * v, v + dt / 2 * a1)
        a3 = accel(t + dt / 2, x + dt / 2 * (v + dt / 2 * a1), v + dt / 2 * a2)
        a4 = accel(t + dt, x + dt * (v + dt / 2 * a2), v + dt * a3)
        x, v = (
            x + dt * (v + dt / 6 * (a1 + a2 + a3)),
            v + dt / 6 * (a1 + 2 * a2 + 2 * a3 + a4),
        )
        xs[i + 1], vs[i + 1] = x, v
    t = np.arange(n + 1) * dt
    tail = t >= duration_s - 4 * 2 * math.pi / w
    idx = np.nonzero(tail)[0]
    xo_seen, vo_seen = xs[idx - lag], vs[idx - lag]
    tt = t[idx]
    force = kh * (np.sin(w * tt) - xo_seen) + dh * (w * np.cos(w * tt) - vo_seen)
    basis = np.column_stack([np.cos(w * tt), np.sin(w * tt), np.ones_like(tt)])
    (c, s_, _), *_ = np.linalg.lstsq(basis, force, rcond=None)
    f_amp = c - 1j * s_  # force = Re(f_amp e^{jwt})
    v_amp = w  # HIP velocity w cos(wt) = Re(w e^{jwt})
    return complex(f_amp / v_amp)


# A well-damped object, so that the simulation's start transient has died out after 40 s.
DAMPED = NveModel(0.25, 0.6, 0.8, 1.2, client_damping_n_s_per_m=0.05, server_damping_n_s_per_m=0.1)


@pytest.mark.parametrize(("up_s", "down_s"), [(0.3, 0.0), (0.0, 0.3), (0.1, 0.2), (0.25, 0.05)])
def test_impedance_matches_simulation_and_depends_on_the_round_trip_only(up_s, down_s):
    w = 1.3
    z_sim = simulate_force(DAMPED, w, up_s, down_s, partners=[])
    z = complex(impedance(DAMPED, np.array([w]), up_s + down_s)[0])
    assert abs(z_sim - z) <= 1e-4 * abs(z)
    # a different round trip gives a clearly different force: the check can fail
    z_other = complex(impedance(DAMPED, np.array([w]), up_s + down_s + 0.05)[0])
    assert abs(z_other - z) > 1e-2 * abs(z)


def test_impedance_refuses_bad_input():
    with pytest.raises(ValueError, match="w_rad_per_s"):
        impedance(SEED, np.array([0.0, 1.0]), 0.1)
    with pytest.raises(ValueError, match="rtt_s"):
        impedance(SEED, np.array([1.0]), -0.1)
    with pytest.raises(ValueError, match="rtt_s"):
        impedance(SEED, np.array([1.0]), math.nan)
    with pytest.raises(ValueError, match="partner_stiffness_n_per_m"):
        NveModel(0.25, 0.0025, 0.5, 0.5, partner_stiffness_n_per_m=-1.0)


# --- (a) the distorted mass and damping: the residual against the exact impedance ----------------


@pytest.mark.parametrize("name", sorted(MODELS))
@pytest.mark.parametrize("rtt_s", RTTS)
def test_distorted_object_matches_the_delayed_impedance_to_second_order(name, rtt_s):
    model = MODELS[name]
    mh, bh = distorted_mass_kg(model, rtt_s), distorted_damping_n_s_per_m(model, rtt_s)
    r = residual(model, rtt_s, mh, bh)
    # a third-order residual in D e^{sR} - D_h: relative error in Z falls as w^2 ...
    assert np.allclose(clean_slopes(W_LOW, r), 2.0, atol=0.02), slopes(W_LOW, r)
    # ... with the leading coefficient c3 / b_h of the derivation
    assert leading_coefficient(W_LOW, r, 2.0) == pytest.approx(third_order_coefficient(model, rtt_s) / bh, rel=1e-3)
    assert r[-1] < 0.05  # still a good approximation at 0.1 rad/s


@pytest.mark.parametrize("name", ["seed", "seed_de", "kh_ne_ke", "dh_de"])
@pytest.mark.parametrize("rtt_s", (0.05, 0.3))
def test_wrong_distortion_formulas_fail_the_same_check(name, rtt_s):
    model = MODELS[name]
    ke, kh, de = model.server_stiffness_n_per_m, model.client_stiffness_n_per_m, model.server_damping_n_s_per_m
    b, m = model.damping_n_s_per_m, model.mass_kg
    bh, mh = distorted_damping_n_s_per_m(model, rtt_s), distorted_mass_kg(model, rtt_s)
    # the mass without the (b + d_e) R term: residual first order (slope 1)
    r = residual(model, rtt_s, m + ke * rtt_s**2 / 2, bh)
    assert np.allclose(clean_slopes(W_LOW, r), 1.0, atol=0.02)
    # the mass from matching the numerator of Z alone (m + d_e R - k_e R^2/2: it would shrink with R)
    r = residual(model, rtt_s, m + de * rtt_s - ke * rtt_s**2 / 2, bh)
    assert np.allclose(clean_slopes(W_LOW, r), 1.0, atol=0.02)
    # the damping with the client's spring: the error does not shrink at all when k_h != k_e
    if kh != ke:
        r = residual(model, rtt_s, mh, b + kh * rtt_s)
        assert np.allclose(clean_slopes(W_LOW, r), 0.0, atol=0.02)
        assert r[0] > 0.1


def fit_object(model: NveModel, rtt_s: float, w: np.ndarray) -> tuple[float, float]:
    """Least-squares (m_h, b_h) of the undelayed loop to the delayed Z over w: the undelayed Z0
    satisfies Z0 (m_h s^2 + (b_h + D) s + K + C_e) = C_h (1 - C_e / (...)) ... written linear in
    (m_h, b_h): m_h (Z s^2 - C_h s) + b_h (Z s - C_h) = C_h (D s + K) - Z (D s + K + C_e) (Levy)."""
    s = 1j * w
    z = impedance(model, w, rtt_s)
    ch = model.client_stiffness_n_per_m + model.client_damping_n_s_per_m * s
    ce = model.server_stiffness_n_per_m + model.server_damping_n_s_per_m * s
    rest = model.partner_damping_n_s_per_m * s + model.partner_stiffness_n_per_m
    a = np.column_stack([z * s * s - ch * s, z * s - ch])
    rhs = ch * rest - z * (rest + ce)
    a_ri = np.vstack([a.real, a.imag]) / np.abs(np.concatenate([rhs, rhs]))[:, None]
    rhs_ri = np.concatenate([rhs.real, rhs.imag]) / np.abs(np.concatenate([rhs, rhs]))
    (mh, bh), *_ = np.linalg.lstsq(a_ri, rhs_ri, rcond=None)
    return float(mh), float(bh)


def extract_object(model: NveModel, rtt_s: float, w: np.ndarray) -> tuple[float, float, float]:
    """(m_h, b_h, k) read off the impedance's own numbers: the object as the client sees it is
    X_or / X_h = 1 - s Z / C_h = C_e e^{-sR} / D(s), so P(jw) = C_e / (1 - s Z / C_h) = D e^{sR}, the
    polynomial an undelayed object would need, k + (b_h + D + d_e) s + m_h s^2 + O(s^3). Its
    coefficients by least squares: Re P = k - m_h w^2 + a4 w^4, Im P / w = (b_h + D + d_e) - a3 w^2."""
    s = 1j * w
    ch = model.client_stiffness_n_per_m + model.client_damping_n_s_per_m * s
    ce = model.server_stiffness_n_per_m + model.server_damping_n_s_per_m * s
    poly = ce / (1.0 - s * impedance(model, w, rtt_s) / ch)
    (k, neg_mh, _), *_ = np.linalg.lstsq(np.column_stack([np.ones_like(w), w**2, w**4]), poly.real, rcond=None)
    (c1, _), *_ = np.linalg.lstsq(np.column_stack([np.ones_like(w), w**2]), poly.imag / w, rcond=None)
    bh = c1 - model.partner_damping_n_s_per_m - model.server_damping_n_s_per_m
    return float(-neg_mh), float(bh), float(k)


@pytest.mark.parametrize("name", sorted(MODELS))
@pytest.mark.parametrize("rtt_s", RTTS)
def test_extracted_mass_and_damping_equal_the_formulas(name, rtt_s):
    model = MODELS[name]
    mh, bh = distorted_mass_kg(model, rtt_s), distorted_damping_n_s_per_m(model, rtt_s)
    mf, bf, kf = extract_object(model, rtt_s, np.linspace(1e-3, 4e-3, 16))
    assert mf == pytest.approx(mh, rel=1e-5)  # m_h w^2 is ~1e-9 of k_e for the stiff model
    assert bf == pytest.approx(bh, rel=1e-6)
    assert kf == pytest.approx(model.server_stiffness_n_per_m, rel=1e-9)


@pytest.mark.parametrize("name", sorted(MODELS))
@pytest.mark.parametrize("rtt_s", RTTS)
def test_fitted_mass_and_damping_equal_the_formulas(name, rtt_s):
    model = MODELS[name]
    mh, bh = distorted_mass_kg(model, rtt_s), distorted_damping_n_s_per_m(model, rtt_s)
    errors = []
    for w0 in (1e-3, 1e-4):
        mf, bf = fit_object(model, rtt_s, np.linspace(w0, 4 * w0, 16))
        errors.append((abs(mf - mh) / mh, abs(bf - bh) / bh))
    assert errors[-1][0] < 1e-4 and errors[-1][1] < 1e-6, errors
    # the fit converges onto the formula as the band goes down
    assert errors[-1][0] <= errors[0][0] + 1e-9


def test_distortions_grow_linearly_and_quadratically():
    """The seed's reading: b_h linear in R, m_h quadratic (second differences)."""
    r = np.linspace(0.0, 1.0, 11)
    for model in MODELS.values():
        bh = np.array([distorted_damping_n_s_per_m(model, x) for x in r])
        mh = np.array([distorted_mass_kg(model, x) for x in r])
        assert np.allclose(np.diff(bh, 2), 0.0, atol=1e-12)
        assert np.allclose(np.diff(mh, 2), model.server_stiffness_n_per_m * 0.1**2, rtol=1e-9)
        assert np.all(np.diff(mh) > 0) and np.all(np.diff(bh) > 0)


def test_gradients_are_the_derivatives():
    for model in MODELS.values():
        for r in (1e-3, 0.1, 0.7):
            h = 1e-6  # central differences are exact on a quadratic, up to rounding
            dm = (distorted_mass_kg(model, r + h) - distorted_mass_kg(model, r - h)) / (2 * h)
            db = (distorted_damping_n_s_per_m(model, r + h) - distorted_damping_n_s_per_m(model, r - h)) / (2 * h)
            assert mass_gradient(model, r) == pytest.approx(dm, rel=1e-6)
            assert damping_gradient(model) == pytest.approx(db, rel=1e-6)
        b_de = model.damping_n_s_per_m + model.server_damping_n_s_per_m
        assert mass_gradient(model) == pytest.approx(b_de)


# --- (c) the spring distortions and the rule -------------------------------------------------------


def spring_error(model: NveModel, rtt_s: float, w: float, spring: float) -> float:
    """|log| of the ratio between the force of the undelayed loop with the true object and client
    spring `spring` and the delayed loop's force, at w (0 = the same force)."""
    wa = np.array([w])
    z = impedance(model, wa, rtt_s)[0]
    z_k = impedance(dataclasses.replace(model, client_stiffness_n_per_m=spring), wa, 0.0)[0]
    return abs(math.log(abs(z_k) / abs(z)))


@pytest.mark.parametrize("name", ["seed", "seed_de", "kh_ne_ke", "stiff_light"])
@pytest.mark.parametrize("rtt_s", RTTS)
def test_damping_based_spring_matches_in_the_damping_band(name, rtt_s):
    model = MODELS[name]
    b, m = model.damping_n_s_per_m, model.mass_kg
    w = 1e-2 * min(b / m, distorted_damping_n_s_per_m(model, rtt_s) / distorted_mass_kg(model, rtt_s))
    assert spring_error(model, rtt_s, w, damping_based_spring_n_per_m(model, rtt_s)) < 1e-3
    # the other one, and the undistorted spring, are far off there
    assert spring_error(model, rtt_s, w, mass_based_spring_n_per_m(model, rtt_s)) > 0.5
    assert spring_error(model, rtt_s, w, model.client_stiffness_n_per_m) > 0.5


@pytest.mark.parametrize(
    ("name", "rtt_s"),
    [("seed", 0.002), ("seed", 0.005), ("seed", 0.01), ("kh_ne_ke", 0.005), ("stiff_light", 2e-4), ("seed_de", 0.005)],
)
def test_mass_based_spring_matches_in_the_mass_band(name, rtt_s):
    """The mass band b_h/m_h << w << min(sqrt(k_e/m_h), k_e/(b_h + d_e)) (where the force's
    numerator is its mass term and its denominator still k_e) exists when R sqrt(k_e/m) << 1:
    its middle."""
    model = MODELS[name]
    bh, mh = distorted_damping_n_s_per_m(model, rtt_s), distorted_mass_kg(model, rtt_s)
    ke = model.server_stiffness_n_per_m
    lo = bh / mh
    hi = min(math.sqrt(ke / mh), ke / (bh + model.server_damping_n_s_per_m))
    assert hi / lo > 20.0
    w = math.sqrt(lo * hi)
    e_m = spring_error(model, rtt_s, w, mass_based_spring_n_per_m(model, rtt_s))
    e_b = spring_error(model, rtt_s, w, damping_based_spring_n_per_m(model, rtt_s))
    assert e_m < 0.03
    assert e_m < e_b / 5


@pytest.mark.parametrize("rtt_s", [0.0005, 0.001, 0.002])
@pytest.mark.parametrize("factor", [1 / 30, 1 / 3, 3.0, 30.0])
def test_seed_rule_picks_the_better_spring_on_both_sides_of_b_over_m(rtt_s, factor):
    """For small R the crossover is w = b / m: the rule's pick is the closer spring."""
    model = SEED
    w = factor * model.damping_n_s_per_m / model.mass_kg
    e = {d: spring_error(model, rtt_s, w, spring_distortion_n_per_m(model, rtt_s, d)) for d in ("mass", "damping")}
    assert dominant_distortion(model, w) == min(e, key=e.__getitem__)
    assert dominant_distortion(model, w) == ("mass" if factor > 1 else "damping")


def test_seed_rule_is_wrong_between_b_over_m_and_the_delayed_crossover():
    """At R = 0.3 s the crossover has moved up by sqrt(b_h m / (b m_h)) (about 7.5x): at 3 b/m the
    seed's rule says 'mass' but k_hb is closer; matching_distortion says 'damping'."""
    model, rtt_s = SEED, 0.3
    w = 3 * model.damping_n_s_per_m / model.mass_kg
    e_m = spring_error(model, rtt_s, w, mass_based_spring_n_per_m(model, rtt_s))
    e_b = spring_error(model, rtt_s, w, damping_based_spring_n_per_m(model, rtt_s))
    assert dominant_distortion(model, w) == "mass"
    assert e_b < e_m
    assert matching_distortion(model, w, rtt_s) == "damping"
    assert distortion_crossover_rad_per_s(model, 0.0) == pytest.approx(model.damping_n_s_per_m / model.mass_kg)
    assert distortion_crossover_rad_per_s(model, rtt_s) / (model.damping_n_s_per_m / model.mass_kg) > 7.0


@pytest.mark.parametrize("name", ["seed", "kh_ne_ke", "stiff_light", "seed_de"])
@pytest.mark.parametrize("rtt_s", [0.001, 0.01, 0.05, 0.3])
def test_matching_distortion_picks_the_better_spring(name, rtt_s):
    """Away from its crossover (x/÷ 2) and inside the low-frequency band (w R <= 0.05, w at most a
    fifth of the natural frequency), matching_distortion's pick is the closer spring."""
    model = MODELS[name]
    wc = distortion_crossover_rad_per_s(model, rtt_s)
    wn = math.sqrt(model.server_stiffness_n_per_m / distorted_mass_kg(model, rtt_s))
    checked = 0
    for factor in (1 / 100, 1 / 10, 1 / 2, 2.0, 10.0, 100.0):
        w = factor * wc
        if w * rtt_s > 0.05 or w > wn / 5:
            continue
        e = {d: spring_error(model, rtt_s, w, spring_distortion_n_per_m(model, rtt_s, d)) for d in ("mass", "damping")}
        assert matching_distortion(model, w, rtt_s) == min(e, key=e.__getitem__), (w, e)
        checked += 1
    assert checked >= 2


def test_spring_distortion_dispatch_and_errors():
    assert spring_distortion_n_per_m(SEED, 0.3, "mass") == mass_based_spring_n_per_m(SEED, 0.3)
    assert spring_distortion_n_per_m(SEED, 0.3, "damping") == damping_based_spring_n_per_m(SEED, 0.3)
    with pytest.raises(ValueError, match="distortion must be one of"):
        spring_distortion_n_per_m(SEED, 0.3, "spring")
    with pytest.raises(ValueError, match="damping b > 0"):
        damping_based_spring_n_per_m(NveModel(0.25, 0.0, 0.5, 0.5), 0.3)
    with pytest.raises(ValueError, match="interaction_rad_per_s"):
        dominant_distortion(SEED, 0.0)
    with pytest.raises(ValueError, match="interaction_rad_per_s"):
        matching_distortion(SEED, -1.0, 0.1)
    # the formulas, from the parameters (seed values at R = 0.3 s)
    assert mass_based_spring_n_per_m(SEED, 0.3) == pytest.approx(0.5 * (0.25 + 0.0025 * 0.3 + 0.25 * 0.09) / 0.25)
    assert damping_based_spring_n_per_m(SEED, 0.3) == pytest.approx(0.5 * (0.0025 + 0.15) / 0.0025)


# --- (d) allowable delays ------------------------------------------------------------------------


def bisect_rtt(f, target: float, hi: float = 1e4) -> float:
    lo = 0.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(mid) <= target else (lo, mid)
    return lo


@pytest.mark.parametrize("name", sorted(MODELS))
def test_allowable_delays_solve_their_equations(name):
    model = MODELS[name]
    for extra in (1e-4, 0.01, 0.2, 3.0):
        m_allow = model.mass_kg * (1 + extra)
        b_allow = model.damping_n_s_per_m * (1 + 10 * extra) + extra
        rm = allowable_rtt_mass_s(model, m_allow)
        rb = allowable_rtt_damping_s(model, b_allow)
        assert distorted_mass_kg(model, rm) == pytest.approx(m_allow, rel=1e-12)
        assert distorted_damping_n_s_per_m(model, rb) == pytest.approx(b_allow, rel=1e-12)
        assert rm == pytest.approx(bisect_rtt(lambda r: distorted_mass_kg(model, r), m_allow), rel=1e-9)
        assert rb == pytest.approx(bisect_rtt(lambda r: distorted_damping_n_s_per_m(model, r), b_allow), rel=1e-9)


def test_allowable_delays_are_monotone_and_handle_edges():
    model = SEED
    ms = np.linspace(0.25, 2.0, 50)
    bs = np.linspace(0.0025, 2.0, 50)
    rm = [allowable_rtt_mass_s(model, x) for x in ms]
    rb = [allowable_rtt_damping_s(model, x) for x in bs]
    assert rm[0] == 0.0 and rb[0] == 0.0  # already at the allowed value
    assert np.all(np.diff(rm) > 0) and np.all(np.diff(rb) > 0)
    assert allowable_rtt_mass_s(model, 0.2) == 0.0  # already above
    assert allowable_rtt_damping_s(model, 0.001) == 0.0
    # no server spring: the damping never grows (infinite), the mass grows linearly with b + d_e
    free = NveModel(0.25, 0.0025, 0.5, 0.0)
    assert allowable_rtt_damping_s(free, 0.01) == math.inf
    assert allowable_rtt_mass_s(free, 0.3) == pytest.approx(0.05 / 0.0025)
    assert allowable_rtt_mass_s(NveModel(0.25, 0.0, 0.5, 0.0), 0.3) == math.inf
    # the seed's numbers: b_h = 0.0025 + 0.5 R, m_h = 0.25 + 0.0025 R + 0.25 R^2
    assert allowable_rtt_damping_s(model, 0.0525) == pytest.approx(0.1)
    assert allowable_rtt_mass_s(model, 0.25 + 0.0025 * 0.4 + 0.25 * 0.16) == pytest.approx(0.4)


def test_tangent_gradient_at_zero_badly_overestimates_the_allowable_mass_delay():
    """Why the mass's allowable delay solves the quadratic: the initial gradient b + d_e alone
    (a linear prediction) gives 0.05 / 0.0025 = 20 s where the exact answer is under 0.45 s."""
    exact = allowable_rtt_mass_s(SEED, 0.3)
    linear = (0.3 - SEED.mass_kg) / mass_gradient(SEED, 0.0)
    assert exact < 0.45 < 20.0 == pytest.approx(linear)


# --- (e) the spring schedules ---------------------------------------------------------------------

models = st.builds(
    NveModel,
    mass_kg=st.floats(0.01, 10.0),
    damping_n_s_per_m=st.floats(1e-4, 5.0),
    client_stiffness_n_per_m=st.floats(0.01, 1e3),
    server_stiffness_n_per_m=st.floats(0.0, 1e3),
    server_damping_n_s_per_m=st.floats(0.0, 2.0),
)


@settings(max_examples=300, deadline=None)
@given(
    model=models,
    rtt=st.floats(0.0, 2.0),
    allowable=st.floats(0.0, 1.0),
    floor_fraction=st.floats(0.0, 1.0),
    distortion=st.sampled_from(["mass", "damping"]),
)
def test_proposed_schedule_against_its_formula(model, rtt, allowable, floor_fraction, distortion):
    kh = model.client_stiffness_n_per_m
    floor = floor_fraction * kh
    k = proposed_spring_n_per_m(model, rtt, distortion, allowable, floor)
    m, b = model.mass_kg, model.damping_n_s_per_m
    ke, de = model.server_stiffness_n_per_m, model.server_damping_n_s_per_m
    if distortion == "mass":
        perceived = kh * (m + (b + de) * rtt + ke * rtt**2 / 2) / m
    else:
        perceived = kh * (b + ke * rtt) / b
    expected = kh if rtt <= allowable else max(floor, kh - (perceived - kh))
    assert k == pytest.approx(expected, rel=1e-12, abs=1e-12)
    assert floor <= k <= kh * (1 + 1e-12)
    # a longer round trip never gives a larger spring
    assert proposed_spring_n_per_m(model, rtt + 0.1, distortion, allowable, floor) <= k * (1 + 1e-12)


@settings(max_examples=300, deadline=None)
@given(
    rtt=st.floats(0.0, 5.0),
    k0=st.floats(0.0, 1e3),
    alpha=st.floats(0.0, 1e3),
    r0=st.floats(0.0, 1.0),
    floor=st.floats(0.0, 1e3),
)
def test_fujimoto04_schedule_against_its_formula(rtt, k0, alpha, r0, floor):
    k = fujimoto04_spring_n_per_m(rtt, k0, alpha, r0, floor)
    expected = k0 if rtt <= r0 else k0 - alpha * (rtt - r0)
    assert k == pytest.approx(max(floor, expected), rel=1e-12, abs=1e-12)
    assert k >= floor
    assert fujimoto04_spring_n_per_m(rtt + 0.1, k0, alpha, r0, floor) <= k


def test_schedules_at_the_seed_values():
    """R = 0.3 s past an allowable delay of 0.1 s: k_h' = k_h - (k_hm - k_h) = 2 * 0.5 - 0.5465."""
    k = proposed_spring_n_per_m(SEED, 0.3, "mass", 0.1, 0.0)
    assert k == pytest.approx(1.0 - 0.5 * 0.27325 / 0.25)
    assert proposed_spring_n_per_m(SEED, 0.05, "mass", 0.1, 0.0) == 0.5
    assert proposed_spring_n_per_m(SEED, 0.3, "damping", 0.1, 0.05) == 0.05  # k_hb = 30.5: floored
    assert fujimoto04_spring_n_per_m(0.3, 0.5, 1.0, 0.1, 0.1) == pytest.approx(0.3)
    assert fujimoto04_spring_n_per_m(0.3, 0.5, 10.0, 0.1, 0.1) == 0.1


# --- several clients ------------------------------------------------------------------------------

GROUP = NveModel(0.25, 0.6, 0.8, 1.2, client_damping_n_s_per_m=0.05, server_damping_n_s_per_m=0.1)
# partners: (k_e, d_e, one-way up delay, held HIP position)
PARTNER_SETS = [
    [(0.7, 0.05, 0.02, 0.1), (0.5, 0.0, 0.4, -0.2)],
    [(0.7, 0.05, 0.35, -0.3), (0.5, 0.0, 0.01, 0.5)],  # the same couplings, other delays and holds
]


@pytest.mark.parametrize("partners", PARTNER_SETS)
def test_client_impedance_with_partners_matches_simulation(partners):
    w, up, down = 1.1, 0.2, 0.1
    model = with_partners(GROUP, [p[0] for p in partners], [p[1] for p in partners])
    assert model.partner_stiffness_n_per_m == pytest.approx(1.2)
    assert model.partner_damping_n_s_per_m == pytest.approx(0.05)
    z_sim = simulate_force(GROUP, w, up, down, partners)
    z = complex(impedance(model, np.array([w]), up + down)[0])
    assert abs(z_sim - z) <= 1e-4 * abs(z)
    # the partners change what the client feels (they are part of its environment) ...
    assert abs(z - impedance(GROUP, np.array([w]), up + down)[0]) > 0.05 * abs(z)
    # ... observers (k_e = d_e = 0) do not, wherever they hold their HIPs and whatever their delay
    z_obs = simulate_force(GROUP, w, up, down, [*partners, (0.0, 0.0, 0.7, 3.0)])
    assert abs(z_obs - z_sim) <= 1e-9 * abs(z)


def test_partners_delays_do_not_enter():
    """Same couplings, other partner delays and holds: the same impedance (to simulation accuracy)."""
    w, up, down = 1.1, 0.2, 0.1
    z = [simulate_force(GROUP, w, up, down, p) for p in PARTNER_SETS]
    assert abs(z[0] - z[1]) <= 1e-5 * abs(z[0])


@pytest.mark.parametrize("rtt_s", (0.05, 0.3, 1.0))
@pytest.mark.parametrize(("stiff", "damp"), [(0.5, 0.0), (2.0, 0.3), (0.0, 0.3)])
def test_distortions_with_partners(rtt_s, stiff, damp):
    """b_h = b + (k_e + K) R, m_h = m + (b + D + d_e) R + (k_e + K) R^2/2: third-order residual
    (relative w^3 when K > 0, the force being spring-like then; w^2 when K = 0). The one-client
    formulas (k_e alone) fail."""
    base = MODELS["seed_de"]
    model = with_partners(base, [stiff], [damp])
    mh, bh = distorted_mass_kg(model, rtt_s), distorted_damping_n_s_per_m(model, rtt_s)
    assert bh == pytest.approx(base.damping_n_s_per_m + (0.5 + stiff) * rtt_s)
    assert mh == pytest.approx(0.25 + (0.0025 + damp + 0.05) * rtt_s + (0.5 + stiff) * rtt_s**2 / 2)
    r = residual(model, rtt_s, mh, bh)
    order = 3.0 if stiff > 0 else 2.0
    assert np.allclose(clean_slopes(W_LOW, r, w_max=1e-1), order, atol=0.03), slopes(W_LOW, r)
    c3 = third_order_coefficient(model, rtt_s)
    ke = base.server_stiffness_n_per_m
    lead = ke * c3 / (stiff * (stiff + ke)) if stiff > 0 else c3 / (bh + damp)
    assert leading_coefficient(W_LOW, r, order) == pytest.approx(lead, rel=1e-3)
    wrong = residual(model, rtt_s, distorted_mass_kg(base, rtt_s), distorted_damping_n_s_per_m(base, rtt_s))
    assert np.all(clean_slopes(W_LOW, wrong, w_max=1e-1) < order - 0.9)
    mf, bf, kf = extract_object(model, rtt_s, np.linspace(1e-3, 4e-3, 16))
    assert mf == pytest.approx(mh, rel=1e-6) and bf == pytest.approx(bh, rel=1e-6)
    assert kf == pytest.approx(0.5 + stiff, rel=1e-9)


def test_damping_based_spring_with_partner_damping_and_no_distortion_in_the_stiffness_band():
    rtt_s = 0.3
    damped = with_partners(SEED, [0.0], [0.05])
    w = 1e-3 * (damped.damping_n_s_per_m + 0.05) / damped.mass_kg
    assert damping_based_spring_n_per_m(damped, rtt_s) == pytest.approx(0.5 * (0.0025 + 0.15 + 0.05) / 0.0525)
    assert spring_error(damped, rtt_s, w, damping_based_spring_n_per_m(damped, rtt_s)) < 1e-3
    # a pushing partner holds the object with a spring: at the lowest frequencies the delayed force
    # is the undelayed one (no spring distortion), k_h itself matches
    held = with_partners(SEED, [0.5])
    assert spring_error(held, rtt_s, 1e-5, held.client_stiffness_n_per_m) < 1e-3
    assert spring_error(held, rtt_s, 1e-5, damping_based_spring_n_per_m(held, rtt_s)) > 1.0


def test_observers_change_nothing():
    obs = with_partners(SEED, [0.0, 0.0], [0.0, 0.0])
    assert obs == SEED
    for r in (0.0, 0.3):
        assert np.array_equal(impedance(obs, W_LOW, r), impedance(SEED, W_LOW, r))
