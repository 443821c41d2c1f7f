"""Whether a bag's energy ledgers are the ones its own signals give, row by row.

**EBA's reservoir** (the default law; an arm's pooled one, or one axis's, whose joint state holds
x, v and the applied force and whose `coupled_reservoir` of one joint is `reservoir1`'s bits): each
side's recorded reservoir (/<side>/eba, first column) must go from one row to the next exactly as
`coupled_reservoir` takes it, with the torque applied at tick k - 1 (/<side>/joint_states' effort)
over the motion to tick k: E(k) = E(k-1) + sum_i (d_i/T) dq_i^2 - tau_i dq_i. A side computes this
from the very values the bag holds, so an honest bag meets it bit for bit (`reservoir_residuals`).

**TDPA** on an arm ("zoh", no reflection): each side's budget is W = E0 + R - E_out + C (core/tdpa_coupled.py):
E_out and the damping credit C follow from that side's own joint positions and applied torques
(`book1` and `coupled_reservoir`, the rules the sides run), E0 is the budget at the first tick
(before any motion is booked), and R is the remote side's cumulative input energy as last
received. Which sample a side had taken at a tick is a matter of timing on a live run, so R is not
recomputed from the received samples' times; instead, for every tick, the R that the recorded
budget implies must be

- exactly one of the values the remote side sent: its own input energy E_in after some tick j,
  recomputed from its signals the same way (or 0, nothing received yet);
- sent no later than the tick that used it (j <= k: no energy from the future);
- never less than at the tick before (a cumulative count only grows: `received1`).

In lockstep the engine's bags meet both to rounding (0 and 1e-16 J). A live bag meets them only if
each row holds what the side had at that tick: its recorder placed the unstamped EBA arrays by
write time before 2026-12-03, and late ticks moved them by 1 to 4 rows (nodes/recorder_placement.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from haptic_teleop.core.eba_coupled import coupled_reservoir
from haptic_teleop.core.tdpa import book1
from haptic_teleop.core.tdpa_coupled import joint_power

SIDES = ("master", "slave")


@dataclass(frozen=True)
class LedgerCheck:
    """One side's check (module docstring): the worst distance (J) of an implied R from every value
    the remote side sent, the ticks that used energy sent later, the ticks whose R fell."""

    side: str
    ticks: int
    worst_j: float
    from_the_future: int
    falling: int

    def holds(self, tolerance_j: float = 1e-9) -> bool:
        return self.worst_j <= tolerance_j and self.from_the_future == 0 and self.falling == 0


def observed(q: npt.NDArray[np.float64], tau: npt.NDArray[np.float64], gain: npt.NDArray[np.float64]) -> tuple[
    npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]
]:  # fmt: skip
    """A side's observer from its signals: E_in, E_out and the damping credit after each tick's
    booking (tick k books tau[k - 1] over q[k] - q[k - 1]; nothing at the first tick)."""
    n = q.shape[0]
    e_in, e_out, credit = np.zeros(n), np.zeros(n), np.zeros(n)
    a = o = c = 0.0
    zero = np.zeros(q.shape[1])
    for k in range(1, n):
        dq = q[k] - q[k - 1]
        a, o = book1(a, o, joint_power(tau[k - 1], dq))
        c = coupled_reservoir(c, gain, zero, dq)
        e_in[k], e_out[k], credit[k] = a, o, c
    return e_in, e_out, credit


Signals = dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]]


def read_signals(bag: Path) -> Signals:
    """Each side's joint positions, applied torques and recorded budget, tick by tick."""
    from haptic_teleop.record.reader import BagReader

    signals = {}
    with BagReader(bag) as r:
        for side in SIDES:
            js = np.asarray(r.read(f"/{side}/joint_states").values)
            n = js.shape[1] // 3
            budget = np.asarray(r.read(f"/{side}/eba").values)[:, 0]
            signals[side] = (js[:, :n], js[:, 2 * n :], budget)
    return signals


def check_signals(signals: Signals, gains: dict[str, npt.NDArray[np.float64]]) -> dict[str, LedgerCheck]:
    """Both sides' checks (`read_signals`'s arrays); `gains`: each side's d_i / T per joint
    (`CoupledBoundConstants.gain`)."""
    obs = {s: observed(signals[s][0], signals[s][1], gains[s]) for s in SIDES}
    out = {}
    for side, other in zip(SIDES, reversed(SIDES), strict=True):
        _, e_out, credit = obs[side]
        budget = signals[side][2]
        implied = budget - budget[0] + e_out - credit
        sent = np.concatenate([[0.0], obs[other][0]])  # 0: nothing received yet
        ordered = np.sort(sent)
        pos = np.clip(np.searchsorted(ordered, implied), 1, ordered.size - 1)
        worst = np.minimum(np.abs(ordered[pos] - implied), np.abs(ordered[pos - 1] - implied))
        # the first tick whose E_in reaches the implied value (E_in only grows): when it was sent
        first = np.searchsorted(obs[other][0], implied - 1e-9, side="left")
        k = np.arange(implied.size)
        out[side] = LedgerCheck(
            side,
            int(implied.size),
            float(worst.max()) if worst.size else 0.0,
            int(np.count_nonzero(first > k)),
            int(np.count_nonzero(np.diff(implied) < -1e-12)),
        )
    return out


def reservoir_residuals(
    signals: Signals, gains: dict[str, npt.NDArray[np.float64]]
) -> dict[str, npt.NDArray[np.float64]]:
    """Each side's recorded reservoir at ticks 1.. less `coupled_reservoir` of its row before (zeros
    for an honest bag recorded with EBA's reservoir law)."""
    out = {}
    for side in SIDES:
        q, tau, energy = signals[side]
        out[side] = np.array(
            [
                energy[k] - coupled_reservoir(energy[k - 1], gains[side], tau[k - 1], q[k] - q[k - 1])
                for k in range(1, q.shape[0])
            ]
        )
    return out


def check_bag(bag: Path, gains: dict[str, npt.NDArray[np.float64]]) -> dict[str, LedgerCheck]:
    """`check_signals` on an arm bag recorded with TDPA ("zoh", no reflection)."""
    return check_signals(read_signals(bag), gains)
