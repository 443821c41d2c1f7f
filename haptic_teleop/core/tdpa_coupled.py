"""TDPA on an arm: the joints of a side are its port, pooled (docs/stabilizers_arms.md, "Pooled joints").

The one-axis rules of core/tdpa.py on the joint vector: over each hold the observer books the
energy the held torques gave the joints, w = sum_i tau_i dq_i (`book1`: E_out grows by w > 0, E_in
by -w otherwise); the side sends its cumulative E_in with every sample (one value, last); its
budget is W = E0 + E_in received - E_out, plus with the "zoh" controller the least the joints'
damping dissipated over the holds, sum_i (d_i/T) dq_i^2 (the pooled reservoir's credit,
`coupled_reservoir` with no torque).

The controllers act on the limited torque vector:
- "zoh": the pooled bound on the hold's worst case, (T/4) tau.T D^-1 tau <= W (`coupled_bounded`
  with the budget for the reservoir: the vector scaled by one factor, as EBA's pooled bound):
  passive for every joint motion over the hold.
- "velocity": the field's impedance-type controller on the predicted release P = sum_i tau_i dq_i
  (the last hold's motion): beyond the budget it adds a damper along that motion,
  tau + beta dq with beta = (W - P) / |dq|^2 (the port's f - alpha v), so that the predicted
  release is W; then the motors' room. One joint goes through `velocity_pc1`, the one-axis rule,
  bit for bit.

`coupled_tdpa` is one side's whole step over arrays and floats, composed of those rules;
The admittance placement (`tdpa_placement`, zoh only): the side's coupling works toward the
received point plus a slip (3 task axes) which moves, per axis, by what the controller took off
the task force over that axis's stiffness (`core.tdpa.slipped1`, the one-axis rule), and returns at
the drift gain; the side tick applies it (assembly/side.py, side_kernel.py), the bound keeps it.

`CoupledTdpaBound` (the interface of `core.eba_coupled.CoupledEnergyBound` that the Python arm
tick uses on a simulated arm: `step`, `applied`, `held`, `energy_j`, `scale`, `constants`,
`state`/`set_state`, and a real arm's `stretch`: a hold that took longer than a period credits
the damping over its real length) calls it, and the compiled arm loop (assembly/side_kernel.py)
compiles the same function.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from haptic_teleop.core.eba_coupled import (
    CoupledBoundConstants,
    CoupledBoundState,
    CoupledEnergyBoundParams,
    coupled_bounded,
    coupled_reservoir,
    joint_limited,
)
from haptic_teleop.core.tdpa import TDPA_CONTROLLERS, book1, received1, reflected1, velocity_pc1

# What a side's pooled TDPA carries beyond EBA's bound state (`CoupledBoundState.extra`, in this
# order): its observed input and output energy, the remote side's input energy it received, the
# damping credit (zoh), what its samples carry.
TDPA_EXTRA = ("energy_in_j", "energy_out_j", "remote_in_j", "credit_j", "sent_j", "slip_x_m", "slip_y_m", "slip_z_m")
Vec = npt.NDArray[np.float64]


def joint_power(held: npt.NDArray[np.float64], dq: npt.NDArray[np.float64]) -> float:
    """sum_i held_i dq_i, joint after joint: the energy the held torques gave the joints over dq."""
    w = 0.0
    for i in range(dq.shape[0]):
        w += held[i] * dq[i]
    return w


def velocity_scaled(
    out: npt.NDArray[np.float64],
    tau: npt.NDArray[np.float64],
    budget: float,
    dq: npt.NDArray[np.float64],
    low: npt.NDArray[np.float64],
    high: npt.NDArray[np.float64],
) -> float:
    """The field's impedance-type controller on the joint vector: out = tau while the predicted
    release P = tau . dq is within `budget` (or there is no motion to predict from); else the
    controller adds a damper along the last hold's motion, out = tau + beta dq with
    beta = (budget - P) / |dq|^2 < 0, whose predicted release is the budget; then brought within
    [low, high] keeping its direction (a tiny motion: the room against it, never an overflow).
    Returns beta (0: the torque passed). One joint: `velocity_pc1` (the same force, W / dx), then
    the room."""
    n = tau.shape[0]
    if n == 1:
        out[0] = min(max(velocity_pc1(tau[0], budget, dq[0], math.inf), low[0]), high[0])
        return 0.0 if out[0] == tau[0] else -1.0
    p = joint_power(tau, dq)
    dd = joint_power(dq, dq)
    if dd == 0.0 or p <= budget:
        for i in range(n):
            out[i] = tau[i]
        return 0.0
    beta = (budget - p) / dd  # may overflow to -inf on a tiny motion: the room then decides
    if math.isinf(beta):
        room = math.inf  # the largest multiple of -dq the motors take
        for i in range(n):
            if dq[i] > 0.0:
                room = min(room, -min(low[i], 0.0) / dq[i])
            elif dq[i] < 0.0:
                room = min(room, -max(high[i], 0.0) / dq[i])
        for i in range(n):
            out[i] = -room * dq[i]
    else:
        for i in range(n):
            out[i] = tau[i] + beta * dq[i]
    joint_limited(out, out, low, high, True)  # within the room (joint by joint: in place); a room that excludes 0
    return beta


def coupled_tdpa(
    out: Vec, limited: Vec, q: Vec, last_q: Vec, held: Vec, dq: Vec, zero: Vec,
    energy_in: float, energy_out: float, remote_in: float, credit: float, has_last: bool,
    gain: Vec, bound_gain: Vec, initial_energy: float, reflection: float, zoh: bool, enabled: bool,
    low: Vec, high: Vec,
) -> tuple[float, float, float, float, float, float]:  # fmt: skip
    """One side's pooled TDPA step (module docstring; `CoupledTdpaBound.step`): observe the hold
    that ended at q (`held` over q - last_q: E_in, E_out; with "zoh" the damping credit), the
    budget W = E0 + remote E_in - E_out (+ credit; a reflected part kept), then the controller on
    `limited` (the torque already within [low, high]) into `out`, which becomes `held`. `zero`:
    n zeros (the credit is the reservoir's with no torque). Returns (E_in, E_out, credit, W, what
    the samples carry, the controller's factor: zoh's scale, velocity's beta, 1 when disabled)."""
    n = q.shape[0]
    if has_last:
        for i in range(n):
            dq[i] = q[i] - last_q[i]
        energy_in, energy_out = book1(energy_in, energy_out, joint_power(held, dq))
        if zoh:
            credit = coupled_reservoir(credit, gain, zero, dq)
    else:
        for i in range(n):
            dq[i] = 0.0
    for i in range(n):
        last_q[i] = q[i]
    w = initial_energy + remote_in - energy_out + credit
    if reflection > 0.0:
        w, sent = reflected1(w, energy_in, reflection)
    else:
        sent = energy_in
    if not enabled:
        for i in range(n):
            out[i] = limited[i]
        factor = 1.0
    elif zoh:
        factor = coupled_bounded(out, limited, w if w > 0.0 else 0.0, bound_gain)
    else:
        factor = velocity_scaled(out, limited, w, dq, low, high)
    for i in range(n):
        held[i] = out[i]
    return energy_in, energy_out, credit, w, sent, factor


class CoupledTdpaBound:
    """One side's pooled TDPA (module docstring): `step(q, tau)` observes the hold that ended at q
    and controls the next torque; `applied`/`held` book what the motors really applied; `receive`
    takes the remote side's cumulative input energy. `energy_j` is the budget W (recorded as the
    side's energy column), `energy_in_j` what this side sends. Disabled (`eba.enabled: false`),
    the observer runs and the limited torque passes."""

    def __init__(
        self,
        params: CoupledEnergyBoundParams,
        controller: str = "velocity",
        kernels: Mapping[str, Callable[..., Any]] | None = None,
        reflection: float = 0.0,
        admittance: bool = False,
        recover: float = 0.0,
    ) -> None:
        if controller not in TDPA_CONTROLLERS:
            raise ValueError(f"tdpa controller must be one of {', '.join(TDPA_CONTROLLERS)}, got {controller!r}")
        if params.slew_nm_per_s:
            raise ValueError("tdpa on an arm: no slew limit (the one-axis law refuses it too)")
        if not 0.0 <= reflection <= 1.0:
            raise ValueError(f"tdpa reflection must be in [0, 1], got {reflection}")
        if admittance and controller != "zoh":
            raise ValueError("tdpa on an arm: the admittance placement needs the zoh controller")
        if not 0.0 <= recover <= 1.0:
            raise ValueError(f"tdpa recover (drift gain times T) must be in [0, 1], got {recover}")
        self.params = params
        self.controller = controller
        self.reflection = reflection  # the fraction of its input the side keeps (`reflected1`)
        n = params.joints
        d = np.array(params.damping_nm_s_per_rad, dtype=float)
        self._gain = d / params.period_s
        self._bound_gain = 4.0 * d / params.hold_s
        lim = np.array(params.torque_limit_nm or (math.inf,) * n, dtype=float)
        self._high, self._low = lim, -lim
        self._zoh = controller == "zoh"
        self._zero = np.zeros(n)
        self._limited = np.zeros(n)
        self._out = np.zeros(n)
        self._dq = np.zeros(n)
        self._last_q = np.zeros(n)
        self._has_last = False
        self._stretch = 1.0  # the next booked hold's length, in periods (`stretch`)
        self.held = np.zeros(n)
        self.energy_in_j = 0.0
        self.sent_j = 0.0  # what its samples carry: its input, less what it keeps (`reflected1`)
        self.energy_out_j = 0.0
        self.remote_in_j = 0.0
        self.credit_j = 0.0
        self.energy_j = params.initial_energy_j
        self.initial_energy_j = params.initial_energy_j  # E0 of the budget (`restart` lowers it)
        self.scale = 1.0  # "zoh": the factor on the torque vector (1: it passed)
        self.beta = 0.0  # "velocity": the damper it added along the motion (0: none), N m s/rad per T
        # The admittance placement: the coupling's reference offset per task axis (module docstring).
        self.admittance = admittance
        self.recover = recover
        self.slip_m = np.zeros(3)
        k = kernels or {}
        self._f_limited = k.get("joint_limited", joint_limited)
        self._f_step = k.get("coupled_tdpa", coupled_tdpa)

    def receive(self, energy_in_j: float) -> None:
        """The remote side's cumulative input energy from the newest accepted sample (only grows:
        an older sample released later keeps the larger value)."""
        self.remote_in_j = received1(self.remote_in_j, energy_in_j)

    def stretch(self, elapsed_s: float) -> None:
        """The hold the next `step` books took `elapsed_s` of wall time (a real arm's late tick):
        with "zoh" its damping credit is d_i dq_i^2 / elapsed_s, the least the joints' damping
        dissipated over that time (Cauchy-Schwarz), not d_i dq_i^2 / T (up to elapsed / T times
        too much), as `CoupledEnergyBound.stretch`. Shorter than a period (or not finite) changes
        nothing. The observer's booking, sum_i tau_i dq_i, does not depend on the time; the zoh bound
        budgets a hold of `params.hold_s`, and the plant's guard stops a longer one
        (docs/stabilizers_arms.md, "TDPA on a real arm")."""
        periods = elapsed_s / self.params.period_s
        self._stretch = periods if periods > 1.0 and math.isfinite(periods) else 1.0

    def restart(self, energy_j: float) -> None:
        """Start the ledger afresh as a new bound with E0 = `energy_j` (a live node calls it at
        scene time 0 with min(budget, E0): docs/stabilizers_arms.md, "TDPA live on arms: the restart"):
        every observed and received energy back to 0, the next `step` takes its q as the first.
        The samples sent from here carry the new count; the remote side's samples stamped before
        its own restart carry the old one and must not reach `receive` (the node filters them)."""
        self.initial_energy_j = float(energy_j)
        self.energy_j = float(energy_j)
        self.energy_in_j = self.energy_out_j = self.remote_in_j = self.credit_j = self.sent_j = 0.0
        self.slip_m[:] = 0.0
        self._has_last = False

    def constants(self) -> CoupledBoundConstants:
        """The per-joint constants the step uses (copies), as `CoupledEnergyBound.constants`."""
        return CoupledBoundConstants(
            self._gain.copy(), self._bound_gain.copy(), self._low.copy(), self._high.copy(), True, None
        )

    def state(self) -> CoupledBoundState:
        """The state the next `step` goes on from (copies; `extra`: TDPA_EXTRA's values)."""
        extra = (
            self.energy_in_j, self.energy_out_j, self.remote_in_j, self.credit_j, self.sent_j, *self.slip_m.tolist()
        )  # fmt: skip
        q = self._last_q.copy()
        velocity = not self._zoh and self.params.enabled
        factor = self.beta if velocity else self.scale  # the controller's factor (the kernel's S_SCALE)
        return CoupledBoundState(self.energy_j, self.held.copy(), q, self._has_last, factor, extra)

    def set_state(self, state: CoupledBoundState) -> None:
        """Restore the state (after a loop that ran this ledger elsewhere: the compiled arm loop)."""
        self.energy_j = state.energy_j
        self.held[:] = state.held_nm
        self._last_q[:] = state.last_q_rad
        self._has_last = state.has_last
        if self._zoh or not self.params.enabled:
            self.scale = state.scale
        else:  # the velocity controller's factor is its beta
            self.beta = state.scale
        self.energy_in_j, self.energy_out_j, self.remote_in_j, self.credit_j, self.sent_j = state.extra[:5]
        self.slip_m[:] = state.extra[5:8]

    def step(
        self,
        q: npt.NDArray[np.float64],
        tau_desired: npt.NDArray[np.float64],
        low: npt.NDArray[np.float64] | None = None,
        high: npt.NDArray[np.float64] | None = None,
    ) -> npt.NDArray[np.float64]:
        lo = self._low if low is None else low
        hi = self._high if high is None else high
        self._f_limited(self._limited, tau_desired, lo, hi, True)
        gain = self._gain if self._stretch == 1.0 else self._gain / self._stretch
        self._stretch = 1.0
        e_in, e_out, credit, w, sent, factor = self._f_step(
            self._out, self._limited, q, self._last_q, self.held, self._dq, self._zero, self.energy_in_j,
            self.energy_out_j, self.remote_in_j, self.credit_j, self._has_last, gain, self._bound_gain,
            self.initial_energy_j, self.reflection, self._zoh, self.params.enabled, lo, hi,
        )  # fmt: skip
        self._has_last = True
        self.energy_in_j, self.energy_out_j, self.credit_j, self.energy_j, self.sent_j = e_in, e_out, credit, w, sent
        if not self.params.enabled:
            self.scale = 1.0
        elif self._zoh:
            self.scale = factor
        else:
            self.beta = factor
        return self._out

    def applied(self, tau: npt.NDArray[np.float64]) -> None:
        """The torque the motors really applied over the hold after the last `step`."""
        self.held[:] = tau
