"""The two-condition law on an arm: the published law joint by joint (docs/stabilizers_arms.md,
"The two conditions, joint by joint").

Each joint is a port of its own with its own controller ledger E_c,i and the one-axis rule of
`core.eba_two_condition` (`two_condition_room1`: the ZOH condition, the controller condition with
its reserve, the motor's room this tick), with d_i the joint's physical damping. Each joint's port
is then passive by the one-axis argument, so the sum, the side's port, is. The side starts with
the scene's initial energy split evenly over its joints (E0 / n each: the same total as the pooled
reservoir's E0).

What it costs against the pooled reservoir (`core.eba_coupled`): each joint is cut alone, so the
torque vector's direction turns where one joint's conditions bind and another's do not (the felt
force is then the task force of the applied torque, as TDPA's velocity controller's); and a
joint's ledger cannot lend to another.

`coupled_two_condition` is one side's whole step over arrays and floats, composed of the one-axis
rule; `CoupledTwoConditionBound` (the interface of `core.eba_coupled.CoupledEnergyBound` that the
Python arm tick uses: `step`, `applied`, `held`, `energy_j`, `scale`, `constants`,
`state`/`set_state`, `restart`) calls it, and the compiled arm loop (assembly/side_kernel.py)
compiles the same function. A real arm's late ticks are not modelled (the ZOH condition credits
the damping over one period): the scene refuses the law on a real device.
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
    joint_limited,
)
from haptic_teleop.core.eba_two_condition import controller_energy1, two_condition_room1

Vec = npt.NDArray[np.float64]


def coupled_two_condition(
    out: Vec, limited: Vec, q: Vec, last_q: Vec, held: Vec, ledgers: Vec, has_last: bool,
    gain: Vec, bound_gain: Vec, low: Vec, high: Vec, enabled: bool,
) -> float:  # fmt: skip
    """One side's step (module docstring): per joint, the motion dq_i = q_i - last_q_i since the
    last step (0 on the first), the one-axis rule on the desired torque `limited[i]` within the
    room [low_i, high_i] (`two_condition_room1`; disabled: the torque passes), the joint's ledger
    E_c,i -= (held_i + out_i) dq_i / 2; `out` becomes `held`. Returns the side's total ledger."""
    total = 0.0
    for i in range(q.shape[0]):
        dx = q[i] - last_q[i] if has_last else 0.0
        last_q[i] = q[i]
        e = ledgers[i]
        f = held[i]
        if enabled:
            t = two_condition_room1(limited[i], e, gain[i], bound_gain[i], f, dx, low[i], high[i])
        else:
            t = limited[i]
        ledgers[i] = controller_energy1(e, f, t, dx)
        out[i] = t
        held[i] = t
        total += ledgers[i]
    return total


def room_within(low: Vec, high: Vec, bound_low: Vec, bound_high: Vec) -> None:
    """low, high := the motors' room this tick within the bound's range (the torque limits), in place."""
    for i in range(low.shape[0]):
        low[i] = max(low[i], bound_low[i])
        high[i] = min(high[i], bound_high[i])


class CoupledTwoConditionBound:
    """One side's joint-by-joint two-condition law (module docstring): `step(q, tau, low, high)`
    books the motion since the last step and bounds each joint's torque; `applied`/`held` take
    what the motors really applied. `energy_j` is the sum of the joints' ledgers (the side's
    energy column), `ledgers_j` each joint's. Disabled (`eba.enabled: false`), the ledgers are
    kept and the torque passes."""

    def __init__(
        self, params: CoupledEnergyBoundParams, kernels: Mapping[str, Callable[..., Any]] | None = None
    ) -> None:
        if params.slew_nm_per_s:
            raise ValueError("two_condition on an arm: no slew limit (the one-axis law refuses it too)")
        if params.max_hold_s is not None:
            raise ValueError("two_condition on an arm: a hold of one period only (its ZOH condition credits one)")
        self.params = params
        n = params.joints
        d = np.array(params.damping_nm_s_per_rad, dtype=float)
        self._gain = d / params.period_s
        self._bound_gain = 4.0 * d / params.period_s
        lim = np.array(params.torque_limit_nm or (math.inf,) * n, dtype=float)
        self._high, self._low = lim, -lim
        self._room_low = np.zeros(n)
        self._room_high = np.zeros(n)
        self._limited = np.zeros(n)
        self._out = np.zeros(n)
        self._last_q = np.zeros(n)
        self._has_last = False
        self.held = np.zeros(n)
        self.ledgers_j = np.full(n, params.initial_energy_j / n)
        self.energy_j = float(np.sum(self.ledgers_j))
        self.scale = 1.0  # the kernels' factor slot: this law has none (always 1)
        k = kernels or {}
        self._f_limited = k.get("joint_limited", joint_limited)
        self._f_step = k.get("coupled_two_condition", coupled_two_condition)
        self._f_room = k.get("room_within", room_within)

    def step(
        self,
        q: npt.NDArray[np.float64],
        tau_desired: npt.NDArray[np.float64],
        low: npt.NDArray[np.float64] | None = None,
        high: npt.NDArray[np.float64] | None = None,
    ) -> npt.NDArray[np.float64]:
        """One tick: q the joint positions now, tau_desired the law's torque; low/high: the motors'
        room this tick (default: the torque limits), taken within the torque limits."""
        lo, hi = self._room_low, self._room_high
        lo[:] = self._low if low is None else low
        hi[:] = self._high if high is None else high
        self._f_room(lo, hi, self._low, self._high)
        self._f_limited(self._limited, tau_desired, lo, hi, True)
        self.energy_j = self._f_step(
            self._out, self._limited, q, self._last_q, self.held, self.ledgers_j, self._has_last,
            self._gain, self._bound_gain, lo, hi, self.params.enabled,
        )  # fmt: skip
        self._has_last = True
        return self._out

    def applied(self, tau: npt.NDArray[np.float64]) -> None:
        """The torque the motors really applied over the period after the last `step`."""
        self.held[:] = tau

    def restart(self, energy_j: float) -> None:
        """Start afresh as a new bound with E0 = `energy_j` (each joint's ledger E0 / n); the next
        `step` takes its q as the first (a live node at scene time 0, as `CoupledEnergyBound.restart`)."""
        self.ledgers_j[:] = float(energy_j) / self.params.joints
        self.energy_j = float(np.sum(self.ledgers_j))
        self._has_last = False

    def constants(self) -> CoupledBoundConstants:
        """The per-joint constants the step uses (copies), as `CoupledEnergyBound.constants`."""
        return CoupledBoundConstants(
            self._gain.copy(), self._bound_gain.copy(), self._low.copy(), self._high.copy(), True, None
        )

    def state(self) -> CoupledBoundState:
        """The state the next `step` goes on from (copies; `extra`: each joint's ledger)."""
        return CoupledBoundState(
            self.energy_j, self.held.copy(), self._last_q.copy(), self._has_last, self.scale, tuple(self.ledgers_j)
        )

    def set_state(self, state: CoupledBoundState) -> None:
        """Restore the state (after a loop that ran this ledger elsewhere: the compiled arm loop)."""
        self.energy_j = state.energy_j
        self.held[:] = state.held_nm
        self._last_q[:] = state.last_q_rad
        self._has_last = state.has_last
        self.scale = state.scale
        self.ledgers_j[:] = state.extra
