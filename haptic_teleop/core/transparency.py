"""Seed 000's transparency analysis of EBA teleoperation in contact, as formulas (docs/transparency.md).

The premise: the robot rests against a wall (stiffness K) pressed with force F0; the master moves
toward it at constant velocity v_m (a position source). Each side runs the stack's laws:
position-position coupling (c1, c2) or force reflection (gain g) on the master, position coupling
on the slave, each bounded by its energy reservoir (core/eba.py; the reservoir law: the force may
grow by at most 2 b v T per period when the bound binds, i.e. with stiffness 2 b / T).

Everything here is pure arithmetic on floats: the contact start of `slave.start: in_contact`
(`contact_start`), the predicted force slope in contact (`force_slope`), the force drop for a
delay (`force_drop`, with its regime), the transparent loss time of a held sample
(`transparent_loss_time`) and the allowable delay and loss time for a required force error
(`allowable_delay`, `allowable_loss_time`). Derivations and their checks against simulation:
docs/transparency.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

LAWS = ("reservoir", "two_condition")
MASTER_LAWS = ("position", "force")


def holding_energy(force_n: float, damping_n_s_per_m: float, period_s: float) -> float:
    """The least reservoir that lets the bound render |force|: F^2 T / (4 b) (|F| <= sqrt(4 b E / T))."""
    return force_n * force_n * period_s / (4.0 * damping_n_s_per_m)


@dataclass(frozen=True)
class ContactStart:
    """The equilibrium a scene with `slave.start: in_contact` starts in (docs/transparency.md,
    "Starting in contact"). Positions in m, forces in N (the master's and the wall's negative:
    they push toward -x), reservoirs in J (the holding energy only; the scene's
    `eba.initial_energy_j` is added on top)."""

    slave_x_m: float
    master_x_m: float
    wall_force_n: float  # the wall's force on the robot, -F0
    slave_force_n: float  # the slave's actuator, +F0
    master_force_n: float  # the master's actuator
    master_energy_j: float
    slave_energy_j: float
    hand_offset_m: float  # how far beyond the master the hand's intended position starts (spring hand)


def contact_start(
    wall_position_m: float,
    wall_stiffness_n_per_m: float,
    contact_force_n: float,
    slave_stiffness_n_per_m: float,
    master_law: str,
    master_stiffness_n_per_m: float,
    master_force_gain: float,
    master_damping_n_s_per_m: float,
    slave_damping_n_s_per_m: float,
    period_s: float,
    hand_stiffness_n_per_m: float,
) -> ContactStart:
    """The rest state with wall force F0 = `contact_force_n`: the robot's tip F0 / K into the wall,
    held there by the slave's coupling spring stretched F0 / c1s (master ahead of it by that), the
    master's actuator holding c1m F0 / c1s (position law) or g F0 (force reflection) against the
    operator, and each reservoir at the holding energy of its force (`holding_energy`): the
    least with which the state is an equilibrium, i.e. no energy the operator did not put in."""
    if master_law not in MASTER_LAWS:
        raise ValueError(f"master_law must be one of {MASTER_LAWS}, got {master_law!r}")
    if not (contact_force_n > 0.0 and wall_stiffness_n_per_m > 0.0 and slave_stiffness_n_per_m > 0.0):
        raise ValueError("contact force, wall stiffness and slave stiffness must be > 0")
    f0 = contact_force_n
    xs = wall_position_m + f0 / wall_stiffness_n_per_m
    xm = xs + f0 / slave_stiffness_n_per_m
    fm = master_force_gain * f0 if master_law == "force" else master_stiffness_n_per_m * f0 / slave_stiffness_n_per_m
    offset = fm / hand_stiffness_n_per_m if hand_stiffness_n_per_m > 0.0 else 0.0
    return ContactStart(
        slave_x_m=xs,
        master_x_m=xm,
        wall_force_n=-f0,
        slave_force_n=f0,
        master_force_n=-fm,
        master_energy_j=holding_energy(fm, master_damping_n_s_per_m, period_s),
        slave_energy_j=holding_energy(f0, slave_damping_n_s_per_m, period_s),
        hand_offset_m=offset,
    )


@dataclass(frozen=True)
class ContactModel:
    """The numbers of a contact scene the predictions use (`haptic_teleop.analysis.transparency`
    reads them from a scene). speed_m_per_s: v_m toward the wall (> 0)."""

    period_s: float
    speed_m_per_s: float
    master_law: str  # "position" or "force"
    master_stiffness_n_per_m: float  # c1m
    master_damping_n_s_per_m: float  # c2m (the coupling's damper)
    master_force_gain: float  # g (force reflection)
    master_physical_damping_n_s_per_m: float  # b_m: the bound's stiffness is 2 b_m / T
    master_force_limit_n: float
    slave_stiffness_n_per_m: float  # c1s
    wall_stiffness_n_per_m: float  # K
    contact_force_n: float  # F0 at the start
    master_eba: bool = True
    slave_damping_n_s_per_m: float = 0.0  # c2s (the coupling's damper)
    slave_physical_damping_n_s_per_m: float = 0.0  # b_s
    wall_damping_n_s_per_m: float = 0.0  # B

    def __post_init__(self) -> None:
        if self.master_law not in MASTER_LAWS:
            raise ValueError(f"master_law must be one of {MASTER_LAWS}, got {self.master_law!r}")
        if not self.speed_m_per_s > 0.0:
            raise ValueError(f"speed_m_per_s must be > 0 (toward the wall), got {self.speed_m_per_s}")

    @property
    def series_stiffness_n_per_m(self) -> float:
        """The slave's coupling spring in series with the wall: c1s K / (c1s + K). The robot's tip
        moves by dF / K, so the wall force grows with it per metre the master advances."""
        c, k = self.slave_stiffness_n_per_m, self.wall_stiffness_n_per_m
        return c * k / (c + k)

    @property
    def wall_lead_s(self) -> float:
        """How far the wall force's ramp leads the quasi-static one c1s K / (c1s + K) x_m: the robot
        (m x'' + (c2s + b_s + B) x' + (c1s + K) x = c1s x_m + c2s v_m) follows a ramp with the
        coupling damper's feed-forward c2s / c1s ahead and its own damping's lag
        (c2s + b_s + B) / (c1s + K) behind."""
        c1, k = self.slave_stiffness_n_per_m, self.wall_stiffness_n_per_m
        damping = self.slave_damping_n_s_per_m + self.slave_physical_damping_n_s_per_m + self.wall_damping_n_s_per_m
        return self.slave_damping_n_s_per_m / c1 - damping / (c1 + k)

    def force_onset_s(self, round_trip_s: float) -> float:
        """Force reflection: when the felt (desired) force's ramp starts, extrapolated back, after
        the master starts: the round trip, one period (the master uses a backward sample the tick
        after it arrives), less the wall force's lead (`wall_lead_s`); 0 at the earliest."""
        return max(0.0, round_trip_s + self.period_s - self.wall_lead_s)

    @property
    def desired_stiffness_n_per_m(self) -> float:
        """How fast the master's control law wants its force to grow per metre of master motion in
        contact: c1m K / (c1s + K) (position law: the master's own spring against a robot that
        yields dF / K), g c1s K / (c1s + K) (force reflection: the wall force's growth)."""
        k, c1s = self.wall_stiffness_n_per_m, self.slave_stiffness_n_per_m
        if self.master_law == "force":
            return self.master_force_gain * self.series_stiffness_n_per_m
        return self.master_stiffness_n_per_m * k / (c1s + k)

    @property
    def bound_stiffness_n_per_m(self) -> float:
        """2 b_m / T: the stiffness the reservoir's bound lets the force grow with at most (inf: EBA off)."""
        if not self.master_eba:
            return math.inf
        return 2.0 * self.master_physical_damping_n_s_per_m / self.period_s

    @property
    def binding(self) -> bool:
        """The bound limits the force's growth (the control law asks for more than 2 b_m / T)."""
        return self.desired_stiffness_n_per_m > self.bound_stiffness_n_per_m

    @property
    def master_start_force_n(self) -> float:
        """|F_m| at the start: c1m F0 / c1s (position law) or g F0."""
        f0 = self.contact_force_n
        if self.master_law == "force":
            return self.master_force_gain * f0
        return self.master_stiffness_n_per_m * f0 / self.slave_stiffness_n_per_m


def _check_law(law: str) -> None:
    if law not in LAWS:
        raise ValueError(f"law must be one of {LAWS}, got {law!r}")


def force_stiffness(m: ContactModel, law: str = "reservoir") -> float:
    """gamma: the felt force's growth per metre of master motion in contact, min(desired, 2 b_m / T)."""
    _check_law(law)
    return min(m.desired_stiffness_n_per_m, m.bound_stiffness_n_per_m)


def force_slope(m: ContactModel, law: str = "reservoir") -> float:
    """s = gamma v_m (N/s): the felt force's slope in contact, once past the start's transient."""
    return force_stiffness(m, law) * m.speed_m_per_s


def catch_up_s(m: ContactModel, round_trip_s: float) -> float:
    """Force reflection with the bound binding, reservoir law: how long after the round trip the
    delayed desired force (flat F_m0 for the round trip R, then slope s_d) takes to meet the bound,
    whose reservoir the operator charged meanwhile (docs/transparency.md, "Force drop").

    With a = 4 b v / T, c = 4 b^2 v^2 / T, u_R^2 = F_m0^2 + (a F_m0 + c) R the bound's square at R,
    tau solves (F_m0 + s_d tau)^2 = u_R^2 + a (F_m0 tau + s_d tau^2 / 2) + c tau."""
    v = m.speed_m_per_s
    b, t = m.master_physical_damping_n_s_per_m, m.period_s
    f0 = m.master_start_force_n
    sd = m.desired_stiffness_n_per_m * v
    a = 4.0 * b * v / t
    c = 4.0 * b * b * v * v / t
    ur2 = f0 * f0 + (a * f0 + c) * round_trip_s
    qa = sd * sd - a * sd / 2.0
    qb = 2.0 * f0 * sd - a * f0 - c
    qc = f0 * f0 - ur2
    if qa <= 0.0:
        return math.inf
    return (-qb + math.sqrt(qb * qb - 4.0 * qa * qc)) / (2.0 * qa)


@dataclass(frozen=True)
class DropPrediction:
    """The felt force's drop against the undelayed run at the same time (N; negative: it is
    higher), once steady, and the regime the formula is for."""

    drop_n: float
    regime: str


def force_drop(
    m: ContactModel, forward_delay_s: float, backward_delay_s: float, law: str = "reservoir", at_s: float = math.inf
) -> DropPrediction:
    """The seed's "force feedback decrease caused by delay" `at_s` after the master starts moving
    (default: once steady), per regime (docs/transparency.md, "Force drop"), R = d_f + d_b:

    - force reflection, bound not binding: the felt force is the wall force a round trip late:
      drop = s min(R, t) (the seed's c2m v_m d with d the round trip);
    - force reflection, bound binding, two-condition law: the ZOH condition's per-step cap
      gamma_max = 2 b_m / T holds whatever energy is stored, so the felt force ramps at s_b from
      the delayed onset: drop = s_b min(R, t), the seed's value;
    - force reflection, bound binding, reservoir law: the operator keeps charging the reservoir
      while the delayed desired force is flat, so the bound is ahead when it rises; once the
      desired force has caught up (`catch_up_s`): drop = s_b R - (s_d - s_b) tau, between s_b R
      (F_m0 -> 0, the seed's value) and 0 (F_m0 >> s R); before: s_b t - s_d max(0, t - R);
    - position law, bound not binding: the master's own spring stretches at once; the robot's
      position comes back a round trip late, less deep, so the felt force is HIGHER by
      c1m c1s / (c1s + K) v_m min(R, t) (a negative drop);
    - position law, bound binding: the bound's ramp, 2 b_m v_m / T from the start whatever the
      delay: no drop.
    """
    _check_law(law)
    r = forward_delay_s + backward_delay_s
    t = at_s
    v = m.speed_m_per_s
    if m.master_law == "position":
        if m.binding:
            return DropPrediction(0.0, "position law, bound binding: the bound's ramp does not see the delay")
        c1m, c1s, k = m.master_stiffness_n_per_m, m.slave_stiffness_n_per_m, m.wall_stiffness_n_per_m
        return DropPrediction(
            -c1m * c1s / (c1s + k) * v * min(r, t), "position law, bound not binding: the felt force rises with delay"
        )
    if not m.binding:
        return DropPrediction(force_slope(m, law) * min(r, t), "force reflection, bound not binding: drop s R")
    sb = m.bound_stiffness_n_per_m * v
    sd = m.desired_stiffness_n_per_m * v
    if law == "two_condition":
        # the ZOH condition caps each step's rise at (2 b_m / T) dx whatever energy is stored, so
        # both runs' felt forces ramp at s_b from their desired forces' onsets, a round trip
        # apart: the seed's s_b R
        return DropPrediction(
            sb * min(r, t), "force reflection, bound binding, two-condition law: the ZOH cap's ramp, a round trip late"
        )
    r = m.force_onset_s(r)  # the undelayed run's onset is 0 (the wall force leads by more than a tick)
    tau = catch_up_s(m, r)
    if t >= r + tau:
        return DropPrediction(sb * r - (sd - sb) * tau, "force reflection, bound binding: the reservoir caught up")
    return DropPrediction(
        sb * t - sd * max(0.0, t - r), "force reflection, bound binding: the delayed force still below the bound"
    )


def force_slope_between(
    m: ContactModel, forward_delay_s: float, backward_delay_s: float, t0_s: float, t1_s: float, law: str = "reservoir"
) -> float:
    """The felt force's mean slope between t0 and t1 after the master starts, N/s: the undelayed
    slope s less the change of the drop (`force_drop`) over the interval. It is s once steady; it
    differs while the delayed force reflection is still below the bound (it rises at s_d then)."""
    if not t1_s > t0_s:
        raise ValueError(f"t1_s must be after t0_s, got {t0_s}, {t1_s}")
    d0 = force_drop(m, forward_delay_s, backward_delay_s, law, t0_s).drop_n
    d1 = force_drop(m, forward_delay_s, backward_delay_s, law, t1_s).drop_n
    return force_slope(m, law) - (d1 - d0) / (t1_s - t0_s)


def transparent_loss_time(m: ContactModel, gap_n: float, felt_n: float, law: str = "reservoir") -> float:
    """How long the felt force still rises after the master's remote sample is held (a loss burst
    on the backward link), s (docs/transparency.md, "Transparent loss time").

    Position law: the held robot position leaves the master's own spring, which its motion keeps
    stretching: the force rises until the saturation, (F_lim - F) / s. Force reflection: the
    desired force stays at the held sample's; the felt force rises while it is below it, at the
    bound's slope when the bound binds: gap / s_b, gap = F_desired - F_felt at the onset (0
    when the bound does not bind: the force stops at once)."""
    _check_law(law)
    s = force_slope(m, law)
    if not s > 0.0:  # a law without stiffness: the force does not rise at all
        return 0.0
    if m.master_law == "position":
        return max(0.0, m.master_force_limit_n - felt_n) / s
    if not m.binding:
        return 0.0
    return max(0.0, gap_n) / (m.bound_stiffness_n_per_m * m.speed_m_per_s)


def allowable_delay(m: ContactModel, error_n: float, law: str = "reservoir") -> float:
    """The largest one-way delay d (the same both ways, round trip 2 d) whose |force drop| stays
    within `error_n`, s; inf when no delay makes it (the bound's ramp in the position law)."""
    _check_law(law)
    if not error_n > 0.0:
        raise ValueError(f"error_n must be > 0, got {error_n}")

    def err(d: float) -> float:
        return abs(force_drop(m, d, d, law).drop_n)

    hi = 1.0
    while err(hi) <= error_n:
        hi *= 2.0
        if hi > 1e6:
            return math.inf
    lo = 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if err(mid) <= error_n:
            lo = mid
        else:
            hi = mid
    return lo


def allowable_loss_time(m: ContactModel, error_n: float, transparent_s: float, law: str = "reservoir") -> float:
    """The longest loss burst whose force error stays within `error_n`, s: the transparent loss
    time, then as long as the undisturbed force takes to rise by the error, T_tr + E / s."""
    _check_law(law)
    if not error_n > 0.0:
        raise ValueError(f"error_n must be > 0, got {error_n}")
    s = force_slope(m, law)
    return transparent_s + error_n / s if s > 0.0 else math.inf
