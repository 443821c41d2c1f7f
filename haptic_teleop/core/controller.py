"""One side's controller: the control law on the newest remote sample (position or force
coupling), its saturation, and the energy bound the scene names behind it (`core.eba.EnergyBound`
or `core.eba_two_condition.TwoConditionBound`); the remote samples' guard (`RemoteLimits`,
`SampleGuard`: a value beyond what the scene can produce is a fault, not physics; docs/eba.md,
"Bad values in packets").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from haptic_teleop.core.eba import EnergyBound, command1, coupling1, saturated1, within1, within2, within3
from haptic_teleop.core.eba_state import EnergyBoundParams
from haptic_teleop.core.eba_two_condition import TwoConditionBound
from haptic_teleop.core.tdpa import ENERGY_LIMIT_J, TdpaBound
from haptic_teleop.core.wave import WaveParams, WaveSide, wave_limit

LAWS = ("position", "force")


@dataclass(frozen=True)
class RemoteLimits:
    """The largest magnitudes a remote sample may carry; anything beyond is a fault, not physics.

    A remote sample with a value that is not finite or beyond its limit is rejected by the
    receiving controller (docs/eba.md, "Bad values in packets"). The engine derives the limits
    from the scene (`haptic_teleop.assembly.parts.remote_limits`).
    """

    position_m: float  # workspace bound on |x|
    velocity_m_per_s: float  # bound on |v|
    force_n: float  # force sensor range: bound on |f_env|

    def __post_init__(self) -> None:
        for name in ("position_m", "velocity_m_per_s", "force_n"):
            v = getattr(self, name)
            if not 0.0 < v < math.inf:
                raise ValueError(f"{name} must be finite and > 0, got {v}")


class SampleGuard:
    """Checks remote samples element by element against per-element limits; counts rejections.

    `accept(payload)` is False, and `rejected` grows by one, when the payload has the wrong
    length or any value is NaN, infinite or beyond its element's limit.
    """

    __slots__ = ("limits", "rejected")

    def __init__(self, limits: Sequence[float]) -> None:
        if not limits or any(not 0.0 < lim < math.inf for lim in limits):
            raise ValueError(f"limits must be finite and > 0, got {tuple(limits)}")
        self.limits = tuple(limits)
        self.rejected = 0

    def accept(self, payload: Sequence[float]) -> bool:
        # abs(v) <= limit is False for NaN and +-inf too. The one-axis layouts (2 and 3 values)
        # are spelled out: a loop (or zip) costs three times as much per sample.
        lim = self.limits
        n = len(lim)
        if len(payload) == n:
            if n == 2:
                if within2(payload[0], payload[1], lim[0], lim[1]):
                    return True
            elif n == 3:
                if within3(payload[0], payload[1], payload[2], lim[0], lim[1], lim[2]):
                    return True
            else:
                for i in range(n):
                    if not within1(payload[i], lim[i]):
                        break
                else:
                    return True
        self.rejected += 1
        return False


@dataclass(frozen=True)
class ControllerParams:
    """One side's control law (before the energy bound) and its saturation."""

    role: str  # "master" or "slave"
    law: str = "position"  # "position": spring-damper on the remote sample; "force": force reflection
    stiffness_n_per_m: float = 1000.0  # c1
    damping_n_s_per_m: float = 10.0  # c2
    force_gain: float = 1.0  # force reflection gain (master with law "force")
    force_limit_n: float = 20.0
    remote_limits: RemoteLimits | None = None  # None: remote samples are not checked

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
    With law tdpa both carry the sender's observed input energy last (E_in_1..E_in_n, J).
    """

    __slots__ = (
        "_c1",
        "_c2",
        "_force_law",
        "_gain",
        "_limit",
        "_n",
        "_off",
        "_params",
        "_remote",
        "bound",
        "force_applied",
        "force_desired",
        "guard",
        "tdpa",
        "wave",
    )

    def __init__(self, params: ControllerParams, bound: EnergyBoundParams, wave: WaveParams | None = None) -> None:
        # The bound `bound.law` names; all have the same step/applied interface.
        self.bound: EnergyBound | TwoConditionBound | TdpaBound | WaveSide
        self.wave: WaveSide | None = None
        if bound.law == "reservoir":
            self.bound = EnergyBound(bound)
        elif bound.law == "two_condition":
            self.bound = TwoConditionBound(bound)
        elif bound.law == "tdpa":
            self.bound = TdpaBound(bound, params.force_limit_n, bound.tdpa_controller)
        else:  # wave variables replace the coupling law and the bound (core/wave.py)
            if wave is None or bound.axes != 1:
                raise ValueError("law wave needs its WaveParams and one axis")
            self.wave = WaveSide(
                params.role == "master", wave, bound.period_s, params.stiffness_n_per_m,
                params.damping_n_s_per_m, bound.initial_energy_j, bound,
            )  # fmt: skip
            self.bound = self.wave
        # TDPA: every sample carries the sender's observed input energy, one value per axis, last.
        self.tdpa: TdpaBound | None = self.bound if isinstance(self.bound, TdpaBound) else None
        self._n = bound.axes
        self._remote: tuple[float, ...] | None = None
        # The controller's own lists, overwritten in place every tick (copy them to keep a value).
        self.force_desired = [0.0] * self._n
        self.force_applied = [0.0] * self._n
        self.params = params
        # Remote payload layout (class docstring): master receives (f_env, x, v), slave (x, v).
        self.guard: SampleGuard | None = None
        lim = params.remote_limits
        if lim is not None:
            kinds = (lim.force_n, lim.position_m, lim.velocity_m_per_s)
            per_kind = kinds if params.role == "master" else kinds[1:]
            if self.tdpa is not None:
                per_kind = (*per_kind, ENERGY_LIMIT_J)
            if wave is not None and self.wave is not None:  # (wave, the sender's position)
                per_kind = (wave_limit(wave.impedance_n_s_per_m, lim.velocity_m_per_s, lim.force_n), lim.position_m)
            self.guard = SampleGuard([k for k in per_kind for _ in range(self._n)])

    @property
    def rejected_samples(self) -> int:
        """Remote samples rejected by the guard so far (0 without a guard)."""
        return 0 if self.guard is None else self.guard.rejected

    @property
    def params(self) -> ControllerParams:
        return self._params

    @params.setter
    def params(self, params: ControllerParams) -> None:
        """Replace the parameters (a watchdog lowers force_limit_n this way) between ticks."""
        self._params = params
        # Constants of the law, looked up once here (the tick reads them as plain attributes).
        self._force_law = params.law == "force"
        self._gain = params.force_gain
        self._c1 = params.stiffness_n_per_m
        self._c2 = params.damping_n_s_per_m
        self._limit = params.force_limit_n
        self._off = self._n if params.role == "master" else 0  # master payload starts with forces

    @property
    def remote(self) -> tuple[float, ...] | None:
        """The remote sample the law works on now (None before the first one was accepted)."""
        return self._remote

    @remote.setter
    def remote(self, payload: tuple[float, ...] | None) -> None:
        """Restore the sample the law works on, unchecked and uncounted (a state carried through a
        loop that ran this controller elsewhere, the compiled loop); new samples go through
        `set_remote`."""
        self._remote = payload

    def set_remote(self, payload: tuple[float, ...]) -> None:
        """The newest remote sample the playout buffer released.

        With a guard, a sample carrying a non-finite or out-of-range value is rejected and
        counted; the controller keeps the sample it had.
        """
        guard = self.guard
        if guard is not None and not guard.accept(payload):
            return
        self._remote = payload
        if self.tdpa is not None:
            self.tdpa.receive(payload[len(payload) - self._n :])
        elif self.wave is not None:
            self.wave.receive(payload)

    def sample1(self, x: float, v: float, f_env: float = 0.0) -> tuple[float, ...]:
        """The sample this side sends after its tick (one axis): the master's (x, v), the slave's
        (f_env, x, v); with TDPA its observed input energy last (core/tdpa.py); a wave port's
        (its wave, x) (core/wave.py). The engine's loops and the live nodes send this."""
        w = self.wave
        if w is not None:
            return w.out
        t = self.tdpa
        if self._off:  # the master
            return (x, v) if t is None else (x, v, t.sent_j[0])
        return (f_env, x, v) if t is None else (f_env, x, v, t.sent_j[0])

    def desired_force(self, x: Sequence[float], v: Sequence[float]) -> list[float]:
        """The control law alone (no saturation, no bound)."""
        n = self._n
        r = self._remote
        if r is None:
            return [0.0] * n
        if self._force_law:
            g = self._gain
            return [g * r[i] for i in range(n)]
        off = self._off
        c1 = self._c1
        c2 = self._c2
        t = self.tdpa
        if t is not None and t.admittance:  # the admittance placement's reference: offset by its slip
            return [coupling1(c1, c2, r[off + i] + t.slip_m[i], r[off + n + i], x[i], v[i]) for i in range(n)]
        return [coupling1(c1, c2, r[off + i], r[off + n + i], x[i], v[i]) for i in range(n)]

    def step(self, x: Sequence[float], v: Sequence[float]) -> list[float]:
        """One tick: returns the force to apply (held until the next tick)."""
        if self._n == 1:
            return [self.step1(x[0], v[0])]
        desired = self.desired_force(x, v)
        lim = self._limit
        sat = [saturated1(f, lim) for f in desired]
        self.force_desired[:] = desired
        applied = self.bound.step(x, sat)
        t = self.tdpa
        if t is not None and not self._force_law:
            for i in range(self._n):
                t.slip(i, sat[i], applied[i], self._c1)
        self.force_applied[:] = applied
        return applied

    def step1(self, x: float, v: float) -> float:
        """`step` for one axis on floats (same arithmetic, same order): `command1`, then the bound's
        `step1` (`bound1` for the reservoir law); returns the force to apply."""
        w = self.wave
        if w is not None:  # the wave port's force, saturated (its sent wave knows it), held
            desired, f = w.port1(x, v, self._limit)
            self.force_desired[0] = desired
            self.force_applied[0] = f
            return f
        r = self._remote
        t = self.tdpa
        if r is None:
            desired, f = command1(False, False, 0.0, 0.0, 0.0, 0.0, 0.0, x, v, self._limit)
        elif self._force_law:
            desired, f = command1(True, True, self._gain, 0.0, 0.0, r[0], 0.0, x, v, self._limit)
        else:
            off = self._off
            ra = r[off] + t.slip_m[0] if t is not None and t.admittance else r[off]  # admittance: its reference
            desired, f = command1(True, False, 0.0, self._c1, self._c2, ra, r[off + 1], x, v, self._limit)
        self.force_desired[0] = desired
        out = self.bound.step1(x, f)
        if t is not None and not self._force_law:  # the admittance placement's slip (`step`, the kernel)
            t.slip(0, f, out, self._c1)
        self.force_applied[0] = out
        return out
