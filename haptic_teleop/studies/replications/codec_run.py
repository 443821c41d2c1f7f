"""One run of the codec experiments (studies/replications/codec.py) as it happened, and the
figures computed from it: shared by the simulation and by the bags it is read back from
(studies/replications/codec_bags.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from haptic_teleop.core.link import DEFAULT_OVERHEAD_BYTES, Packet

PERIOD_NS = 1_000_000
PERIOD_S = PERIOD_NS * 1e-9
UDP_IP_HEADER_BYTES = 28  # IPv4 20 + UDP 8: a compact wire (the sample as float64s, no middleware)


@dataclass
class Result:
    """One scheme's run, as it happened: the object the server streamed and the one the client
    played, every packet on both links with its fate, the decoder's latency. The forces and wire
    figures of the table are computed from these, for a run in memory and for one read back from
    its bag (studies/replications/codec_bags.py) alike."""

    label: str
    t_s: np.ndarray
    object_m: np.ndarray  # the server's object surface, every tick
    played_m: np.ndarray  # the object the decoder reconstructs (NaN before the first)
    stiffness_n_per_m: float
    latency_ticks: int  # the decoder plays this many ticks behind the server
    link_delay_ticks: int  # the link's one-way delay in ticks
    forward: list[Packet]  # every packet the encoder put on the link, with its fate
    reverse: list[Packet]  # the decoder's acknowledgements (ARQ)

    def _behind(self, ticks: int) -> np.ndarray:
        x = np.full(self.object_m.shape, math.nan)
        x[ticks:] = self.object_m[: self.object_m.size - ticks]
        return x

    @property
    def force_n(self) -> np.ndarray:
        """From the reconstructed object (NaN before the first)."""
        return force_n(self.played_m, self.stiffness_n_per_m)

    @property
    def true_n(self) -> np.ndarray:
        """From the true object at the tick the decoder plays."""
        return force_n(self._behind(self.latency_ticks), self.stiffness_n_per_m)

    @property
    def present_n(self) -> np.ndarray:
        """From the true object one link delay ago (the codec's own latency is error)."""
        return force_n(self._behind(min(self.link_delay_ticks, self.latency_ticks)), self.stiffness_n_per_m)

    @property
    def packets(self) -> int:
        return len(_originals(self.forward))

    @property
    def ros_bytes(self) -> int:
        return _ros_bytes(self.forward)

    @property
    def compact_bytes(self) -> int:
        """The payloads as float64s plus IPv4 + UDP headers."""
        return sum(8 * len(p.payload) + UDP_IP_HEADER_BYTES for p in _originals(self.forward))

    @property
    def reverse_packets(self) -> int:
        return len(_originals(self.reverse))

    @property
    def reverse_ros_bytes(self) -> int:
        return _ros_bytes(self.reverse)


def _originals(packets: list[Packet]) -> list[Packet]:
    """The packets a sender put on the link (not a duplicating effect's copies)."""
    return [p for p in packets if not p.duplicate]


def _ros_bytes(packets: list[Packet]) -> int:
    """On the wire with each packet's message size and the IPv4 + UDP + RTPS headers."""
    return sum(p.size_bytes + DEFAULT_OVERHEAD_BYTES for p in _originals(packets))


def object_position_m(t_s: np.ndarray, period_s: float) -> np.ndarray:
    """The object's surface: from 0 to -0.1 m and back, a raised cosine of `period_s`."""
    return -0.05 * (1.0 - np.cos(2.0 * math.pi * t_s / period_s))


def force_n(x_obj_m: np.ndarray, stiffness_n_per_m: float) -> np.ndarray:
    """The device at 0 inside the object whose surface is at x_obj <= 0: F = k max(0, -x_obj)."""
    out: np.ndarray = stiffness_n_per_m * np.maximum(0.0, -x_obj_m)
    return out
