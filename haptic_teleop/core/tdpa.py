"""The Time-Domain Passivity Approach (TDPA) in its network-aware form for delayed teleoperation:
a passivity observer (PO) and a passivity controller (PC) at each side's port, one per axis.

Each side observes the energy that crosses its port over every hold of the force (zero-order
hold, the force the actuator really applied over the period, `applied1`): `held * dx`, with dx the
motion over the hold. Positive, the network gave the device energy (the side's output, E_out);
negative, the device pushed energy into the network (its input, E_in). Each side sends its E_in
with every sample; the other side may release, over its whole history, at most the E_in it has
received (delayed, some packets lost: a cumulative figure is still a lower bound of what was put
in). The PC dissipates only what the output would otherwise create. Derivation, the two
controllers and why both sides sum to a passive two-port: docs/stabilizers.md.

Two passivity controllers (`controllers.<side>.eba.tdpa_controller`):
- "velocity": the field's impedance-type PC. The energy the next hold will release is predicted
  from the motion of the last hold (f dx, the velocity estimate times T); when it exceeds the
  budget W = E0 + E_in(remote) - E_out, the force is set to W / dx (f - alpha v with the usual
  alpha), at most the controller's force limit. Exact only while the motion over the next hold
  equals the last one's: a held force on an accelerating device releases more (docs/stabilizers.md).
- "zoh": the budget also credits the device's own damping b over each hold, (b/T) dx^2 (the least
  a damper dissipates over dx in T), and bounds the next hold's worst case: a force F held over
  T can release at most F^2 T / (4 b) beyond what the damper takes, so |F| <= sqrt(4 b W / T).
  This one holds for every motion of the device, whatever the sampling.

Two placements of the passivity controller (`controllers.<side>.eba.tdpa_placement`):
- "impedance": it acts on the force (the controllers above).
- "admittance": it acts on the side's reference instead. The coupling's reference is the received
  position plus a slip; whatever the controller takes off the force moves the slip by that force
  over the coupling's stiffness, so the spring then holds the force the controller let through,
  and the slip returns toward the received position at `tdpa_drift_gain_per_s` (`slipped1`). The
  force held is still the controller's, so the passivity argument is the impedance one; what
  differs is what follows a shortage: a reference that yielded (drift, recovered gradually)
  instead of a spring still stretched to the received position (docs/stabilizers.md).

Scalar functions of floats (the rule, written once, for the Python loop and any compiled loop);
`TdpaBound` is the per-side object with the bound interface `TeleopController` uses.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from haptic_teleop.core.eba import bounded1, reservoir1, saturated1
from haptic_teleop.core.eba_state import AxisBoundState, EnergyBoundParams

TDPA_CONTROLLERS = ("velocity", "zoh")
# The largest cumulative port energy a packet may carry (J): beyond it a sample is a fault.
ENERGY_LIMIT_J = 1e9
# What a one-axis TdpaBound carries beyond `AxisBoundState`'s four values, in `extra`'s order.
TDPA_EXTRA = ("energy_in_j", "energy_out_j", "remote_in_j", "credit_j", "sent_j", "slip_m")


def observe1(energy_in: float, energy_out: float, held: float, dx: float) -> tuple[float, float]:
    """The passivity observer over one hold: the energy `held * dx` the held force put into the
    device (E_out grows) or took from it (E_in grows by its magnitude)."""
    return book1(energy_in, energy_out, held * dx)


def book1(energy_in: float, energy_out: float, w: float) -> tuple[float, float]:
    """The observer's booking of the energy `w` the port gave the device over one hold (an arm's
    joints pooled: the sum of tau_i dq_i): E_out grows by it, or E_in by its magnitude."""
    if w > 0.0:
        return energy_in, energy_out + w
    return energy_in - w, energy_out


def received1(remote_in: float, energy_in: float) -> float:
    """The remote side's cumulative input energy after a sample carrying `energy_in`: a cumulative
    figure only grows, so an older sample released later keeps the larger value."""
    return energy_in if energy_in > remote_in else remote_in


def velocity_pc1(force: float, budget: float, dx: float, cap: float) -> float:
    """The impedance-type PC on a predicted hold: the next hold is predicted to release
    `force * dx` (dx: the last hold's motion); beyond `budget` the force becomes budget / dx, the
    force whose predicted release is the budget (a negative budget: a force that takes the debt
    back), its magnitude at most `cap`. No motion, no prediction: the force passes."""
    if dx == 0.0 or force * dx <= budget:
        return force
    return saturated1(budget / dx, cap)


def reflected1(budget: float, energy_in: float, reflection: float) -> tuple[float, float]:
    """Energy reflection: of the side's cumulative input `energy_in` it keeps the fraction
    `reflection` for its own output (the budget grows by it) and sends the rest (returned second:
    what its samples carry). Both parts only grow, and no energy is counted on both sides."""
    kept = reflection * energy_in
    return budget + kept, energy_in - kept


def slipped1(slip: float, before: float, after: float, stiffness: float, recover: float) -> float:
    """The admittance-type controller's reference offset after a tick: moved by what the controller
    took off the force (`after - before`) over the coupling's `stiffness`, so that the spring holds
    the force let through, then a fraction `recover` (drift gain times T) of the way back to 0
    (the received position)."""
    if stiffness > 0.0:
        slip += (after - before) / stiffness
    return slip - recover * slip


def zoh_pc1(force: float, budget: float, bound_gain: float) -> float:
    """The PC on the hold's worst case: |F| <= sqrt(bound_gain W), bound_gain = 4 b / T (none
    when the budget is spent)."""
    return bounded1(force, budget if budget > 0.0 else 0.0, bound_gain)


def tdpa1(
    energy_in: float,
    energy_out: float,
    credit: float,
    remote_in: float,
    held: float,
    last: float,
    has_last: bool,
    x: float,
    force: float,
    initial_energy: float,
    gain: float,
    bound_gain: float,
    reflection: float,
    zoh: bool,
    enabled: bool,
    cap: float,
) -> tuple[float, float, float, float, float, float]:
    """One axis of one side, one tick (the rule once: `TdpaBound` and the compiled loop run it):
    observe the hold of `held` that ended at `x` (from `last`; none before the first tick), credit
    the device's damping (`zoh`: gain = b/T), the budget W = E0 + E_in(remote) - E_out (+ credit),
    the reflection split, the passivity controller on `force`. Returns (E_in, E_out, credit, W,
    the energy the side's samples carry, the force to hold)."""
    if has_last:
        dx = x - last
        energy_in, energy_out = observe1(energy_in, energy_out, held, dx)
        if zoh:
            credit = reservoir1(credit, gain, 0.0, dx)
    else:
        dx = 0.0
    w = initial_energy + remote_in - energy_out + credit
    sent = energy_in
    if reflection > 0.0:
        w, sent = reflected1(w, energy_in, reflection)
    if enabled:
        force = zoh_pc1(force, w, bound_gain) if zoh else velocity_pc1(force, w, dx, cap)
    return energy_in, energy_out, credit, w, sent, force


class TdpaBound:
    """One side's TDPA (the bound interface of `core.eba.EnergyBound`): `step1`/`step` observe the
    last hold and control the next force, `applied1`/`applied` book the force the actuator really
    applied, `receive` takes the remote side's cumulative input energy from a sample.

    `energy_j` (recorded as the side's energy column) is the observer's budget W per axis:
    E0 + E_in received - E_out (+ the damping credit with the "zoh" controller). `energy_in_j` is
    what this side sends. Disabled (`eba.enabled: false`), the observer still runs and the force
    passes unchanged: the unprotected variant, observed."""

    __slots__ = (
        "_bound_gain",
        "_credit",
        "_enabled",
        "_gain",
        "_has_last",
        "_held",
        "_last",
        "_reflect",
        "_zoh",
        "admittance",
        "cap_n",
        "energy_in_j",
        "energy_j",
        "energy_out_j",
        "params",
        "recover",
        "remote_in_j",
        "sent_j",
        "slip_m",
    )

    def __init__(self, params: EnergyBoundParams, force_cap_n: float, controller: str = "velocity") -> None:
        if controller not in TDPA_CONTROLLERS:
            raise ValueError(f"tdpa controller must be one of {', '.join(TDPA_CONTROLLERS)}, got {controller!r}")
        if not 0.0 < force_cap_n < math.inf:
            raise ValueError(f"force_cap_n must be finite and > 0, got {force_cap_n}")
        self.params = params
        n = params.axes
        self._zoh = controller == "zoh"
        self._enabled = params.enabled
        self.cap_n = force_cap_n if params.force_limit_n is None else min(force_cap_n, params.force_limit_n)
        self._gain = list(params.reservoir_gains())
        self._bound_gain = list(params.bound_gains())
        self.energy_in_j = [0.0] * n
        # Energy reflection: the fraction of its input the side keeps for its own output; it
        # sends the rest (`sent_j`, the value its samples carry; all of it with 0).
        self._reflect = params.tdpa_reflection
        self.sent_j = self.energy_in_j if self._reflect == 0.0 else [0.0] * n
        self.energy_out_j = [0.0] * n
        self.remote_in_j = [0.0] * n
        self._credit = [0.0] * n
        self.energy_j = [params.initial_energy_j] * n
        self._held = [0.0] * n
        self._last = [0.0] * n
        self._has_last = False
        # The admittance placement's reference offset per axis (the controller applies it: `slip`).
        self.admittance = params.tdpa_placement == "admittance"
        self.recover = params.tdpa_drift_gain_per_s * params.period_s
        self.slip_m = [0.0] * n

    def slip(self, i: int, before: float, after: float, stiffness: float) -> None:
        """The admittance placement, axis `i`: the reference's offset after the controller took the
        force from `before` to `after` (`slipped1`); nothing with the impedance placement."""
        if self.admittance:
            self.slip_m[i] = slipped1(self.slip_m[i], before, after, stiffness, self.recover)

    def receive(self, energy_in: Sequence[float]) -> None:
        """The remote side's cumulative input energy, per axis, from the newest accepted sample. A
        cumulative figure only grows: an older sample released later keeps the larger value."""
        r = self.remote_in_j
        for i in range(len(r)):
            r[i] = received1(r[i], energy_in[i])

    def _axis(self, i: int, x: float, force: float) -> float:
        self.energy_in_j[i], self.energy_out_j[i], self._credit[i], w, sent, force = tdpa1(
            self.energy_in_j[i], self.energy_out_j[i], self._credit[i], self.remote_in_j[i], self._held[i],
            self._last[i], self._has_last, x, force, self.params.initial_energy_j, self._gain[i],
            self._bound_gain[i], self._reflect, self._zoh, self._enabled, self.cap_n,
        )  # fmt: skip
        self.sent_j[i] = sent  # (without reflection `sent_j` is `energy_in_j` itself: the same value)
        self._last[i] = x
        self.energy_j[i] = w
        self._held[i] = force
        return force

    def step1(self, x: float, force_desired: float) -> float:
        """One axis: observe the hold that ended at `x`, control the next force."""
        f = self._axis(0, x, force_desired)
        self._has_last = True
        return f

    def step(self, x: Sequence[float], force_desired: Sequence[float]) -> list[float]:
        out = [self._axis(i, x[i], force_desired[i]) for i in range(len(self.energy_j))]
        self._has_last = True
        return out

    def applied1(self, force: float) -> None:
        """The force the actuator applied over the hold that follows the last `step1`."""
        self._held[0] = force

    def applied(self, force: Sequence[float]) -> None:
        self._held[:] = list(force)

    @property
    def total_energy_j(self) -> float:
        return sum(self.energy_j)

    def axis_state(self) -> AxisBoundState:
        """A one-axis bound's state (ValueError for more axes), as `EnergyBound.axis_state`: the
        budget W, the held force, the last position, whether there was one, and `TDPA_EXTRA`."""
        self._one_axis()
        extra = (
            self.energy_in_j[0], self.energy_out_j[0], self.remote_in_j[0], self._credit[0], self.sent_j[0],
            self.slip_m[0],
        )  # fmt: skip
        return AxisBoundState(self.energy_j[0], self._held[0], self._last[0], self._has_last, extra)

    def set_axis_state(self, state: AxisBoundState) -> None:
        """Restore what `axis_state` gave (the compiled loop's state); without `extra`, the
        observer's energies stay as they are."""
        self._one_axis()
        self.energy_j[0], self._held[0], self._last[0], self._has_last = (
            state.energy_j, state.held_n, state.last_x_m, state.has_last,
        )  # fmt: skip
        if state.extra:
            e_in, e_out, self.remote_in_j[0], self._credit[0], sent, self.slip_m[0] = state.extra
            self.energy_in_j[0], self.energy_out_j[0] = e_in, e_out
            self.sent_j[0] = sent

    def _one_axis(self) -> None:
        if len(self.energy_j) != 1:
            raise ValueError(f"the axis state is that of a one-axis bound; this one has {len(self.energy_j)} axes")
