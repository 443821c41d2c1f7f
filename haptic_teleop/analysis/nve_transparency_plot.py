"""Figures and the table of the NVE transparency analysis (docs/nve.md): the magnitude of the
impedance the user feels against round-trip time, with its low-frequency approximations, and the
distortions (m_h, b_h, k_hm, k_hb) against round-trip time. Everything is computed from
`core/nve_transparency.py` (no bag needed). Figures are plain `matplotlib.figure.Figure` objects (no
pyplot state), saved as PNG."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from haptic_teleop.core.nve_transparency import (
    NveModel,
    allowable_rtt_damping_s,
    allowable_rtt_mass_s,
    damping_based_spring_n_per_m,
    distorted_damping_n_s_per_m,
    distorted_mass_kg,
    distortion_crossover_rad_per_s,
    impedance,
    mass_based_spring_n_per_m,
    mass_gradient,
)

DPI = 100
W_MIN_RAD_PER_S = 1e-6
W_MAX_RAD_PER_S = 1e2
DEFAULT_RTTS_S = (0.0, 0.05, 0.1, 0.2, 0.3)
POINTS = 1200


def check_rtts(rtts_s: Sequence[float]) -> tuple[float, ...]:
    """The round trips to draw: 1 to 10 distinct finite values >= 0, in increasing order."""
    out = tuple(float(r) for r in rtts_s)
    if not 1 <= len(out) <= 10:
        raise ValueError(f"rtts must hold 1 to 10 round-trip times, got {len(out)}")
    for r in out:
        if not (math.isfinite(r) and r >= 0.0):
            raise ValueError(f"each round-trip time must be finite and >= 0 s, got {r}")
    if any(b <= a for a, b in itertools.pairwise(out)):
        raise ValueError(f"round-trip times must be distinct and increasing, got {list(out)}")
    return out


def _undelayed_impedance(model: NveModel, w: np.ndarray, mass_kg: float, damping_n_s_per_m: float) -> np.ndarray:
    """The low-frequency approximation: the undelayed loop with the object (m_h, b_h)."""
    undelayed = NveModel(
        mass_kg=mass_kg,
        damping_n_s_per_m=damping_n_s_per_m,
        client_stiffness_n_per_m=model.client_stiffness_n_per_m,
        server_stiffness_n_per_m=model.server_stiffness_n_per_m,
        client_damping_n_s_per_m=model.client_damping_n_s_per_m,
        server_damping_n_s_per_m=model.server_damping_n_s_per_m,
        partner_stiffness_n_per_m=model.partner_stiffness_n_per_m,
        partner_damping_n_s_per_m=model.partner_damping_n_s_per_m,
    )
    return impedance(undelayed, w, 0.0)


def _model_label(model: NveModel) -> str:
    return (
        f"m = {model.mass_kg:g} kg, b = {model.damping_n_s_per_m:g} N s/m, "
        f"k_h = {model.client_stiffness_n_per_m:g} N/m, k_e = {model.server_stiffness_n_per_m:g} N/m"
    )


def impedance_figure(model: NveModel, rtts_s: Sequence[float] = DEFAULT_RTTS_S) -> Figure:
    """|Z_h(jw; R)| over 1e-6..1e2 rad/s, one solid line per R; the low-frequency approximation
    (undelayed loop with m_h, b_h) dashed in the same colour; |Z_e| = |m jw + b| dotted."""
    rtts = check_rtts(rtts_s)
    w = np.logspace(math.log10(W_MIN_RAD_PER_S), math.log10(W_MAX_RAD_PER_S), POINTS)
    fig = Figure(figsize=(9.0, 6.0))
    ax = fig.add_subplot(1, 1, 1)
    colors = [f"C{i}" for i in range(len(rtts))]
    for r, c in zip(rtts, colors, strict=True):
        ax.loglog(w, np.abs(impedance(model, w, r)), color=c, lw=1.6, label=f"|Z_h|, R = {r * 1e3:g} ms")
        if r > 0.0:
            approx = _undelayed_impedance(model, w, distorted_mass_kg(model, r), distorted_damping_n_s_per_m(model, r))
            ax.loglog(
                w,
                np.abs(approx),
                color=c,
                lw=1.2,
                ls="--",
                label=f"low-frequency approx. (m_h, b_h), R = {r * 1e3:g} ms",
            )
    ze = np.abs(model.mass_kg * 1j * w + model.damping_n_s_per_m)
    ax.loglog(w, ze, color="black", lw=1.2, ls=":", label="|Z_e| = |m jw + b| (the object alone)")
    ax.set_xlim(W_MIN_RAD_PER_S, W_MAX_RAD_PER_S)
    ax.set_xlabel("angular frequency w [rad/s]")
    ax.set_ylabel("|Z| = |F_h / V_h| [N s/m]")
    ax.set_title(f"Impedance felt by the user against round trip R\n{_model_label(model)}", fontsize=10)
    ax.grid(True, which="major", alpha=0.4)
    ax.grid(True, which="minor", alpha=0.12)
    ax.legend(fontsize=7.5, loc="upper left", ncol=2)
    fig.tight_layout()
    return fig


def distortion_figure(model: NveModel, rtt_max_s: float) -> Figure:
    """m_h/m and b_h/b (left) and the spring distortions k_hm, k_hb with k_h (right) against R in
    [0, rtt_max_s], log y."""
    if not (math.isfinite(rtt_max_s) and rtt_max_s > 0.0):
        raise ValueError(f"rtt_max must be finite and > 0 s, got {rtt_max_s}")
    r = np.linspace(0.0, rtt_max_s, 400)
    mh = np.array([distorted_mass_kg(model, x) for x in r])
    bh = np.array([distorted_damping_n_s_per_m(model, x) for x in r])
    khm = np.array([mass_based_spring_n_per_m(model, x) for x in r])
    fig = Figure(figsize=(11.0, 4.8))
    ax1, ax2 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    ax1.semilogy(r, mh / model.mass_kg, color="C0", lw=1.6, label="m_h / m (distorted mass)")
    ax2.semilogy(r, khm, color="C0", lw=1.6, label="k_hm = k_h m_h / m (mass-based)")
    if model.damping_n_s_per_m > 0.0:
        khb = np.array([damping_based_spring_n_per_m(model, x) for x in r])
        ax1.semilogy(r, bh / model.damping_n_s_per_m, color="C1", lw=1.6, label="b_h / b (distorted damping)")
        ax2.semilogy(r, khb, color="C1", lw=1.6, label="k_hb = k_h b_h / b (damping-based)")
    ax2.axhline(model.client_stiffness_n_per_m, color="black", lw=1.0, ls=":", label="k_h (undistorted)")
    ax1.set_ylabel("ratio to the true value [-]")
    ax1.set_title("Perceived mass and damping", fontsize=10)
    ax2.set_ylabel("perceived spring coefficient [N/m]")
    ax2.set_title("Perceived spring coefficient", fontsize=10)
    for ax in (ax1, ax2):
        ax.set_xlabel("round-trip time R [s]")
        ax.set_xlim(0.0, rtt_max_s)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(_model_label(model), fontsize=10)
    fig.tight_layout()
    return fig


def write_impedance_plot(path: Path | str, model: NveModel, rtts: Sequence[float] = DEFAULT_RTTS_S) -> Path:
    """Save `impedance_figure` as a PNG; returns the path."""
    fig = impedance_figure(model, rtts)
    out = Path(path)
    fig.savefig(out, dpi=DPI)
    return out


def write_distortion_plot(path: Path | str, model: NveModel, rtt_max: float) -> Path:
    """Save `distortion_figure` as a PNG; returns the path."""
    fig = distortion_figure(model, rtt_max)
    out = Path(path)
    fig.savefig(out, dpi=DPI)
    return out


def distortion_table(model: NveModel, rtts_s: Sequence[float]) -> str:
    """A markdown table, one row per R: m_h, b_h (and their ratios to m, b), the mass gradient c_m(R),
    k_hm, k_hb, and the crossover sqrt(b b_h / (m m_h)) between the two spring distortions."""
    rtts = check_rtts(rtts_s)
    lines = [
        "| R [s] | m_h [kg] | m_h/m | b_h [N s/m] | b_h/b | c_m(R) [kg/s] "
        "| k_hm [N/m] | k_hb [N/m] | crossover [rad/s] |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    m, b = model.mass_kg, model.damping_n_s_per_m
    for r in rtts:
        mh, bh = distorted_mass_kg(model, r), distorted_damping_n_s_per_m(model, r)
        b_ratio = f"{bh / b:.5g}" if b > 0.0 else "-"
        khb = f"{damping_based_spring_n_per_m(model, r):.5g}" if b > 0.0 else "-"
        lines.append(
            f"| {r:g} | {mh:.6g} | {mh / m:.5g} | {bh:.6g} | {b_ratio} | {mass_gradient(model, r):.5g} "
            f"| {mass_based_spring_n_per_m(model, r):.5g} | {khb} | {distortion_crossover_rad_per_s(model, r):.4g} |"
        )
    return "\n".join(lines) + "\n"


def allowable_table(model: NveModel, ratios: Sequence[float]) -> str:
    """A markdown table, one row per ratio x: m_allowable = x m and its allowable delay R_m (exact,
    the root of m_h(R) = m_allowable), the linear prediction with the initial gradient c_m(0) for
    contrast, b_allowable = x b and its allowable delay R_b = (b_allowable - b) / c_b."""
    lines = [
        "| x | m_allowable = x m [kg] | R_m [s] | (m_allowable - m) / c_m(0) [s] "
        "| b_allowable = x b [N s/m] | R_b [s] |",
        "| ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    m, b = model.mass_kg, model.damping_n_s_per_m
    c0 = mass_gradient(model, 0.0)
    for x in ratios:
        if not (math.isfinite(x) and x >= 1.0):
            raise ValueError(f"each ratio must be finite and >= 1, got {x}")
        linear = (x - 1.0) * m / c0 if c0 > 0.0 else math.inf
        lines.append(
            f"| {x:g} | {x * m:.5g} | {allowable_rtt_mass_s(model, x * m):.4g} | {linear:.4g} "
            f"| {x * b:.5g} | {allowable_rtt_damping_s(model, x * b):.4g} |"
        )
    return "\n".join(lines) + "\n"
