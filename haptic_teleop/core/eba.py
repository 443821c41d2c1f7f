"""Energy Bounding Algorithm (EBA): per-axis energy reservoirs and the force bound that keeps them >= 0.

The laws, their derivation and every parameter are in docs/eba.md. In short, for each axis i with
physical damping b_i and period T, with dx = x(n) - x(n-1) and F(n-1) the force held over it:

    E_i(n) = E_i(n-1) + (b_i / T) dx_i^2 - F_i(n-1) dx_i          (reservoir)
    |F_i(n)| <= 2 sqrt(b_i E_i(n) / T)                            (bound)

The bound makes E_i(n+1) >= 0 for *any* next displacement, because min over dx of
(b/T) dx^2 - F dx is -F^2 T / (4 b).

The tick path works on plain lists of floats: for the one to six axes of a haptic device that is
several times cheaper than numpy, and it is the same code for every n.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

LAWS = ("position", "force")


@dataclass(frozen=True)
class EnergyBoundParams:
    """Parameters of one side's energy bound."""

    period_s: float
    damping_n_s_per_m: tuple[float, ...]
    initial_energy_j: float = 0.0
    enabled: bool = True

    def __post_init__(self) -> None:
        if not self.period_s > 0.0:
            raise ValueError(f"period_s must be > 0, got {self.period_s}")
        if not self.damping_n_s_per_m or any(not b > 0.0 for b in self.damping_n_s_per_m):
            raise ValueError(f"damping_n_s_per_m must be > 0 on every axis, got {self.damping_n_s_per_m}")
        if not self.initial_energy_j >= 0.0:
            raise ValueError(f"initial_energy_j must be >= 0, got {self.initial_energy_j}")

    @property
    def axes(self) -> int:
        return len(self.damping_n_s_per_m)

    def max_stiffness_n_per_m(self) -> tuple[float, ...]:
        """The stiffness the bounded force can grow with at most: 2 b / T per axis (Colgate)."""
        return tuple(2.0 * b / self.period_s for b in self.damping_n_s_per_m)


class EnergyBound:
    """One side's reservoirs and force bound; `step` is called once per tick."""

    __slots__ = ("_bound_gain", "_enabled", "_gain", "_held", "_last_x", "energy_j", "params")

    def __init__(self, params: EnergyBoundParams) -> None:
        self.params = params
        n = params.axes
        t = params.period_s
        self._gain = [b / t for b in params.damping_n_s_per_m]
        self._bound_gain = [4.0 * b / t for b in params.damping_n_s_per_m]
        # The initial energy is per axis: each axis is its own port with its own damping.
        self.energy_j = [params.initial_energy_j] * n
        self._held = [0.0] * n
        self._last_x: list[float] | None = None
        self._enabled = params.enabled

    def step(self, x: Sequence[float], force_desired: Sequence[float]) -> list[float]:
        """Account for the motion since the last tick, then bound the desired force.

        Returns the force to hold over the next period. With the bound disabled the reservoir is
        still kept (so the unprotected variant can be inspected) but the force passes unchanged.
        """
        energy = self.energy_j
        held = self._held
        last = self._last_x
        if last is not None:
            gain = self._gain
            for i in range(len(energy)):
                dx = x[i] - last[i]
                energy[i] += gain[i] * dx * dx - held[i] * dx
        self._last_x = list(x)
        if not self._enabled:
            out = list(force_desired)
        else:
            out = []
            bound_gain = self._bound_gain
            for i in range(len(energy)):
                e = energy[i]
                limit = math.sqrt(bound_gain[i] * e) if e > 0.0 else 0.0
                f = force_desired[i]
                if f > limit:
                    f = limit
                elif f < -limit:
                    f = -limit
                out.append(f)
        self._held = out
        return out

    @property
    def total_energy_j(self) -> float:
        return sum(self.energy_j)


@dataclass(frozen=True)
class ControllerParams:
    """One side's control law (before the energy bound) and its saturation."""

    role: str  # "master" or "slave"
    law: str = "position"  # "position": spring-damper on the remote sample; "force": force reflection
    stiffness_n_per_m: float = 1000.0  # c1
    damping_n_s_per_m: float = 10.0  # c2
    force_gain: float = 1.0  # force reflection gain (master with law "force")
    force_limit_n: float = 20.0

    def __post_init__(self) -> None:
        if self.role not in ("master", "slave"):
            raise ValueError(f"role must be 'master' or 'slave', got {self.role!r}")
        if self.law not in LAWS:
            raise ValueError(f"law must be one of {LAWS}, got {self.law!r}")
        if self.law == "force" and self.role != "master":
            raise ValueError("force reflection ('force' law) is a master law; the slave tracks position")
        if not self.force_limit_n > 0.0:
            raise ValueError(f"force_limit_n must be > 0, got {self.force_limit_n}")


class TeleopController:
    """Control law on the latest remote sample, saturation, then the energy bound.

    Remote payloads (flat tuples, n = axes):
      master -> slave: (x_1..x_n, v_1..v_n)
      slave -> master: (f_env_1..f_env_n, x_1..x_n, v_1..v_n), f_env the environment's force on
      the robot (negative when the robot pushes a wall at +x).
    """

    __slots__ = ("_n", "_remote", "bound", "force_applied", "force_desired", "params")

    def __init__(self, params: ControllerParams, bound: EnergyBoundParams) -> None:
        self.params = params
        self.bound = EnergyBound(bound)
        self._n = bound.axes
        self._remote: tuple[float, ...] | None = None
        self.force_desired = [0.0] * self._n
        self.force_applied = [0.0] * self._n

    def set_remote(self, payload: tuple[float, ...]) -> None:
        """The newest remote sample the playout buffer released."""
        self._remote = payload

    def desired_force(self, x: Sequence[float], v: Sequence[float]) -> list[float]:
        """The control law alone (no saturation, no bound)."""
        p = self.params
        n = self._n
        r = self._remote
        if r is None:
            return [0.0] * n
        if p.law == "force":
            g = p.force_gain
            return [g * r[i] for i in range(n)]
        off = n if p.role == "master" else 0  # master payload starts with forces
        c1 = p.stiffness_n_per_m
        c2 = p.damping_n_s_per_m
        return [c1 * (r[off + i] - x[i]) + c2 * (r[off + n + i] - v[i]) for i in range(n)]

    def step(self, x: Sequence[float], v: Sequence[float]) -> list[float]:
        """One tick: returns the force to apply (held until the next tick)."""
        desired = self.desired_force(x, v)
        lim = self.params.force_limit_n
        sat = [lim if f > lim else (-lim if f < -lim else f) for f in desired]
        self.force_desired = desired
        applied = self.bound.step(x, sat)
        self.force_applied = applied
        return applied
