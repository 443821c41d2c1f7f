"""A client-server haptic networked virtual environment (NVE, seed 000): the consistency server's
virtual object, each client's spring-damper force, the round trip a client measures from the
packets' stamps, and the spring schedules that compensate delay.

Model (docs/nve.md, "Model"): the server integrates one object of mass m and damping b, pulled
toward each client's haptic interaction pointer (HIP) *as the server last received it* by that
client's server-side spring-damper (k_e, d_e); a client whose HIP has not reached the server yet
pulls nothing, and a client with k_e = d_e = 0 is an observer. The object is integrated exactly
over one period with the received HIPs held (zero-order hold): one linear system per axis,
discretised once with the matrix exponential, so it is stable for any stiffness and mass. Each
client renders F = k_h (x_h - x_o') + d_h (v_h - v_o') toward the object as it last received it.

Measured round trip (as a real client measures it, with its own clock only): every object packet
echoes the send stamp of the newest HIP sample of that client the object state reflects; when the
client's playout buffer releases the packet at tick time t, R = t - echo.

Pure: no I/O, no clock; times are passed in (seconds, floats).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from haptic_teleop.core.nve_transparency import (
    NveModel,
    allowable_rtt_damping_s,
    allowable_rtt_mass_s,
    dominant_distortion,
    fujimoto04_spring_n_per_m,
    proposed_spring_n_per_m,
)

SCHEMES = ("none", "transparency", "fujimoto04")


def expm(a: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small square matrix: scaling and squaring of a Taylor series
    (terms until they no longer change the sum in double precision)."""
    a = np.asarray(a, dtype=np.float64)
    norm = float(np.abs(a).sum(axis=1).max()) if a.size else 0.0
    squarings = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    x = a / (2.0**squarings)
    out = np.eye(a.shape[0])
    term = np.eye(a.shape[0])
    for k in range(1, 40):
        term = term @ x / k
        out = out + term
        if float(np.abs(term).max()) <= 1e-18 * float(np.abs(out).max()):
            break
    for _ in range(squarings):
        out = out @ out
    return out


@dataclass(frozen=True)
class Coupling:
    """One client's two spring-dampers (SI units): k_h, d_h at the client, k_e, d_e at the server."""

    client_stiffness_n_per_m: float
    client_damping_n_s_per_m: float
    server_stiffness_n_per_m: float
    server_damping_n_s_per_m: float

    @property
    def pushes(self) -> bool:
        """False for an observer: its HIP exerts nothing on the object."""
        return self.server_stiffness_n_per_m > 0.0 or self.server_damping_n_s_per_m > 0.0


class ObjectServer:
    """The consistency server's object: exact zero-order-hold steps of

        m a = -b v + sum_i [k_e,i (x_hr,i - x) + d_e,i (v_hr,i - v)]

    per axis, over the clients whose HIP has arrived. `receive` takes a client's newest released
    HIP sample; `step` advances one period and remembers, per client, the send stamp of the HIP
    sample it used (`echo_s`): the object state it produces reflects that sample."""

    def __init__(
        self,
        mass_kg: float,
        damping_n_s_per_m: float,
        couplings: Sequence[Coupling],
        period_s: float,
        start_position_m: Sequence[float],
    ) -> None:
        if not mass_kg > 0.0:
            raise ValueError(f"mass_kg must be > 0, got {mass_kg}")
        if not period_s > 0.0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.mass_kg = mass_kg
        self.damping_n_s_per_m = damping_n_s_per_m
        self.couplings = tuple(couplings)
        self.period_s = period_s
        self.axes = len(start_position_m)
        self.x = np.array(start_position_m, dtype=np.float64)
        self.v = np.zeros(self.axes)
        n = len(self.couplings)
        self._hip_x = np.zeros((n, self.axes))
        self._hip_v = np.zeros((n, self.axes))
        self._hip_stamp = np.full(n, math.nan)
        self._arrived = np.zeros(n, dtype=bool)
        self.echo_s = np.full(n, math.nan)  # per client: the HIP stamp the current state reflects
        self.coupling_force_n = np.zeros(self.axes)
        self._ke = np.array([c.server_stiffness_n_per_m for c in self.couplings])
        self._de = np.array([c.server_damping_n_s_per_m for c in self.couplings])
        self._cache: dict[tuple[bool, ...], tuple[np.ndarray, np.ndarray]] = {}

    def receive(self, client: int, x_m: Sequence[float], v_m_per_s: Sequence[float], stamp_s: float) -> None:
        """Client `client`'s newest released HIP sample (position, velocity, its send stamp)."""
        self._hip_x[client] = x_m
        self._hip_v[client] = v_m_per_s
        self._hip_stamp[client] = stamp_s
        self._arrived[client] = True

    def _discrete(self, active: tuple[bool, ...]) -> tuple[np.ndarray, np.ndarray]:
        """(Phi, Gamma) of x' = A x + B u, x = (position, velocity), u = the acceleration input
        sum(k_e x_hr + d_e v_hr) / m held over one period."""
        cached = self._cache.get(active)
        if cached is not None:
            return cached
        on = np.array(active, dtype=bool)
        k = float(self._ke[on].sum())
        d = float(self._de[on].sum())
        m = self.mass_kg
        # Balanced: in (x, v / s) with s = 2^round(log2 omega) the matrix's entries are alike in size,
        # so the exponential keeps the map's energy to roundoff even at omega T >> 1 (a stiff
        # spring on a light object); scaling by a power of two is exact.
        omega = math.sqrt(k / m)
        sc = 2.0 ** round(math.log2(omega)) if omega > 0.0 else 1.0
        aug = np.zeros((3, 3))
        aug[0, 1] = sc
        aug[1, 0] = -k / m / sc
        aug[1, 1] = -(self.damping_n_s_per_m + d) / m
        aug[1, 2] = 1.0 / sc
        e = expm(aug * self.period_s)
        phi = e[:2, :2].copy()
        phi[0, 1] /= sc
        phi[1, 0] *= sc
        gamma = e[:2, 2].copy()
        gamma[1] *= sc
        out = (phi, gamma)
        self._cache[active] = out
        return out

    def step(self) -> None:
        """Advance the object one period with the received HIPs held."""
        active = tuple(bool(a) for a in self._arrived)
        on = self._arrived
        ke = self._ke[on][:, None]
        de = self._de[on][:, None]
        hx = self._hip_x[on]
        hv = self._hip_v[on]
        self.coupling_force_n = (ke * (hx - self.x) + de * (hv - self.v)).sum(axis=0)
        u = (ke * hx + de * hv).sum(axis=0) / self.mass_kg
        phi, gamma = self._discrete(active)
        x = phi[0, 0] * self.x + phi[0, 1] * self.v + gamma[0] * u
        v = phi[1, 0] * self.x + phi[1, 1] * self.v + gamma[1] * u
        self.x, self.v = x, v
        self.echo_s = np.where(self._arrived, self._hip_stamp, self.echo_s)

    def energy_j(self) -> float:
        """The object's kinetic energy."""
        return 0.5 * self.mass_kg * float(self.v @ self.v)


class SpringSchedule(Protocol):
    """A client's spring coefficient k_h as a function of the round trip it measured."""

    @property
    def name(self) -> str: ...

    def spring_n_per_m(self, rtt_s: float) -> float: ...


@dataclass(frozen=True)
class NoCompensation:
    spring: float
    name: str = "none"

    def spring_n_per_m(self, rtt_s: float) -> float:
        return self.spring


@dataclass(frozen=True)
class TransparencyCompensation:
    """Seed 000's scheme: the allowable delay of the distortion that dominates (mass-based if
    m w >= b at the interaction frequency w) from m_allowable or b_allowable; past it, the
    perceived spring increment subtracted from k_h (core/nve_transparency.py)."""

    model: NveModel
    distortion: str  # "mass" | "damping"
    allowable_rtt_s: float
    min_spring_n_per_m: float
    name: str = "transparency"

    def spring_n_per_m(self, rtt_s: float) -> float:
        if math.isnan(rtt_s):
            return self.model.client_stiffness_n_per_m
        return proposed_spring_n_per_m(
            self.model, rtt_s, self.distortion, self.allowable_rtt_s, self.min_spring_n_per_m
        )

    @classmethod
    def build(
        cls,
        model: NveModel,
        rule: str,
        interaction_rad_per_s: float,
        allowable_mass_kg: float,
        allowable_damping_n_s_per_m: float,
        min_spring_n_per_m: float,
    ) -> TransparencyCompensation:
        distortion = dominant_distortion(model, interaction_rad_per_s) if rule == "auto" else rule
        if distortion == "damping" and model.damping_n_s_per_m <= 0.0:
            raise ValueError("the damping-based distortion needs an object damping > 0 (use rule 'mass')")
        if distortion == "mass":
            allowable = allowable_rtt_mass_s(model, allowable_mass_kg)
        else:
            allowable = allowable_rtt_damping_s(model, allowable_damping_n_s_per_m)
        return cls(model, distortion, allowable, min_spring_n_per_m)


@dataclass(frozen=True)
class Fujimoto04:
    """The baseline: K = K0 - alpha max(0, R - R0), not below K_min (docs/nve.md, "Fujimoto04")."""

    initial_spring_n_per_m: float
    reduction_n_per_m_per_s: float
    threshold_rtt_s: float
    min_spring_n_per_m: float
    name: str = "fujimoto04"

    def spring_n_per_m(self, rtt_s: float) -> float:
        if math.isnan(rtt_s):
            return self.initial_spring_n_per_m
        return fujimoto04_spring_n_per_m(
            rtt_s,
            self.initial_spring_n_per_m,
            self.reduction_n_per_m_per_s,
            self.threshold_rtt_s,
            self.min_spring_n_per_m,
        )


class NveClient:
    """One client: measures the round trip from the object packets' echoes and renders the
    spring-damper force toward the object as last received (zero before the first)."""

    def __init__(self, coupling: Coupling, schedule: SpringSchedule, axes: int) -> None:
        self.coupling = coupling
        self.schedule = schedule
        self.obj_x = np.full(axes, math.nan)
        self.obj_v = np.full(axes, math.nan)
        self.rtt_s = math.nan
        self.spring_n_per_m = schedule.spring_n_per_m(math.nan)
        self.received = False

    def receive(self, x_m: Sequence[float], v_m_per_s: Sequence[float], echo_s: float, now_s: float) -> None:
        """The object sample the client's playout buffer released at `now_s`."""
        self.obj_x = np.asarray(x_m, dtype=np.float64)
        self.obj_v = np.asarray(v_m_per_s, dtype=np.float64)
        self.received = True
        if not math.isnan(echo_s):
            self.rtt_s = now_s - echo_s
            self.spring_n_per_m = self.schedule.spring_n_per_m(self.rtt_s)

    def force(self, hip_x_m: np.ndarray, hip_v_m_per_s: np.ndarray) -> np.ndarray:
        """The force fed back to the user at this tick."""
        if not self.received:
            return np.zeros(len(hip_x_m))
        out: np.ndarray = self.spring_n_per_m * (hip_x_m - self.obj_x) + self.coupling.client_damping_n_s_per_m * (
            hip_v_m_per_s - self.obj_v
        )
        return out
