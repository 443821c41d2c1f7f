"""The codec stage live (docs/live_network.md, "Codecs live"): real node processes over real DDS, each
compared with `haptic-teleop run` of the same scene and seed where that is meaningful.

Two launches of 3 s of scene time (one process per node): a deadband on both directions of the
default scene, and ARQ on the forward direction over links that lose 20 % each way. No rate or
duration is asserted; live timing differs from the engine's lockstep (ticks can run late, the
operator's hand reaches the master over DDS, the relay stamps a packet when it takes it), so live
and engine figures are compared within generous bands only.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from launched import CLI, Launch
from sent_velocities import check_sent_velocities

DURATION_S = 3.0
TICKS = 3000
DEADBAND = ("--set", "network.forward.codec.kind=deadband", "--set", "network.backward.codec.kind=deadband")
# ARQ forward over 20 % loss each way (the acknowledgements cross the backward effects), delays of
# 10 ms so a retransmission after mu = 30 ms is still within the decoder's history.
ARQ = (
    "--set", "network.forward.codec.kind=arq",
    "--set", "network.forward.codec.timeout_s=0.03",
    "--set", "network.forward.codec.max_retransmissions=2",
    "--set", "network.forward.effects.delay.delay_s=0.01",
    "--set", "network.backward.effects.delay.delay_s=0.01",
    "--set", "network.forward.effects.loss.probability=0.2",
    # backward: a Gilbert channel losing 20 % in bursts (p / (p + r)), with HLI on that direction,
    # so one launch runs both (the acknowledgements cross it too)
    "--set", "network.backward.effects.loss={model: gilbert, p: 0.05, r: 0.2}",
    "--set", "network.backward.codec.kind=hli",
)  # fmt: skip
NODES = ("operator_source", "master_eba", "slave_eba", "forward_relay", "forward_buffer", "backward_relay",
         "backward_buffer", "recorder")  # fmt: skip


def _engine(tmp: Path, sets: tuple[str, ...], scene: str = "wall_contact", duration_s: float = DURATION_S) -> dict:
    out = tmp / "engine"
    r = subprocess.run(
        [*CLI, "run", scene, "--set", f"scene.duration_s={duration_s}", *sets, "--out", str(out),
         "--no-plots", "--quiet"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    return _result(out, one_axis=scene == "wall_contact")


def _result(out: Path, one_axis: bool = True) -> dict:
    from haptic_teleop.analysis.metrics import read_run_info
    from haptic_teleop.record.reader import BagReader

    with BagReader(out / "bag") as r:
        info = read_run_info(r)
        packets = {d: r.packets(f"/{d}/packets") for d in ("forward", "backward")}
        master_force = np.asarray(r.read("/master/joint_states").field("effort")) if one_axis else None
    summary = json.loads((out / "summary.json").read_text())
    return {"info": info, "packets": packets, "master_force": master_force, "summary": summary}


def _live(
    tmp: Path,
    sets: tuple[str, ...],
    interrupt_after_s: float | None = None,
    scene: str = "wall_contact",
    duration_s: float = DURATION_S,
) -> dict:
    """A live run of `duration_s`; or (`interrupt_after_s`) of 60 s, stopped by SIGINT (Ctrl-C)
    once the nodes' clock is that far past scene time 0."""
    out = tmp / "live"
    duration = duration_s if interrupt_after_s is None else 60.0
    launch = Launch(scene, "--duration", str(duration), "--record", str(out), "--no-plots", *sets,
                    cwd=tmp)  # fmt: skip
    if interrupt_after_s is None and _dds_failure_at_start(launch):
        # DDS failing before scene time 0 (docs/live_launch.md, "Native crashes at start"): a node
        # crashed in Fast DDS 3.2 (a CI run saw backward_relay's create_publisher die with SIGSEGV),
        # or a link carried nothing until the operator's start timeout (a CI run saw the backward
        # link silent for 30 s, every loop ticking). Not what this module tests: start again in
        # another domain, which is what a user would do; the first launch's end is printed.
        print("first launch failed before scene time 0, started again in another domain:\n" + launch.failure)
        shutil.rmtree(out, ignore_errors=True)
        env = {**os.environ, "ROS_DOMAIN_ID": str(1 + (int(os.environ.get("ROS_DOMAIN_ID", "0")) + 50) % 100)}
        launch = Launch(scene, "--duration", str(duration), "--record", str(out), "--no-plots", *sets,
                        cwd=tmp, env=env)  # fmt: skip
    if interrupt_after_s is not None:
        stamp0 = int(launch.wait_for(r"scene time 0 at stamp (\d+) ns", 60).group(1))
        while time.time_ns() < stamp0 + interrupt_after_s * 1e9 and launch.proc.poll() is None:
            time.sleep(0.05)
        launch.proc.send_signal(signal.SIGINT)
    code = launch.finish(180)
    res = _result(out, one_axis=scene == "wall_contact") if (out / "summary.json").is_file() else {}
    return {"code": code, "launch": launch, "out": out, **res}


def _dds_failure_at_start(launch: Launch) -> bool:
    """Whether the launch ended before scene time 0 because a node crashed in native code or the
    graph never came up (the launcher's and the operator source's own lines say so); waits for the
    launch to end."""
    launch.finish(180)
    failed = "a node crashed in native code" in launch.text or "node graph was not up within" in launch.text
    return failed and "scene time 0 at stamp" not in launch.text


@pytest.fixture(scope="module")
def deadband_runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("codec_deadband")
    return {"live": _live(tmp, DEADBAND), "engine": _engine(tmp, DEADBAND)}


@pytest.fixture(scope="module")
def arq_run(tmp_path_factory):
    return _live(tmp_path_factory.mktemp("codec_arq"), ARQ, interrupt_after_s=DURATION_S + 0.5)


@pytest.fixture(scope="module")
def arm_runs(tmp_path_factory):
    """touch_ur5e_wall (a 3-axis task, the arms in MuJoCo) with a deadband both ways, 2 s."""
    tmp = tmp_path_factory.mktemp("codec_arm")
    return {
        "live": _live(tmp, DEADBAND, scene="touch_ur5e_wall", duration_s=2.0),
        "engine": _engine(tmp, DEADBAND, scene="touch_ur5e_wall", duration_s=2.0),
    }


def _bag_holds(run: dict, topic: str) -> bool:
    """Whether the live bag holds `topic`'s samples at 90 % of its ticks or more (the recorder
    counts the rows it held over for want of a sample: `samples_filled`). On a 2-core machine with
    two busy loops beside the launch the recorder got 334 of 2,000 operator samples of an arm run,
    and the bag is mostly held rows; what the physics did is checked only where the bag saw it."""
    filled = run["info"]["samples_filled"][topic]
    ticks = run["summary"]["ticks"]
    print(f"{topic}: {filled} of {ticks} rows held over")
    return bool(filled <= 0.1 * ticks)


def _reduction(facts: dict) -> float:
    """A live direction's packet reduction from its encoder's own counters (the samples it was
    offered, the packets it sent), which do not depend on the packet records reaching the bag."""
    return 1.0 - facts["encoder_sent"] / facts["encoder_offered"]


def _records_came(rows: np.ndarray, facts: dict) -> bool:
    """Whether the bag holds most of a direction's packet records (at least half of the packets its
    encoder sent). On a busy 2-core machine a recorder sometimes gets none of one relay's batches
    (docs/live_network.md, "Packet records on a busy machine"); the bag says so (its packet records fewer
    than the encoder's count in the run facts), and the checks on the records are made where they
    came."""
    came = rows.shape[0] >= 0.5 * facts["encoder_sent"]
    print(f"packet records: {rows.shape[0]} for {facts['encoder_sent']} packets sent")
    return bool(came)


def _clean_exit(run: dict, nodes: tuple[str, ...], code: int = 0) -> None:
    launch = run["launch"]
    assert run["code"] == code, launch.failure
    codes = launch.exit_codes()
    assert {n: codes.get(n) for n in nodes} == dict.fromkeys(nodes, 0), launch.failure
    assert "Traceback" not in launch.text


def test_live_deadband_runs_and_records_only_the_encoders_packets(deadband_runs):
    """Every process exits 0; each direction's packet records are the encoder's packets: one per
    sample the encoder sent in the scene's window (its own counter, from the sending node), at
    most one per tick, far fewer than the ticks; no ack relay without ARQ."""
    live = deadband_runs["live"]
    print(live["launch"].loop_table())
    _clean_exit(live, NODES)
    assert "ack_relay" not in live["launch"].text
    ticks = live["summary"]["ticks"]
    assert ticks >= TICKS - 20
    for d in ("forward", "backward"):
        rows = live["packets"][d]
        facts = live["info"][f"codec_{d}"]
        assert facts["kind"] == "deadband"
        # Every tick of the window the sending node's loop ran (a loop far behind skips ticks: the
        # loop table counts them) went to the encoder.
        assert 0.5 * TICKS < facts["encoder_offered"] <= TICKS, facts
        sent = facts["encoder_sent"]
        assert sent + facts["encoder_filtered"] == facts["encoder_offered"]
        # The recorder writes the records of the ticks it wrote (a few short of the duration at most),
        # all of them where the relay's batches came (`_records_came`).
        assert "counters_not_final" not in facts, facts  # the recorder waited for the nodes' last counters
        assert rows.shape[0] <= sent, (d, rows.shape[0], sent)
        if _records_came(rows, facts):
            # the relay's batch in flight as the recorder closes may miss it, and on a busy machine a
            # reliable batch can be lost (docs/live_network.md, "Packet records on a busy machine";
            # CI 2026-12-03: 857 of 905, one batch and a half short): two batches' worth, 0.2 s
            last_batches = 0.2 / DURATION_S * sent
            assert sent - (TICKS - ticks) - 1 - last_batches <= rows.shape[0], (d, rows.shape[0], sent, ticks)
        seq = rows[:, 0]
        assert np.unique(seq).size == seq.size, "a deadband sends at most one packet per tick"
        assert 0 < sent < 0.6 * ticks, (d, sent)
        assert np.all(rows[:, 5] == 72.0 if d == "forward" else rows[:, 5] == 84.0)  # the engine's message_bytes


def test_live_deadband_reduction_is_near_the_engines(deadband_runs):
    """Packet reduction per direction, live vs `haptic-teleop run` of the same scene and seed. Not
    equal: the deadband fires on the velocity (and the force backward), and live the trajectories
    differ (ticks run late, the hand force reaches the master over DDS, the first packet before
    scene time 0 is not in the window), so how close they come is the machine's (printed: within
    0.02 on a quiet machine and with two busy loops, 0.12 once in a full CI run): physics is
    asserted in lockstep only. Live, the deadband must filter at all, and the summary must count
    the packets the bag holds."""
    live, eng = deadband_runs["live"]["summary"], deadband_runs["engine"]["summary"]
    for d in ("forward", "backward"):
        a, b = _reduction(deadband_runs["live"]["info"][f"codec_{d}"]), eng[f"codec_packet_reduction_{d}"]
        print(f"{d}: packet reduction live {a:.3f}, engine {b:.3f}, difference {a - b:+.3f}")
        assert b > 0.5, (d, b)  # the deadband does reduce in this scene
        assert a > 0.3, (d, a, b)  # and live it filters too
        assert live[f"codec_packets_{d}"] == deadband_runs["live"]["packets"][d].shape[0]


def test_live_summary_has_the_engines_codec_keys(deadband_runs):
    live, eng = deadband_runs["live"], deadband_runs["engine"]
    keys = {k for k in eng["summary"] if k.startswith("codec_")}
    assert keys and keys == {k for k in live["summary"] if k.startswith("codec_")}
    for key in ("codec_plain_bytes",):
        assert live["info"][key] == eng["info"][key]
    for d in ("forward", "backward"):
        assert set(live["info"][f"codec_{d}"]) >= set(eng["info"][f"codec_{d}"])
        assert np.isfinite(live["summary"][f"codec_wire_bits_per_s_{d}"])


def test_live_deadband_master_still_feels_the_wall(deadband_runs):
    """The slave's contact force comes back through the backward deadband: the master renders a
    force against the push, as the engine's does."""
    live, eng = deadband_runs["live"], deadband_runs["engine"]
    assert eng["master_force"].min() < -1.0
    if _bag_holds(live, "/master/joint_states"):
        assert live["master_force"].min() < -1.0, live["master_force"].min()
    if _bag_holds(live, "/slave/contact_wrench"):
        assert live["summary"]["contact_force_max_n"] > 1.0


def test_live_arq_retransmits_over_a_lossy_link_and_the_ack_relay_carries_the_acks(arq_run):
    """ARQ forward over 20 % loss each way, stopped by Ctrl-C (SIGINT): every process, the ack
    relay (its own process, the backward effects) included, exits 0 and the launch 130; the bag is
    closed and readable with the codec's run facts. The encoder retransmits what was not
    acknowledged, the decoder recovers samples from retransmissions and acknowledges every packet;
    some acknowledgements are lost on the way back (the reverse direction's loss), so fewer arrive
    at the encoder than were sent."""
    _clean_exit(arq_run, (*NODES, "forward_ack_relay"), code=130)
    text = arq_run["launch"].text
    assert "forward_ack_relay" in text and "backward_ack_relay" not in text
    f = arq_run["info"]["codec_forward"]
    print({k: v for k, v in f.items()})
    assert f["kind"] == "arq" and "counters_missing" not in f and "counters_not_final" not in f
    s = arq_run["summary"]
    assert s["interrupted"] is True and s["ticks"] >= 0.5 * TICKS
    # Interrupted: the counters run to each node's stop, the bag to the last tick every stream reached
    # (a stream far behind is held at its last value: counted as filled); the encoder gets every
    # tick the master's loop ran (a loop far behind skips ticks: counted).
    skipped = arq_run["launch"].loop_row("master_eba")[2]
    held = arq_run["info"]["samples_filled"]["/master/joint_states"]
    assert f["encoder_samples"] + skipped + held >= 0.9 * s["ticks"], (f, s["ticks"], skipped, held)
    assert f["encoder_retransmitted"] > 0.05 * f["encoder_samples"], f
    assert f["encoder_sent"] == f["encoder_samples"] + f["encoder_retransmitted"]
    assert f["decoder_recovered"] > 0, f
    assert f["ack_packets"] == f["decoder_acks_sent"] == f["decoder_received"] > 0
    assert f["ack_bytes"] == 60 * f["ack_packets"]  # message_bytes(1): one name, position only
    # (the reverse link loses 20 %; on a busy machine more never reach a master that stopped first)
    assert 0 < f["encoder_acked"] + f["encoder_acks_stale"] < f["ack_packets"], f
    rows = arq_run["packets"]["forward"]
    orig = rows[rows[:, 4] == 0.0]
    if _records_came(rows, f):
        _, counts = np.unique(orig[:, 0], return_counts=True)
        assert np.any(counts > 1), "no retransmission in the packet records"
        lost = np.count_nonzero(orig[:, 3] != 0.0)
        assert 0.1 < lost / orig.shape[0] < 0.3, lost / orig.shape[0]  # the forward link's 20 %
    assert s["codec_ack_packets_backward"] == f["ack_packets"]  # counted in the direction they travel
    assert s["codec_packets_forward"] == orig.shape[0] <= f["encoder_sent"]


def test_live_hli_sends_the_engines_hli_messages_and_rebuilds(arq_run):
    """HLI on the backward direction (the ARQ run's, over a Gilbert channel losing 20 % in bursts):
    its packets are HLI's own messages, of the
    engine's sizes by class (core/hli_codec.hli_message_bytes: HLI2 and HLI1 packets of a
    3-value sample), HLI0 samples are never sent, and the decoder rebuilds lost HLI2 events from
    the followers that came through; summary.json names the codec and its reduction."""
    from haptic_teleop.core.hli_codec import HLI1, HLI2, hli_message_bytes

    _clean_exit(arq_run, (*NODES, "forward_ack_relay"), code=130)
    f = arq_run["info"]["codec_backward"]
    print(f)
    assert f["kind"] == "hli" and "counters_missing" not in f and "counters_not_final" not in f
    assert f["encoder_hli0"] > 0 and f["encoder_hli2"] > 0 and f["encoder_hli1"] > 0
    assert f["encoder_sent"] == f["encoder_hli2"] + f["encoder_hli1"] - f["encoder_filtered_hli1"]
    assert f["decoder_received"] < f["encoder_sent"]  # the Gilbert channel lost some
    # A rebuild needs the followers of a lost HLI2 event in time; on a busy machine most packets
    # may reach the decoder after their tick (its `late` counter): 1,128 late of 1,204 seen.
    assert f["decoder_rebuilt"] > 0 or f["decoder_late"] > 0.5 * f["decoder_received"], f
    rows = arq_run["packets"]["backward"]
    sizes = set(np.unique(rows[:, 5]).tolist())
    hli_sizes = {hli_message_bytes(3, HLI2), hli_message_bytes(3, HLI1)}
    assert sizes <= hli_sizes, sizes  # never a plain sample's size, never an HLI0 packet
    if _records_came(rows, f):
        assert sizes == hli_sizes, sizes
    s = arq_run["summary"]
    # The backward wire also carries the forward ARQ's acknowledgements (codec_ack_packets_backward,
    # in its packet reduction): HLI's own packets are fewer than the samples.
    assert s["codec_kind_backward"] == "hli" and s["codec_packets_backward"] == rows[rows[:, 4] == 0.0].shape[0]
    assert s["codec_packets_backward"] < 0.8 * s["codec_samples_backward"]


def test_live_arm_deadband_sends_the_engines_arm_messages_and_reduces_as_the_engine(arm_runs):
    """An arm scene: the encoders in the arm ticks, the arm's codec message (one name per task
    axis: the plain arm packet's size for the plain payloads), the packet reduction (the encoder's
    own counters) within 0.3 of the engine's, the contact force comes back. The band is wider than
    the one-axis case's: the forward deadband fires on the handle's 3-D velocity, which the
    operator's hand force, reaching the master over DDS a tick early or late, perturbs more (live
    0.69-0.74 forward against the engine's 0.81 in four runs on an idle machine, 0.60 with two busy
    loops beside the launch; backward 0.78-0.80 against 0.77)."""
    live, eng = arm_runs["live"], arm_runs["engine"]
    print(live["launch"].loop_table())
    _clean_exit(live, NODES)
    assert live["info"]["codec_plain_bytes"] == eng["info"]["codec_plain_bytes"]
    for d in ("forward", "backward"):
        rows = live["packets"][d]
        facts = live["info"][f"codec_{d}"]
        assert rows.shape[0] <= facts["encoder_sent"] < 0.6 * facts["encoder_offered"], (d, facts)
        assert np.unique(rows[:, 0]).size == rows.shape[0]
        assert np.all(rows[:, 5] == live["info"]["codec_plain_bytes"][d])  # 6 and 9 values: the plain arm packet
        assert set(np.unique(eng["packets"][d][:, 5])) == {live["info"]["codec_plain_bytes"][d]}
        a, b = _reduction(facts), eng["summary"][f"codec_packet_reduction_{d}"]
        print(f"arm {d}: packet reduction live {a:.3f}, engine {b:.3f}")
        assert b > 0.5 and a > 0.5 and abs(a - b) <= 0.3, (d, a, b)
    assert eng["summary"]["contact_force_max_n"] > 1.0
    if _bag_holds(live, "/slave/contact_wrench"):
        assert live["summary"]["contact_force_max_n"] > 0.5 * eng["summary"]["contact_force_max_n"]


def test_live_arm_codec_bag_records_the_sent_velocities(arm_runs):
    """With a codec on both directions /<dir>/sent carries the encoder's packets, not a sample per
    tick: the arm sides publish their tick's sample on /<dir>/sample, and the bag's sent rows get
    the handle's and the tool's velocities from it (they were 0.0 on every row before)."""
    live = arm_runs["live"]
    assert live["code"] == 0, live["launch"].failure
    check_sent_velocities(live["out"], {"forward": "/forward/sample", "backward": "/backward/sample"})


def test_codec_wire_message_is_the_engines_size_and_round_trips():
    """The live wire message of a codec payload of F values is exactly
    assembly.channel.message_bytes(F) bytes (an arm scene's: assembly.side.arm_message_bytes(F))
    and decodes to the payload and the stamp."""
    from haptic_teleop.assembly.channel import message_bytes
    from haptic_teleop.assembly.side import arm_message_bytes
    from haptic_teleop.nodes.codec_stage import CodecWire

    rng = np.random.default_rng(3)
    for arm, size_of in ((False, message_bytes), (True, arm_message_bytes)):
        wire = CodecWire(arm)
        for f in range(1, 19):
            payload = tuple(rng.normal(size=f).tolist())
            raw = wire.encode(1_795_000_000_123_000_000, payload)
            assert len(raw) == size_of(f), (arm, f, len(raw), size_of(f))
            assert wire.decode(raw) == (1_795_000_000_123_000_000, payload)
    # HLI's own message: (x..., class, offset, previous x...[, HLI2 copy...]) of d-value samples
    from haptic_teleop.core.hli_codec import HLI1, HLI2, hli_message_bytes

    for arm in (False, True):
        for d in (2, 3, 6, 9):
            wire = CodecWire(arm, hli_dim=d)
            for cls, n in ((HLI2, 2 * d + 2), (HLI1, 3 * d + 2)):
                payload = list(rng.normal(size=n).tolist())
                payload[d], payload[d + 1] = float(cls), (0.0 if cls == HLI2 else 4.0)
                raw = wire.encode(1_795_000_000_123_000_000, payload)
                assert len(raw) == hli_message_bytes(d, cls) == wire.size_of(payload), (arm, d, cls)
                assert wire.decode(raw) == (1_795_000_000_123_000_000, tuple(payload))


def _node(module: str, *params: str) -> subprocess.CompletedProcess:
    args = [a for p in params for a in ("-p", p)]
    return subprocess.run([sys.executable, "-m", f"haptic_teleop.nodes.{module}", "--ros-args", *args],
                          capture_output=True, text=True, timeout=60)  # fmt: skip


FWD, BWD = "network.forward", "network.backward"
BAD = [
    ("network_relay", ("carries:=everything",), ("carries", "samples")),
    ("network_relay", ("direction:=alice/up", "carries:=ack"), ("direction", "forward or backward")),
    ("network_relay", ("direction:=alice/up", "nve.client_names:=[alice]", "carries:=codec"), ("carries", "teleop")),
    ("sync_buffer", ("direction:=forward", f"{FWD}.codec.kind:=zip"), (f"{FWD}.codec", "kind")),
    ("sync_buffer", ("direction:=forward", f"{FWD}.codec.kind:=deadband", f"{FWD}.codec.deadband:=-1.0"), ("in [0",)),
    ("master_eba", (f"{FWD}.codec.kind:=arq", f"{FWD}.buffer.policy:=fixed"), ("buffer.policy none",)),
    ("slave_eba", (f"{BWD}.codec.kind:=arq", f"{BWD}.codec.k:=2"), ("no key k",)),
    (
        "master_eba",
        (f"{FWD}.codec.kind:=arq", f"{FWD}.codec.ack_every_ticks:=4", f"{FWD}.buffer.policy:=none"),
        (f"{FWD}.codec.ack_every_ticks", "must be 1"),
    ),
]


@pytest.mark.parametrize(("module", "params", "names"), BAD)
def test_bad_codec_parameters_stop_the_node_with_one_line(module, params, names):
    r = _node(module, *params)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    for n in names:
        assert n in r.stderr, r.stderr


def test_launch_refuses_what_the_live_nodes_do_not_run(tmp_path):
    """A codec on an arm scene whose side runs at its own period: one line, exit 2, nothing started."""
    own = ("--set", "network.forward.codec.kind=deadband", "--set", "slave.period_s=0.002")
    r = subprocess.run([*CLI, "launch", "touch_ur5e_wall", *own], capture_output=True, text=True, timeout=60,
                       cwd=tmp_path)  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    assert "network.forward.codec" in r.stderr and "slave.period_s" in r.stderr
    assert "Traceback" not in r.stderr and "[launcher] started" not in r.stdout
