"""One direction of the network: packets, their fates, and the `Link` that applies its effects.

Times are integer nanoseconds so that arrival-versus-tick comparisons are exact and a run is
reproducible bit for bit. A `Link` applies its effects in order when a packet is sent (as netem
does: every impairment is decided at enqueue time) and then holds delivered packets in a
time-ordered queue until `deliver(now_ns)` releases those that have arrived. The order is in
docs/network.md, the models and their formulas in docs/network_effects.md; the effects are in
`core/loss.py` and `core/delay.py`, their config and `build_link`, which builds only the effects
a scene names in `CANONICAL_ORDER`, in `core/netconfig.py`.

Rules that keep runs comparable across scenes (common random numbers):
- every random decision of an effect is drawn once per original packet sent, whether or not an
  earlier effect already lost that packet, so the n-th packet's draws depend only on the seed,
  the direction, the effect's parameters and n;
- duplicate copies draw from a separate stream per effect (`"<effect>:copy"`), so duplication
  never shifts the draws of the originals;
- only the deterministic queue state (token bucket, `keep_order`) sees just the packets that
  actually pass.
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from haptic_teleop.core.uniform import uniform_source

# Fate codes, recorded per packet (see docs/network.md).
DELIVERED = 0
LOST_NETWORK = 1
LOST_QUEUE = 2
LOST_CORRUPT = 3
LOST_LATE = 4  # set by the playout buffer: arrived, but too late to be played


def taken_tick(arrival_ns: Any, period_ns: int) -> Any:
    """The tick at which a receiver on the tick grid takes a packet that arrives at `arrival_ns`:
    the first at or after it (`Link.deliver` at each tick's time does exactly this). Ints or
    numpy integer arrays."""
    return -(-arrival_ns // period_ns)


FATE_NAMES = {
    DELIVERED: "delivered",
    LOST_NETWORK: "network",
    LOST_QUEUE: "queue_overflow",
    LOST_CORRUPT: "corruption",
    LOST_LATE: "late",
}

# The order a packet meets the effects on its way (config field names). "reorder" is decided in
# the delay stage: it chooses whether a packet keeps the delay just computed.
CANONICAL_ORDER = ("blackout", "rate_limit", "loss", "duplicate", "corrupt", "delay", "reorder")

# Per-packet bytes on the wire besides the serialized message: IPv4 header 20, UDP header 8,
# RTPS message header 20, RTPS DATA submessage header (with its submessage header) 24.
IPV4_HEADER_BYTES = 20
UDP_HEADER_BYTES = 8
RTPS_HEADER_BYTES = 20
RTPS_DATA_SUBMESSAGE_BYTES = 24
DEFAULT_OVERHEAD_BYTES = IPV4_HEADER_BYTES + UDP_HEADER_BYTES + RTPS_HEADER_BYTES + RTPS_DATA_SUBMESSAGE_BYTES


@dataclass(slots=True)
class Packet:
    """One haptic sample on the wire."""

    seq: int
    send_time_ns: int
    payload: tuple[float, ...]
    size_bytes: int = 0
    arrival_time_ns: int = 0
    fate: int = DELIVERED
    duplicate: bool = False


# --------------------------------------------------------------------------------------------
# Effects. `apply` mutates the packet (arrival time, fate) and returns a new copy it made
# (duplication) or None.


class Effect(Protocol):
    """One impairment. `apply` may change the packet's arrival time or fate, and returns a copy
    it made (duplication) or None."""

    name: str

    def apply(self, packet: Packet) -> Packet | None: ...


class Duplicate:
    """netem `duplicate p [corr]`: a delivered packet gets a copy (`duplicate=True`) that then
    meets the remaining effects on its own."""

    name = "duplicate"

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
        self._u = uniform_source(rng, correlation, correlation_model)
        self.copies = 0

    def apply(self, packet: Packet) -> Packet | None:
        if packet.duplicate:
            return None  # a copy is never copied again (netem: tc_depth)
        if self._u() < self.probability and packet.fate == DELIVERED:
            self.copies += 1
            return Packet(
                packet.seq, packet.send_time_ns, packet.payload, packet.size_bytes,
                packet.arrival_time_ns, DELIVERED, True,
            )  # fmt: skip
        return None


class Link:
    """One direction: effects in order at send time, then a time-ordered in-flight queue."""

    def __init__(self, effects: Sequence[Effect]) -> None:
        self.effects = tuple(effects)
        self._applies = tuple(e.apply for e in self.effects)
        # In-order arrivals go to a deque (O(1)); only packets that overtake go to a heap.
        self._fifo: deque[tuple[int, int, Packet]] = deque()
        self._heap: list[tuple[int, int, Packet]] = []
        self._order = 0
        self.sent = 0
        self.lost = 0  # originals lost in the network (not counting copies or late packets)
        self.duplicates = 0
        self.log: list[Packet] = []  # every packet (and copy) with its fate, for the bag (its reader may drain it)
        self._one_by_one = False  # a packet went through `send`: `schedule_all` would not continue it

    def send(self, packet: Packet) -> None:
        packet.arrival_time_ns = packet.send_time_ns
        self.sent += 1
        self._one_by_one = True
        self.log.append(packet)
        for i, apply in enumerate(self._applies, 1):
            extra = apply(packet)
            if extra is not None:
                self._send_copy(extra, i)
        if packet.fate == DELIVERED:
            self._enqueue(packet)
        else:
            self.lost += 1

    def _send_copy(self, copy: Packet, start: int) -> None:
        self.duplicates += 1
        self.log.append(copy)
        for apply in self._applies[start:]:
            apply(copy)
        if copy.fate == DELIVERED:
            self._enqueue(copy)

    def _enqueue(self, p: Packet) -> None:
        a = p.arrival_time_ns
        entry = (a, self._order, p)  # the counter keeps equal arrival times in send order
        self._order += 1
        fifo = self._fifo
        if not fifo or a >= fifo[-1][0]:
            fifo.append(entry)
        else:
            heapq.heappush(self._heap, entry)

    def deliver(self, now_ns: int) -> list[Packet]:
        """Packets that have arrived by `now_ns`, in arrival order."""
        fifo, heap = self._fifo, self._heap
        out: list[Packet] = []
        if not heap:
            while fifo and fifo[0][0] <= now_ns:
                out.append(fifo.popleft()[2])
            return out
        while True:
            if fifo and (not heap or fifo[0] < heap[0]):
                if fifo[0][0] > now_ns:
                    break
                out.append(fifo.popleft()[2])
            elif heap:
                if heap[0][0] > now_ns:
                    break
                out.append(heapq.heappop(heap)[2])
            else:
                break
        return out

    @property
    def in_flight(self) -> int:
        return len(self._fifo) + len(self._heap)

    def oldest_in_flight_seq(self) -> int | None:
        """The lowest sequence number among the packets still in flight, or None if none is."""
        seqs = [e[2].seq for e in self._fifo] + [e[2].seq for e in self._heap]
        return min(seqs) if seqs else None

    def oldest_in_flight_send_ns(self) -> int | None:
        """The earliest send time among the packets still in flight, or None if none is."""
        times = [e[2].send_time_ns for e in self._fifo] + [e[2].send_time_ns for e in self._heap]
        return min(times) if times else None

    @property
    def vectorized(self) -> bool:
        """True if `schedule_all` can decide the link's packets in batches (none went through `send`,
        and every effect has an `apply_all` whose decisions do not depend on the packets before)."""
        return not self._one_by_one and all(getattr(e, "vectorized", False) for e in self.effects)

    def schedule_all(
        self, send_ns: np.ndarray, runs: Mapping[str, Any] | None = None, size_bytes: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Fates and arrival times of original packets sent at `send_ns`, decided all at once.

        The same decisions, from the same random numbers, as `send` on each packet in turn
        (test_vectorized_schedule_equals_send). Consecutive calls continue one another (each
        effect's random stream goes on where the last call left it), so a run can be decided in
        windows of any size with the same result. Only for a link whose effects are all
        `vectorized` and that no packet went through `send` on (see the property); the packets
        are not queued or logged. Updates `sent` and `lost`. Returns (arrival_ns, fate) arrays.
        `runs`: a Markov loss chain's run over the window (core/loss.py `gilbert_run`,
        `four_state_run`) by name, compiled (engine/compiled/link_runs.py); the plain functions
        without it. `size_bytes`: the packets' size, for an effect whose decisions depend on it
        (`sized`: a rate limit).
        """
        if not self.vectorized:
            raise ValueError(
                "this link cannot decide a run at once (packets went through send, or an effect without apply_all)"
            )
        send_ns = np.asarray(send_ns, dtype=np.int64)
        arrival = send_ns.copy()
        fate = np.full(len(send_ns), DELIVERED, dtype=np.int64)
        for e in self.effects:
            if getattr(e, "sized", False):
                e.apply_all(send_ns, arrival, fate, runs, size_bytes)  # type: ignore[attr-defined]
            else:
                e.apply_all(send_ns, arrival, fate, runs)  # type: ignore[attr-defined]
        self.sent += len(send_ns)
        self.lost += int(np.count_nonzero(fate != DELIVERED))
        return arrival, fate

    def fate_counts(self, include_duplicates: bool = False) -> dict[str, int]:
        """Packets in the log per fate name (originals only unless `include_duplicates`)."""
        counts = dict.fromkeys(FATE_NAMES.values(), 0)
        for p in self.log:
            if include_duplicates or not p.duplicate:
                counts[FATE_NAMES[p.fate]] += 1
        return counts

    def loss_rate(self) -> float:
        """Fraction of original packets lost in the network so far (late ones are not counted)."""
        return self.lost / self.sent if self.sent else 0.0
