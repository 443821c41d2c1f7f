"""What the window-form tests share (test_delay_vectorized.py, test_loss_vectorized.py,
test_rate_limit_vectorized.py): a link run packet by packet through `Link.send`, and the same
link decided in windows of uneven sizes (`Link.schedule_all`)."""

from __future__ import annotations

import itertools

import numpy as np

from haptic_teleop.core.link import Link, Packet

MS = 1_000_000
N = 6000  # more than a block of 4096 numbers
CUTS = (0, 1, 8, 308, 1308, N)  # windows of 1, 7, 300, 1000 and the rest


def one_by_one(link: Link, send_ns: np.ndarray, size_bytes: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Arrivals and fates of packets sent at `send_ns` one at a time."""
    for k, t in enumerate(send_ns.tolist()):
        link.send(Packet(k, t, (), size_bytes))
    return (
        np.array([p.arrival_time_ns for p in link.log], dtype=np.int64),
        np.array([p.fate for p in link.log], dtype=np.int64),
    )


def in_windows(link: Link, send_ns: np.ndarray, runs, size_bytes: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """The same decided in the windows CUTS (the last one: the rest of `send_ns`)."""
    assert link.vectorized
    cuts = [*CUTS[:-1], len(send_ns)]
    parts = [link.schedule_all(send_ns[a:b], runs, size_bytes) for a, b in itertools.pairwise(cuts)]
    return np.concatenate([a for a, _ in parts]), np.concatenate([f for _, f in parts])


def send_times(seed: int, n: int = N) -> np.ndarray:
    """1 ms apart with some uneven gaps (a pause, packets at the same time)."""
    gaps = np.random.default_rng(seed).choice([0, MS, MS, MS, 7 * MS], size=n)
    return np.cumsum(gaps).astype(np.int64)
