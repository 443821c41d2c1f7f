"""What both one-axis energy-bound laws (`core.eba.EnergyBound`, the reservoir;
`core.eba_two_condition.TwoConditionBound`, the published two conditions) share: their parameters
(`EnergyBoundParams`, the law named in it), and the state a bound carries from one tick to the
next (`AxisBoundState`). Its own module, so that both laws use it without importing each other."""

from __future__ import annotations

import math
from dataclasses import dataclass

# The energy-bound laws a side can run (`controllers.<side>.eba.law`).
EBA_LAWS = ("reservoir", "two_condition", "tdpa", "wave")


@dataclass(frozen=True)
class AxisBoundState:
    """What a one-axis `EnergyBound` carries from one tick to the next: the reservoir, the force
    held over the current period (the reservoir's F(n-1)), the position of the last step and
    whether there was one. `EnergyBound.axis_state`
    and `set_axis_state` move it in and out (the compiled loop, engine/compiled/axis_host.py, carries it).
    `extra`: what a law carries beyond these (TDPA: `core.tdpa.TDPA_EXTRA`; wave variables:
    `core.wave.WAVE_EXTRA`); empty for the EBA laws."""

    energy_j: float
    held_n: float
    last_x_m: float
    has_last: bool
    extra: tuple[float, ...] = ()


@dataclass(frozen=True)
class EnergyBoundParams:
    """Parameters of one side's energy bound."""

    period_s: float
    damping_n_s_per_m: tuple[float, ...]
    initial_energy_j: float = 0.0
    enabled: bool = True
    # The actuator's limits downstream of the bound (docs/eba_actuator_limits.md, "Actuator limits inside the
    # bound"): it clips |F| to force_limit_n and changes F by at most slew_rate_n_per_s * T per
    # period. None: no such limit (the bound is then the plain one, bit for bit).
    force_limit_n: float | None = None
    slew_rate_n_per_s: float | None = None
    # Which bound: "reservoir" (one pooled reservoir per axis, `EnergyBound`) or "two_condition"
    # (the ZOH and controller energy conditions, `core.eba_two_condition.TwoConditionBound`);
    # docs/eba_two_condition.md, "The published two-condition law"; or "tdpa" (core/tdpa.py), or
    # "wave" (wave variables, core/wave.py: they replace the coupling law as well).
    law: str = "reservoir"
    # With law "tdpa": its passivity controller, "velocity" or "zoh" (core/tdpa.py), and the
    # fraction of its input energy the side keeps for its own output (energy reflection; 0: it
    # sends all of it, the network-aware standard).
    tdpa_controller: str = "velocity"
    tdpa_reflection: float = 0.0
    # Where TDPA's passivity controller acts: "impedance" (on the force, the field's default) or
    # "admittance" (on the side's reference position: the coupling's reference slips, and returns
    # toward the received position at `tdpa_drift_gain_per_s`; core/tdpa.py, docs/stabilizers.md).
    tdpa_placement: str = "impedance"
    tdpa_drift_gain_per_s: float = 0.0

    def __post_init__(self) -> None:
        if self.law not in EBA_LAWS:
            raise ValueError(f"law must be one of {', '.join(EBA_LAWS)}, got {self.law!r}")
        if self.law in ("two_condition", "tdpa", "wave") and self.slew_rate_n_per_s is not None:
            raise ValueError(
                f"the {self.law} law does not model an actuator slew limit; allowed with a slew limit: law reservoir"
            )
        if not 0.0 <= self.tdpa_reflection <= 1.0:
            raise ValueError(f"tdpa_reflection must be in [0, 1], got {self.tdpa_reflection}")
        if self.tdpa_placement not in ("impedance", "admittance"):
            raise ValueError(f"tdpa_placement must be impedance or admittance, got {self.tdpa_placement!r}")
        if not 0.0 <= self.tdpa_drift_gain_per_s * self.period_s <= 1.0:
            raise ValueError(f"tdpa_drift_gain_per_s must be in [0, 1 / period_s], got {self.tdpa_drift_gain_per_s}")
        for name in ("force_limit_n", "slew_rate_n_per_s"):
            v = getattr(self, name)
            if v is not None and not 0.0 < v < math.inf:
                raise ValueError(f"{name} must be finite and > 0 (or None), got {v}")
        if not self.period_s > 0.0:
            raise ValueError(f"period_s must be > 0, got {self.period_s}")
        if not self.damping_n_s_per_m or any(not b > 0.0 for b in self.damping_n_s_per_m):
            raise ValueError(f"damping_n_s_per_m must be > 0 on every axis, got {self.damping_n_s_per_m}")
        if not self.initial_energy_j >= 0.0:
            raise ValueError(f"initial_energy_j must be >= 0, got {self.initial_energy_j}")

    @property
    def axes(self) -> int:
        return len(self.damping_n_s_per_m)

    @property
    def limited(self) -> bool:
        """Whether the bound models an actuator limit (`actuator_bounded1`) or is the plain one."""
        return self.force_limit_n is not None or self.slew_rate_n_per_s is not None

    def actuator_limits(self) -> tuple[float, float]:
        """(force limit, slew step S T) of the actuator, inf where there is none."""
        f = math.inf if self.force_limit_n is None else self.force_limit_n
        s = math.inf if self.slew_rate_n_per_s is None else self.slew_rate_n_per_s * self.period_s
        return f, s

    def max_stiffness_n_per_m(self) -> tuple[float, ...]:
        """The stiffness the bounded force can grow with at most: 2 b / T per axis (Colgate)."""
        return tuple(2.0 * b / self.period_s for b in self.damping_n_s_per_m)

    def reservoir_gains(self) -> tuple[float, ...]:
        """b / T per axis: the reservoir's gain on dx^2 (`reservoir1`'s `gain`)."""
        return tuple(b / self.period_s for b in self.damping_n_s_per_m)

    def bound_gains(self) -> tuple[float, ...]:
        """4 b / T per axis: the bound's gain, |F| <= sqrt(bound_gain E) (`bounded1`'s `bound_gain`)."""
        return tuple(4.0 * b / self.period_s for b in self.damping_n_s_per_m)
