"""Effects that lose packets: blackout windows, netem's loss models (Bernoulli, Gilbert-Elliott,
4-state), a replayed loss pattern, and corruption (the receiver discards the packet).

Each marks a packet's fate and draws its random numbers per original packet, lost or not (the
rules in `core/link.py`); the formulas are in docs/network_effects.md.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from haptic_teleop.core.link import DELIVERED, LOST_CORRUPT, LOST_NETWORK, Packet
from haptic_teleop.core.uniform import NetemCorrelatedUniform, UniformSource, netem_next, uniform_source

# The loss rules as plain functions: the one definition the effects below call and the compiled
# links inline (engine/compiled/codec_link.py). Fates are integer codes, DELIVERED 0.


def first_fate(fate: int, lost: bool, code: int) -> int:
    """A packet's fate after an effect's verdict: the first effect that loses it names the fate
    (every effect still draws its numbers for it, see core/link.py)."""
    return code if lost and fate == DELIVERED else fate


def _mark_lost(fate: np.ndarray, lost: np.ndarray, effect: Any) -> None:
    """`first_fate` over a window (`apply_all`): the packets an effect loses that no effect before
    it lost take its fate, and count as its drops."""
    hit = lost & (fate == DELIVERED)
    fate[hit] = LOST_NETWORK
    effect.dropped += int(hit.sum())


def blackout_at(windows: np.ndarray, i: int, t_ns: int) -> tuple[int, bool]:
    """Blackout windows (rows [start, end) ns, sorted, not overlapping) at time `t_ns`, searched
    from row `i` (the answer for an earlier time, or 0): the number of windows that start by
    `t_ns`, and whether `t_ns` is inside the last of them."""
    n = windows.shape[0]
    while i < n and windows[i, 0] <= t_ns:
        i += 1
    return i, i > 0 and t_ns < windows[i - 1, 1]


def bernoulli_lost(u: float, p: float) -> bool:
    """Bernoulli loss (netem `loss random p`): the packet whose uniform number is `u` is lost."""
    return u < p


def bernoulli_run(fresh: np.ndarray, rho: float, last_u: float, p: float, lost: np.ndarray) -> float:
    """`bernoulli_lost` on packets in turn: packet i's number is the fresh uniform fresh[i],
    netem-correlated with the last one (`last_u`) if rho > 0 (`netem_next`); lost[i] set for each.
    Returns the correlated stream's last number. One definition for `BernoulliLoss.apply_all` and,
    compiled, the compiled loop's network schedule (engine/compiled/link_runs.py)."""
    for i in range(lost.shape[0]):
        u = fresh[i]
        if rho > 0.0:
            u = netem_next(u, rho, last_u)
            last_u = u
        lost[i] = bernoulli_lost(u, p)
    return last_u


def trace_lost(pattern: Sequence[float] | np.ndarray, n: int, repeat: bool) -> bool:
    """A replayed loss pattern (nonzero: lost) on the n-th packet (from 0): past its end the
    pattern starts again if `repeat`, else every packet passes."""
    m = len(pattern)
    if n >= m:
        if not repeat:
            return False
        n %= m
    return bool(pattern[n] != 0)


def trace_run(pattern: np.ndarray, n0: int, repeat: bool, lost: np.ndarray) -> int:
    """`trace_lost` on packets in turn, the first being the n0-th of the stream: lost[i] set for
    each; returns the count of packets after the last. One definition for `TraceLoss.apply_all`
    and, compiled, the compiled loop's network schedule (engine/compiled/link_runs.py)."""
    for i in range(lost.shape[0]):
        lost[i] = trace_lost(pattern, n0 + i, repeat)
    return n0 + len(lost)


class Blackout:
    """The link is down in [start, end) windows: every packet sent inside one is lost."""

    name = "blackout"

    def __init__(self, windows_ns: Sequence[tuple[int, int]]) -> None:
        ws = sorted((int(a), int(b)) for a, b in windows_ns)
        for (a, b), nxt in zip(ws, [*ws[1:], None], strict=True):
            if not b > a:
                raise ValueError(f"blackout window must end after it starts, got [{a}, {b}) ns")
            if nxt is not None and nxt[0] < b:
                raise ValueError(f"blackout windows overlap: [{a}, {b}) and [{nxt[0]}, {nxt[1]}) ns")
        self.windows = np.array(ws, dtype=np.int64).reshape(-1, 2)
        self._i = 0  # `blackout_at`'s row for the last packet's time
        self._t = -(1 << 62)
        self.dropped = 0

    vectorized = True

    def apply_all(
        self, send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray, runs: Runs | None = None
    ) -> None:
        """`apply` on every original packet of a run at once (see `Link.schedule_all`)."""
        starts, ends = self.windows[:, 0], self.windows[:, 1]
        i = np.searchsorted(starts, send_ns, side="right") - 1
        _mark_lost(fate, (i >= 0) & (send_ns < ends[np.maximum(i, 0)]), self)

    def apply(self, packet: Packet) -> Packet | None:
        t = packet.send_time_ns
        self._i, hit = blackout_at(self.windows, self._i if t >= self._t else 0, t)
        self._t = t
        fate = first_fate(packet.fate, hit, LOST_NETWORK)
        if fate != packet.fate:
            packet.fate = fate
            self.dropped += 1
        return None


class BernoulliLoss:
    """Independent loss with probability p per packet (netem `loss random p [corr]`)."""

    name = "loss"

    def __init__(
        self,
        probability: float,
        rng: np.random.Generator,
        correlation: float = 0.0,
        correlation_model: str = "netem",
    ) -> None:
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        self.probability = probability
        self._rng = rng
        self._u = uniform_source(rng, correlation, correlation_model)
        self.dropped = 0
        # Uncorrelated draws are plain uniforms: a whole run's can be drawn in one call;
        # netem-correlated ones are run over the window (`bernoulli_run`); not the copula's.
        self.vectorized = type(getattr(self._u, "__self__", None)) in (UniformSource, NetemCorrelatedUniform)

    def apply_all(
        self, send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray, runs: Runs | None = None
    ) -> None:
        """`apply` on every original packet of a run at once, before any `apply` (`Link.schedule_all`).

        Uncorrelated: `rng.random(n)` gives the numbers `UniformSource` hands out one at a time
        (it draws the same stream in blocks), so the same packets are lost. netem-correlated: the
        next n fresh numbers of its inner source (`UniformSource.take`), correlated and compared
        by `bernoulli_run` (or `runs["bernoulli_run"]`, compiled); its last number written back."""
        if not self.vectorized:
            raise ValueError("gaussian_copula-correlated loss draws have no vectorized form")
        n = len(send_ns)
        src = self._u.__self__  # type: ignore[attr-defined]
        if type(src) is NetemCorrelatedUniform:
            run = bernoulli_run if runs is None else runs.get("bernoulli_run", bernoulli_run)
            lost = np.zeros(n, dtype=np.bool_)
            fresh = src._fresh.__self__.take(n)  # type: ignore[attr-defined]
            src._last = float(run(fresh, src._rho, src._last, self.probability, lost))
            _mark_lost(fate, lost, self)
            return
        _mark_lost(fate, self._rng.random(n) < self.probability, self)  # bernoulli_lost, per packet

    def apply(self, packet: Packet) -> Packet | None:
        fate = first_fate(packet.fate, bernoulli_lost(self._u(), self.probability), LOST_NETWORK)
        if fate != packet.fate:
            packet.fate = fate
            self.dropped += 1
        return None


def gilbert_step(
    bad: bool, move: float, u: float, p: float, r: float, loss_bad: float, loss_good: float
) -> tuple[bool, bool]:
    """One packet of the Gilbert-Elliott chain from its two uniforms (the transition's `move`,
    then the loss draw `u`): (the state after it, whether the packet is lost). The loss uses the
    state the packet met; then good->bad with p, bad->good with r. One definition for
    `GilbertElliottLoss` and the compiled loop (engine/compiled/codec_kernel.py)."""
    if bad:
        return move >= r, u < loss_bad
    return move < p, u < loss_good


def gilbert_run(
    bad: bool, draws: np.ndarray, p: float, r: float, loss_bad: float, loss_good: float, lost: np.ndarray
) -> bool:
    """`gilbert_step` on packets in turn (packet i's two uniforms are draws[2 i] and draws[2 i + 1]):
    lost[i] set for each; returns the state after the last. One definition for
    `GilbertElliottLoss.apply_all` and, compiled, the compiled loop's network schedule
    (engine/compiled/link_runs.py)."""
    for i in range(lost.shape[0]):
        bad, lost[i] = gilbert_step(bad, draws[2 * i], draws[2 * i + 1], p, r, loss_bad, loss_good)
    return bad


# A chain's run over a window (`gilbert_run`, `four_state_run`): the plain functions above, or the
# same functions compiled (`Link.schedule_all(send, runs)`: engine/compiled/link_runs.py).
Runs = Mapping[str, Callable[..., Any]]


class GilbertElliottLoss:
    """2-state Markov loss (netem `loss gemodel p r 1-h 1-k`).

    Per packet, as netem does: draw the transition (good->bad with p, bad->good with r), then
    draw the loss with the loss probability of the state the packet met (1-k in good, 1-h in
    bad). Starts in the good state. Gilbert is the case 1-k = 0, simple Gilbert 1-h = 1 too.
    """

    name = "loss"

    def __init__(self, p: float, r: float, one_minus_h: float, one_minus_k: float, rng: np.random.Generator) -> None:
        for key, v in (("p", p), ("r", r), ("one_minus_h", one_minus_h), ("one_minus_k", one_minus_k)):
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{key} must be in [0, 1], got {v}")
        self.p, self.r = p, r
        self.loss_bad, self.loss_good = one_minus_h, one_minus_k
        self._rng = rng
        self._u = UniformSource(rng).next
        self.bad = False
        self.dropped = 0

    vectorized = True

    def apply_all(
        self, send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray, runs: Runs | None = None
    ) -> None:
        """`apply` on every original packet of a window at once, before any `apply`
        (`Link.schedule_all`): the same two draws a packet (`rng.random(2 n)` is the stream
        `UniformSource` hands out), the chain run by `gilbert_run` (or `runs["gilbert_run"]`)."""
        run = gilbert_run if runs is None else runs.get("gilbert_run", gilbert_run)
        lost = np.zeros(len(send_ns), dtype=np.bool_)
        self.bad = bool(
            run(self.bad, self._rng.random(2 * len(send_ns)), self.p, self.r, self.loss_bad, self.loss_good, lost)
        )
        _mark_lost(fate, lost, self)

    def apply(self, packet: Packet) -> Packet | None:
        u = self._u
        move = u()
        self.bad, lost = gilbert_step(self.bad, move, u(), self.p, self.r, self.loss_bad, self.loss_good)
        fate = first_fate(packet.fate, lost, LOST_NETWORK)
        if fate != packet.fate:
            packet.fate = fate
            self.dropped += 1
        return None


def four_state_next(s: int, u: float, p13: float, p31: float, p32: float, p23: float, p14: float) -> int:
    """netem's 4-state chain's move from state `s` on the uniform `u`."""
    if s == 1:
        if u < p14:
            return 4
        if u < p14 + p13:
            return 3
        return 1
    if s == 2:
        return 3 if u < p23 else 2
    if s == 3:
        if u < p32:
            return 2
        if u < p32 + p31:
            return 1
        return 3
    return 1


def four_state_step(s: int, u: float, p13: float, p31: float, p32: float, p23: float, p14: float) -> tuple[int, bool]:
    """One packet of netem's 4-state chain from its uniform `u`: (the state after it, whether the
    packet is lost: in 3 and 4). One definition for `FourStateLoss` and the compiled links
    (engine/compiled/codec_link.py)."""
    state = four_state_next(s, u, p13, p31, p32, p23, p14)
    return state, state >= 3


def four_state_run(
    s: int, draws: np.ndarray, p13: float, p31: float, p32: float, p23: float, p14: float, lost: np.ndarray
) -> int:
    """`four_state_step` on packets in turn (packet i's uniform is draws[i]): lost[i] set for each;
    returns the state after the last. One definition for `FourStateLoss.apply_all` and, compiled,
    the compiled loop's network schedule."""
    for i in range(lost.shape[0]):
        s, lost[i] = four_state_step(s, draws[i], p13, p31, p32, p23, p14)
    return s


class FourStateLoss:
    """netem's 4-state Markov loss (`loss state p13 p31 p32 p23 p14`, the GI model).

    States: 1 received in a gap, 2 received in a burst, 3 lost in a burst, 4 isolated loss in a
    gap. One draw per packet moves the chain; the packet is lost if the new state is 3 or 4.
    1 -> 4 (p14), 1 -> 3 (p13); 2 -> 3 (p23); 3 -> 2 (p32), 3 -> 1 (p31); 4 -> 1 always.
    """

    name = "loss"

    def __init__(self, p13: float, p31: float, p32: float, p23: float, p14: float, *, rng: np.random.Generator) -> None:
        for key, v in (("p13", p13), ("p31", p31), ("p32", p32), ("p23", p23), ("p14", p14)):
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{key} must be in [0, 1], got {v}")
        if p13 + p14 > 1.0 or p31 + p32 > 1.0:
            raise ValueError("need p13 + p14 <= 1 and p31 + p32 <= 1")
        self.p13, self.p31, self.p32, self.p23, self.p14 = p13, p31, p32, p23, p14
        self._rng = rng
        self._u = UniformSource(rng).next
        self.state = 1
        self.dropped = 0

    vectorized = True

    def apply_all(
        self, send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray, runs: Runs | None = None
    ) -> None:
        """`apply` on every original packet of a window at once, before any `apply`
        (`Link.schedule_all`): one draw a packet, the chain run by `four_state_run` (or
        `runs["four_state_run"]`)."""
        run = four_state_run if runs is None else runs.get("four_state_run", four_state_run)
        lost = np.zeros(len(send_ns), dtype=np.bool_)
        draws = self._rng.random(len(send_ns))
        self.state = int(run(self.state, draws, self.p13, self.p31, self.p32, self.p23, self.p14, lost))
        _mark_lost(fate, lost, self)

    def apply(self, packet: Packet) -> Packet | None:
        self.state, lost = four_state_step(self.state, self._u(), self.p13, self.p31, self.p32, self.p23, self.p14)
        fate = first_fate(packet.fate, lost, LOST_NETWORK)
        if fate != packet.fate:
            packet.fate = fate
            self.dropped += 1
        return None


class TraceLoss:
    """Replay a recorded loss pattern: the n-th packet is lost if pattern[n] is true."""

    name = "loss"

    def __init__(self, pattern: Sequence[bool] | np.ndarray, repeat: bool = True) -> None:
        self._pattern = [bool(x) for x in pattern]
        if not self._pattern:
            raise ValueError("a loss trace needs at least one entry")
        self._trace = np.array(self._pattern, dtype=np.float64)  # the same, for `trace_run`
        self._repeat = repeat
        self._n = 0
        self.dropped = 0

    vectorized = True

    def apply_all(
        self, send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray, runs: Runs | None = None
    ) -> None:
        """`apply` on every original packet of a window at once (`Link.schedule_all`): the pattern
        from the packets so far on, by `trace_run` (or `runs["trace_run"]`, compiled)."""
        run = trace_run if runs is None else runs.get("trace_run", trace_run)
        lost = np.zeros(len(send_ns), dtype=np.bool_)
        self._n = int(run(self._trace, self._n, bool(self._repeat), lost))
        _mark_lost(fate, lost, self)

    def apply(self, packet: Packet) -> Packet | None:
        n = self._n
        self._n = n + 1
        fate = first_fate(packet.fate, trace_lost(self._pattern, n, self._repeat), LOST_NETWORK)
        if fate != packet.fate:
            packet.fate = fate
            self.dropped += 1
        return None


class Corrupt:
    """netem `corrupt p [corr]`: a bit error; the receiver's UDP checksum fails and the stack
    discards the packet (LOST_CORRUPT)."""

    name = "corrupt"

    def __init__(
        self,
        probability: float,
        rng: np.random.Generator,
        correlation: float = 0.0,
        correlation_model: str = "netem",
        copy_rng: np.random.Generator | None = None,
    ) -> None:
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        self.probability = probability
        self._u = uniform_source(rng, correlation, correlation_model)
        # Copies draw from their own stream so they never shift the originals' draws.
        self._copy_rng = copy_rng if copy_rng is not None else rng.spawn(1)[0]
        self._copy_u: Callable[[], float] | None = None
        self.dropped = 0

    def apply(self, packet: Packet) -> Packet | None:
        if packet.duplicate:
            if self._copy_u is None:
                self._copy_u = UniformSource(self._copy_rng).next
            u = self._copy_u()
        else:
            u = self._u()
        fate = first_fate(packet.fate, bernoulli_lost(u, self.probability), LOST_CORRUPT)
        if fate != packet.fate:
            packet.fate = fate
            if not packet.duplicate:
                self.dropped += 1
        return None
