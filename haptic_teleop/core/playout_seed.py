"""Seed 000's playout buffers (docs/playout_seed.md): transparency-driven buffering (`TransparencyBuffer`:
hold a sample as long as the force error it costs stays within the allowed distortion) and the
network-adaptive buffer (`NetworkAdaptiveBuffer`: the allowable delay and loss time of the scene's
transparency analysis against the link's measured delay). Built by core/playout_config.py.
"""

from __future__ import annotations

import math

from haptic_teleop.core.playout import ScheduledBuffer, Window
from haptic_teleop.core.playout_rules import (
    POLICY_NETWORK_ADAPTIVE,
    POLICY_TRANSPARENCY,
    Q_ALLOW_LOSS,
    Q_BUDGET,
    Q_T_ALLOW,
    Q_T_COUNT,
    Q_T_D0,
    Q_T_DIRTY,
    Q_T_HORIZON,
    network_adaptive_need,
    retarget_due,
    transparency_decide,
)


class TransparencyBuffer(ScheduledBuffer):
    """Policy `transparency` (seed 000): the buffering time that minimises the EBA force error.

    Seed 000: in contact the felt force rises at slope s = c * v_m; a latency D lowers it by
    s * D and every hold (the due sample missing) lowers it by s * the hold time. With b the
    buffering above the window's minimum relative delay, d0 the smallest one-way delay, x the
    relative delays above the window minimum and H the contact horizon, the expected force error
    at the end of a contact is (derivation in docs/playout_seed.md)

        e(b) = s * (d0 + b + H * P(x > b))

    b is the minimiser of e over {0} and the window's values, subject to the allowable-latency
    cap d0 + b <= D_allow = allowed_force_error / s (b = 0 when the cap is below d0).
    """

    name = "transparency"
    policy = POLICY_TRANSPARENCY

    def __init__(
        self,
        period_ns: int,
        *,
        allowed_force_error_n: float = 0.1,
        force_slope_n_per_s: float | None = None,
        min_one_way_delay_ns: int = 0,
        contact_horizon_ns: int = 1_000_000_000,
        window_packets: int = 1000,
        gap: str = "hold",
        max_extrapolation_ns: int = 0,
        max_slew_rate: float = 0.05,
        hysteresis_ns: int = 0,
    ) -> None:
        if not allowed_force_error_n > 0.0:
            raise ValueError(f"allowed_force_error_n must be > 0, got {allowed_force_error_n}")
        if not contact_horizon_ns > 0:
            raise ValueError(f"contact_horizon_ns must be > 0, got {contact_horizon_ns}")
        super().__init__(
            period_ns,
            gap=gap,
            max_extrapolation_ns=max_extrapolation_ns,
            max_slew_rate=max_slew_rate,
            hysteresis_ns=hysteresis_ns,
        )
        self.allowed_force_error_n = allowed_force_error_n
        self.contact_horizon_ns = contact_horizon_ns
        self.Q[Q_T_HORIZON] = contact_horizon_ns
        self._slope: float | None = None
        self._d0 = 0
        self._bounds()
        self.set_force_slope(force_slope_n_per_s)
        self.set_min_one_way_delay(min_one_way_delay_ns)
        self._window = Window(window_packets)
        self.buffering_ns = 0  # b: the chosen buffering above the minimum relative delay
        self.expected_hold_ns = 0  # H * P(x > b) at the last decision
        self.expected_force_error_n: float | None = None  # e(b) at the last decision (None: no slope)

    def set_force_slope(self, slope_n_per_s: float | None) -> None:
        """The engine's current s (e.g. `contact_force_slope(stiffness, speed)`); None: no cap.

        Cheap enough to call every tick: the next decision (at the next arrival) uses it.
        """
        if slope_n_per_s is not None and not (slope_n_per_s >= 0.0 and math.isfinite(slope_n_per_s)):
            raise ValueError(f"force slope must be a finite value >= 0, got {slope_n_per_s}")
        if slope_n_per_s != self._slope:
            self._slope = slope_n_per_s
            self._bounds()
            self.Q[Q_T_DIRTY] = 1

    def set_min_one_way_delay(self, delay_ns: int) -> None:
        """d0: the smallest one-way delay (e.g. half the minimum round trip); not observable here."""
        if delay_ns < 0:
            raise ValueError(f"min one-way delay must be >= 0, got {delay_ns}")
        if delay_ns != self._d0:
            self._d0 = delay_ns
            self._bounds()
            self.Q[Q_T_DIRTY] = 1

    @property
    def allowed_latency_ns(self) -> int | None:
        """D_allow = allowed_force_error / s, or None when s is unknown or 0 (no cap)."""
        s = self._slope
        if not s:
            return None
        return min(round(self.allowed_force_error_n / s * 1e9), 1 << 62)

    def _bounds(self) -> None:
        """D_allow (-1: no cap) and d0 where the rules (and the compiled schedule) read them."""
        allow = self.allowed_latency_ns
        self.Q[Q_T_ALLOW] = -1 if allow is None else allow
        self.Q[Q_T_D0] = self._d0

    def _observe(self, rel_ns: int) -> None:
        self._window.add(rel_ns)
        Q = self.Q
        Q[Q_T_COUNT] += 1
        if retarget_due(Q[Q_T_COUNT], Q[Q_T_DIRTY] != 0):
            self._decide()

    def _decide(self) -> None:
        Q = self.Q
        Q[Q_T_DIRTY] = 0
        srt = self._window.sorted
        best_b, best_cost = transparency_decide(srt, len(srt), Q[Q_T_HORIZON], Q[Q_T_ALLOW], Q[Q_T_D0])
        self.buffering_ns = best_b
        self.expected_hold_ns = round(best_cost) - best_b
        self._set_target(srt[0] + best_b)
        s = self._slope
        self.expected_force_error_n = None if s is None else s * (self._d0 + best_cost) * 1e-9


class NetworkAdaptiveBuffer(ScheduledBuffer):
    """Policy `network_adaptive`: seed 000's network-adaptive buffering time control, read as the
    seed states it (docs/playout_claim.md, "The haptic-synchronization claim, tested fairly").

    From the transparency analysis of the scene (core/transparency.py) it takes the allowable
    delay D_a (the largest one-way delay whose force drop stays within the required distortion E)
    and the allowable loss time L_a = T_tr + E / s (the transparent loss time, then as long as the
    undisturbed force takes to rise by E); from the network, the minimum one-way delay d0. With x
    the relative delays above the window's minimum, a sample x late is held about x - b past its
    slot; the buffering time is the least that keeps every hold the window predicts within L_a,
    as long as the latency d0 + b stays within D_a:

        b = min( max(0, max(x) - L_a), max(0, D_a - d0) )

    No free parameter decides between latency and holds: both bounds come from the analysis.
    `requirement_met` is False when the window's holds need more buffering than D_a - d0 allows
    (the seed's requirement cannot be met at this jitter; the latency bound wins).
    """

    name = "network_adaptive"
    policy = POLICY_NETWORK_ADAPTIVE

    def __init__(
        self,
        period_ns: int,
        *,
        allowable_delay_ns: int | None = None,
        allowable_loss_time_ns: int = 0,
        min_one_way_delay_ns: int = 0,
        window_packets: int = 1000,
        gap: str = "hold",
        max_extrapolation_ns: int = 0,
        max_slew_rate: float = 0.05,
        hysteresis_ns: int = 0,
    ) -> None:
        super().__init__(
            period_ns,
            gap=gap,
            max_extrapolation_ns=max_extrapolation_ns,
            max_slew_rate=max_slew_rate,
            hysteresis_ns=hysteresis_ns,
        )
        self._window = Window(window_packets)
        self._allow_delay: int | None = None
        self._allow_loss = 0
        self._d0 = 0
        self.set_allowable(allowable_delay_ns, allowable_loss_time_ns)
        self.set_min_one_way_delay(min_one_way_delay_ns)
        self.buffering_ns = 0  # b: the chosen buffering above the window's minimum relative delay
        self.requirement_met = True

    def set_allowable(self, delay_ns: int | None, loss_time_ns: int) -> None:
        """D_a (None: no delay bound) and L_a, from the transparency analysis (the engine passes
        them, `assembly.build_network`); the next arrival's decision uses them."""
        if delay_ns is not None and delay_ns < 0:
            raise ValueError(f"allowable delay must be >= 0, got {delay_ns}")
        if loss_time_ns < 0:
            raise ValueError(f"allowable loss time must be >= 0, got {loss_time_ns}")
        self._allow_delay = delay_ns
        self._allow_loss = loss_time_ns
        self._bounds()

    def set_min_one_way_delay(self, delay_ns: int) -> None:
        """d0: the smallest one-way delay (the engine: the link's; a node: half the minimum round trip)."""
        if delay_ns < 0:
            raise ValueError(f"min one-way delay must be >= 0, got {delay_ns}")
        self._d0 = delay_ns
        self._bounds()

    @property
    def delay_budget_ns(self) -> int | None:
        """D_a - d0 (at least 0): the most buffering the allowable delay leaves; None: no bound."""
        a = self._allow_delay
        return None if a is None else max(0, a - self._d0)

    def _observe(self, rel_ns: int) -> None:
        w = self._window
        w.add(rel_ns)
        srt = w.sorted
        need, self.requirement_met = network_adaptive_need(srt[0], srt[-1], self._allow_loss, self.Q[Q_BUDGET])
        self.buffering_ns = need
        self._set_target(srt[0] + need)

    def _bounds(self) -> None:
        """L_a and D_a - d0 (-1: none) where the rules (and the compiled schedule) read them."""
        cap = self.delay_budget_ns
        self.Q[Q_ALLOW_LOSS] = self._allow_loss
        self.Q[Q_BUDGET] = -1 if cap is None else cap
