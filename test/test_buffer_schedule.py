"""The compiled buffered schedule (engine/compiled/buffer_schedule.py) against the very `Link` and
buffer objects ticked one packet at a time (`TickedSchedule`): the same releases, occupancy and
packet records, bit for bit, window sizes apart; and the playout rules' one edge of their own."""

from __future__ import annotations

import numpy as np
import pytest

from haptic_teleop.assembly.parts import build_network
from haptic_teleop.core import playout_rules as rules
from haptic_teleop.core.link import LOST_LATE, Packet
from haptic_teleop.core.playout import AdaptiveBuffer, FixedBuffer
from haptic_teleop.engine.compiled import axis_host
from haptic_teleop.engine.compiled.buffer_schedule import BufferedSchedule
from haptic_teleop.scene.load import find_scene, load_scene

FWD = "network.forward"
PERIOD = 1_000_000

CASES = {
    "adaptive": ("jitter", []),
    "none_jitter_keep_order_off": ("jitter", [f"{FWD}.buffer.policy=none"]),
    "bandwidth_none": ("bandwidth", []),
    "varying_delay_adaptive": ("varying_delay", [f"{FWD}.buffer.policy=adaptive"]),
    "percentile_small_window": (
        "jitter",
        [f"{FWD}.buffer.policy=percentile", f"{FWD}.buffer.window_packets=50", f"{FWD}.buffer.quantile=0.9"],
    ),
    "seed_contact_playout": ("seed_contact_playout", []),
    "varying_delay_transparency": ("varying_delay", []),
    "transparency_capped_small_window": (
        "jitter",
        [
            f"{FWD}.buffer.policy=transparency",
            f"{FWD}.buffer.window_packets=40",
            f"{FWD}.buffer.allowed_force_error_n=0.05",
            f"{FWD}.buffer.contact_horizon_s=0.05",
        ],
    ),
    "adaptive_reorder_correlated_loss": (
        "jitter",
        [
            f"{FWD}.effects.reorder.probability=0.05",
            f"{FWD}.effects.loss.probability=0.1",
            f"{FWD}.effects.loss.correlation=0.25",
        ],
    ),
    "fixed_gilbert": (
        "jitter",
        [
            f"{FWD}.buffer.policy=fixed",
            f"{FWD}.buffer.buffering_time_s=0.004",
            f"{FWD}.effects.loss.model=gilbert_elliott",
            f"{FWD}.effects.loss.p=0.05",
            f"{FWD}.effects.loss.r=0.3",
        ],
    ),
    "adaptive_wide_jitter_hysteresis": (
        "jitter",
        [f"{FWD}.effects.delay.jitter_s=0.03", f"{FWD}.buffer.hysteresis_s=0.0005", f"{FWD}.buffer.max_slew_rate=0.2"],
    ),
    "long_delay_uniform": (
        "jitter",
        [f"{FWD}.effects.delay.delay_s=1.3", f"{FWD}.effects.delay.distribution=uniform", f"{FWD}.buffer.policy=fixed"],
    ),
}


def _network(case):
    name, overrides = CASES[case]
    scene = load_scene(find_scene(name), overrides=overrides)
    fwd, _, buf, _ = build_network(scene.config, PERIOD)
    return fwd, buf


def _ticked_and_buffered(case):
    link_t, buf_t = _network(case)
    link_b, buf_b = _network(case)
    ticked = axis_host.TickedSchedule(link_t, buf_t, PERIOD, 72)
    buffered = axis_host.schedule(link_b, buf_b, PERIOD, 72)
    assert type(buffered) is BufferedSchedule
    return ticked, buffered


@pytest.mark.parametrize("case", sorted(CASES))
def test_buffered_schedule_equals_the_ticked_objects(case):
    ticked, buffered = _ticked_and_buffered(case)
    n, block = 6000, 1000
    rel_t, occ_t, rows_t = [], [], []
    for n0 in range(0, n, 100):  # the ticked schedule a loop chunk at a time
        r, o = ticked.window(n0, n0 + 100)
        rel_t.append(r)
        occ_t.append(o)
        if (n0 + 100) % block == 0:
            rows_t.append(ticked.settled(n0 + 100, False))
    rel_b, occ_b, rows_b = [], [], []
    for w0, w1 in ((0, 2500), (2500, 2501), (2501, 6000)):  # uneven windows
        r, o = buffered.window(w0, w1)
        rel_b.append(r)
        occ_b.append(o)
        for sent in range(w0 // block * block + block, w1 + 1, block):
            if sent > w0:
                rows_b.append(buffered.settled(sent, False))
    rows_t.append(ticked.settled(n, True))
    rows_b.append(buffered.settled(n, True))
    released = np.concatenate(rel_t)
    assert np.array_equal(released, np.concatenate(rel_b))
    assert np.array_equal(np.concatenate(occ_t), np.concatenate(occ_b))
    assert len(rows_t) == len(rows_b)
    for a, b in zip(rows_t, rows_b, strict=True):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)
    # not a vacuous comparison: samples were released, some held, some late
    fates = np.concatenate([r for r in rows_t if r is not None])[:, 3]
    assert np.count_nonzero(released >= 0) > n / 5
    assert np.max(np.concatenate(occ_t)) > 1 or "none" in case  # (none holds nothing past a release)
    # the buffer objects say the same after the run (counters, playout delay, target)
    bt, bb = ticked.buf, buffered.buf
    assert (bt.late, bt.played, bt.duplicates, bt.occupancy) == (bb.late, bb.played, bb.duplicates, bb.occupancy)
    if not case.startswith(("none", "bandwidth")):
        assert (bt.playout_delay_ns, bt.target_delay_ns) == (bb.playout_delay_ns, bb.target_delay_ns)
    assert np.count_nonzero(fates == LOST_LATE) > 0 or case in ("long_delay_uniform", "bandwidth_none")


def test_a_run_stopped_mid_window_records_what_had_happened():
    """The window is decided 2000 ticks ahead; stopped at 1300, the records are those the objects
    give when ticked to 1300: no late mark of a later tick, packets on their way delivered."""
    ticked, buffered = _ticked_and_buffered("adaptive")
    ticked.window(0, 1300)
    buffered.window(0, 2000)
    np.testing.assert_array_equal(ticked.settled(1300, True), buffered.settled(1300, True))


def test_playout_rules_count_a_packet_that_would_share_a_held_slot_late():
    """Two held packets SEEN_SLOTS sequence numbers apart would share a slot: the newer is late
    (documented bound: a playout delay of 32,768 periods)."""
    buf = FixedBuffer(PERIOD, buffering_ns=10**12)
    a = Packet(5, 5 * PERIOD, (), 0)
    b = Packet(5 + rules.SEEN_SLOTS, (5 + rules.SEEN_SLOTS) * PERIOD, (), 0)
    buf.push(a, 6 * PERIOD)
    buf.push(b, (6 + rules.SEEN_SLOTS) * PERIOD)
    assert b.fate == LOST_LATE and buf.late == 1 and buf.occupancy == 1


def test_an_adaptive_buffer_keeps_its_rules_in_arrays_the_compiled_schedule_takes():
    buf = AdaptiveBuffer(PERIOD)
    for k in range(60):
        buf.push(Packet(k, k * PERIOD, (), 0), k * PERIOD + 50 * PERIOD + (k % 7) * 100_000)
        buf.release(k * PERIOD + 50 * PERIOD)
    Q, E, seen, R, window = buf.rule_arrays()
    assert Q[rules.Q_N] == 60 and E[rules.E_V] > 0 and seen[59] == 59 and window == 1
    assert Q[rules.Q_COUNT] == buf.occupancy and R[59 * rules.R_WIDTH + rules.R_SEQ] == (
        59 if buf.occupancy else rules.NO_SEQ
    )
    assert buf.delay_estimate_ns == Q[rules.Q_REF] + E[rules.E_D]
