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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DISTORTIONS = ("mass", "damping")
RULES = ("auto", *DISTORTIONS)


@dataclass(frozen=True)
class NveModel:
    """One client's view of the NVE: the object, the two couplings (SI units)."""

    mass_kg: float
    damping_n_s_per_m: float
    client_stiffness_n_per_m: float
    server_stiffness_n_per_m: float
    client_damping_n_s_per_m: float = 0.0
    server_damping_n_s_per_m: float = 0.0

    def __post_init__(self) -> None:
        if not self.mass_kg > 0.0:
            raise ValueError(f"mass_kg must be > 0, got {self.mass_kg}")
        for name in (
            "damping_n_s_per_m",
            "client_stiffness_n_per_m",
            "server_stiffness_n_per_m",
            "client_damping_n_s_per_m",
            "server_damping_n_s_per_m",
        ):
            v = getattr(self, name)
            if not (v >= 0.0 and math.isfinite(v)):
                raise ValueError(f"{name} must be finite and >= 0, got {v}")


def impedance(model: NveModel, w_rad_per_s: np.ndarray, rtt_s: float) -> np.ndarray:
    """Z_h(j w; R) = F_h / V_h, complex, at each angular frequency (> 0)."""
    s = 1j * np.asarray(w_rad_per_s, dtype=np.float64)
    m, b = model.mass_kg, model.damping_n_s_per_m
    ch = model.client_stiffness_n_per_m + model.client_damping_n_s_per_m * s
    ce = model.server_stiffness_n_per_m + model.server_damping_n_s_per_m * s
    den = m * s * s + b * s + ce
    # 1 - e^{-sR} without cancellation at small |sR|: -expm1(-sR)
    lag = -np.expm1(-s * rtt_s)
    out: np.ndarray = ch * (m * s * s + b * s + ce * lag) / (s * den)
    return out


def distorted_damping_n_s_per_m(model: NveModel, rtt_s: float) -> float:
    """b_h = b + k_e R: the damping of the undelayed object that feels like the delayed one."""
    return model.damping_n_s_per_m + model.server_stiffness_n_per_m * rtt_s


def distorted_mass_kg(model: NveModel, rtt_s: float) -> float:
    """m_h = m + (b + d_e) R + k_e R^2 / 2."""
    b_de = model.damping_n_s_per_m + model.server_damping_n_s_per_m
    return model.mass_kg + b_de * rtt_s + 0.5 * model.server_stiffness_n_per_m * rtt_s * rtt_s


def damping_gradient(model: NveModel) -> float:
    """c_b = d b_h / d R = k_e (b_h is linear in R)."""
    return model.server_stiffness_n_per_m


def mass_gradient(model: NveModel, rtt_s: float = 0.0) -> float:
    """c_m = d m_h / d R at R: b + d_e + k_e R (the tangent; at R = 0 the initial gradient)."""
    return model.damping_n_s_per_m + model.server_damping_n_s_per_m + model.server_stiffness_n_per_m * rtt_s


def mass_based_spring_n_per_m(model: NveModel, rtt_s: float) -> float:
    """k_hm = k_h m_h / m."""
    return model.client_stiffness_n_per_m * distorted_mass_kg(model, rtt_s) / model.mass_kg


def damping_based_spring_n_per_m(model: NveModel, rtt_s: float) -> float:
    """k_hb = k_h b_h / b (needs b > 0)."""
    b = model.damping_n_s_per_m
    if b <= 0.0:
        raise ValueError("the damping-based spring distortion needs an object damping b > 0")
    return model.client_stiffness_n_per_m * distorted_damping_n_s_per_m(model, rtt_s) / b


def dominant_distortion(model: NveModel, interaction_rad_per_s: float) -> str:
    """'mass' if the object's dynamics at the user's interaction frequency w are dominated by its
    mass (m w >= b), else 'damping' (the rule of seed 000, slide "Distortion of spring coefficient")."""
    if not interaction_rad_per_s > 0.0:
        raise ValueError(f"interaction_rad_per_s must be > 0, got {interaction_rad_per_s}")
    return "mass" if model.mass_kg * interaction_rad_per_s >= model.damping_n_s_per_m else "damping"


def spring_distortion_n_per_m(model: NveModel, rtt_s: float, distortion: str) -> float:
    """The spring coefficient the user perceives at R: k_hm or k_hb."""
    if distortion == "mass":
        return mass_based_spring_n_per_m(model, rtt_s)
    if distortion == "damping":
        return damping_based_spring_n_per_m(model, rtt_s)
    raise ValueError(f"distortion must be one of {DISTORTIONS}, got {distortion!r}")


def allowable_rtt_damping_s(model: NveModel, allowable_damping_n_s_per_m: float) -> float:
    """The largest R with b_h(R) <= b_allowable: (b_allowable - b) / c_b (0 if already above;
    infinite if k_e = 0)."""
    room = allowable_damping_n_s_per_m - model.damping_n_s_per_m
    if room <= 0.0:
        return 0.0
    cb = damping_gradient(model)
    return math.inf if cb == 0.0 else room / cb


def allowable_rtt_mass_s(model: NveModel, allowable_mass_kg: float) -> float:
    """The largest R with m_h(R) <= m_allowable: the positive root of
    k_e R^2 / 2 + (b + d_e) R - (m_allowable - m) = 0 (0 if already above)."""
    room = allowable_mass_kg - model.mass_kg
    if room <= 0.0:
        return 0.0
    c0 = model.damping_n_s_per_m + model.server_damping_n_s_per_m
    ke = model.server_stiffness_n_per_m
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
