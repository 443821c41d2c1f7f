"""A rate limit (core/delay.py `TokenBucket`) decided a window at a time (`apply_all`, `token_run`,
compiled in engine/compiled/link_runs.py) gives what `Link.send` gives packet by packet: the same
departures, queue drops and state, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from windowed import in_windows, one_by_one

from haptic_teleop.core.delay import ConstantDelay, TokenBucket
from haptic_teleop.core.link import DELIVERED, LOST_QUEUE, Link
from haptic_teleop.core.loss import BernoulliLoss

CASES = {
    # (rate_bps, burst_bytes, queue_limit_packets, size_bytes, send gaps in ns)
    "shaping, tail drops": (4e5, 1500, 50, 72, (1_000_000,)),
    "policing": (4e5, 1500, 0, 72, (1_000_000,)),
    "one packet of room": (2e6, 200, 1, 100, (1_000_000, 0, 250_000)),
    "fast link, long idle gaps": (1e9, 1100, 5, 1000, (1_000_000, 0, 10_000_000_000)),
}


def _links(rate, burst, limit, seed=3):
    def make():
        return Link(
            [
                BernoulliLoss(0.05, np.random.default_rng(seed)),
                TokenBucket(rate, burst, limit),
                ConstantDelay(0.01),
            ]
        )

    return make(), make()


def _send_times(gaps, n, seed=5):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.choice(np.array(gaps, dtype=np.int64), size=n)).astype(np.int64)


@pytest.mark.parametrize("case", sorted(CASES))
def test_rate_limit_windows_equal_packet_by_packet(case, runs):
    rate, burst, limit, size, gaps = CASES[case]
    n = 4000
    send = _send_times(gaps, n)
    one, win = _links(rate, burst, limit)
    arrival_1, fate_1 = one_by_one(one, send, size)
    arrival_w, fate_w = in_windows(win, send, runs, size)
    delivered = fate_1 == DELIVERED
    np.testing.assert_array_equal(fate_w, fate_1)
    np.testing.assert_array_equal(arrival_w[delivered], arrival_1[delivered])
    tb_1, tb_w = one.effects[1], win.effects[1]
    assert (tb_1.dropped, tb_1.queue_length, tb_1._s, tb_1._r) == (tb_w.dropped, tb_w.queue_length, tb_w._s, tb_w._r)
    assert (one.sent, one.lost) == (win.sent, win.lost)
    # not vacuous: the queue delayed packets, and dropped some where it is short
    assert np.any(arrival_1[delivered] - send[delivered] > 10_000_000) or limit == 0
    if limit <= 1:
        assert np.count_nonzero(fate_1 == LOST_QUEUE) > 0


def test_a_rate_limit_needs_the_packets_size_to_decide_a_window():
    link = Link([TokenBucket(4e5, 1500, 50)])
    with pytest.raises(ValueError, match="known size"):
        link.schedule_all(np.arange(3, dtype=np.int64) * 1_000_000)
    with pytest.raises(ValueError, match="exceeds burst_bytes"):
        link.schedule_all(np.arange(3, dtype=np.int64), size_bytes=2000)
