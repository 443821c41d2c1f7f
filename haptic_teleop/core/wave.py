"""Wave variables: the scattering transformation between the two sides (docs/stabilizers.md,
"Wave variables").

The channel carries waves instead of positions and forces. With wave impedance b and s = sqrt(2 b),
a port with velocity xdot and force F (the force the device exerts into the channel) has

    u = (b xdot + F) / s        (the wave it sends)        w = (b xdot - F) / s   (the wave it gets)

and the power into the channel is F xdot = (u^2 - w^2) / 2: what is sent minus what comes back.
A delay only stores wave energy in transit, so the channel is passive for any constant delay.

- **Master** (impedance port: its velocity in, a force out): from its measured velocity v and
  the wave w it received, the force on the handle is s w - b v and it sends u = s v - w
  (`master_wave1`).
- **Slave** (admittance port: the wave u in, a desired velocity out): a local spring-damper K, B
  pulls the robot toward the reference x_d, whose velocity solves the port equations together
  with the spring's force: xdot_d = (s u - K (x_d - x) + B v) / (b + B), F = K (x_d - x) +
  B (xdot_d - v), and it sends w = u - 2 F / s (`slave_wave1`).
- **Impedance matching** (optional, slave): the slave's port terminated in the wave impedance, a
  damper b in parallel at the channel's end, so free motion sends no wave back (the unmatched
  port returns w = u - 2 F / s, all of u when F = 0: the master feels its own motion again a
  round trip later, and again, an echo). Matched: xdot_d = (s u - K (x_d - x) + B v) / (2 b + B)
  and w = -F / s: the wave back carries the robot's force alone (`slave_wave1`, `matched`).
- **Each received wave is used once.** A tick without a new sample uses 0 (a held wave would
  release its energy again each tick); so loss, jitter, reordering and duplicates never give
  out more wave energy than was sent.
- **Wave filter** (optional): a first-order low-pass on the incoming wave, gain <= 1 at every
  frequency, so it never adds wave energy (`filter1`).
- **Drift compensation** (optional): waves carry velocity, so position drifts (lost samples, the
  slave's contact). The master's position rides along; the slave nudges the incoming wave toward
  closing x_m(delayed) - x_d, never beyond the wave's own magnitude (`drift1`: |u'| <= |u|, so
  the correction spends no energy it did not receive).

Scalar functions of floats (the rule, once) and `WaveSide`, one side's state for the Python loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from haptic_teleop.core.eba import saturated1
from haptic_teleop.core.eba_state import AxisBoundState, EnergyBoundParams

# What a WaveSide carries beyond `AxisBoundState`'s four values (the ledger, the held force, the
# last position, started), in `extra`'s order.
WAVE_EXTRA = ("w_in", "fresh", "remote_x_m", "filtered_w", "reference_x_m")


@dataclass(frozen=True)
class WaveParams:
    """One side's wave-variable settings (the impedance is the scene's: both sides use the same)."""

    impedance_n_s_per_m: float  # b
    filter_hz: float | None = None  # the incoming wave's low-pass cutoff; None: no filter
    drift_gain_per_s: float = 0.0  # the slave's drift correction rate; 0: none
    matched: bool = False  # the slave's port terminated in the wave impedance (no reflection)

    def __post_init__(self) -> None:
        if not 0.0 < self.impedance_n_s_per_m < math.inf:
            raise ValueError(f"impedance_n_s_per_m must be finite and > 0, got {self.impedance_n_s_per_m}")
        if self.filter_hz is not None and not 0.0 < self.filter_hz < math.inf:
            raise ValueError(f"filter_hz must be finite and > 0 (or None), got {self.filter_hz}")
        if not 0.0 <= self.drift_gain_per_s < math.inf:
            raise ValueError(f"drift_gain_per_s must be finite and >= 0, got {self.drift_gain_per_s}")


def wave_limit(impedance_n_s_per_m: float, velocity_limit: float, force_limit: float) -> float:
    """The largest plausible wave a sample can carry (a remote sample's guard), from the largest
    plausible velocity and force: |u| = |b v + F| / s <= s v_max + 2 F_max / s."""
    s = math.sqrt(2.0 * impedance_n_s_per_m)
    return s * velocity_limit + 2.0 * force_limit / s


def master_wave1(w: float, v: float, s: float, b: float) -> tuple[float, float]:
    """The master's port: (force on the handle, wave sent) from the wave received and its velocity."""
    return s * w - b * v, s * v - w


def slave_wave1(
    u: float, x: float, v: float, xd: float, s: float, b: float, k: float, c: float, matched: bool = False
) -> tuple[float, float, float]:
    """The slave's port with its local spring k and damper c toward the reference xd: (force on the
    robot, wave sent back, the reference's velocity). `matched`: a damper b in parallel at the
    channel's end (the port's force b xdot_d + F), which reflects nothing of u (docs/stabilizers.md,
    "Impedance matching")."""
    m = 2.0 * b if matched else b
    xd_dot = (s * u - k * (xd - x) + c * v) / (m + c)
    f = k * (xd - x) + c * (xd_dot - v)
    return f, (-f / s if matched else u - 2.0 * f / s), xd_dot


def consistent1(sent: float, got: float, power: float) -> float:
    """The wave to send, at most as large as the port's energy allows: sent^2 / 2 <= got^2 / 2 -
    power (power: what the port gave its device, force applied times the velocity the port equations
    used). Exactly `sent` while the applied force is the port's own; smaller when the actuator
    applied less (a saturation): the channel never carries more than the device really gave it."""
    room = got * got - 2.0 * power
    return saturated1(sent, math.sqrt(room)) if room > 0.0 else 0.0


def filter1(state: float, w: float, a: float) -> float:
    """First-order low-pass step (pole a in [0, 1); a = 0: no filter)."""
    return a * state + (1.0 - a) * w


def drift1(u: float, correction: float) -> float:
    """The incoming wave moved by `correction`, its magnitude at most the wave's own."""
    return saturated1(u + correction, abs(u))


def wave1(
    master: bool,
    energy: float,
    held: float,
    last_x: float,
    started: bool,
    xd: float,
    wf: float,
    w_in: float,
    fresh: bool,
    remote_x: float,
    x: float,
    v: float,
    limit: float,
    t: float,
    s: float,
    b: float,
    k: float,
    c: float,
    a: float,
    drift_gain: float,
    matched: bool,
) -> tuple[float, float, float, float, float, float]:
    """One side's port, one tick (the rule once: `WaveSide.port1` and the compiled loop run it): the
    ledger books the last hold of `held` (from `last_x` to `x`; the reference starts at `x`), the
    received wave `w_in` is used if `fresh` (else 0), filtered (pole `a`), the master's or the
    slave's port equations (the slave's drift correction toward `remote_x` at `drift_gain`, its
    impedance matching if `matched`), the
    force saturated at `limit`, the wave sent kept consistent with the force applied. Returns (the
    ledger, the slave's reference, the filter's state, the port's force, the force applied, the
    wave to send)."""
    if started:
        energy -= held * (x - last_x)
    else:
        xd = x
    w = w_in if fresh else 0.0
    energy += 0.5 * w * w * t
    wf = filter1(wf, w, a)
    got = wf
    if master:
        f, sent = master_wave1(got, v, s, b)
        fa = saturated1(f, limit)
        sent = consistent1(sent, got, fa * v)
    else:
        if drift_gain > 0.0:
            got = drift1(got, (b + c) / s * drift_gain * (remote_x - xd))
        f, sent, xd_dot = slave_wave1(got, x, v, xd, s, b, k, c, matched)
        fa = saturated1(f, limit)
        # What the port gave: the force applied, and the matching damper's b xdot_d, at xdot_d.
        sent = consistent1(sent, got, (fa + b * xd_dot if matched else fa) * xd_dot)
        xd += xd_dot * t
    energy -= 0.5 * sent * sent * t
    return energy, xd, wf, f, fa, sent


class WaveSide:
    """One side's wave-variable port (one axis), with the bound interface the controller and the
    side stage use: `receive` a sample, `port1(x, v, limit)` the force, `out` the sample to send,
    `applied1` the force the actuator applied. `energy_j` is the side's wave ledger: E0 plus the
    wave energy it used and the energy its device put in, minus the wave energy it sent and what
    its force released (w^2 T / 2, u^2 T / 2 and the held force times the motion): a side that
    kept it >= 0 gave out no more than it got."""

    def __init__(
        self,
        master: bool,
        params: WaveParams,
        period_s: float,
        stiffness_n_per_m: float,
        damping_n_s_per_m: float,
        initial_energy_j: float,
        bound_params: EnergyBoundParams,
    ) -> None:
        self.master = master
        self.params = bound_params  # the side's EnergyBoundParams (law "wave"), as every bound has
        # The actuator's own clip below the controller's (`<side>.effects.saturation`), if any.
        self.clip_n = math.inf if bound_params.force_limit_n is None else bound_params.force_limit_n
        self.wave = params
        self._b = params.impedance_n_s_per_m
        self.s = math.sqrt(2.0 * self._b)
        self._t = period_s
        self._k, self._c = stiffness_n_per_m, damping_n_s_per_m
        self.pole = 0.0 if params.filter_hz is None else math.exp(-2.0 * math.pi * params.filter_hz * period_s)
        self._lambda = params.drift_gain_per_s
        self._matched = params.matched and not master  # a slave's termination (the master's port has none)
        self._w_in = 0.0
        self._fresh = False
        self._remote_x = 0.0
        self._wf = 0.0
        self._xd = 0.0
        self._started = False
        self._held = 0.0
        self._last_x = 0.0
        self.energy_j = [initial_energy_j]
        self.out: tuple[float, float] = (0.0, 0.0)

    def receive(self, payload: tuple[float, ...]) -> None:
        """A sample the buffer released: (wave, the sender's position)."""
        self._w_in, self._remote_x = payload[0], payload[1]
        self._fresh = True

    def step1(self, x: float, force_desired: float) -> float:
        """Not a bound on a desired force: the port makes the force from the velocity (`port1`)."""
        raise TypeError("a wave port makes its force from the velocity: call port1(x, v, limit)")

    def step(self, x: object, force_desired: object) -> list[float]:
        raise TypeError("a wave port is one axis and makes its force from the velocity: call port1(x, v, limit)")

    def port1(self, x: float, v: float, limit: float = math.inf) -> tuple[float, float]:
        """One tick on the measured position and velocity: (the port's force, the force applied:
        saturated at `limit`); the sample to send is then `out`."""
        e, self._xd, self._wf, f, fa, sent = wave1(
            self.master, self.energy_j[0], self._held, self._last_x, self._started, self._xd, self._wf,
            self._w_in, self._fresh, self._remote_x, x, v, min(limit, self.clip_n), self._t, self.s, self._b,
            self._k, self._c, self.pole, self._lambda, self._matched,
        )  # fmt: skip
        self.energy_j[0] = e
        self._started = True
        self._fresh = False
        self._last_x = x
        self.out = (sent, x)
        self._held = fa
        return f, fa

    def applied1(self, force: float) -> None:
        self._held = force

    @property
    def total_energy_j(self) -> float:
        return self.energy_j[0]

    def axis_state(self) -> AxisBoundState:
        """The port's state, as `EnergyBound.axis_state` (the ledger, the held force, the last
        position, started) with `WAVE_EXTRA`."""
        extra = (self._w_in, 1.0 if self._fresh else 0.0, self._remote_x, self._wf, self._xd)
        return AxisBoundState(self.energy_j[0], self._held, self._last_x, self._started, extra)

    def set_axis_state(self, state: AxisBoundState) -> None:
        """Restore what `axis_state` gave (the compiled loop's state)."""
        self.energy_j[0], self._held, self._last_x, self._started = (
            state.energy_j, state.held_n, state.last_x_m, state.has_last,
        )  # fmt: skip
        if state.extra:
            self._w_in, fresh, self._remote_x, self._wf, self._xd = state.extra
            self._fresh = fresh != 0.0
