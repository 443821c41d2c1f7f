"""Transparency of a client-server haptic NVE against round-trip time (seed 000), and the spring
coefficient schedules that compensate its distortion.

The model (docs/nve.md, "Model"): a consistency server integrates a virtual object of mass m and
damping b, pulled by a spring-damper (k_e, d_e) toward the client's haptic interaction pointer
(HIP) as the server last received it; the client feels a spring-damper (k_h, d_h) toward the
object as it last received it. With a one-way delay T1 up and T2 down, R = T1 + T2:

    X_o = C_e e^{-s T1} X_h / (m s^2 + b s + C_e),        C_e = k_e + d_e s
    F_h = C_h (X_h - e^{-s T2} X_o),                      C_h = k_h + d_h s

so the impedance the user feels (F_h over the HIP's velocity V_h = s X_h) depends on R alone:

    Z_h(s; R) = C_h (m s^2 + b s + C_e (1 - e^{-s R})) / (s (m s^2 + b s + C_e)).

Low-frequency approximation (human input is slow): the undelayed object (m_h, b_h) that gives the
same Z_h to second order in s is

    b_h = b + k_e R,        m_h = m + (b + d_e) R + k_e R^2 / 2,

and the spring coefficients that give, without delay and with the true object, the force the
delayed system gives are k_hm = k_h m_h / m (mass-based) and k_hb = k_h b_h / b (damping-based).
Derivations and their checks against the exact Z_h are in docs/nve.md. Pure functions on floats
(numpy only for the frequency response): no I/O, no clock.

Other clients (docs/nve.md, "Several clients"): partners that hold their HIPs still and push the
object with their own couplings act on it as a spring-damper to ground, K = sum k_e,j and
D = sum d_e,j over the partners (`NveModel.partner_*`, `with_partners`). Client i's impedance is then

    Z_i(s; R_i) = C_h (D_i(s) - C_e e^{-s R_i}) / (s D_i(s)),   D_i = m s^2 + (b + D) s + K + C_e,

which holds the client's own round trip R_i only (not the partners' delays), and the distortions keep
their form with the total coupling: b_h = b + (k_e + K) R, m_h = m + (b + D + d_e) R + (k_e + K) R^2/2.
Observers (k_e = d_e = 0) add nothing. With no partners every formula is the one-client one above.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

DISTORTIONS = ("mass", "damping")
RULES = ("auto", *DISTORTIONS)


@dataclass(frozen=True)
class NveModel:
    """One client's view of the NVE: the object, the two couplings, and the other clients' total
    coupling to the object (partners holding their HIPs still: a spring-damper to ground; 0 for a
    single client or observers only). SI units."""

    mass_kg: float
    damping_n_s_per_m: float
    client_stiffness_n_per_m: float
    server_stiffness_n_per_m: float
    client_damping_n_s_per_m: float = 0.0
    server_damping_n_s_per_m: float = 0.0
    partner_stiffness_n_per_m: float = 0.0
    partner_damping_n_s_per_m: float = 0.0

    def __post_init__(self) -> None:
        if not self.mass_kg > 0.0:
            raise ValueError(f"mass_kg must be > 0, got {self.mass_kg}")
        for name in (
            "damping_n_s_per_m",
            "client_stiffness_n_per_m",
            "server_stiffness_n_per_m",
            "client_damping_n_s_per_m",
            "server_damping_n_s_per_m",
            "partner_stiffness_n_per_m",
            "partner_damping_n_s_per_m",
        ):
            v = getattr(self, name)
            if not (v >= 0.0 and math.isfinite(v)):
                raise ValueError(f"{name} must be finite and >= 0, got {v}")


def with_partners(
    model: NveModel,
    server_stiffnesses_n_per_m: Sequence[float],
    server_dampings_n_s_per_m: Sequence[float] = (),
) -> NveModel:
    """`model` (one client's) with the other clients' server couplings k_e,j (and d_e,j) added to
    its partner spring-damper (observers: 0)."""
    return replace(
        model,
        partner_stiffness_n_per_m=model.partner_stiffness_n_per_m + math.fsum(server_stiffnesses_n_per_m),
        partner_damping_n_s_per_m=model.partner_damping_n_s_per_m + math.fsum(server_dampings_n_s_per_m),
    )


def _coupling_stiffness(model: NveModel) -> float:
    """k_e + K: every spring that holds the object (own coupling and partners')."""
    return model.server_stiffness_n_per_m + model.partner_stiffness_n_per_m


def _object_damping(model: NveModel) -> float:
    """b + D: the object's damping with the partners' coupling damping (undistorted by R)."""
    return model.damping_n_s_per_m + model.partner_damping_n_s_per_m


def impedance(model: NveModel, w_rad_per_s: np.ndarray, rtt_s: float) -> np.ndarray:
    """Z_h(j w; R) = F_h / V_h, complex, at each angular frequency (> 0), R >= 0 the round trip."""
    w = np.asarray(w_rad_per_s, dtype=np.float64)
    if not bool(np.all(w > 0.0)) or not bool(np.all(np.isfinite(w))):
        raise ValueError("w_rad_per_s must be finite and > 0")
    if not (rtt_s >= 0.0 and math.isfinite(rtt_s)):
        raise ValueError(f"rtt_s must be finite and >= 0, got {rtt_s}")
    s = 1j * w
    m = model.mass_kg
    ch = model.client_stiffness_n_per_m + model.client_damping_n_s_per_m * s
    ce = model.server_stiffness_n_per_m + model.server_damping_n_s_per_m * s
    # the object with the partners' coupling as a spring-damper to ground, without the client's own
    rest = m * s * s + _object_damping(model) * s + model.partner_stiffness_n_per_m
    den = rest + ce
    # 1 - e^{-sR} without cancellation at small |sR|: -expm1(-sR)
    lag = -np.expm1(-s * rtt_s)
    out: np.ndarray = ch * (rest + ce * lag) / (s * den)
    return out


def distorted_damping_n_s_per_m(model: NveModel, rtt_s: float) -> float:
    """b_h = b + k_e R: the damping of the undelayed object that feels like the delayed one
    (with partners: b + (k_e + K) R)."""
    return model.damping_n_s_per_m + _coupling_stiffness(model) * rtt_s


def distorted_mass_kg(model: NveModel, rtt_s: float) -> float:
    """m_h = m + (b + d_e) R + k_e R^2 / 2 (with partners: m + (b + D + d_e) R + (k_e + K) R^2 / 2)."""
    c0 = _object_damping(model) + model.server_damping_n_s_per_m
    return model.mass_kg + c0 * rtt_s + 0.5 * _coupling_stiffness(model) * rtt_s * rtt_s


def damping_gradient(model: NveModel) -> float:
    """c_b = d b_h / d R = k_e (b_h is linear in R; with partners k_e + K)."""
    return _coupling_stiffness(model)


def mass_gradient(model: NveModel, rtt_s: float = 0.0) -> float:
    """c_m = d m_h / d R at R: b + d_e + k_e R (the tangent; at R = 0 the initial gradient;
    with partners b + D + d_e + (k_e + K) R)."""
    return _object_damping(model) + model.server_damping_n_s_per_m + _coupling_stiffness(model) * rtt_s


def mass_based_spring_n_per_m(model: NveModel, rtt_s: float) -> float:
    """k_hm = k_h m_h / m."""
    return model.client_stiffness_n_per_m * distorted_mass_kg(model, rtt_s) / model.mass_kg


def damping_based_spring_n_per_m(model: NveModel, rtt_s: float) -> float:
    """k_hb = k_h b_h / b (needs b > 0; with partners k_h (b_h + D) / (b + D))."""
    b = _object_damping(model)
    if b <= 0.0:
        raise ValueError("the damping-based spring distortion needs an object damping b > 0")
    return (
        model.client_stiffness_n_per_m
        * (distorted_damping_n_s_per_m(model, rtt_s) + model.partner_damping_n_s_per_m)
        / b
    )


def dominant_distortion(model: NveModel, interaction_rad_per_s: float) -> str:
    """'mass' if the object's dynamics at the user's interaction frequency w are dominated by its
    mass (m w >= b; with partners m w >= b + D), else 'damping' (the rule of seed 000, slide
    "Distortion of spring coefficient"). It picks the spring distortion closer to the delayed
    system's for R -> 0; at larger R the crossover moves up to `distortion_crossover_rad_per_s`
    (docs/nve.md, "Which spring distortion applies")."""
    if not interaction_rad_per_s > 0.0:
        raise ValueError(f"interaction_rad_per_s must be > 0, got {interaction_rad_per_s}")
    return "mass" if model.mass_kg * interaction_rad_per_s >= _object_damping(model) else "damping"


def distortion_crossover_rad_per_s(model: NveModel, rtt_s: float) -> float:
    """The interaction frequency at which k_hm and k_hb are equally far (in ratio) from the spring
    that reproduces the delayed system's low-frequency force: sqrt(b b_h / (m m_h)) (with partners
    b + D and b_h + D). Equals b / m, the seed's rule, at R = 0; grows with R."""
    b = _object_damping(model)
    bh = distorted_damping_n_s_per_m(model, rtt_s) + model.partner_damping_n_s_per_m
    return math.sqrt(b * bh / (model.mass_kg * distorted_mass_kg(model, rtt_s)))


def matching_distortion(model: NveModel, interaction_rad_per_s: float, rtt_s: float) -> str:
    """The seed's rule made exact at round trip R: 'mass' iff w >= `distortion_crossover_rad_per_s`
    (m m_h w^2 >= b b_h), i.e. iff k_hm is at least as close as k_hb to the spring that gives the
    delayed system's force at w (low-frequency model, docs/nve.md)."""
    if not interaction_rad_per_s > 0.0:
        raise ValueError(f"interaction_rad_per_s must be > 0, got {interaction_rad_per_s}")
    return "mass" if interaction_rad_per_s >= distortion_crossover_rad_per_s(model, rtt_s) else "damping"


def spring_distortion_n_per_m(model: NveModel, rtt_s: float, distortion: str) -> float:
    """The spring coefficient the user perceives at R: k_hm or k_hb."""
    if distortion == "mass":
        return mass_based_spring_n_per_m(model, rtt_s)
    if distortion == "damping":
        return damping_based_spring_n_per_m(model, rtt_s)
    raise ValueError(f"distortion must be one of {DISTORTIONS}, got {distortion!r}")


def allowable_rtt_damping_s(model: NveModel, allowable_damping_n_s_per_m: float) -> float:
    """The largest R with b_h(R) <= b_allowable: (b_allowable - b) / c_b (0 if already above;
    infinite if c_b = k_e (+ K) = 0)."""
    room = allowable_damping_n_s_per_m - model.damping_n_s_per_m
    if room <= 0.0:
        return 0.0
    cb = damping_gradient(model)
    return math.inf if cb == 0.0 else room / cb


def allowable_rtt_mass_s(model: NveModel, allowable_mass_kg: float) -> float:
    """The largest R with m_h(R) <= m_allowable: the positive root of
    k_e R^2 / 2 + (b + d_e) R - (m_allowable - m) = 0, i.e. the integral of the gradient c_m(R)
    from 0 reaching m_allowable - m (0 if already above; with partners k_e + K and b + D + d_e)."""
    room = allowable_mass_kg - model.mass_kg
    if room <= 0.0:
        return 0.0
    c0 = mass_gradient(model, 0.0)
    ke = _coupling_stiffness(model)
    if ke == 0.0:
        return math.inf if c0 == 0.0 else room / c0
    # numerically stable positive root of (ke/2) R^2 + c0 R - room
    return 2.0 * room / (c0 + math.sqrt(c0 * c0 + 2.0 * ke * room))


def proposed_spring_n_per_m(
    model: NveModel,
    rtt_s: float,
    distortion: str,
    allowable_rtt_s: float,
    min_spring_n_per_m: float,
) -> float:
    """Seed 000's delay compensation: within the allowable delay the spring is left as it is; past
    it, the spring increment the user perceives (k_hd(R) - k_h) is subtracted from k_h, not below
    `min_spring_n_per_m`."""
    kh = model.client_stiffness_n_per_m
    if not rtt_s > allowable_rtt_s:
        return kh
    increment = spring_distortion_n_per_m(model, rtt_s, distortion) - kh
    return max(min_spring_n_per_m, kh - increment)


def fujimoto04_spring_n_per_m(
    rtt_s: float,
    initial_spring_n_per_m: float,
    reduction_n_per_m_per_s: float,
    threshold_rtt_s: float,
    min_spring_n_per_m: float,
) -> float:
    """The baseline (Fujimoto04 as seed 000 describes it: the spring coefficient changed with the
    measured end-to-end delay): K = K_0 - alpha max(0, R - R_0), not below K_min. K_0, alpha and R_0
    are its initial settings, found by trial and error (docs/nve.md, "Fujimoto04")."""
    return max(min_spring_n_per_m, initial_spring_n_per_m - reduction_n_per_m_per_s * max(0.0, rtt_s - threshold_rtt_s))
