"""The server's energy balance in an NVE run, from the recorded signals (docs/nve_scenes.md, "The
server's energy balance").

Over tick n the server holds each client's received HIP (h_i, g_i: position and velocity, the
sample its buffer released last) and the object moves exactly under

    m x'' = -b x' + sum_i [k_e,i (h_i - x) + d_e,i (g_i - x')].

Its stored energy S = m |x'|^2 / 2 + sum_i k_e,i |h_i - x|^2 / 2 changes within the tick by
-integral (b + sum d_e) |x'|^2 + sum_i d_e,i g_i . (x(n+1) - x(n)) (h is constant), and at the
tick boundary, where a new sample replaces h_i, by k_e,i (|h_i' - x|^2 - |h_i - x|^2) / 2: the
work the received HIPs put in. So D(n) = W_in(n) - (S(n) - S(0)) is the energy dissipated by the
object's damping and the couplings' dampers up to tick n, >= 0 for a passive server: the margin.
Everything here comes from the bag's rows (the object's x, v; each client's HIP columns at the tick
its released sample was sent), never from the server's own state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClientPort:
    """One client's coupling at the server and its recorded signals (arrays over ticks)."""

    stiffness_n_per_m: float
    damping_n_s_per_m: float
    hip_x_m: np.ndarray  # (ticks, axes): the HIP each tick sent
    hip_v_m_per_s: np.ndarray
    up_rx_seq: np.ndarray  # (ticks,): the tick whose sample the server released at each tick, -1 none


def _held(port: ClientPort) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(h, g, active) per tick: the HIP sample the server held for each tick's step."""
    rx = np.asarray(port.up_rx_seq)
    idx = np.where(rx >= 0, np.arange(len(rx)), -1)
    last = np.maximum.accumulate(idx) if len(idx) else idx  # the tick of the latest release so far
    active = last >= 0
    src = np.where(active, rx[np.maximum(last, 0)], 0).astype(np.int64)
    return port.hip_x_m[src], port.hip_v_m_per_s[src], active


def step_dissipation_j(
    mass_kg: float, obj_x_m: np.ndarray, obj_v_m_per_s: np.ndarray, ports: list[ClientPort]
) -> tuple[np.ndarray, np.ndarray]:
    """(d, S): the energy each tick's step dissipated, d(n) = S_start(n) + W_damper(n) - S_end(n)
    (>= 0 for a passive server; the run's last tick has no end and gives 0), and S_start(n), the
    stored energy at the start of each step (for the tolerance: roundoff is relative to it)."""
    n = len(obj_x_m)
    if n == 0:
        return np.zeros(0), np.zeros(0)
    x = np.asarray(obj_x_m, dtype=np.float64)
    v = np.asarray(obj_v_m_per_s, dtype=np.float64)
    kinetic = 0.5 * mass_kg * np.sum(v * v, axis=1)
    start = kinetic.copy()  # S at the start of tick n's step (its held h)
    end = np.zeros(n)  # S at the end of tick n's step, same held h: x(n+1), v(n+1)
    end[:-1] = kinetic[1:]
    work = np.zeros(n)  # the input through the dampers over tick n's step
    dx = np.zeros_like(x)
    dx[:-1] = x[1:] - x[:-1]
    for p in ports:
        h, g, active = _held(p)
        start += 0.5 * p.stiffness_n_per_m * np.sum((h - x) ** 2, axis=1) * active
        end[:-1] += 0.5 * p.stiffness_n_per_m * np.sum((h[:-1] - x[1:]) ** 2, axis=1) * active[:-1]
        work += p.damping_n_s_per_m * np.sum(g * dx, axis=1) * active
    d = start + work - end
    d[-1] = 0.0
    return d, start
