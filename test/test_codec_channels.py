"""The codec stage in teleoperation's channels (docs/codec_channels.md): scene keys,
the engine's wiring, the bag's packet records and the wire accounting in summary.json.

Run: `.venv/bin/python -m pytest -q -p no:cacheprovider test/test_codec_channels.py`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from haptic_teleop.analysis.stream import summarize_bag
from haptic_teleop.assembly.channel import message_bytes
from haptic_teleop.cli.main import main
from haptic_teleop.core.link import DEFAULT_OVERHEAD_BYTES
from haptic_teleop.engine.lockstep import COL, Engine
from haptic_teleop.engine.run import record_run
from haptic_teleop.errors import ConfigError, InputError
from haptic_teleop.record.layouts import joint_state_size
from haptic_teleop.record.reader import BagReader
from haptic_teleop.scene.load import find_scene, load_scene

# Wall contact with the operator pushing from 0.2 s, and bursty loss with 5 ms delay each way.
BASE = (
    "scene.duration_s=1.5",
    "slave.wall.position_m=0.005",
    "operator.start_s=0.2",
    "operator.speed_m_per_s=0.05",
    "operator.distance_m=0.03",
    *(
        f"network.{d}.effects.loss={{model: gilbert_elliott, p: 0.02, r: 0.3, one_minus_h: 0.9, one_minus_k: 0.001}}"
        for d in ("forward", "backward")
    ),
    *(f"network.{d}.effects.delay.delay_s=0.005" for d in ("forward", "backward")),
)


def _codec(direction: str, text: str) -> str:
    return f"network.{direction}.codec={text}"


def _record(tmp: Path, *overrides: str) -> tuple[Engine, Path]:
    scene = load_scene(find_scene("wall_contact"), overrides=[*BASE, *overrides])
    bag = tmp / "bag"
    engine, _ = record_run(scene, bag, parallel=False, handle_sigint=False, keep=True)
    return engine, bag


def _packets(bag: Path, direction: str) -> np.ndarray:
    with BagReader(bag) as r:
        blocks = list(r.packet_blocks(f"/{direction}/packets"))
    return np.concatenate(blocks) if blocks else np.zeros((0, 6))


def _run_info(bag: Path) -> dict[str, Any]:
    with BagReader(bag) as r:
        return dict(json.loads(r.string("/haptic_teleop/run_info")))


@pytest.fixture(scope="module")
def deadband_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Engine, Path, dict[str, Any]]:
    tmp = tmp_path_factory.mktemp("deadband")
    engine, bag = _record(
        tmp,
        _codec("forward", "{kind: deadband, deadband: 0.1}"),
        _codec("backward", "{kind: deadband, deadband: 0.1, reconstruction: extrapolate}"),
    )
    return engine, bag, summarize_bag(bag)


def test_deadband_forward_packets_are_the_encoders(deadband_run: tuple[Engine, Path, dict[str, Any]]) -> None:
    engine, bag, summary = deadband_run
    fwd = engine.codecs[0]
    assert fwd is not None
    rows = _packets(bag, "forward")
    originals = rows[rows[:, 4] == 0.0]
    sent = fwd.encoder.counters["sent"]
    # Filtered samples send nothing: far fewer packets than ticks, and every one in the bag.
    assert 0 < sent < 0.5 * engine.ticks_done
    assert len(originals) == sent == summary["codec_packets_forward"]
    assert fwd.encoder.counters["offered"] == engine.ticks_done
    # The rule by hand on the master's recorded (x, v): forward, the deadband's threshold applies
    # to the velocity (seed 001's velocity stream): send when |v - v_sent| > p |v_sent|; the
    # bag's records are at exactly those ticks (seq = tick, send time = tick * T).
    data = engine.data
    T = engine.period_s
    mine: list[int] = []
    v_sent = None
    for n in range(engine.ticks_done):
        v = data[n, COL["m_v_m_per_s"]]
        if v_sent is None or abs(v - v_sent) > 0.1 * abs(v_sent):
            mine.append(n)
            v_sent = v
    assert originals[:, 0].astype(int).tolist() == mine
    np.testing.assert_allclose(originals[:, 1], np.array(mine) * T, rtol=0, atol=1e-12)
    assert set(originals[:, 5].tolist()) == {float(joint_state_size(2))}  # the plain JointState


def test_the_summary_reduction_matches_the_counts(deadband_run: tuple[Engine, Path, dict[str, Any]]) -> None:
    engine, bag, s = deadband_run
    ticks = engine.ticks_done
    duration = ticks * engine.period_s
    for d, floats in (("forward", 2), ("backward", 3)):
        rows = _packets(bag, d)
        orig = rows[rows[:, 4] == 0.0]
        n = len(orig)
        bits = 8.0 * float(np.sum(orig[:, 5] + DEFAULT_OVERHEAD_BYTES))
        plain = 8.0 * ticks * (joint_state_size(floats) + DEFAULT_OVERHEAD_BYTES)
        assert s[f"codec_kind_{d}"] == "deadband"
        assert s[f"codec_samples_{d}"] == ticks
        assert s[f"codec_packets_{d}"] == n
        assert s[f"codec_ack_packets_{d}"] == 0
        assert s[f"codec_wire_packets_per_s_{d}"] == pytest.approx(n / duration)
        assert s[f"codec_wire_bits_per_s_{d}"] == pytest.approx(bits / duration)
        assert s[f"codec_plain_wire_bits_per_s_{d}"] == pytest.approx(plain / duration)
        assert s[f"codec_packet_reduction_{d}"] == pytest.approx(1.0 - n / ticks)
        assert s[f"codec_bit_reduction_{d}"] == pytest.approx(1.0 - bits / plain)
        assert s[f"codec_packet_reduction_{d}"] > 0.5


def test_the_controller_gets_the_decoders_sample(deadband_run: tuple[Engine, Path, dict[str, Any]]) -> None:
    """The received column holds the newest arrival's seq on the ticks one arrived; between
    arrivals nothing new comes (the decoder holds): as many arrivals as packets delivered."""
    engine, bag, _ = deadband_run
    rows = _packets(bag, "forward")
    last_tick_s = (engine.ticks_done - 1) * engine.period_s
    delivered = rows[(rows[:, 3] == 0.0) & (rows[:, 4] == 0.0) & (rows[:, 2] <= last_tick_s + 1e-12)]
    rx = engine.data[:, COL["fwd_rx_seq"]]
    got = rx[rx >= 0]
    assert np.all(np.diff(got) > 0)  # newest only, in order
    assert set(got.astype(int).tolist()) <= set(delivered[:, 0].astype(int).tolist())
    assert len(got) == len(delivered)  # constant delay: every delivered packet is the newest
    assert np.all(engine.data[:, COL["fwd_occupancy"]] == 0.0)


@pytest.mark.parametrize("every", [1, 4])
def test_arq_acknowledgements_count_in_the_reverse_direction(tmp_path: Path, every: int) -> None:
    arq = f"{{kind: arq, timeout_s: 0.02, max_retransmissions: 2, ack_every_ticks: {every}}}"
    engine, bag = _record(tmp_path, _codec("forward", arq))
    s = summarize_bag(bag)
    info = _run_info(bag)["codec_forward"]
    fwd = engine.codecs[0]
    assert fwd is not None and engine.codecs[1] is None
    acks = fwd.ack_packets
    assert acks == info["ack_packets"] == info["decoder_acks_sent"] > 0
    # each ACK's message is its payload's: k = 1 (seq,); k > 1 (newest, bitmap): the retransmissions
    # arrive 25 ticks after their original's slot, inside the 52-seq window, so none is named below it
    if every == 1:
        assert acks > engine.ticks_done and info["ack_bytes"] == acks * message_bytes(1)
    else:
        assert acks <= engine.ticks_done // every + 1 and info["ack_bytes"] == acks * message_bytes(2)
    # Retransmissions are in the forward records (same seq again), ACKs only in the counts.
    rows = _packets(bag, "forward")
    orig = rows[rows[:, 4] == 0.0]
    assert len(orig) == fwd.encoder.counters["sent"] == engine.ticks_done + fwd.encoder.counters["retransmitted"]
    assert fwd.encoder.counters["retransmitted"] > 0
    assert s["codec_packets_forward"] == len(orig)
    assert s["codec_ack_packets_backward"] == acks and s["codec_ack_packets_forward"] == 0
    ticks = engine.ticks_done
    brows = _packets(bag, "backward")
    borig = brows[brows[:, 4] == 0.0]
    assert len(borig) == ticks  # the backward direction runs without a codec: one packet a tick
    ack_bits = 8.0 * (info["ack_bytes"] + acks * DEFAULT_OVERHEAD_BYTES)
    bits = 8.0 * float(np.sum(borig[:, 5] + DEFAULT_OVERHEAD_BYTES)) + ack_bits
    assert s["codec_kind_backward"] == "none"
    assert s["codec_wire_bits_per_s_backward"] == pytest.approx(bits / (ticks * engine.period_s))
    assert s["codec_packet_reduction_backward"] == pytest.approx(1.0 - (ticks + acks) / ticks)


def test_codec_less_runs_keep_their_summary_keys_and_yaml(tmp_path: Path) -> None:
    scene = load_scene(find_scene("wall_contact"), overrides=["scene.duration_s=0.2"])
    assert "codec" not in scene.to_yaml()
    bag = tmp_path / "bag"
    record_run(scene, bag, parallel=False, handle_sigint=False)
    assert not [k for k in summarize_bag(bag) if k.startswith("codec_")]
    withc = load_scene(
        find_scene("wall_contact"), overrides=["scene.duration_s=0.2", _codec("backward", "{kind: fec, k: 3}")]
    )
    text = withc.to_yaml()
    assert "codec:\n      kind: fec\n      k: 3\n" in text and "null" not in text.split("codec:")[1].split("buffer")[0]


def _one_line(err: str) -> str:
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.parametrize(
    ("codec", "expect"),
    [
        ("{kind: zip}", "allowed: one of deadband, hli, prediction, fec, arq"),
        ("{kind: deadband, k: 2}", "codec 'deadband' has no key k"),
        ("{kind: deadband, deadband: 1.5}", "deadband must be in [0.0, 1.0]"),
        ("{kind: fec, scheme: xor}", "scheme must be one of repetition, parity"),
        ("{kind: arq, timeout_s: 0}", "timeout_s must be > 0.0"),
        ("{kind: hli}", "codec hli needs this direction's effects.loss to be a gilbert"),
        ("{kind: hli, p: 0.1}", "network.forward.codec.p = 0.1: unknown key"),
        ("{kind: deadband, deadbnd: 0.1}", "unknown key"),
    ],
)
def test_bad_codec_keys_exit_2_with_one_line(capsys: pytest.CaptureFixture[str], codec: str, expect: str) -> None:
    code = main(["run", "wall_contact", "--dry-run", "--set", _codec("forward", codec)])
    line = _one_line(capsys.readouterr().err)
    assert code == 2 and expect in line and "network.forward.codec" in line, line


def test_a_codec_needs_buffer_policy_none(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["run", "wall_contact", "--dry-run", "--set", _codec("backward", "{kind: prediction}")]
    code = main([*argv, "--set", "network.backward.buffer.policy=fixed"])
    line = _one_line(capsys.readouterr().err)
    assert code == 2 and "needs buffer.policy none" in line
    assert main(argv) == 0


def test_arm_scene_runs_codecs_in_the_python_loop(tmp_path: Path) -> None:
    """The arm loop: forward deadband on the handle's velocity (3-D), backward FEC; the bag's
    records are the encoders' packets and the plain reference is the arm's JointState."""
    from haptic_teleop.assembly.side import wire_payload_bytes

    overrides = [
        "scene.duration_s=1.5",
        _codec("forward", "{kind: deadband, deadband: 0.1}"),
        _codec("backward", "{kind: fec, k: 1}"),
    ]
    scene = load_scene(find_scene("touch_ur5e_wall"), overrides=overrides)
    bag = tmp_path / "bag"
    # (the compiled arm loop gives the same run: test/test_compiled_arm_codec.py)
    engine, _ = record_run(scene, bag, parallel=False, handle_sigint=False, loop="python", keep=True)
    assert engine.loop_kind == "python"
    s = summarize_bag(bag)
    # The slave follows the decoded handle: the tool goes down toward the table with the handle.
    g = engine.schema.group
    z_handle, z_tool = engine.data[:, g("m_x_m")][:, 2], engine.data[:, g("s_x_m")][:, 2]
    assert z_handle[0] - z_handle[-1] > 0.005 and z_tool[0] - z_tool[-1] > 0.5 * (z_handle[0] - z_handle[-1])
    fwd, bwd = engine.codecs
    assert fwd is not None and bwd is not None
    ticks = engine.ticks_done
    sent = fwd.encoder.counters["sent"]
    assert 0 < sent < ticks and s["codec_packets_forward"] == sent == len(_packets(bag, "forward"))
    assert s["codec_packets_backward"] == ticks == len(_packets(bag, "backward"))
    for d, fields in (("forward", 2), ("backward", 3)):
        plain = 8.0 * (wire_payload_bytes(3, fields) + DEFAULT_OVERHEAD_BYTES) / engine.period_s
        assert s[f"codec_plain_wire_bits_per_s_{d}"] == pytest.approx(plain)
    # Each FEC packet carries the sample (9 values) and the previous one: 18 values, 6 names.
    fec_bytes = set(_packets(bag, "backward")[:, 5].tolist())
    assert fec_bytes == {float(wire_payload_bytes(6, 3))}
    assert s["codec_packet_reduction_forward"] == pytest.approx(1.0 - sent / ticks)
    for side in ("master", "slave"):
        assert s[f"{side}_energy_margin_min_j"] >= -1e-9
    assert s["all_finite"]


def test_compiled_loop_is_refused_and_auto_runs_python(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    pytest.importorskip("numba")
    jittery = [_codec("forward", "{kind: prediction}"), "network.forward.effects.delay.jitter_s=0.002"]
    scene = load_scene(find_scene("wall_contact"), overrides=["scene.duration_s=0.1", *jittery])
    with pytest.raises(InputError, match=r"effect delay \(Delay\) on the forward link with a codec"):
        Engine(scene, loop="compiled")
    e = Engine(scene, loop="auto")
    assert e.loop_kind == "python" and "codec" in (e.compiled_reason or "")
    plain = Engine(load_scene(find_scene("wall_contact"), overrides=["scene.duration_s=0.1"]), loop="auto")
    assert plain.codecs == (None, None)
    argv = ["run", "wall_contact", "--loop", "compiled", "--out", str(tmp_path / "o")]
    code = main([*argv, "--set", "scene.duration_s=0.1", "--set", jittery[0], "--set", jittery[1]])
    line = _one_line(capsys.readouterr().err)
    assert code == 2 and "effect delay (Delay) on the forward link with a codec" in line


def test_launch_runs_the_live_codecs_and_refuses_the_others() -> None:
    """The live nodes run every codec (docs/live_network.md, "Codecs live"); a codec on an arm scene whose
    side has its own period is refused with one line."""
    from haptic_teleop.live.launcher import node_plan

    scene = load_scene(find_scene("wall_contact"), overrides=[_codec("backward", "{kind: prediction}")])
    relay = next(s for s in node_plan(scene) if s.name == "backward_relay")
    assert relay.params["carries"] == "codec"
    hli = load_scene(
        find_scene("wall_contact"),
        overrides=[
            _codec("forward", "{kind: hli}"),
            "network.forward.effects.loss={model: gilbert, p: 0.01, r: 0.5}",
        ],
    )
    assert {s.name for s in node_plan(hli)} >= {"forward_relay", "forward_buffer"}  # HLI runs live too
    arm = load_scene(find_scene("touch_ur5e_wall"), overrides=[_codec("forward", "{kind: arq}")])
    plan = {s.name: s for s in node_plan(arm)}
    assert plan["forward_ack_relay"].params["task_axes"] == 3 and plan["forward_relay"].params["carries"] == "codec"
    own = load_scene(
        find_scene("touch_ur5e_wall"), overrides=[_codec("forward", "{kind: deadband}"), "slave.period_s=0.002"]
    )
    with pytest.raises(ConfigError, match=r"network\.forward\.codec.*slave\.period_s\) runs no codec live yet"):
        node_plan(own)
    assert node_plan(load_scene(find_scene("wall_contact")))  # without one: the node set


@pytest.mark.parametrize(
    ("delay_s", "fwd", "bwd", "copies"),
    [
        # the default scene's 100 ms round trip: mu = 25 ms sends each sample 4 times, mu = 4 ms
        # with nu = 1 twice, mu = 150 ms once
        (0.05, "{kind: arq, timeout_s: 0.025, max_retransmissions: 4}", "{kind: arq, timeout_s: 0.15}", (4, 1)),
        (0.05, "{kind: arq, timeout_s: 0.15}", "{kind: arq, timeout_s: 0.004, max_retransmissions: 1}", (1, 2)),
        (0.05, "{kind: arq, timeout_s: 0.075}", None, (2, None)),  # above one way, under the round trip
        # seed 000's network (10 ms round trip): its 25 ms once, its 4 ms (nu = 1) twice
        (0.005, "{kind: arq, timeout_s: 0.025, max_retransmissions: 4}", None, (1, None)),
        (0.005, "{kind: arq, timeout_s: 0.004, max_retransmissions: 1}", None, (2, None)),
    ],
)
def test_arq_under_its_round_trip_is_named_with_the_copies_it_sends(delay_s, fwd, bwd, copies) -> None:
    """`arq_round_trip_notes` names each ARQ direction whose timeout is under its round trip with
    the copies it sends of every sample, as many as a lossless run sends (sent / samples rounded)."""
    from haptic_teleop.assembly.channel import arq_round_trip_notes

    over = ["scene.duration_s=2", *(f"network.{d}.effects.delay.delay_s={delay_s}" for d in ("forward", "backward"))]
    over += [f"network.forward.codec={fwd}"] + ([f"network.backward.codec={bwd}"] if bwd else [])
    scene = load_scene(find_scene("wall_contact"), overrides=over)
    notes = arq_round_trip_notes(scene.config)
    e = Engine(scene)
    e.run(handle_sigint=False)
    for d, n in zip(("forward", "backward"), copies, strict=True):
        if n is None:
            continue
        f = e.codec_facts()[f"codec_{d}"]
        assert round(f["encoder_sent"] / f["encoder_samples"]) == n
        said = [s for s in notes if f"on the {d} link" in s]
        assert said == ([] if n == 1 else [said[0]]) and (n == 1 or f"goes out {n} times" in said[0])
    assert len(notes) == sum(1 for n in copies if n is not None and n > 1)


def test_run_notes_arq_under_its_round_trip_unless_quiet(tmp_path: Path, capsys: Any) -> None:
    over = ["--set", "scene.duration_s=0.3", "--set", "network.forward.codec={kind: arq, timeout_s: 0.025}"]
    assert main(["run", "wall_contact", "--out", str(tmp_path / "a"), "--no-plots", *over]) == 0
    err = capsys.readouterr().err
    assert "haptic-teleop: note: ARQ on the forward link retransmits after 25 ms, under its 100 ms round trip" in err
    assert main(["run", "wall_contact", "--out", str(tmp_path / "b"), "--no-plots", "--quiet", *over]) == 0
    assert "note:" not in capsys.readouterr().err
