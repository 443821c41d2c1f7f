"""A discrete task-space admittance for position- or velocity-controlled arms (docs/ur.md,
"servoL/speedL with an admittance").

Per axis, a virtual mass M (kg) and damper D (N s/m) driven by the commanded force plus the
measured external force:

    M dv/dt + D v = f_cmd + f_ext

f_cmd is the force the teleoperation law wants the tool to apply to the environment (the robot
pushes with f_cmd); f_ext is the environment's force on the tool, as the wrist sensor measures
it. In free space the tool reaches v = f_cmd / D; against a wall it stops where f_ext = -f_cmd,
so the wall feels f_cmd. The robot is then commanded the admittance's velocity (speedL) or
position (servoL).

Discretisation: exact for a force held over each period h (zero-order hold), with
a = exp(-D h / M):
    v[k+1] = a v[k] + (1 - a) f / D
    x[k+1] = x[k] + (M / D)(1 - a) v[k] + (f / D)(h - (M / D)(1 - a))
so the samples equal the continuous step response, and the energy the force puts in over a
period, f (x[k+1] - x[k]), equals the kinetic energy gained plus what D dissipated: the discrete
admittance is passive for every D > 0 (no sampling energy leak). Pure numpy, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AdmittanceParams:
    """Virtual mass (kg, or kg m^2 for rotations) and damping (N s/m, N m s/rad) per axis; period h (s)."""

    mass: tuple[float, ...]
    damping: tuple[float, ...]
    period_s: float

    def __post_init__(self) -> None:
        if len(self.mass) != len(self.damping) or not self.mass:
            raise ValueError(f"mass and damping need one value per axis ({len(self.mass)} vs {len(self.damping)})")
        if any(not (m > 0.0 and math.isfinite(m)) for m in self.mass):
            raise ValueError(f"every virtual mass must be > 0 and finite, got {self.mass}")
        if any(not (d > 0.0 and math.isfinite(d)) for d in self.damping):
            raise ValueError(f"every damping must be > 0 (the admittance's passivity needs it), got {self.damping}")
        if not (self.period_s > 0.0 and math.isfinite(self.period_s)):
            raise ValueError(f"period_s must be > 0, got {self.period_s}")

    @property
    def time_constant_s(self) -> np.ndarray:
        """M / D per axis: the admittance's own lag (its velocity reaches 63 % of f/D after this)."""
        out: np.ndarray = np.asarray(self.mass) / np.asarray(self.damping)
        return out


class Admittance:
    """The state (offset x from the start, velocity v) of one admittance; `step` advances one period."""

    def __init__(self, params: AdmittanceParams) -> None:
        self.params = params
        m = np.asarray(params.mass, dtype=float)
        d = np.asarray(params.damping, dtype=float)
        h = params.period_s
        self._a = np.exp(-d * h / m)
        self._tau = m / d
        self._d = d
        self._h = h
        self.x = np.zeros(len(m))
        self.v = np.zeros(len(m))

    def reset(self) -> None:
        self.x[:] = 0.0
        self.v[:] = 0.0

    def step(self, f_cmd: np.ndarray, f_ext: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hold f = f_cmd + f_ext over one period; returns (x, v) at its end (copies)."""
        f = np.asarray(f_cmd, dtype=float) + np.asarray(f_ext, dtype=float)
        g = 1.0 - self._a
        self.x = self.x + self._tau * g * self.v + (f / self._d) * (self._h - self._tau * g)
        self.v = self._a * self.v + g * f / self._d
        return self.x.copy(), self.v.copy()

    def energy_j(self) -> float:
        """Kinetic energy of the virtual mass."""
        return float(0.5 * np.sum(np.asarray(self.params.mass) * self.v * self.v))


def step_response(params: AdmittanceParams, f: np.ndarray, t_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The continuous admittance's (x, v) at time t after a force step f from rest (closed form)."""
    m = np.asarray(params.mass, dtype=float)
    d = np.asarray(params.damping, dtype=float)
    tau = m / d
    e = np.exp(-t_s / tau)
    v = np.asarray(f, dtype=float) / d * (1.0 - e)
    x = np.asarray(f, dtype=float) / d * (t_s - tau * (1.0 - e))
    return x, v


def delayed_wall_damping_margin(stiffness_n_per_m: float, lag_s: float) -> float:
    """The least admittance damping (N s/m) for which a wall of this stiffness, seen through a robot
    whose position lags the admittance by `lag_s`, stays passive to first order: D > K T / 2
    (docs/ur.md, "Passivity and lag")."""
    return 0.5 * stiffness_n_per_m * lag_s
