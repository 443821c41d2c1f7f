"""The codec stage in the compiled 1-DoF loop (engine/compiled/codec_host.py, engine/compiled/codec_kernel.py
and its stages, codec_*.py) gives the Python loop's run bit for bit, and says precisely what it cannot run.

Each identity case runs one scene in both loops and compares every call on the sink (blocks of
columns, batches of packet records, at the same points of the run), the controllers' final state,
the codec counters of the run facts (`codec_<direction>`) and the links' counts. Together the
cases cover each compiled codec configuration (deadband hold, extrapolation from the sent rate
and from the last two, the velocity-adaptive p, the floor; prediction extrapolating and holding;
FEC repetition and parity, playing late by wait_ticks or not, extrapolating or holding; HLI with
and without a bandwidth budget; ARQ with ACKs in time and late, in its own test),
on the forward link, the backward link and both, over constant delay with uncorrelated loss,
Gilbert-Elliott loss and blackouts. 1.5 s of scene each, a sinusoidal operator in contact with the
wall, so every quantity moves.
"""

import re

import numpy as np
import pytest
from compiled_identity import (
    ADAPTIVE,
    BERNOULLI,
    COPULA_JITTER,
    COPULA_LOSS,
    CORRELATED,
    FLOOR,
    FOUR_STATE,
    GILBERT,
    HOLD,
    LAST_TWO,
    PREDICTION,
    PREDICTION_HOLD,
    SENT_RATE,
    Calls,
)

from haptic_teleop.engine.lockstep import COL, Engine
from haptic_teleop.errors import HapticTeleopError
from haptic_teleop.scene.load import find_scene, load_scene

MOVING = ("operator.profile=sinusoid", "operator.amplitude_m=0.03", "operator.frequency_hz=2")
BLACKOUT = "{starts_s: [0.5, 1.2], ends_s: [0.65, 1.25]}"
# 150 ms down, one packet through (tick 650), 49 ms down again: after that packet the prediction
# decoder has forgotten the one before it (151 ticks older, beyond its history's 64 + 20), so it
# holds instead of extrapolating over the second window. Then the same with the packet through
# exactly 84 ticks after the one before (tick 983 after 899): that one is still remembered.
ONE_THROUGH = "{starts_s: [0.5, 0.651, 0.9, 0.984, 1.2], ends_s: [0.65, 0.7, 0.983, 1.0, 1.25]}"

REPETITION_WAIT = "{kind: fec, scheme: repetition, k: 3, wait_ticks: 2}"
REPETITION_HOLD = "{kind: fec, scheme: repetition, k: 2, gap: hold}"
PARITY_WAIT = "{kind: fec, scheme: parity, k: 3, wait_ticks: 3, max_extrapolation_s: 0.02}"
PARITY_HOLD = "{kind: fec, scheme: parity, k: 4, gap: hold}"
HLI_LINEAR = "{kind: hli}"
HLI_HOLD_BUDGET = "{kind: hli, predictor: hold, allowed_bandwidth_bps: 1500000, rate_window_s: 0.02}"

# case: {direction: (codec, effects)}; effects: (loss, blackout) scene values or None.
CASES = {
    "hold_both_bernoulli_gilbert": {"forward": (HOLD, (BERNOULLI, None)), "backward": (HOLD, (GILBERT, None))},
    "sent_rate_backward_blackout_bernoulli": {"backward": (SENT_RATE, (BERNOULLI, BLACKOUT))},
    "last_two_forward_gilbert_blackout": {"forward": (LAST_TWO, (GILBERT, BLACKOUT))},
    "adaptive_both": {"forward": (ADAPTIVE, (BERNOULLI, None)), "backward": (ADAPTIVE, (None, BLACKOUT))},
    "floor_backward_gilbert": {"backward": (FLOOR, (GILBERT, None))},
    "prediction_both": {"forward": (PREDICTION, (None, ONE_THROUGH)), "backward": (PREDICTION, (GILBERT, None))},
    # netem-correlated loss (bursts) both ways, its numbers from the effects' own sources
    "hold_correlated_fec_backward_correlated_blackout": {
        "forward": (HOLD, (CORRELATED, None)),
        "backward": (REPETITION_WAIT, (CORRELATED, BLACKOUT)),
    },
    "prediction_hold_forward": {"forward": (PREDICTION_HOLD, (BERNOULLI, ONE_THROUGH))},
    "fec_repetition_both": {
        "forward": (REPETITION_WAIT, (BERNOULLI, None)),
        "backward": (REPETITION_HOLD, (GILBERT, BLACKOUT)),
    },
    "fec_parity_both": {"forward": (PARITY_WAIT, (GILBERT, BLACKOUT)), "backward": (PARITY_HOLD, (BERNOULLI, None))},
    # HLI needs Gilbert loss on its direction (N_HLI1); backward: HLI1 followers filtered under a budget
    "hli_both": {"forward": (HLI_LINEAR, (GILBERT, None)), "backward": (HLI_HOLD_BUDGET, (GILBERT, BLACKOUT))},
}


def _overrides(case):
    out = ["scene.duration_s=1.5", *MOVING]
    for d, (codec, (loss, blackout)) in CASES[case].items():
        out.append(f"network.{d}.codec={codec}")
        if loss is not None:
            out.append(f"network.{d}.effects.loss={loss}")
        if blackout is not None:
            out.append(f"network.{d}.effects.blackout={blackout}")
    return out


def _scene(overrides, name="wall_contact"):
    return load_scene(find_scene(name), overrides=list(overrides))


def _run(scene, loop, stop_at=None):
    e = Engine(scene, loop=loop)
    assert e.loop_kind == loop, e.compiled_reason
    sink = Calls()

    def progress(n):
        if stop_at is not None and n >= stop_at:
            e.request_stop()

    r = e.run(handle_sigint=False, progress=progress, sink=sink)
    return e, r, sink


def _last(draw):
    """A netem-correlated source's last number (written back after a compiled run), else None."""
    return getattr(getattr(draw, "__self__", None), "_last", None)


def _effect_state(x):
    """An effect's counts and state: dropped, the Gilbert and 4-state chains' state, a trace's
    packets so far, the correlated numbers' last, the jitter's last arrival kept in order."""
    u, ju = _last(getattr(x, "_u", None)), _last(getattr(x, "_ju", None))
    state = (getattr(x, "bad", None), getattr(x, "state", None), getattr(x, "_n", None))
    return (x.name, getattr(x, "dropped", None), *state, u, ju, getattr(x, "_last_arrival", None))


def _link(link):
    return (
        link.sent,
        link.lost,
        tuple(_effect_state(x) for x in link.effects),
    )


def _links(e):
    return {d: _link(getattr(e, d)) for d in ("forward", "backward")}


def _assert_same(compiled, python):
    (ec, rc, sc), (ep, rp, sp) = compiled, python
    assert rc.ticks == rp.ticks
    assert [k for k, _ in sc.calls] == [k for k, _ in sp.calls]
    for (kind, c), (_, p) in zip(sc.calls, sp.calls, strict=True):
        assert np.array_equal(c, p, equal_nan=True), kind
    for side in ("master_ctrl", "slave_ctrl"):
        a, b = getattr(ec, side), getattr(ep, side)
        assert a.rejected_samples == b.rejected_samples
        assert a.bound.axis_state() == b.bound.axis_state()
        assert a.remote == b.remote
    assert ec.codec_facts() == ep.codec_facts()
    for a, b in zip(ec.codecs, ep.codecs, strict=True):
        if a is not None:
            assert (a.encoder.counters, a.decoder.counters) == (b.encoder.counters, b.decoder.counters)
            assert a.newest_seq == b.newest_seq
            if a.kind in ("prediction", "fec", "arq"):
                assert (a.decoder.rec.predicted, a.decoder.rec.late) == (b.decoder.rec.predicted, b.decoder.rec.late)
    assert _links(ec) == _links(ep)
    for a, b in zip(ec.codecs, ep.codecs, strict=True):
        if a is not None and a.ack_link is not None:
            assert (a.ack_packets, a.ack_bytes) == (b.ack_packets, b.ack_bytes)
            assert _link(a.ack_link) == _link(b.ack_link)
    assert ec.slave.contact_force() == ep.slave.contact_force()


@pytest.mark.parametrize("case", sorted(CASES))
def test_compiled_codec_equals_python_loop(case):
    scene = _scene(_overrides(case))
    compiled, python = _run(scene, "compiled"), _run(scene, "python")
    _assert_same(compiled, python)
    # Not vacuous: the codec decided, the link lost packets, the decoder reconstructed.
    e, sink = compiled[0], compiled[2]
    facts = e.codec_facts()
    for d, (codec, _) in CASES[case].items():
        f = facts[f"codec_{d}"]
        rows = sink.packets(d)
        assert len(rows) == f["encoder_sent"] and np.count_nonzero(rows[:, 3] != 0) > 10
        if "hli" in codec:
            assert f["encoder_filtered_hli0"] > 100 and f["decoder_rebuilt"] > 0 and f["decoder_predicted"] > 100
            assert (f["encoder_filtered_hli1"] > 10) == ("bandwidth" in codec)
            continue
        if "deadband" in codec:
            assert 0 < f["encoder_sent"] < 0.7 * f["encoder_offered"]
            if "extrapolate" in codec:
                assert f["decoder_extrapolated"] > 10
        else:
            predicted = e.codecs[("forward", "backward").index(d)].decoder.rec.predicted
            assert f["encoder_sent"] == e.ticks and predicted > (0 if "fec" in codec else 10)
            if "fec" in codec:  # recovered in time (with wait_ticks) and too late
                assert f["decoder_recovered"] > 10 and 0 < f["decoder_recovered_late"]
                if "wait" in codec:
                    assert f["decoder_recovered_late"] < f["decoder_recovered"]
    rows = np.concatenate([a for kind, a in sink.calls if kind == "rows"])
    assert len(rows) == e.ticks and np.ptp(rows[:, COL["s_x_m"]]) > 1e-3


OTHER_NETWORKS = {
    # the direction without a codec ticked through the Python objects (jitter, a fixed buffer)
    "ticked_other_direction": [
        f"network.forward.codec={LAST_TWO}",
        "network.backward.effects.delay.jitter_s=0.005",
        "network.backward.buffer.policy=fixed",
    ],
    # delays longer than a block: records wait several blocks, the in-flight ring is 2048 deep
    "long_delays": [
        "scene.duration_s=3.0",
        f"network.forward.codec={PREDICTION}",
        f"network.backward.codec={HOLD}",
        "network.forward.effects.delay.delay_s=1.5",
        "network.backward.effects.delay.delay_s=1.3",
        f"network.backward.effects.loss={BERNOULLI}",
    ],
}


@pytest.mark.parametrize("case", sorted(OTHER_NETWORKS))
def test_compiled_codec_beside_other_networks(case):
    scene = _scene(["scene.duration_s=1.5", *MOVING, *OTHER_NETWORKS[case]])
    compiled, python = _run(scene, "compiled"), _run(scene, "python")
    _assert_same(compiled, python)
    kinds = [k for k, _ in compiled[2].calls]
    assert kinds.count("rows") >= 2 and {"forward", "backward"} <= set(kinds)


ARQ_SLOW = "{kind: arq, timeout_s: 0.025, max_retransmissions: 4}"
ARQ_FAST = "{kind: arq, timeout_s: 0.004, max_retransmissions: 1, wait_ticks: 5, gap: hold}"
ARQ_CASES = {
    # the ACKs come back within mu (10 ms each way): retransmissions only for what was lost
    "arq_both_in_time": [
        f"network.forward.codec={ARQ_SLOW}",
        f"network.backward.codec={ARQ_SLOW}",
        "network.forward.effects.delay.delay_s=0.01",
        "network.backward.effects.delay.delay_s=0.01",
        f"network.forward.effects.loss={BERNOULLI}",
        f"network.backward.effects.loss={GILBERT}",
        f"network.backward.effects.blackout={BLACKOUT}",
    ],
    # the same over netem-correlated loss both ways (the ACKs' too)
    "arq_both_in_time_correlated": [
        f"network.forward.codec={ARQ_SLOW}",
        f"network.backward.codec={ARQ_SLOW}",
        "network.forward.effects.delay.delay_s=0.01",
        "network.backward.effects.delay.delay_s=0.01",
        f"network.forward.effects.loss={CORRELATED}",
        f"network.backward.effects.loss={CORRELATED}",
        f"network.backward.effects.blackout={BLACKOUT}",
    ],
    # mu below the round trip (50 ms each way): every sample retransmitted, then given up; the
    # ACKs over the backward link's Gilbert loss and blackouts
    "arq_forward_late_acks": [
        f"network.forward.codec={ARQ_FAST}",
        f"network.forward.effects.loss={BERNOULLI}",
        f"network.backward.effects.loss={GILBERT}",
        f"network.backward.effects.blackout={BLACKOUT}",
    ],
    # mu = 10 ms, 4 retries, 120 ms each way: a sample's copies arrive 120 to 160 ticks after it
    # was sampled, the later ones after its row of X (128 rows: the delay, the pending span and
    # the decoder's history) went to a newer sample; the decoder plays 20 ticks behind the newest
    # (wait_ticks), so a sample whose first copies were lost is played from one of those. 1550
    # ticks: the last chunk, and so the last plan, is a half one.
    "arq_forward_last_copies_late": [
        "network.forward.codec={kind: arq, timeout_s: 0.01, max_retransmissions: 4, wait_ticks: 20,"
        " max_extrapolation_s: 0.0}",
        "network.forward.effects.delay.delay_s=0.12",
        f"network.forward.effects.loss={BERNOULLI}",
        f"network.forward.effects.blackout={BLACKOUT}",
        f"network.backward.effects.loss={GILBERT}",
        "scene.duration_s=1.55",
    ],
}


@pytest.mark.parametrize("case", sorted(ARQ_CASES))
def test_compiled_arq_equals_python_loop(case):
    """ARQ: several packets a tick (retransmissions), records handed over by send time, the ACK
    link run in the kernel with its own random numbers."""
    scene = _scene(["scene.duration_s=1.5", *MOVING, *ARQ_CASES[case]])
    compiled, python = _run(scene, "compiled"), _run(scene, "python")
    _assert_same(compiled, python)
    e = compiled[0]
    for d, ch in zip(("forward", "backward"), e.codecs, strict=True):
        if ch is None:
            continue
        f = e.codec_facts()[f"codec_{d}"]
        rows = compiled[2].packets(d)
        assert len(rows) == f["encoder_sent"] > e.ticks and f["encoder_retransmitted"] > 10
        assert np.any(np.diff(rows[:, 0]) < 0)  # retransmissions: not in seq order
        assert f["decoder_recovered"] > 10 and f["decoder_duplicates"] > 10 and ch.ack_link.lost > 10
        in_time = case.startswith("arq_both_in_time")
        assert f["encoder_gave_up"] > 0 and (f["encoder_acks_stale"] > 0) != in_time
        assert (f["encoder_acked"] > 0.5 * e.ticks) == in_time


# Cumulative selective ACKs (ack_every_ticks): forward mu 150 ms over the 100 ms round trip, its
# retransmissions named below the ACK's window (150 ticks behind the newest seq); backward mu 51 ms,
# its retransmissions arrive inside the window and leave it before their ACK (2 ms delay, the
# ACKs over the forward link's 50 ms and 20 % loss, so many come late); ACKs lost both ways.
ARQ_CUMULATIVE = [
    "network.forward.codec={kind: arq, timeout_s: 0.15, max_retransmissions: 4, ack_every_ticks: 4}",
    f"network.forward.effects.loss={BERNOULLI}",
    "network.backward.codec={kind: arq, timeout_s: 0.051, max_retransmissions: 3, ack_every_ticks: 5, gap: hold}",
    "network.backward.effects.delay.delay_s=0.002",
    f"network.backward.effects.loss={GILBERT}",
    f"network.backward.effects.blackout={BLACKOUT}",
]


def test_compiled_arq_cumulative_acks_equal_python_loop():
    from haptic_teleop.assembly.channel import message_bytes

    scene = _scene(["scene.duration_s=1.5", *MOVING, *ARQ_CUMULATIVE])
    compiled, python = _run(scene, "compiled"), _run(scene, "python")
    _assert_same(compiled, python)
    e = compiled[0]
    for d, ch, k in zip(("forward", "backward"), e.codecs, (4, 5), strict=True):
        f = e.codec_facts()[f"codec_{d}"]
        # (forward: the retransmissions come 200 ms after their slot, too old for the decoder's
        # history, so none is recovered)
        assert f["encoder_retransmitted"] > 10 and ch.ack_link.lost > 10
        assert (f["decoder_recovered"] > 10) == (d == "backward")
        assert 0.5 * e.ticks / k < f["decoder_acks_sent"] == ch.ack_packets <= e.ticks // k + 1
        assert ch.ack_bytes > ch.ack_packets * message_bytes(2)  # some name seqs below the window
        assert f["encoder_acked"] > 0.5 * e.ticks and f["encoder_gave_up"] > 0


def test_codec_nets_are_made_ready_a_thousand_ticks_ahead(monkeypatch):
    """The nets' random numbers and record rows are topped up once per READY_TICKS, not once per
    chunk of CHUNK_TICKS, and enough for every packet ARQ may send in them (four a tick here: its
    timeout under the round trip, with losses): the run is still the Python loop's."""
    from haptic_teleop.engine.compiled import codec_host, windows

    assert windows.READY_TICKS == 10 * windows.CHUNK_TICKS
    asked = []
    ready = codec_host.CodecNet.ready

    def counting(net, ticks):
        asked.append(ticks)
        ready(net, ticks)

    monkeypatch.setattr(codec_host.CodecNet, "ready", counting)
    arq = "{kind: arq, timeout_s: 0.025, max_retransmissions: 4}"
    scene = _scene(
        ["scene.duration_s=2.5", *MOVING, f"network.forward.codec={arq}", f"network.forward.effects.loss={BERNOULLI}"]
    )
    compiled = _run(scene, "compiled")
    assert asked == [1000, 1000, 500]  # the forward direction's net: ticks 0, 1000, 2000
    python = _run(scene, "python")
    _assert_same(compiled, python)
    assert compiled[0].codec_facts()["codec_forward"]["encoder_sent"] > 4 * compiled[0].ticks


# A deadband direction's link may jitter in the kernel (uncorrelated or netem-correlated, any
# distribution, with or without keep_order): packets overtake each other, the in-flight ring keeps
# them in arrival order, the decoder counts the ones older than what it holds as stale.
NORMAL_JITTER = "{delay_s: 0.02, jitter_s: 0.004, correlation: 0.25}"  # (netem-correlated)
UNIFORM_JITTER = "{delay_s: 0.03, jitter_s: 0.01, distribution: uniform}"
PARETONORMAL_KEEP = "{delay_s: 0.025, jitter_s: 0.01, distribution: paretonormal, keep_order: true}"
PARETO_JITTER = "{delay_s: 0.01, jitter_s: 0.006, distribution: pareto}"
JITTER_CASES = {
    "hold_normal_bernoulli_sent_rate_uniform_blackout": [
        f"network.forward.codec={HOLD}",
        f"network.forward.effects.delay={NORMAL_JITTER}",
        f"network.forward.effects.loss={BERNOULLI}",
        f"network.backward.codec={SENT_RATE}",
        f"network.backward.effects.delay={UNIFORM_JITTER}",
        f"network.backward.effects.blackout={BLACKOUT}",
    ],
    "last_two_keep_order_gilbert_adaptive_pareto": [
        f"network.forward.codec={LAST_TWO}",
        f"network.forward.effects.delay={PARETONORMAL_KEEP}",
        f"network.forward.effects.loss={GILBERT}",
        f"network.backward.codec={ADAPTIVE}",
        f"network.backward.effects.delay={PARETO_JITTER}",
    ],
}


@pytest.mark.parametrize("stop_at", [None, 700])
@pytest.mark.parametrize("case", sorted(JITTER_CASES))
def test_compiled_deadband_over_jitter_equals_python_loop(case, stop_at):
    """Jitter on a deadband's link runs in the kernel, bit for bit the Python loop (stopped or not:
    the records handed over up to the oldest packet in flight, which is no longer the ring's first)."""
    scene = _scene(["scene.duration_s=1.5", *MOVING, *JITTER_CASES[case]])
    compiled, python = _run(scene, "compiled", stop_at), _run(scene, "python", stop_at)
    _assert_same(compiled, python)
    facts = compiled[0].codec_facts()
    keep = case.startswith("last_two_keep_order")
    # packets overtook each other where the order is not kept (stale arrivals), never where it is
    assert (facts["codec_forward"]["decoder_stale"] > 0) != keep
    assert facts["codec_backward"]["decoder_stale"] > 0
    assert compiled[0].forward.effects[-1]._last_arrival == python[0].forward.effects[-1]._last_arrival


def test_stopped_compiled_codec_run_leaves_the_python_loops_records():
    """Stopped at the same tick, both loops hand over the same columns and packet records."""
    scene = _scene(_overrides("hold_both_bernoulli_gilbert"))
    compiled, python = _run(scene, "compiled", stop_at=700), _run(scene, "python", stop_at=700)
    assert compiled[1].interrupted and compiled[1].ticks == 700
    _assert_same(compiled, python)


@pytest.mark.parametrize(("repeat", "stop_at"), [(True, None), (False, None), (True, 700)])
def test_compiled_codec_over_four_state_and_trace_loss_equals_python_loop(tmp_path, repeat, stop_at):
    """The 4-state chain and a loss trace in the kernel: ARQ forward over 4-state loss, its ACKs
    and a deadband backward over a 100-packet trace (repeated: every link starts it over; not
    repeated: the packets after it all pass), a run stopped at tick 700 too."""
    rng = np.random.default_rng(7)
    trace = tmp_path / "loss.csv"
    trace.write_text("lost\n" + "".join(f"{int(x)}\n" for x in rng.random(100) < 0.2))
    over = [
        "scene.duration_s=1.5",
        *MOVING,
        f"network.forward.codec={ARQ_SLOW}",
        f"network.backward.codec={HOLD}",
        *(f"network.{d}.effects.delay.delay_s=0.01" for d in ("forward", "backward")),
        f"network.forward.effects.loss={FOUR_STATE}",
        f"network.backward.effects.loss={{model: trace, file: {trace}, repeat: {str(repeat).lower()}}}",
    ]
    scene = _scene(over)
    compiled, python = _run(scene, "compiled", stop_at), _run(scene, "python", stop_at)
    _assert_same(compiled, python)
    e = compiled[0]
    fwd, bwd = (next(x for x in getattr(e, d).effects if x.name == "loss") for d in ("forward", "backward"))
    assert type(fwd).__name__ == "FourStateLoss" and fwd.dropped > 20
    assert type(bwd).__name__ == "TraceLoss" and bwd.dropped > 5 and (bwd._n > 100 or stop_at is not None)
    assert e.codecs[0].ack_link.lost > 10


def test_stopped_compiled_arq_run_leaves_the_python_loops_records():
    """ARQ plans its ticks ahead (`codec_arq.arq_block`): stopped at the same tick, both loops
    still hand over the same columns, packet records and codec counts."""
    scene = _scene(["scene.duration_s=1.5", *MOVING, *ARQ_CASES["arq_both_in_time"]])
    compiled, python = _run(scene, "compiled", stop_at=700), _run(scene, "python", stop_at=700)
    assert compiled[1].interrupted and compiled[1].ticks == 700
    _assert_same(compiled, python)


def _codec_on(d, codec, *effects):
    return [f"network.{d}.codec={codec}", *(f"network.{d}.effects.{e}" for e in effects)]


@pytest.mark.parametrize(
    ("overrides", "reason"),
    [
        (
            _codec_on("forward", "{kind: hli}", f"loss={GILBERT}", "delay.jitter_s=0.002"),
            "effect delay (Delay) on the for",
        ),
        (
            [*_codec_on("forward", "{kind: arq}"), "network.backward.effects.delay.jitter_s=0.002"],
            "effect delay (Delay) on the forward:ack link",
        ),
        (_codec_on("forward", "{kind: arq, max_retransmissions: 100, timeout_s: 0.05}"), "keeps a sample up to"),
        (_codec_on("backward", "{kind: fec}", "duplicate.probability=0.1"), "effect duplicate (Duplicate) on the back"),
        (_codec_on("backward", PREDICTION, "delay.jitter_s=0.002"), "effect delay (Delay) on the backward link"),
        (
            _codec_on("backward", HOLD, *COPULA_JITTER),
            "gaussian_copula-correlated jitter on the backward link",
        ),
        (
            _codec_on("forward", HOLD, "delay.jitter_s=0.002", "reorder={probability: 0.02}"),
            "reordering on the forward",
        ),
        (
            _codec_on(
                "forward", HOLD, "delay={delay_s: 0.0, sinusoid: {min_delay_s: 0.0, max_delay_s: 0.04, period_s: 2.0}}"
            ),
            "a time-varying delay (schedule, sinusoid or trace) on the forward link",
        ),
        (
            _codec_on("forward", HOLD, "rate_limit={rate_bps: 1000000, burst_bytes: 2000}"),
            "effect rate_limit (TokenBucket) on the forward link",
        ),
        (_codec_on("forward", PREDICTION, "duplicate.probability=0.1"), "effect duplicate (Duplicate)"),
        (_codec_on("forward", HOLD, *COPULA_LOSS), "gaussian_copula-correlated loss on the forward"),
    ],
)
def test_codec_scenes_the_compiled_loop_cannot_run_say_why(overrides, reason):
    scene = _scene(["scene.duration_s=0.1", *overrides])
    e = Engine(scene)
    assert e.loop_kind == "python" and reason in e.compiled_reason
    with pytest.raises(HapticTeleopError, match=re.escape(reason)):
        Engine(scene, loop="compiled")


def test_auto_runs_compiled_codecs_compiled():
    e = Engine(_scene(["scene.duration_s=0.1", *_overrides("prediction_both")[2:]]))
    assert e.loop_kind == "compiled" and e.compiled_reason is None
