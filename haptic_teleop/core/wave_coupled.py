"""Wave variables on an arm: one wave port per task axis (docs/stabilizers_arms.md, "Wave
variables on arms").

Each task axis k of a side is the one-axis port of `core.wave`: the master's from its handle's task
velocity v_k (force s w_k - b v_k on the handle, wave u_k = s v_k - w_k sent), the slave's with its
local spring and damper (the coupling's c1_k, c2_k) toward its reference x_d,k (force on the tool,
the wave back, the reference's velocity; matched or not), the incoming wave used once, filtered,
and on the slave nudged toward the master's position (`core.wave`'s `filter1`, `drift1`,
`master_wave1`, `slave_wave1`, `consistent1`: the rules, once). The task force is the port forces,
rendered through the arm's Jacobian (J^T F, with the side's own orientation hold and null-space
damping, both local and dissipative in continuous time, outside the ports).

The motors' limits act after the ports: the force limit on |F| and the room of each motor scale
the whole torque by one factor r (direction kept), so the force applied is r F_k on every axis.
A side's tick is therefore two calls: `wave_ports_begin` (the ledger books the last hold, the port
equations give the desired force) before the torque is made, `wave_ports_end(r)` (each axis's
wave cut to what its applied force allows, `consistent1`, the reference advanced, the ledger
charged with the waves sent) after. The side's wave ledger is E0 plus the wave energy used and the
energy its device put in, minus the wave energy sent and what its force released: sum over axes
of `core.wave.wave1`'s.

The state lives in one float array (`WAVE_ARM_SIZE` values in the `W_*` layout), so the Python
side tick (`CoupledWaveBound`) and the compiled side (assembly/side_kernel.py: a slice of its
state) run these same functions on it. The sample a side sends is (x[3], its waves[3]) forward and
(x[3], waves[3], f_env[3]) backward: the plain arm payloads' sizes and fields, the waves where the
velocities were.
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
from haptic_teleop.core.wave import WaveParams, consistent1, drift1, filter1, master_wave1, slave_wave1

Vec = npt.NDArray[np.float64]

# The port state's layout (one float64 array): the ledger, started and fresh flags, then per task
# axis the received wave, the sender's position, the filter's state, the slave's reference, the
# task force applied over the last hold and the point where it started; then the tick's values
# between the two calls (the wave after the filter and drift, the wave to send, the reference's
# velocity, the desired port force).
W_ENERGY, W_STARTED, W_FRESH = 0, 1, 2
W_IN, W_REMOTE_X, W_FILTERED, W_XD, W_HELD, W_LAST_X = 3, 6, 9, 12, 15, 18
W_GOT, W_SENT, W_XD_DOT, W_FORCE = 21, 24, 27, 30
WAVE_ARM_SIZE = 33
AXES = 3


def wave_ports_begin(
    ws: Vec, force: Vec, x: Vec, v: Vec, master: bool, s: float, b: float, k: Vec, c: Vec,
    pole: float, drift_gain: float, matched: bool, t: float,
) -> None:  # fmt: skip
    """The tick's first half (module docstring): book the last hold (sum_k held_k (x_k - last_k);
    the reference starts at x on the first tick), use each fresh wave once (w^2 T / 2 into the
    ledger; 0 without a new sample), filter it (pole), on the slave move it toward the sender's
    position (`drift1`), and solve each axis's port: `force[k]` (k < 3) the desired port force."""
    e = ws[W_ENERGY]
    started = ws[W_STARTED] != 0.0
    fresh = ws[W_FRESH] != 0.0
    for i in range(AXES):
        if started:
            e -= ws[W_HELD + i] * (x[i] - ws[W_LAST_X + i])
        else:
            ws[W_XD + i] = x[i]
        ws[W_LAST_X + i] = x[i]
        w = ws[W_IN + i] if fresh else 0.0
        e += 0.5 * w * w * t
        ws[W_FILTERED + i] = filter1(ws[W_FILTERED + i], w, pole)
        got = ws[W_FILTERED + i]
        if master:
            f, sent = master_wave1(got, v[i], s, b)
            xd_dot = v[i]
        else:
            if drift_gain > 0.0:
                got = drift1(got, (b + c[i]) / s * drift_gain * (ws[W_REMOTE_X + i] - ws[W_XD + i]))
            f, sent, xd_dot = slave_wave1(got, x[i], v[i], ws[W_XD + i], s, b, k[i], c[i], matched)
        ws[W_GOT + i] = got
        ws[W_SENT + i] = sent
        ws[W_XD_DOT + i] = xd_dot
        ws[W_FORCE + i] = f
        force[i] = f
    ws[W_ENERGY] = e
    ws[W_STARTED] = 1.0
    ws[W_FRESH] = 0.0


def wave_ports_end(ws: Vec, ratio: float, master: bool, b: float, matched: bool, t: float) -> float:
    """The tick's second half: the force applied is `ratio` times the desired on every axis; each
    axis's wave is cut to what that force allows (`consistent1` with the port's power: the force
    applied times the velocity the port equations used, and the matching damper's b xd_dot^2);
    the slave's reference advances; the ledger pays the waves sent (u^2 T / 2). Returns the ledger."""
    e = ws[W_ENERGY]
    for i in range(AXES):
        fa = ratio * ws[W_FORCE + i]
        xd_dot = ws[W_XD_DOT + i]
        if master:
            power = fa * xd_dot
        else:
            power = (fa + b * xd_dot) * xd_dot if matched else fa * xd_dot
            ws[W_XD + i] += xd_dot * t
        sent = consistent1(ws[W_SENT + i], ws[W_GOT + i], power)
        ws[W_SENT + i] = sent
        e -= 0.5 * sent * sent * t
        ws[W_HELD + i] = fa
    ws[W_ENERGY] = e
    return float(e)


def wave_receive(ws: Vec, sample: Vec) -> None:
    """A sample the guard accepted, (x[3], waves[3], ...): its waves, to be used once, and the
    sender's position (the slave's drift correction)."""
    for i in range(AXES):
        ws[W_REMOTE_X + i] = sample[i]
        ws[W_IN + i] = sample[AXES + i]
    ws[W_FRESH] = 1.0


class CoupledWaveBound:
    """One side's wave ports on an arm (module docstring), with the bound interface the arm side
    tick and the stages use: `begin(x, v)` the desired task force, `step(q, tau)` the torque within
    the motors' limits (no energy bound: the ports are the stabilizer), `end(ratio)` after it,
    `receive(sample)`, `sent` (the waves to send), `held`, `energy_j` (the wave ledger),
    `state`/`set_state` (`extra`: the port state), `restart`."""

    def __init__(
        self,
        params: CoupledEnergyBoundParams,
        wave: WaveParams,
        master: bool,
        stiffness_n_per_m: Vec,
        damping_n_s_per_m: Vec,
        kernels: Mapping[str, Callable[..., Any]] | None = None,
    ) -> None:
        if params.slew_nm_per_s:
            raise ValueError("wave variables on an arm: no slew limit (the one-axis port refuses it too)")
        if params.max_hold_s is not None:
            raise ValueError("wave variables on an arm: simulated arms only (a hold of one period)")
        self.params = params
        self.wave = wave
        self.master = master
        self.matched = wave.matched and not master  # a slave's termination (the master's port has none)
        self.impedance = wave.impedance_n_s_per_m
        self.s = math.sqrt(2.0 * self.impedance)
        t = params.period_s
        self.pole = 0.0 if wave.filter_hz is None else math.exp(-2.0 * math.pi * wave.filter_hz * t)
        self.drift_gain = 0.0 if master else wave.drift_gain_per_s
        self.k = np.array(stiffness_n_per_m, dtype=float)
        self.c = np.array(damping_n_s_per_m, dtype=float)
        n = params.joints
        lim = np.array(params.torque_limit_nm or (math.inf,) * n, dtype=float)
        self._high, self._low = lim, -lim
        d = np.array(params.damping_nm_s_per_rad, dtype=float)
        self._gain, self._bound_gain = d / t, 4.0 * d / t  # (constants(): the kernel's slots; unused here)
        self.ws = np.zeros(WAVE_ARM_SIZE)
        self.ws[W_ENERGY] = params.initial_energy_j
        self.force = np.zeros(AXES)
        self.held = np.zeros(n)
        self._last_q = np.zeros(n)
        self._has_last = False
        self._out = np.zeros(n)
        self.scale = 1.0
        kf = kernels or {}
        self._f_limited = kf.get("joint_limited", joint_limited)
        self._f_begin = kf.get("wave_ports_begin", wave_ports_begin)
        self._f_end = kf.get("wave_ports_end", wave_ports_end)

    @property
    def energy_j(self) -> float:
        return float(self.ws[W_ENERGY])

    @property
    def sent(self) -> Vec:
        """The waves this tick sends, one per task axis (after `end`)."""
        return self.ws[W_SENT : W_SENT + AXES]

    def receive(self, sample: tuple[float, ...]) -> None:
        """A sample the guard accepted: (x[3], waves[3], ...)."""
        wave_receive(self.ws, np.asarray(sample[: 2 * AXES], dtype=float))

    def begin(self, x: Vec, v: Vec) -> Vec:
        """The tick's first half (`wave_ports_begin`): the desired port force per task axis."""
        self._f_begin(
            self.ws, self.force, x, v, self.master, self.s, self.impedance, self.k, self.c, self.pole,
            self.drift_gain, self.matched, self.params.period_s,
        )  # fmt: skip
        return self.force

    def step(self, q: Vec, tau_desired: Vec) -> Vec:
        """The torque within the motors' limits (direction kept), held until the next tick."""
        self._f_limited(self._out, tau_desired, self._low, self._high, True)
        self._last_q[:] = q
        self._has_last = True
        self.held[:] = self._out
        return self._out

    def end(self, ratio: float) -> float:
        """The tick's second half (`wave_ports_end`) with the applied / desired force ratio."""
        return float(self._f_end(self.ws, ratio, self.master, self.impedance, self.matched, self.params.period_s))

    def applied(self, tau: Vec) -> None:
        self.held[:] = tau

    def restart(self, energy_j: float) -> None:
        """Start afresh with the ledger at `energy_j` (a live node at scene time 0): the next tick is
        the first (the reference starts where the tool is), no wave in hand or in the filter."""
        self.ws[:] = 0.0
        self.ws[W_ENERGY] = float(energy_j)

    def constants(self) -> CoupledBoundConstants:
        return CoupledBoundConstants(
            self._gain.copy(), self._bound_gain.copy(), self._low.copy(), self._high.copy(), True, None
        )

    def state(self) -> CoupledBoundState:
        """The state the next tick goes on from (copies; `extra`: the port state, W_* layout)."""
        return CoupledBoundState(
            self.energy_j, self.held.copy(), self._last_q.copy(), self._has_last, self.scale, tuple(self.ws)
        )

    def set_state(self, state: CoupledBoundState) -> None:
        self.held[:] = state.held_nm
        self._last_q[:] = state.last_q_rad
        self._has_last = state.has_last
        self.scale = state.scale
        self.ws[:] = state.extra
        self.ws[W_ENERGY] = state.energy_j
