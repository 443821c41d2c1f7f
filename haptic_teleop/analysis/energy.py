"""True energy margins of n physical ports, from recorded plant signals (docs/eba.md).

A port is one joint: its position q (m or rad) and the force or torque tau its actuator really
applied (N or N m), held over each period, with the joint's physical damping d (N s/m or N m s/rad).
Over the period from tick k to k+1 the port absorbs at least

    (d / T) dq_k^2 - tau_k dq_k,          dq_k = q[k+1] - q[k]

((d/T) dq^2 is the least a damper d can dissipate over a displacement dq in time T, by
Cauchy-Schwarz). Summed from the start, per port and pooled over the ports of a side, plus the
initial energy, this is the energy margin: the port (or the side) stayed passive while it is >= 0.
With the damping the simulator (or the hardware) really has, it is the *true* margin; with the
damping a controller assumed, it is that controller's ledger, which can pass while the true one
fails (the model is less damped than the controller believes).

Pure numpy: no bag, no MuJoCo. One port (n = 1) gives `metrics.port_energy` bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class EnergyMargins:
    """Energy margins of the n ports of one side over N ticks (J)."""

    absorbed_j: np.ndarray  # (N, n): energy absorbed by each port since tick 0 (0 at tick 0)
    port_margin_j: np.ndarray  # (N, n): each port's initial energy plus what it absorbed
    pooled_margin_j: np.ndarray  # (N,): the side's initial energy plus what all its ports absorbed

    @property
    def port_min_j(self) -> np.ndarray:
        """(n,): each port's smallest margin."""
        return np.asarray(np.min(self.port_margin_j, axis=0))

    @property
    def pooled_min_j(self) -> float:
        """The side's smallest pooled margin: >= 0 means the side stayed passive."""
        return float(np.min(self.pooled_margin_j))


def _columns(a: npt.ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(a, dtype=float)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"{name} must be (N,) or (N, n), got shape {arr.shape}")
    return arr


def energy_margins(
    positions: npt.ArrayLike,
    forces: npt.ArrayLike,
    damping: npt.ArrayLike,
    period_s: float,
    initial_energy_j: float | npt.ArrayLike = 0.0,
) -> EnergyMargins:
    """Per-port and pooled energy margins of one side.

    positions: (N, n) joint positions per tick (m or rad); a (N,) array is one port.
    forces: (N, n) force or torque the actuator applied, row k held over [t_k, t_k+1) (N or N m).
    damping: (n,) physical damping per port (N s/m or N m s/rad), or one value for every port.
    period_s: the control period T (s).
    initial_energy_j: a float is the side's one reservoir (the pooled margin starts there, each
        port's own margin at 0); a (n,) array gives each port its own budget (the pooled margin
        then starts at their sum). 1-DoF: the two are the same.

    The row count N must be at least 1 and equal in both arrays; damping must be finite and >= 0.
    """
    q = _columns(positions, "positions")
    tau = _columns(forces, "forces")
    if q.shape != tau.shape or q.shape[0] < 1:
        raise ValueError(f"positions and forces must have the same shape (N >= 1, n), got {q.shape} and {tau.shape}")
    n = q.shape[1]
    d = np.broadcast_to(np.asarray(damping, dtype=float), (n,))
    if not np.all(np.isfinite(d)) or np.any(d < 0.0):
        raise ValueError(f"damping must be finite and >= 0 per port, got {d}")
    if not period_s > 0.0:
        raise ValueError(f"period_s must be > 0, got {period_s}")
    e0 = np.asarray(initial_energy_j, dtype=float)
    if e0.ndim == 0:
        port_e0 = np.zeros(n)
        pooled_e0 = float(e0)
    else:
        port_e0 = np.broadcast_to(e0, (n,))
        pooled_e0 = float(np.sum(port_e0))
    dq = np.diff(q, axis=0)
    # The same expression, in the same order, as metrics.port_energy (one port: the same bits).
    step = (d / period_s) * dq * dq - tau[:-1] * dq
    absorbed = np.concatenate([np.zeros((1, n)), np.cumsum(step, axis=0)])
    pooled = absorbed[:, 0] if n == 1 else np.sum(absorbed, axis=1)
    return EnergyMargins(absorbed_j=absorbed, port_margin_j=port_e0 + absorbed, pooled_margin_j=pooled_e0 + pooled)
