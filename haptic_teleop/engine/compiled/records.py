"""Bag records of the original packets a compiled network schedule decided (no `Packet` objects)."""

from __future__ import annotations

import numpy as np

from haptic_teleop.core.link import DELIVERED, LOST_LATE


def packet_rows(
    send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray, size_bytes: int, first_seq: int = 0
) -> np.ndarray:
    """Bag records (record.layouts.PACKET_FIELDS) of original packets: the values `record.layouts.packet_rows` gives
    for the same `Packet` objects (times in s; arrival NaN unless delivered or late)."""
    rows = np.zeros((len(send_ns), 6))
    rows[:, 0] = np.arange(first_seq, first_seq + len(send_ns))
    rows[:, 1] = send_ns.astype(np.float64) * 1e-9
    arrived = (fate == DELIVERED) | (fate == LOST_LATE)
    rows[:, 2] = np.where(arrived, arrival_ns.astype(np.float64) * 1e-9, np.nan)
    rows[:, 3] = fate
    rows[:, 5] = size_bytes
    return rows
