"""The playout buffers' rules over arrays, one definition for the Python buffers (core/playout.py:
`PlayOnArrival`'s duplicates, `ScheduledBuffer`, `FixedBuffer`, `AdaptiveBuffer`) and the
compiled loops' network schedule (engine/compiled/buffer_schedule.py compiles these functions
with `compiling.compile_tree`; this module must stay plain Python that numba can compile).

Every array is indexed by one integer, so the same functions run on numpy arrays compiled and on
Python lists and `array("q")` in the interpreter (the Python buffers' choice: a numpy scalar
access costs three times a list's). State (docs/playout.md, "Rules over arrays"):
- `seen`: int64[SEEN_SLOTS], the last sequence number seen in each slot (seq & SEEN_MASK), for
  duplicates; NO_SEQ where none was.
- `R`: int64[SEEN_SLOTS * 3], the held packets by slot (slot i at 3 i): their seq (NO_SEQ: the
  slot holds none), the time they were pushed (the receiver's tick) and their send stamp. A scheduled buffer
  releases in sequence order, so the held packets are found by walking their slots from the
  lowest held seq; two held packets SEEN_SLOTS apart cannot share a slot: the newer one is
  counted late (a playout delay of 32,768 periods: 32.8 s at 1 kHz).
- `Q`: int64[Q_SIZE], the integer state and settings (Q_* below); `E`: float64[E_SIZE], the
  slew rate and the adaptive estimator's constants and state (E_* below).
- `late`: int64[SEEN_SLOTS], the sequence numbers a release marked late (Q[Q_NLATE] of them),
  so that the Python buffer can give its packets their fate.

Every time is an integer of nanoseconds on the receiver's clock; relative delays are taken
against the first packet's (Q_REF), so a constant clock offset changes no computation.
"""

from __future__ import annotations

import math
from array import array
from typing import Any

import numpy as np

from haptic_teleop.core.sorted_search import bisect_left_in, bisect_right_in

SEEN_SLOTS = 1 << 15  # 32.8 s of sequence numbers at 1 kHz
SEEN_MASK = SEEN_SLOTS - 1
NO_SEQ = -(1 << 63)
NONE_HELD = 1 << 62  # buffer_window's lowest held seq after a tick that ends with nothing held

# R's columns
R_SEQ = 0
R_PUSHED = 1
R_SEND = 2
R_WIDTH = 3

# Q: integer state and settings
Q_POLICY = 0  # POLICY_*
Q_HYSTERESIS = 1  # ns
Q_LAST_OUT = 2  # seq of the last released packet, received or made up (NO_SEQ: none)
Q_COUNT = 3  # packets held
Q_MIN = 4  # lowest held seq (when Q_COUNT > 0)
Q_MAX = 5  # highest held seq (when Q_COUNT > 0)
Q_HAS_REF = 6
Q_REF = 7  # relative delay of the first packet
Q_TARGET = 8  # the policy's target D, relative to Q_REF
Q_HAS_DELAY = 9
Q_DELAY = 10  # D in use (receiver clock - send stamp)
Q_STARTED = 11  # a packet was played
Q_MOVING = 12  # D is slewing towards the target
Q_LAST_RELEASE = 13  # time of the last release
Q_LATE = 14  # packets that arrived but were never played
Q_DUPLICATES = 15
Q_PLAYED = 16
Q_LAST_BUFFERING = 17  # release time - push time of the last released packet (-1: made up)
Q_N = 18  # adaptive: relative delays observed
Q_HAS_MIN_REL = 19  # fixed: a minimum was seen
Q_MIN_REL = 20  # fixed: the minimum relative delay before playout started
Q_BUFFERING = 21  # fixed: the buffering time, ns
Q_NLATE = 22  # late marks of the last push or release (in `late`)
Q_PENDING_PUSHED = 23  # none: when the pending packet was pushed
Q_HAS_REAL = 24  # none: a received packet was played
Q_LAST_REAL = 25  # none: its seq
Q_W_HEAD = 26  # percentile, network_adaptive: the window's ring (wv) head
Q_W_COUNT = 27  # its values
Q_W_N = 28  # the sorted window's (ws) length
Q_ALLOW_LOSS = 29  # network_adaptive: L_a, ns
Q_BUDGET = 30  # network_adaptive: D_a - d0 (at least 0), ns; -1: no delay bound
Q_T_HORIZON = 31  # transparency: the contact horizon H, ns
Q_T_ALLOW = 32  # transparency: the allowable latency D_allow, ns; -1: no cap
Q_T_D0 = 33  # transparency: the smallest one-way delay d0, ns
Q_T_COUNT = 34  # transparency: arrivals observed
Q_T_DIRTY = 35  # transparency: a parameter changed since the last decision
Q_SIZE = 36

# E: floats
E_SLEW = 0  # max slew rate, s/s
E_A = 1  # adaptive: smoothing alpha
E_B = 2  # 1 - alpha
E_BETA = 3  # variation factor
E_D = 4  # d_hat (relative)
E_V = 5  # v_hat
E_QUANTILE = 6  # percentile: q
E_SIZE = 7

# policies whose estimator is written here (others set Q_TARGET from Python)
POLICY_OTHER = 0
POLICY_FIXED = 1
POLICY_ADAPTIVE = 2
POLICY_NONE = 3  # play on arrival: Q_COUNT (0 or 1) and Q_MIN are its pending packet
POLICY_PERCENTILE = 4
POLICY_NETWORK_ADAPTIVE = 5
POLICY_TRANSPARENCY = 6

# transparency: a new decision (O(window)) every RETARGET_PACKETS arrivals, and at arrivals 1, 2,
# 4, ... while the window fills
RETARGET_PACKETS = 64

# what a push did
PUSH_HELD = 0
PUSH_DUPLICATE = 1
PUSH_LATE = 2


def new_seen() -> array[int]:
    """An empty duplicates ring."""
    return array("q", [NO_SEQ]) * SEEN_SLOTS


def new_held() -> array[int]:
    """An empty ring of held packets (R)."""
    return array("q", [NO_SEQ, 0, 0]) * SEEN_SLOTS


def new_state(policy: int, hysteresis_ns: int, slew: float) -> tuple[list[int], list[float]]:
    """Q and E of a buffer before its first packet (Python lists; `as_arrays` for numpy)."""
    Q = [0] * Q_SIZE
    Q[Q_POLICY] = policy
    Q[Q_HYSTERESIS] = hysteresis_ns
    Q[Q_LAST_OUT] = NO_SEQ
    Q[Q_LAST_BUFFERING] = -1
    E = [0.0] * E_SIZE
    E[E_SLEW] = slew
    return Q, E


def as_arrays(
    Q: list[int], E: list[float], seen: array[int], R: array[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A Python buffer's state as numpy arrays (copies) for the compiled functions."""
    return (
        np.array(Q, dtype=np.int64),
        np.array(E, dtype=np.float64),
        np.frombuffer(seen, dtype=np.int64).copy(),
        np.frombuffer(R, dtype=np.int64).copy(),
    )


def seen_before(seen: Any, seq: int) -> bool:
    """Whether `seq` was seen already (a duplicate), remembering it if not: the last SEEN_SLOTS
    sequence numbers are kept, an older repeat is not recognised (the buffer counts it late)."""
    i = seq & SEEN_MASK
    if seen[i] == seq:
        return True
    seen[i] = seq
    return False


def none_push(Q: Any, seen: Any, late: Any, seq: int, now_ns: int) -> int:
    """Policy `none`: an arrival older than the last received one played, or than the pending one,
    is late (PUSH_LATE); else it becomes the pending one, and a pending one it displaces is late
    (its seq in `late`, Q[Q_NLATE] = 1)."""
    Q[Q_NLATE] = 0
    if seen_before(seen, seq):
        Q[Q_DUPLICATES] += 1
        return PUSH_DUPLICATE
    pending = Q[Q_COUNT] > 0
    if (Q[Q_HAS_REAL] and seq <= Q[Q_LAST_REAL]) or (pending and seq < Q[Q_MIN]):
        Q[Q_LATE] += 1
        return PUSH_LATE
    if pending:
        late[0] = Q[Q_MIN]
        Q[Q_NLATE] = 1
        Q[Q_LATE] += 1
    Q[Q_COUNT] = 1
    Q[Q_MIN] = seq
    Q[Q_MAX] = seq
    Q[Q_PENDING_PUSHED] = now_ns
    return PUSH_HELD


def none_release(Q: Any, now_ns: int) -> int:
    """Policy `none`: the pending packet (its seq), played at once, or NO_SEQ."""
    Q[Q_NLATE] = 0
    if Q[Q_COUNT] == 0:
        return NO_SEQ
    seq = Q[Q_MIN]
    Q[Q_COUNT] = 0
    Q[Q_PLAYED] += 1
    Q[Q_LAST_BUFFERING] = now_ns - Q[Q_PENDING_PUSHED]
    Q[Q_LAST_OUT] = seq
    Q[Q_HAS_REAL] = 1
    Q[Q_LAST_REAL] = seq
    return seq  # type: ignore[no-any-return]


def fixed_observe(Q: Any, rel_ns: int) -> None:
    """Policy `fixed`: D = the minimum relative delay seen before playout starts + the buffering
    time, then frozen."""
    if Q[Q_STARTED]:
        return
    if not Q[Q_HAS_MIN_REL] or rel_ns < Q[Q_MIN_REL]:
        Q[Q_HAS_MIN_REL] = 1
        Q[Q_MIN_REL] = rel_ns
        Q[Q_TARGET] = rel_ns + Q[Q_BUFFERING]


def adaptive_observe(Q: Any, E: Any, rel_ns: int) -> None:
    """Policy `adaptive` (Ramjee et al. 1994, algorithm 1): d = a d + (1 - a) n,
    v = a v + (1 - a) |d - n|, D = d + beta v (d_1 = n_1, v_1 = 0)."""
    if Q[Q_N] == 0:
        d = float(rel_ns)
        v = 0.0
    else:
        a = E[E_A]
        b = E[E_B]
        d = a * E[E_D] + b * rel_ns
        v = a * E[E_V] + b * abs(d - rel_ns)
    Q[Q_N] += 1
    E[E_D] = d
    E[E_V] = v
    Q[Q_TARGET] = round(d + E[E_BETA] * v)


def percentile_target(srt: Any, n: int, q: float) -> int:
    """Policy `percentile`: the nearest-rank q-quantile of the sorted window `srt` (n values): the
    smallest value with at least a fraction q of the window at or below it."""
    rank = math.ceil(q * n - 1e-9)  # 1-based nearest rank
    return srt[min(n, max(1, rank)) - 1]  # type: ignore[no-any-return]


def network_adaptive_need(lo: int, hi: int, allow_loss: int, budget: int) -> tuple[int, bool]:
    """Policy `network_adaptive` (seed 000): the buffering above the window's minimum `lo` that
    keeps every hold the window predicts within L_a (`allow_loss`), b = max(0, max x - L_a), at
    most `budget` = D_a - d0 (-1: no bound); and whether the requirement is met within it."""
    need = hi - lo - allow_loss
    need = max(need, 0)
    if budget >= 0 and need > budget:
        return budget, False
    return need, True


def retarget_due(count: int, dirty: bool) -> bool:
    """Policy `transparency`: whether the arrival numbered `count` decides again."""
    return dirty or count % RETARGET_PACKETS == 0 or (count < RETARGET_PACKETS and count & (count - 1) == 0)


def transparency_decide(srt: Any, w: int, horizon_ns: int, allow_ns: int, d0_ns: int) -> tuple[int, float]:
    """Policy `transparency` (seed 000, docs/playout_seed.md): over the sorted window `srt` (w
    values) the buffering b above its minimum that minimises e(b) / s - d0 = b + H P(x > b), under
    the cap d0 + b <= D_allow (`allow_ns`; -1: none). The cost is linear between window values and
    steps down at each, so the minimum is at b = 0 or at a window value (the last of a run of equal
    values). Returns (b, its cost)."""
    lo = srt[0]
    per_packet = horizon_ns / w  # H * P(x > b) drops by this per value covered
    cap = math.inf
    if allow_ns >= 0:
        cap = max(0, allow_ns - d0_ns)
    first_above = bisect_right_in(srt, w, lo)
    best_b = 0
    best_cost = (w - first_above) * per_packet
    for i in range(first_above, w):
        b = srt[i] - lo
        if b > cap or b >= best_cost:
            break  # the cost is at least b: no larger b can win
        if i + 1 < w and srt[i + 1] == srt[i]:
            continue
        cost = b + (w - 1 - i) * per_packet
        if cost < best_cost:
            best_b = b
            best_cost = cost
    return best_b, best_cost


def window_add(Q: Any, wv: Any, ws: Any, x: int) -> None:
    """The window of the last len(wv) relative delays, in order (the ring wv) and sorted (ws, one
    longer): `x` inserted after equal values (bisect_right), then the oldest removed when the window
    is over its size (the first equal value: bisect_left), as the Python buffers' `Window` (a list,
    C's bisect) keeps it."""
    n = Q[Q_W_N]
    lo = bisect_right_in(ws, n, x)
    for j in range(n, lo, -1):
        ws[j] = ws[j - 1]
    ws[lo] = x
    n += 1
    size = len(wv)
    head = Q[Q_W_HEAD]
    count = Q[Q_W_COUNT]
    if count < size:
        k = head + count
        wv[k - size if k >= size else k] = x
        Q[Q_W_COUNT] = count + 1
    else:
        old = wv[head]
        wv[head] = x
        Q[Q_W_HEAD] = head + 1 if head + 1 < size else 0
        lo = bisect_left_in(ws, n, old)
        for j in range(lo, n - 1):
            ws[j] = ws[j + 1]
        n -= 1
    Q[Q_W_N] = n


def policy_observe(Q: Any, E: Any, wv: Any, ws: Any, rel_ns: int) -> None:
    """The estimator of the buffer's policy, when it is written here (`percentile` and
    `network_adaptive` over the window arrays wv, ws)."""
    policy = Q[Q_POLICY]
    if policy == POLICY_ADAPTIVE:
        adaptive_observe(Q, E, rel_ns)
    elif policy == POLICY_FIXED:
        fixed_observe(Q, rel_ns)
    elif policy == POLICY_PERCENTILE:
        window_add(Q, wv, ws, rel_ns)
        Q[Q_TARGET] = percentile_target(ws, Q[Q_W_N], E[E_QUANTILE])
    elif policy == POLICY_NETWORK_ADAPTIVE:
        window_add(Q, wv, ws, rel_ns)
        lo = ws[0]
        need, _ = network_adaptive_need(lo, ws[Q[Q_W_N] - 1], Q[Q_ALLOW_LOSS], Q[Q_BUDGET])
        Q[Q_TARGET] = lo + need
    elif policy == POLICY_TRANSPARENCY:
        window_add(Q, wv, ws, rel_ns)
        Q[Q_T_COUNT] += 1
        if retarget_due(Q[Q_T_COUNT], Q[Q_T_DIRTY] != 0):
            Q[Q_T_DIRTY] = 0
            b, _ = transparency_decide(ws, Q[Q_W_N], Q[Q_T_HORIZON], Q[Q_T_ALLOW], Q[Q_T_D0])
            Q[Q_TARGET] = ws[0] + b


def push_begin(Q: Any, seen: Any, seq: int, send_ns: int, now_ns: int) -> int:
    """A packet's arrival, first part: NO_SEQ for a duplicate (counted, ignored), else its
    relative delay against the first packet's, for the policy's estimator."""
    if seen_before(seen, seq):
        Q[Q_DUPLICATES] += 1
        return NO_SEQ
    rel = now_ns - send_ns
    if not Q[Q_HAS_REF]:
        Q[Q_HAS_REF] = 1
        Q[Q_REF] = rel
    return rel - Q[Q_REF]  # type: ignore[no-any-return]


def push_hold(Q: Any, R: Any, seq: int, send_ns: int, now_ns: int) -> int:
    """A packet's arrival, after the estimator has seen it: late (PUSH_LATE) if its turn has
    passed, else held (PUSH_HELD); before playout starts D follows the target."""
    at = (seq & SEEN_MASK) * R_WIDTH
    if seq <= Q[Q_LAST_OUT] or R[at + R_SEQ] != NO_SEQ:
        Q[Q_LATE] += 1
        return PUSH_LATE
    R[at + R_SEQ] = seq
    R[at + R_PUSHED] = now_ns
    R[at + R_SEND] = send_ns
    if Q[Q_COUNT] == 0:
        Q[Q_MIN] = seq
        Q[Q_MAX] = seq
    elif seq < Q[Q_MIN]:
        Q[Q_MIN] = seq
    elif seq > Q[Q_MAX]:
        Q[Q_MAX] = seq
    Q[Q_COUNT] += 1
    if not Q[Q_STARTED]:
        Q[Q_HAS_DELAY] = 1
        Q[Q_DELAY] = Q[Q_REF] + Q[Q_TARGET]
    return PUSH_HELD


def sched_push(Q: Any, E: Any, seen: Any, R: Any, wv: Any, ws: Any, seq: int, send_ns: int, now_ns: int) -> int:
    """A packet's arrival at a buffer whose policy's estimator is written here (`policy_observe`):
    PUSH_HELD, PUSH_DUPLICATE or PUSH_LATE."""
    rel = push_begin(Q, seen, seq, send_ns, now_ns)
    if rel == NO_SEQ:
        return PUSH_DUPLICATE
    policy_observe(Q, E, wv, ws, rel)
    return push_hold(Q, R, seq, send_ns, now_ns)


def slewed_delay(Q: Any, E: Any, now_ns: int) -> int:
    """D at this release: after the first sample is played it moves towards the target once they
    differ by more than the hysteresis, by at most the slew rate times the time since the last
    release."""
    delay = Q[Q_DELAY]
    if Q[Q_STARTED]:
        target = Q[Q_TARGET] + Q[Q_REF]
        if target == delay:
            Q[Q_MOVING] = 0
        elif Q[Q_MOVING] or abs(target - delay) > Q[Q_HYSTERESIS]:
            step = int((now_ns - Q[Q_LAST_RELEASE]) * E[E_SLEW])
            delay = min(target, delay + step) if target > delay else max(target, delay - step)
            Q[Q_MOVING] = 1 if delay != target else 0
            Q[Q_DELAY] = delay
    Q[Q_LAST_RELEASE] = now_ns
    return delay  # type: ignore[no-any-return]


def sched_release(Q: Any, E: Any, R: Any, now_ns: int, late: Any) -> int:
    """The packet to use from this tick on (its seq), or NO_SEQ to keep the last one: every held
    packet whose send stamp is at or before now - D leaves, in sequence order; the newest of them
    is played, the others (and any not newer than the last one out) are late (their seqs in
    `late`, Q[Q_NLATE] of them)."""
    Q[Q_NLATE] = 0
    if not Q[Q_HAS_DELAY]:
        return NO_SEQ
    cutoff = now_ns - slewed_delay(Q, E, now_ns)
    last_out = Q[Q_LAST_OUT]
    best = NO_SEQ
    best_pushed = 0
    s = Q[Q_MIN]
    hi = Q[Q_MAX]
    nlate = 0
    while Q[Q_COUNT] > 0 and s <= hi:
        at = (s & SEEN_MASK) * R_WIDTH
        if R[at + R_SEQ] == s:
            if R[at + R_SEND] > cutoff:
                break
            R[at + R_SEQ] = NO_SEQ
            Q[Q_COUNT] -= 1
            if s <= last_out:
                late[nlate] = s  # only if send stamps are not seq * period
                nlate += 1
            else:
                if best != NO_SEQ:
                    late[nlate] = best  # skipped: a newer sample is due too
                    nlate += 1
                best = s
                best_pushed = R[at + R_PUSHED]
        s += 1
    Q[Q_MIN] = s
    Q[Q_NLATE] = nlate
    Q[Q_LATE] += nlate
    if best == NO_SEQ:
        return NO_SEQ
    Q[Q_STARTED] = 1
    Q[Q_PLAYED] += 1
    Q[Q_LAST_BUFFERING] = now_ns - best_pushed
    Q[Q_LAST_OUT] = best
    return best  # type: ignore[no-any-return]


def window_push(
    Q: Any, E: Any, seen: Any, R: Any, wv: Any, ws: Any, late: Any, seq: int, send_ns: int, now_ns: int
) -> int:
    """An arrival at a buffer whose rules are all written here (`none`, `fixed`, `adaptive`): as
    `none_push` or `sched_push` (late marks of other packets in `late`, Q[Q_NLATE] of them)."""
    if Q[Q_POLICY] == POLICY_NONE:
        return none_push(Q, seen, late, seq, now_ns)
    Q[Q_NLATE] = 0
    return sched_push(Q, E, seen, R, wv, ws, seq, send_ns, now_ns)


def window_release(Q: Any, E: Any, R: Any, now_ns: int, late: Any) -> int:
    """A release of such a buffer: as `none_release` or `sched_release`."""
    if Q[Q_POLICY] == POLICY_NONE:
        return none_release(Q, now_ns)
    return sched_release(Q, E, R, now_ns, late)


def buffer_window(
    Q: Any,
    E: Any,
    seen: Any,
    R: Any,
    wv: Any,
    ws: Any,
    late: Any,
    p_seq: Any,
    p_send: Any,
    p_tick: Any,
    n0: int,
    n1: int,
    period_ns: int,
    released: Any,
    occupancy: Any,
    held_min: Any,
    late_seq: Any,
    late_tick: Any,
) -> tuple[int, int]:
    """The engine's order for ticks [n0, n1) of one direction without a codec, for a buffer whose
    policy's estimator is written here: each tick, the packets that arrive by it (p_*: in the
    order the link delivers them, the tick they arrive in, ascending) are pushed, then the buffer
    releases. Writes the seq released at each tick (-1: none), the occupancy after it, the lowest
    seq held after it (NONE_HELD: none) and every late mark (its seq and tick, from the
    start of `late_seq`). Returns (packets pushed, late marks). The policy is `none`, `fixed`,
    `adaptive`, `percentile` or `network_adaptive` (`window_push`; wv, ws: the last two's window)."""
    i = 0
    k = 0
    m = len(p_seq)
    for n in range(n0, n1):
        now = n * period_ns
        while i < m and p_tick[i] <= n:
            if window_push(Q, E, seen, R, wv, ws, late, p_seq[i], p_send[i], now) == PUSH_LATE:
                late_seq[k] = p_seq[i]
                late_tick[k] = n
                k += 1
            for j in range(Q[Q_NLATE]):
                late_seq[k] = late[j]
                late_tick[k] = n
                k += 1
            i += 1
        s = window_release(Q, E, R, now, late)
        for j in range(Q[Q_NLATE]):
            late_seq[k] = late[j]
            late_tick[k] = n
            k += 1
        released[n - n0] = -1 if s == NO_SEQ else s
        occupancy[n - n0] = Q[Q_COUNT]
        held_min[n - n0] = Q[Q_MIN] if Q[Q_COUNT] > 0 else NONE_HELD
    return i, k
