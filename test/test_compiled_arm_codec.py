"""An arm scene's codec stage in the compiled arm loop (engine/compiled/arm_codec_kernel.py, loaded only with
a codec) gives the Python arm loop's run bit for bit, and says precisely what it cannot run.

Each identity case runs `touch_ur5e_wall` (1 s; the operator starts at 0.1 s at 0.1 m/s, so the
tool meets the table at about 0.4 s and every quantity moves) in both loops and compares every
call on the sink (blocks of columns, batches of packet records, at the same points of the run),
the sides' final state, the run facts `codec_<direction>`, the codecs' and the links' counters.
The cases cover deadband hold, extrapolation from the sent rate and from the last two, the
velocity-adaptive p (the 3-D speed), the floor, and prediction extrapolating and holding, on each
direction and both, over constant delay with uncorrelated loss, Gilbert-Elliott loss and
blackouts, beside a direction on its schedule (vectorized and ticked); FEC repetition and parity
recovering losses (in time with wait_ticks, and late), ARQ with its timeout above and below the
round trip, an ACK per packet and cumulative ACKs, lossy both ways; HLI over Gilbert loss with
its default and under an allowed bandwidth. The arm codec kernel compiles once per process
(about a minute cold): every compiled run of this module shares it.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path
from typing import Any

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
    assert_same_arm_sides,
    assert_same_calls,
)

from haptic_teleop.analysis.energy import energy_margins
from haptic_teleop.analysis.stream import summarize_bag
from haptic_teleop.cli.main import main
from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.engine.run import record_run
from haptic_teleop.errors import HapticTeleopError
from haptic_teleop.scene.load import find_scene, load_scene

SCENE = "touch_ur5e_wall"
MOVING = ("operator.start_s=0.1", "operator.speed_m_per_s=0.1", "operator.distance_m=0.06")
BLACKOUT = "{starts_s: [0.3, 0.7], ends_s: [0.42, 0.75]}"
# 120 ms down, one packet through (tick 421), 49 ms down again: the prediction decoder has
# forgotten the packet before it (beyond its history) and holds over the second window.
ONE_THROUGH = "{starts_s: [0.3, 0.422, 0.7], ends_s: [0.421, 0.471, 0.75]}"

# case: {direction: (codec, loss, blackout)}, and overrides of the scene besides
CASES: dict[str, tuple[dict[str, tuple[str, str | None, str | None]], tuple[str, ...]]] = {
    "hold_both_bernoulli_gilbert": ({"forward": (HOLD, BERNOULLI, None), "backward": (HOLD, GILBERT, None)}, ()),
    "sent_rate_backward_blackout_bernoulli": ({"backward": (SENT_RATE, BERNOULLI, BLACKOUT)}, ()),
    # the backward direction on the ticked schedule (jitter, a fixed buffer)
    "last_two_forward_gilbert_blackout": (
        {"forward": (LAST_TWO, GILBERT, BLACKOUT)},
        ("network.backward.effects.delay.jitter_s=0.005", "network.backward.buffer.policy=fixed"),
    ),
    "adaptive_both": ({"forward": (ADAPTIVE, BERNOULLI, None), "backward": (ADAPTIVE, None, BLACKOUT)}, ()),
    "floor_backward_gilbert": ({"backward": (FLOOR, GILBERT, None)}, ()),
    "prediction_both": ({"forward": (PREDICTION, None, ONE_THROUGH), "backward": (PREDICTION, GILBERT, None)}, ()),
    "prediction_hold_forward": ({"forward": (PREDICTION_HOLD, BERNOULLI, ONE_THROUGH)}, ()),
}
# FEC: forward repetition (its recoveries late: extrapolation bases), backward parity played
# 3 ticks late (recoveries in time); ARQ: per-packet ACKs forward (played 40 ticks late: the
# retransmissions in time), cumulative ones backward (every 4 and 5 ticks), with mu above the
# round trip (10 ms each way) and below it (4 and 51 ms over 50 ms each way: the ACKs come late,
# samples are given up), the ACKs lost on the reverse links; HLI: the default
# forward, backward held under an allowed bandwidth that filters HLI1 followers (a threshold of
# 20 mm on the 9-value sample of which the force is part, in N).
REPETITION = "{kind: fec, scheme: repetition, k: 2}"
PARITY = "{kind: fec, scheme: parity, k: 3, wait_ticks: 3, max_extrapolation_s: 0.02}"
ARQ_ACK = "{kind: arq, timeout_s: 0.025, max_retransmissions: 4, wait_ticks: 40}"
ARQ_CUMULATIVE = "{kind: arq, timeout_s: 0.025, max_retransmissions: 3, ack_every_ticks: 4, gap: hold}"
ARQ_FAST = "{kind: arq, timeout_s: 0.004, max_retransmissions: 1, wait_ticks: 5, gap: hold}"
ARQ_LATE_CUMULATIVE = "{kind: arq, timeout_s: 0.051, max_retransmissions: 3, ack_every_ticks: 5}"
HLI = "{kind: hli}"
HLI_BUDGET = "{kind: hli, predictor: hold, threshold_m: 0.02, allowed_bandwidth_bps: 1000000, rate_window_s: 0.02}"
DELAY_10MS = tuple(f"network.{d}.effects.delay.delay_s=0.01" for d in ("forward", "backward"))
CASES.update(
    {
        "fec_both": ({"forward": (REPETITION, BERNOULLI, None), "backward": (PARITY, GILBERT, BLACKOUT)}, ()),
        "arq_in_time": (
            {"forward": (ARQ_ACK, BERNOULLI, None), "backward": (ARQ_CUMULATIVE, GILBERT, BLACKOUT)},
            DELAY_10MS,
        ),
        "arq_late_acks": (
            {"forward": (ARQ_FAST, GILBERT, None), "backward": (ARQ_LATE_CUMULATIVE, BERNOULLI, BLACKOUT)},
            (),
        ),
        "hli_both": ({"forward": (HLI, GILBERT, None), "backward": (HLI_BUDGET, GILBERT, BLACKOUT)}, ()),
        # netem-correlated loss both ways (ARQ's ACKs too); the 4-state chain
        "correlated_arq_fec": (
            {"forward": (ARQ_ACK, CORRELATED, None), "backward": (REPETITION, CORRELATED, BLACKOUT)},
            DELAY_10MS,
        ),
        "four_state_fec_arq": (
            {"forward": (REPETITION, FOUR_STATE, BLACKOUT), "backward": (ARQ_ACK, FOUR_STATE, None)},
            DELAY_10MS,
        ),
        # a deadband's link jitters in the kernel too: packets overtake each other forward, keep
        # their order backward
        "deadband_jitter_both": (
            {"forward": (HOLD, BERNOULLI, None), "backward": (SENT_RATE, None, BLACKOUT)},
            (
                "network.forward.effects.delay={delay_s: 0.02, jitter_s: 0.006, correlation: 0.25}",
                "network.backward.effects.delay={delay_s: 0.03, jitter_s: 0.01, distribution: paretonormal, "
                "keep_order: true}",
            ),
        ),
    }
)
STOP_AT = 600  # the stopped cases (STOPPED) stopped at this tick in both loops
STOPPED = ("hold_both_bernoulli_gilbert", "arq_late_acks", "deadband_jitter_both")


def _overrides(case: str, duration_s: float = 1.0) -> list[str]:
    codecs, extra = CASES[case]
    out = [f"scene.duration_s={duration_s}", *MOVING, *extra]
    for d, (codec, loss, blackout) in codecs.items():
        out.append(f"network.{d}.codec={codec}")
        if loss is not None:
            out.append(f"network.{d}.effects.loss={loss}")
        if blackout is not None:
            out.append(f"network.{d}.effects.blackout={blackout}")
    return out


def _scene(overrides: list[str]) -> Any:
    return load_scene(find_scene(SCENE), overrides=overrides)


Run = tuple[Engine, Any, Calls]


def _run(scene: Any, loop: str, stop_at: int | None = None) -> Run:
    e = Engine(scene, loop=loop)
    assert e.loop_kind == loop, e.compiled_reason
    sink = Calls()

    def progress(n: int) -> None:
        if stop_at is not None and n >= stop_at:
            e.request_stop()

    r = e.run(handle_sigint=False, progress=progress, sink=sink)
    return e, r, sink


@pytest.fixture(scope="module")
def runs() -> dict[str, tuple[Run, Run]]:
    """Every case in both loops, once per module (the compiled runs share one compilation)."""
    out = {}
    for case in CASES:
        scene = _scene(_overrides(case))
        out[case] = (_run(scene, "compiled"), _run(scene, "python"))
    for case in STOPPED:
        scene = _scene(_overrides(case))
        out[f"stopped_{case}"] = (_run(scene, "compiled", STOP_AT), _run(scene, "python", STOP_AT))
    return out


def _link(link: Any) -> tuple[Any, ...]:
    effects = tuple((x.name, getattr(x, "dropped", None), getattr(x, "bad", None)) for x in link.effects)
    return link.sent, link.lost, effects


def _links(e: Engine) -> dict[str, Any]:
    out = {d: _link(getattr(e, d)) for d in ("forward", "backward")}
    for d, ch in zip(("forward", "backward"), e.codecs, strict=True):
        if ch is not None and ch.ack_link is not None:  # ARQ's ACKs: counted, their link's counts
            out[f"{d}:ack"] = (ch.ack_packets, ch.ack_bytes, _link(ch.ack_link))
    return out


def _assert_same(compiled: Run, python: Run) -> None:
    (ec, rc, sc), (ep, rp, sp) = compiled, python
    assert rc.ticks == rp.ticks
    assert_same_calls(sc.calls, sp.calls)
    assert_same_arm_sides(ec, ep)
    assert ec.codec_facts() == ep.codec_facts()
    for a, b in zip(ec.codecs, ep.codecs, strict=True):
        if a is not None:
            assert (a.encoder.counters, a.decoder.counters) == (b.encoder.counters, b.decoder.counters)
            assert a.newest_seq == b.newest_seq
            if a.kind in ("prediction", "fec", "arq"):
                assert (a.decoder.rec.predicted, a.decoder.rec.late) == (b.decoder.rec.predicted, b.decoder.rec.late)
            if a.kind == "hli":
                assert a.encoder.last_class == b.encoder.last_class
    assert _links(ec) == _links(ep)


@pytest.mark.parametrize("case", sorted(CASES))
def test_compiled_arm_codec_equals_python_arm_loop(runs: dict[str, tuple[Run, Run]], case: str) -> None:
    compiled, python = runs[case]
    _assert_same(compiled, python)
    # Not vacuous: the codec decided, the link lost packets, the decoder reconstructed, the tool
    # touched the table.
    e, _, sink = compiled
    facts = e.codec_facts()
    for d, (codec, _, _) in CASES[case][0].items():
        f = facts[f"codec_{d}"]
        ch = e.codecs[("forward", "backward").index(d)]
        rows = sink.packets(d)
        assert len(rows) == f["encoder_sent"] and np.count_nonzero(rows[:, 3] != 0) > 5
        if "deadband" in codec:
            assert 0 < f["encoder_sent"] < 0.7 * f["encoder_offered"]
            if "extrapolate" in codec:
                assert f["decoder_extrapolated"] > 10
        elif "fec" in codec:  # recovered: in time (played late: wait_ticks) or after the slot only
            in_time = f["decoder_recovered"] - f["decoder_recovered_late"]
            assert f["encoder_sent"] == e.ticks and ch.decoder.rec.predicted > 0
            assert f["decoder_recovered"] > 20 and (in_time > 20) == ("wait" in codec)
        elif "arq" in codec:
            # (4 ms: every sample given up before its ACKs come back, all stale; a cumulative ACK is
            # stale only if it names no pending sample)
            fast = codec == ARQ_FAST
            assert f["encoder_sent"] > e.ticks and f["encoder_retransmitted"] > 10 and ch.ack_link.lost > 5
            assert f["encoder_gave_up"] > 0 and (f["encoder_acks_stale"] > 0) == fast
            assert f["decoder_recovered"] > 10 and (f["encoder_acked"] > 0.5 * e.ticks) != fast
            in_time = f["decoder_recovered"] - f["decoder_recovered_late"]
            assert (in_time > 50) == ("wait" in codec)
            assert (ch.ack_packets < e.ticks / 3) == ("ack_every" in codec)
        elif "hli" in codec:
            assert f["encoder_filtered_hli0"] > 100 and f["decoder_rebuilt"] > 0 and f["decoder_predicted"] > 100
            assert (f["encoder_filtered_hli1"] > 10) == ("bandwidth" in codec)
        else:
            assert f["encoder_sent"] == e.ticks and ch.decoder.rec.predicted > 10
    if case == "deadband_jitter_both":  # overtaken forward (stale on arrival), in order backward
        assert facts["codec_forward"]["decoder_stale"] > 0 == facts["codec_backward"]["decoder_stale"]
    data = sink.data()
    assert len(data) == e.ticks
    assert np.abs(data[:, e.schema.group("s_contact_n")]).max() > 0.1


@pytest.mark.parametrize("case", STOPPED)
def test_stopped_compiled_arm_codec_run_leaves_the_python_loops_records(
    runs: dict[str, tuple[Run, Run]], case: str
) -> None:
    compiled, python = runs[f"stopped_{case}"]
    assert compiled[1].interrupted and compiled[1].ticks == STOP_AT
    _assert_same(compiled, python)


@pytest.mark.parametrize("codec", [ADAPTIVE, REPETITION, ARQ_ACK, HLI])
def test_auto_runs_an_arm_scenes_codec_compiled(codec: str) -> None:
    e = Engine(
        _scene(["scene.duration_s=0.05", f"network.forward.codec={codec}", f"network.forward.effects.loss={GILBERT}"])
    )
    try:
        assert e.loop_kind == "compiled" and e.compiled_reason is None
    finally:
        e.close_plants()


def _codec_on(d: str, codec: str, *effects: str) -> list[str]:
    return [f"network.{d}.codec={codec}", *(f"network.{d}.effects.{x}" for x in effects)]


REFUSED = [
    (
        _codec_on("forward", "{kind: arq, timeout_s: 0.5, max_retransmissions: 4}"),
        "arq on the forward link keeps a sample up to (max_retransmissions + 1) timeout_s = 2.5 s",
    ),
    (_codec_on("backward", "{kind: fec}", "delay.jitter_s=0.002"), "effect delay (Delay) on the backward link"),
    # the ACKs run over the reverse direction's effects
    ([*_codec_on("forward", "{kind: arq}"), "network.backward.effects.delay.jitter_s=0.002"], "forward:ack link"),
    (
        _codec_on("backward", HOLD, *COPULA_JITTER),
        "gaussian_copula-correlated jitter on the backward link",
    ),
    (_codec_on("forward", HOLD, *COPULA_LOSS), "gaussian_copula-correlated loss on the forward"),
    # the arm loop's own limits hold with a codec too
    ([*_codec_on("forward", HOLD), "master.period_s=0.002"], "master: its own period 0.002 s"),
]


@pytest.mark.parametrize(("overrides", "reason"), REFUSED)
def test_arm_codec_scenes_the_compiled_loop_cannot_run_say_why(overrides: list[str], reason: str) -> None:
    scene = _scene(["scene.duration_s=0.05", *overrides])
    e = Engine(scene)
    try:
        assert e.loop_kind == "python" and reason in (e.compiled_reason or "")
    finally:
        e.close_plants()
    with pytest.raises(HapticTeleopError, match=re.escape(reason)):
        Engine(scene, loop="compiled")


def test_loop_compiled_refusal_on_the_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`run --loop compiled` on an arm scene whose codec the kernel cannot run: exit 2, one line."""
    argv = ["run", SCENE, "--loop", "compiled", "--out", str(tmp_path / "o"), "--quiet"]
    argv += ["--set", "scene.duration_s=0.05", "--set", "network.backward.codec={kind: fec}"]
    argv += ["--set", "network.backward.effects.delay.jitter_s=0.002"]
    code = main(argv)
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err
    assert "--loop compiled" in lines[0] and "effect delay (Delay) on the backward link with a codec" in lines[0]


# The EBA with a coarse deadband both ways on the arm (p = 40 %, the forward one extrapolating)
# over bursty loss and 100 ms each way, pressing the table: both sides stay passive, judged from
# the recorded bag's plant signals (test/test_hard_cases_arm.py's measure), run compiled.
GE_BURSTY = "{model: gilbert_elliott, p: 0.02, r: 0.16, one_minus_h: 0.9, one_minus_k: 0.0}"
EBA_CASE = (
    "scene.duration_s=2.0",
    *MOVING,
    "network.forward.codec={kind: deadband, deadband: 0.4, reconstruction: extrapolate}",
    "network.backward.codec={kind: deadband, deadband: 0.4}",
    *(f"network.{d}.effects.{k}" for d in ("forward", "backward") for k in ("delay.delay_s=0.1", f"loss={GE_BURSTY}")),
    *(f"controllers.{s}.{k}" for s in ("master", "slave") for k in ("stiffness_n_per_m=20000", "damping_n_s_per_m=5")),
)


def test_eba_keeps_both_arms_passive_with_a_deadband_compiled(tmp_path: Path) -> None:
    scene = _scene(list(EBA_CASE))
    bag = tmp_path / "bag"
    engine, timing = record_run(scene, bag, parallel=False, handle_sigint=False, keep=True)
    assert engine.loop_kind == "compiled" and not timing.interrupted
    s = summarize_bag(bag)
    assert s["all_finite"] and s["ticks"] == engine.ticks
    assert np.abs(engine.data[:, engine.schema.group("s_contact_n")]).max() > 1.0
    for d in ("forward", "backward"):  # the deadband held most samples back, the link lost some of the rest
        assert s[f"packets_lost_{d}"] > 0 and s[f"codec_packet_reduction_{d}"] > 0.5
    for side, plant in (("master", engine.master), ("slave", engine.slave)):
        assert s[f"{side}_energy_margin_simulator_min_j"] >= 0.0, side
        e0 = getattr(scene.config.controllers, side).eba.initial_energy_j
        m = energy_margins(
            engine.data[:, engine.schema.group(f"{side[0]}_q")],
            engine.data[:, engine.schema.group(f"{side[0]}_tau_nm")],
            plant.joint_damping(),
            engine.period_s,
            e0,
        )
        assert m.pooled_min_j == pytest.approx(s[f"{side}_energy_margin_simulator_min_j"], abs=1e-9)


def test_codec_less_arm_runs_never_load_the_arm_codec_kernel() -> None:
    """A codec-less arm scene compiled loads the arm kernel only (its own process: nothing loaded
    before)."""
    code = (
        "import sys\n"
        "from haptic_teleop.engine.lockstep import Engine\n"
        "from haptic_teleop.scene.load import find_scene, load_scene\n"
        f"e = Engine(load_scene(find_scene({SCENE!r}), overrides=['scene.duration_s=0.05']), loop='compiled')\n"
        "e.run(handle_sigint=False)\n"
        "print(sorted(m for m in sys.modules if m.startswith('haptic_teleop.engine.') and 'kernel' in m))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=True)
    loaded = r.stdout.strip().splitlines()[-1]
    assert "haptic_teleop.engine.compiled.arm_kernel" in loaded and "arm_codec_kernel" not in loaded, loaded
