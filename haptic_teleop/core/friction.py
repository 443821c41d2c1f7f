"""Joint friction identification, the pure part (docs/identify.md): the excitation profile and
the estimator.

Model of one joint moving alone (the others held still):

    tau = M(q) qdd + C(q, qd) qd + g(q) + b qd + c sign(qd)   (+ d, an unmodelled bias)

The excitation drives the joint through constant-velocity passes at several speeds in both
directions; in each pass's measure window qdd is (nearly) 0, so the friction torque
tau_f = tau - g(q) - M qdd (the small residual of the inertial term taken out from the window's
velocity change) is averaged into one sample (v, tau_f). The estimator fits tau_f = b v + c sign(v)
(+ d) by least squares, with standard errors from the residuals, and gives the largest damping
the Energy Bounding Algorithm may assume: the lower confidence bound max(0, b - z sigma_b).

Nothing here does I/O or reads a clock; the loop that runs the excitation on a joint driver is
haptic_teleop/engine/excitation.py.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

FIT_SHARE = 0.85  # the share of a joint's usable span one pass may cover (the rest: tracking slack)
Z_DEFAULT = 3.0  # the confidence bound's width in standard errors (one-sided 99.87 % for a normal error)


# --------------------------------------------------------------------------------------------
# The estimator


@dataclass(frozen=True)
class FrictionFit:
    """The fit of one joint's friction samples.

    viscous_nm_s_per_rad (b) and coulomb_nm (c) with their standard errors; offset_nm (d) when
    fitted, else 0; residual_std_nm: the residuals' standard deviation (N - p degrees of freedom);
    n: the number of samples; z: the bound's width; safe_damping_nm_s_per_rad: max(0, b - z se_b).
    """

    viscous_nm_s_per_rad: float
    coulomb_nm: float
    offset_nm: float
    se_viscous: float
    se_coulomb: float
    se_offset: float
    residual_std_nm: float
    n: int
    z: float

    @property
    def safe_damping_nm_s_per_rad(self) -> float:
        """The largest damping EBA may assume: the lower confidence bound of b, never below 0."""
        return max(0.0, self.viscous_nm_s_per_rad - self.z * self.se_viscous)

    def predict(self, v: np.ndarray | Sequence[float]) -> np.ndarray:
        """The fitted friction torque at velocities v."""
        x = np.asarray(v, dtype=float)
        out: np.ndarray = self.viscous_nm_s_per_rad * x + self.coulomb_nm * np.sign(x) + self.offset_nm
        return out


def fit_friction(
    velocity_rad_per_s: Sequence[float] | np.ndarray,
    friction_nm: Sequence[float] | np.ndarray,
    offset: bool = False,
    z: float = Z_DEFAULT,
) -> FrictionFit:
    """Least-squares fit of tau_f = b v + c sign(v) (+ d with `offset`) to the samples.

    The standard errors are sigma sqrt(diag((X^T X)^-1)) with sigma^2 = RSS / (N - p). ValueError
    (naming what is missing) when the samples cannot determine the parameters: fewer than p + 1
    samples, a zero velocity, one direction only, or (with the offset) too few distinct speeds.
    """
    v = np.asarray(velocity_rad_per_s, dtype=float)
    tau = np.asarray(friction_nm, dtype=float)
    if v.shape != tau.shape or v.ndim != 1:
        raise ValueError(f"velocities and torques must be two lists of one length, got {v.shape} and {tau.shape}")
    if not (np.isfinite(v).all() and np.isfinite(tau).all()):
        raise ValueError("velocities and torques must be finite")
    if not z >= 0.0 or not math.isfinite(z):
        raise ValueError(f"z must be a finite number >= 0, got {z}")
    p = 3 if offset else 2
    if v.size < p + 1:
        raise ValueError(f"the fit needs at least {p + 1} samples (it has {v.size})")
    if (v == 0.0).any():
        raise ValueError("a friction sample at zero velocity has no direction; allowed: moving samples only")
    if not ((v > 0.0).any() and (v < 0.0).any()):
        raise ValueError("the samples need both directions of motion to tell viscous from Coulomb friction")
    cols = [v, np.sign(v)] + ([np.ones_like(v)] if offset else [])
    x = np.column_stack(cols)
    if np.linalg.matrix_rank(x) < p:
        raise ValueError("the samples do not determine the fit (with an offset: at least two speeds in one direction)")
    beta, _, _, _ = np.linalg.lstsq(x, tau, rcond=None)
    resid = tau - x @ beta
    dof = v.size - p
    sigma2 = float(resid @ resid) / dof
    cov = sigma2 * np.linalg.inv(x.T @ x)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return FrictionFit(
        viscous_nm_s_per_rad=float(beta[0]),
        coulomb_nm=float(beta[1]),
        offset_nm=float(beta[2]) if offset else 0.0,
        se_viscous=float(se[0]),
        se_coulomb=float(se[1]),
        se_offset=float(se[2]) if offset else 0.0,
        residual_std_nm=math.sqrt(sigma2),
        n=int(v.size),
        z=z,
    )


# --------------------------------------------------------------------------------------------
# One measure window -> one sample


class Window:
    """Accumulates one measure window of the excited joint: the friction torque's sum (applied
    torque minus gravity torque), the velocity's sum, and every joint's velocity trend.

    The inertial residual is M a, with a the least-squares slope of each joint's velocity over the
    window: the window mean of M qdd when M is constant over it and the velocity changes linearly,
    and with N samples of velocity noise sigma its error is about sigma sqrt(12 / N) / T (the
    difference of the two end samples would carry sigma sqrt(2) / T)."""

    __slots__ = ("_s_t", "_s_tt", "_s_tv", "_s_v", "count", "sum_tau", "sum_v")

    def __init__(self) -> None:
        self.count = 0
        self.sum_tau = 0.0
        self.sum_v = 0.0
        self._s_t = 0.0
        self._s_tt = 0.0
        self._s_v: np.ndarray | None = None
        self._s_tv: np.ndarray | None = None

    def add(self, t_s: float, v: float, tau_minus_gravity: float, qd_all: np.ndarray) -> None:
        qd = np.asarray(qd_all, dtype=float)
        if self._s_v is None or self._s_tv is None:
            self._s_v = np.zeros(qd.size)
            self._s_tv = np.zeros(qd.size)
        self.count += 1
        self.sum_tau += tau_minus_gravity
        self.sum_v += v
        self._s_t += t_s
        self._s_tt += t_s * t_s
        self._s_v += qd
        self._s_tv += t_s * qd

    def mean_acceleration(self) -> np.ndarray:
        """Each joint's velocity slope over the window (least squares; 0 for fewer than 2 samples)."""
        if self._s_v is None or self._s_tv is None:
            return np.zeros(0)
        n = self.count
        var_t = self._s_tt - self._s_t * self._s_t / n
        if n < 2 or var_t <= 0.0:
            return np.zeros(self._s_v.size)
        return (self._s_tv - self._s_t * self._s_v / n) / var_t

    def sample(self, inertia_row: np.ndarray) -> tuple[float, float]:
        """(mean velocity, mean friction torque), the friction with the inertial residual
        `inertia_row` . mean_acceleration() taken out (the excited joint's row of M(q))."""
        if self.count == 0:
            raise ValueError("an empty measure window has no sample")
        acc = self.mean_acceleration()
        inertial = float(np.asarray(inertia_row, dtype=float) @ acc) if acc.size else 0.0
        return self.sum_v / self.count, self.sum_tau / self.count - inertial


# --------------------------------------------------------------------------------------------
# The excitation profile


@dataclass(frozen=True)
class Excitation:
    """How a joint is excited (docs/identify.md, "Excitation").

    speeds_rad_per_s: the pass speeds (magnitudes; each is run in both directions); accel_rad_per_s2:
    the ramp's acceleration to and from a speed; settle_s: time at speed before measuring (the
    velocity loop settles, the inertial term dies out); measure_s: the measure time per speed and
    direction (split over several back-and-forth passes when one pass does not fit in the range);
    min_measure_s: the shortest measure window a pass may have (a speed needing shorter ones is
    left out); margin_rad: kept from each end of the joint's range; repeats: the whole speed list
    run this many times; torque_fraction: the excitation's torque beyond gravity compensation is
    clamped to this fraction of the motor's limit; rest_s: at rest between passes.
    """

    speeds_rad_per_s: tuple[float, ...] = (0.2, 0.4, 0.7, 1.0, 1.5)
    accel_rad_per_s2: float = 5.0
    settle_s: float = 0.25
    measure_s: float = 0.5
    min_measure_s: float = 0.08
    margin_rad: float = 0.1
    repeats: int = 2
    torque_fraction: float = 0.3
    rest_s: float = 0.05

    def __post_init__(self) -> None:
        if not self.speeds_rad_per_s:
            raise ValueError("speeds_rad_per_s needs at least one speed")
        for s in self.speeds_rad_per_s:
            if not (s > 0.0 and math.isfinite(s)):
                raise ValueError(f"speeds_rad_per_s must be finite and > 0, got {s}")
        for name in ("accel_rad_per_s2", "measure_s", "min_measure_s"):
            v = getattr(self, name)
            if not (v > 0.0 and math.isfinite(v)):
                raise ValueError(f"{name} must be finite and > 0, got {v}")
        for name in ("settle_s", "margin_rad", "rest_s"):
            v = getattr(self, name)
            if not (v >= 0.0 and math.isfinite(v)):
                raise ValueError(f"{name} must be finite and >= 0, got {v}")
        if self.min_measure_s > self.measure_s:
            raise ValueError(f"min_measure_s ({self.min_measure_s}) must be at most measure_s ({self.measure_s})")
        if self.repeats < 1:
            raise ValueError(f"repeats must be >= 1, got {self.repeats}")
        if not 0.0 < self.torque_fraction <= 1.0:
            raise ValueError(f"torque_fraction must be in (0, 1], got {self.torque_fraction}")


@dataclass(frozen=True)
class Pass:
    """One constant-velocity pass: a trapezoid of speed `speed_rad_per_s` (magnitude) in the
    direction the loop picks (`prefer` +1 or -1, reversed at the range's ends), ramp up, settle,
    measure (`measure` False: a move without a measure window), ramp down, rest."""

    speed_rad_per_s: float
    accel_rad_per_s2: float
    settle_s: float
    measure_s: float
    rest_s: float
    prefer: int
    measure: bool = True

    @property
    def ramp_s(self) -> float:
        return self.speed_rad_per_s / self.accel_rad_per_s2

    @property
    def hold_s(self) -> float:
        return self.settle_s + self.measure_s

    @property
    def duration_s(self) -> float:
        return 2.0 * self.ramp_s + self.hold_s + self.rest_s

    @property
    def travel_rad(self) -> float:
        """The distance the pass covers: speed x (ramp + settle + measure)."""
        return self.speed_rad_per_s * (self.ramp_s + self.hold_s)

    def velocity(self, t_s: float) -> float:
        """The speed reference (magnitude) at time t_s into the pass."""
        v, r = self.speed_rad_per_s, self.ramp_s
        if t_s < 0.0:
            return 0.0
        if t_s < r:
            return self.accel_rad_per_s2 * t_s
        if t_s < r + self.hold_s:
            return v
        if t_s < 2.0 * r + self.hold_s:
            return max(0.0, v - self.accel_rad_per_s2 * (t_s - r - self.hold_s))
        return 0.0

    def in_window(self, t_s: float) -> bool:
        """Whether t_s into the pass lies in its measure window."""
        start = self.ramp_s + self.settle_s
        return self.measure and start <= t_s < start + self.measure_s


@dataclass(frozen=True)
class Plan:
    """A joint's passes, and the speeds left out because no pass at them fits in the range."""

    passes: tuple[Pass, ...]
    dropped_speeds_rad_per_s: tuple[float, ...]

    @property
    def duration_s(self) -> float:
        return sum(p.duration_s for p in self.passes)


def usable_span(range_rad: tuple[float, float], margin_rad: float) -> float:
    """The length of the range with the margin kept at each end (inf for an unlimited joint)."""
    lo, hi = range_rad
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return math.inf
    return max(0.0, hi - lo - 2.0 * margin_rad)


def plan_passes(exc: Excitation, range_rad: tuple[float, float]) -> Plan:
    """The passes of one joint: every speed, `repeats` times, in both directions.

    A speed's measure time per direction goes into one pass when its travel fits in the usable
    span, else into n back-and-forth passes of measure_s / n each (n the fewest that fit; at least
    min_measure_s each, so a speed may get a little more than measure_s); a
    speed whose pass with the shortest window (min_measure_s) does not fit is dropped. A pass is
    planned to fill at most FIT_SHARE of the span: the rest is slack for the velocity loop's lag
    and for `reposition`. Directions
    alternate (+, -, +, -, ...), so the joint comes back near where it started."""
    span = FIT_SHARE * usable_span(range_rad, exc.margin_rad)
    passes: list[Pass] = []
    dropped: list[float] = []
    sign = 1
    for _ in range(exc.repeats):
        for v in exc.speeds_rad_per_s:
            fixed = v * (v / exc.accel_rad_per_s2 + exc.settle_s)  # ramp + settle travel
            room = span - fixed
            if room < v * exc.min_measure_s:
                if v not in dropped:
                    dropped.append(v)
                continue
            n = 1 if math.isinf(room) else max(1, math.ceil(v * exc.measure_s / room - 1e-12))
            # measure_s / n fits (room / v); min_measure_s fits (checked above): so does the larger
            window = max(exc.measure_s / n, exc.min_measure_s)
            for _ in range(2 * n):
                passes.append(Pass(v, exc.accel_rad_per_s2, exc.settle_s, window, exc.rest_s, sign))
                sign = -sign
    return Plan(tuple(passes), tuple(dropped))


def choose_direction(
    q_rad: float, range_rad: tuple[float, float], margin_rad: float, travel_rad: float, prefer: int
) -> int:
    """The direction (+1 or -1) a pass of `travel_rad` starting at q takes: `prefer` when the range
    (less the margin) has room that way, else the other way if it has, else 0 (neither)."""
    lo, hi = range_rad
    room = {1: (hi - margin_rad) - q_rad, -1: q_rad - (lo + margin_rad)}
    for s in (prefer, -prefer):
        if room[s] >= travel_rad:
            return s
    return 0


def reposition(
    q_rad: float,
    range_rad: tuple[float, float],
    margin_rad: float,
    travel_rad: float,
    speed_rad_per_s: float,
    accel_rad_per_s2: float,
) -> Pass | None:
    """A move (no measuring) that brings the joint where a pass of `travel_rad` fits: to the end of
    the usable range farther from q, just far enough; None if a pass fits already or never will."""
    lo, hi = range_rad
    span = usable_span(range_rad, margin_rad)
    if travel_rad > span or choose_direction(q_rad, range_rad, margin_rad, travel_rad, 1) != 0:
        return None
    up = (hi - margin_rad) - q_rad
    down = q_rad - (lo + margin_rad)
    # Toward the end with more room, until the other way has `travel_rad` (up + down = span >= travel).
    slack = 0.5 * (span - travel_rad)  # aim past the least move, by half the spare room
    if up >= down:
        distance, sign = travel_rad - down + slack, 1
    else:
        distance, sign = travel_rad - up + slack, -1
    v = min(speed_rad_per_s, math.sqrt(accel_rad_per_s2 * distance)) if distance > 0.0 else speed_rad_per_s
    hold = max(0.0, distance / v - v / accel_rad_per_s2)
    return Pass(v, accel_rad_per_s2, hold, 0.0, 0.0, sign, measure=False)


def brake_speed(distance_rad: float, accel_rad_per_s2: float) -> float:
    """The largest speed from which the joint stops within `distance_rad` at `accel_rad_per_s2`."""
    return math.sqrt(2.0 * accel_rad_per_s2 * max(0.0, distance_rad))
