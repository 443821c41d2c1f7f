"""A codec direction's link inside the compiled loops (numba): each packet's fate from its index and
send time (blackout, Bernoulli, netem-correlated, Gilbert-Elliott, 4-state and trace loss, one
verdict: `loss_fate`), its arrival (constant delay; a deadband's jitter), the in-flight ring in
arrival order. The loss models' per-packet steps are core/loss.py's, compiled from their one
definition (codec_host.py has the design, codec_layout.py the arrays' layouts).
"""

from __future__ import annotations

import numba
import numpy as np

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import codec_layout as L
from haptic_teleop.core import delay, loss, uniform

jit = numba.njit(cache=True, nogil=True)


inline = numba.njit(cache=True, nogil=True, inline="always")  # as axis_kernel's tick parts


# The FEC and ARQ ticks are compiled once (not inlined into each direction: compile time), also
# without reference counting (every array they are handed would be counted in and out).
part_jit = numba.njit(cache=True, nogil=True, _nrt=False)


gilbert_step = jit(loss.gilbert_step)


four_state_step = compile_tree(loss.four_state_step)


# the verdicts' order and the blackout, Bernoulli and trace rules, one definition (core/loss.py)
first_fate = compile_tree(loss.first_fate, inline=True)


blackout_at = compile_tree(loss.blackout_at, inline=True)


bernoulli_lost = compile_tree(loss.bernoulli_lost, inline=True)


trace_lost = compile_tree(loss.trace_lost, inline=True)


# netem's correlated numbers, the jitter's value, the delay and the arrival's rounding and order,
# one definition (core/uniform.py, core/delay.py: `Delay.apply`, `NetemCorrelatedUniform`)
netem_next = compile_tree(uniform.netem_next, inline=True)


unit_jitter = compile_tree(uniform.unit_jitter, inline=True)


delay_value_ns = compile_tree(delay.delay_value_ns, inline=True)


arrival_ns = compile_tree(delay.arrival_ns, inline=True)


DELIVERED = 0.0


LOST_NETWORK = 1.0


@part_jit  # type: ignore[misc]
def chain_or_trace_fate(C: np.ndarray, S: np.ndarray, U: np.ndarray, u: int) -> tuple[bool, int]:
    # `loss_fate` of the 4-state chain and of a trace (U its pattern, u the packets so far):
    # compiled once, not inlined into every link (cold compile time).
    if C[L.C_LOSS] == L.LOSS_FOUR_STATE:
        state, lost = four_state_step(
            int(S[L.S_BAD]), U[u], C[L.C_LP], C[L.C_LR], C[L.C_LBAD], C[L.C_LGOOD], C[L.C_LP14]
        )
        S[L.S_BAD] = state
        return lost, u + 1
    return trace_lost(U, u, C[L.C_LP] != 0.0), u + 1  # (C_LP: repeated)


@inline  # type: ignore[misc]
def loss_fate(C: np.ndarray, S: np.ndarray, U: np.ndarray, u: int) -> tuple[bool, int]:
    # The loss effect's verdict on the next packet (its draws whatever the packet's fate) from
    # its numbers U from index u; and the next index. Bernoulli (netem-correlated if C_LRHO:
    # NetemCorrelatedUniform.next), Gilbert-Elliott (two numbers), the 4-state chain and a
    # trace (`chain_or_trace_fate`).
    kind = C[L.C_LOSS]
    if kind == L.LOSS_BERNOULLI:
        x = U[u]
        rho = C[L.C_LRHO]
        if rho != 0.0:
            x = netem_next(x, rho, S[L.S_LLAST])
            S[L.S_LLAST] = x
        return bernoulli_lost(x, C[L.C_LP]), u + 1
    if kind == L.LOSS_GILBERT:
        bad, lost = gilbert_step(S[L.S_BAD] != 0.0, U[u], U[u + 1], C[L.C_LP], C[L.C_LR], C[L.C_LBAD], C[L.C_LGOOD])
        S[L.S_BAD] = 1.0 if bad else 0.0
        return lost, u + 2
    return chain_or_trace_fate(C, S, U, u)


@inline  # type: ignore[misc]
def fate_of(C: np.ndarray, S: np.ndarray, U: np.ndarray, B: np.ndarray, now: int, u: int) -> tuple[int, int]:
    # Link.send's effects on one packet sent at `now` (blackout, loss: its draws whatever the
    # fate), the link's counts and its next random number kept by the caller: 0 delivered,
    # 1 lost in a blackout, 2 lost by the loss model; and the next random number.
    fate = 0
    if B.shape[0] > 0:
        i, hit = blackout_at(B, int(S[L.S_BLACKOUT_I]), now)
        S[L.S_BLACKOUT_I] = i
        fate = first_fate(fate, hit, 1)
    if C[L.C_LOSS] != L.LOSS_NONE:
        lost, u = loss_fate(C, S, U, u)
        fate = first_fate(fate, lost, 2)
    return fate, u


@inline  # type: ignore[misc]
def link_fate(C: np.ndarray, S: np.ndarray, U: np.ndarray, B: np.ndarray, now: int) -> float:
    # `fate_of` with the link's counts and its next random number in S. Returns the fate.
    fate, u = fate_of(C, S, U, B, now, int(S[L.S_U]))
    S[L.S_U] = u
    S[L.S_LINK_SENT] += 1.0
    if fate == 0:
        return DELIVERED
    S[L.S_LINK_LOST] += 1.0
    if fate == 1:
        S[L.S_DROP_BLACKOUT] += 1.0
    else:
        S[L.S_DROP_LOSS] += 1.0
    return LOST_NETWORK


@inline  # type: ignore[misc]
def jitter_arrival(C: np.ndarray, S: np.ndarray, W: np.ndarray, now: int, fate: float) -> int:
    # Delay.apply without a time-varying part or reordering: delay_s + jitter_s J, J the
    # distribution's value of the packet's uniform number (every packet draws one, lost or not;
    # netem-correlated with the one before if C_JRHO),
    # rounded to the ns, 0 if not positive; with keep_order a delivered packet arrives no earlier
    # than the one delivered before it. W: the distribution's table (C_JN values), then the
    # uniform numbers.
    n = int(C[L.C_JN])
    u = W[n + int(S[L.S_JU])]
    S[L.S_JU] += 1.0
    rho = C[L.C_JRHO]
    if rho != 0.0:  # NetemCorrelatedUniform.next
        u = netem_next(u, rho, S[L.S_JLAST])
        S[L.S_JLAST] = u
    d = delay_value_ns(C[L.C_JBASE_NS], 0.0, C[L.C_JSIGMA_NS], unit_jitter(u, W, n))
    t = now + int(C[L.C_DELAY_NS])  # (a constant delay before it: none that build_link makes)
    arrival, last = arrival_ns(t, d, C[L.C_JKEEP] != 0.0, fate == DELIVERED, int(S[L.S_LAST_ARRIVAL]))
    S[L.S_LAST_ARRIVAL] = last
    return arrival


@inline  # type: ignore[misc]
def link_send(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    seq: int,
    now: int,
    smp: np.ndarray,
    rate: np.ndarray,
    with_rate: bool,
    with_record: bool = True,
    with_payload: bool = True,
    W: np.ndarray | None = None,
) -> None:
    # Link.send of one packet: blackout, loss (its draws whatever the fate), constant delay;
    # the record; a delivered packet joins the in-flight FIFO. (ARQ's ACK link keeps neither its
    # records nor a payload: `with_record`, `with_payload` False, constants once inlined.) With
    # `W` (a deadband direction's) the link may have jitter (`jitter_arrival`): the packet then
    # joins the FIFO in arrival order.
    fate = link_fate(C, S, U, B, now)
    jitter = W is not None and C[L.C_JIT] != 0.0
    if jitter:
        arrival = jitter_arrival(C, S, W, now, fate)
    else:
        arrival = now + int(C[L.C_DELAY_NS])
    # (2-D arrays are indexed in full, never sliced: a view costs reference counting)
    r = int(S[L.S_RECS])
    if with_record:
        S[L.S_RECS] += 1.0
        rec[r, 0] = seq
        rec[r, 1] = float(now) * 1e-9
        rec[r, 3] = fate
        rec[r, 4] = 0.0
        rec[r, 5] = C[L.C_SIZE]
    if fate != DELIVERED:
        if with_record:
            rec[r, 2] = np.nan
        return
    if with_record:
        rec[r, 2] = float(arrival) * 1e-9
    depth = ring.shape[0]
    count = int(S[L.S_COUNT])
    j = (int(S[L.S_HEAD]) + count) & (depth - 1)
    S[L.S_COUNT] = count + 1
    if jitter:  # Link._enqueue: in arrival order, equal arrivals in send order
        head = int(S[L.S_HEAD])
        while count > 0 and ring[(head + count - 1) & (depth - 1), 1] > arrival:
            k = (head + count - 1) & (depth - 1)
            for c in range(ring.shape[1]):
                ring[j, c] = ring[k, c]
            j = k
            count -= 1
    ring[j, 0] = seq
    ring[j, 1] = arrival
    if not with_payload:
        return
    dim = int(C[L.C_DIM])
    for i in range(dim):
        ring[j, 2 + i] = smp[i]
        if with_rate:
            ring[j, 2 + dim + i] = rate[i]


@inline  # type: ignore[misc]
def packet_send(
    C: np.ndarray, S: np.ndarray, U: np.ndarray, B: np.ndarray, ring: np.ndarray, rec: np.ndarray,
    seq: int, now: int, value: np.ndarray, unused: np.ndarray,
) -> None:  # fmt: skip
    # An encoder's packet of `value` (no rate) counted and into Link.send.
    S[L.S_SENT] += 1.0
    S[L.S_BYTES] += C[L.C_SIZE]
    link_send(C, S, U, B, ring, rec, seq, now, value, unused, False)


@inline  # type: ignore[misc]
def link_next(S: np.ndarray, ring: np.ndarray, now: int) -> int:
    # Link.deliver, one packet: the ring row of the next packet due by `now` (taken off the
    # in-flight FIFO), or -1.
    if S[L.S_COUNT] <= 0.0:
        return -1
    head = int(S[L.S_HEAD])
    if ring[head, 1] > now:
        return -1
    S[L.S_HEAD] = (head + 1) & (ring.shape[0] - 1)
    S[L.S_COUNT] -= 1.0
    return head


@inline  # type: ignore[misc]
def newest(S: np.ndarray, seq: int, rx: int) -> int:
    # The `received` column's seq after a delivery of `seq` (the newest delivered so far, else rx).
    if seq > S[L.S_NEWEST]:
        S[L.S_NEWEST] = seq
        return seq
    return rx
