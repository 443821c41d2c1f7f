"""Live equals the engine: the same scene and seed run by `haptic-teleop run` and live, composed
(`launch --single-process`), give bags whose network streams are the same, stream by stream
(docs/live_network.md, "Live against the engine").

Live runs in simulated time here (`--sim-time-rate`: every node follows /clock, so a busy machine
makes the run slower, not different): physics and data paths are asserted in simulated time only.
What is compared:
- the packet records of both directions: seq, send and arrival times, fate and size of every
  packet, so the same samples were sent, lost, delivered and played or skipped;
- the released samples: at which tick the sync buffer released which sample, both directions;
- what depends on scene time only: the operator's hand position and velocity, the sent samples'
  stamps;
- the summary's network figures (packets sent, lost, late; delays; loss rates), taken from what
  was delivered.
The sides' physics are not compared: live, the operator's force at a tick answers the master's
state the tick before (the nodes exchange it on topics), in the engine the same tick.
"""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
from launched import CLI, Launch

pytest.importorskip("rclpy")

P_NS = 1_000_000
DURATION = "1.5"
CASES = {
    # The default scene: constant 50 ms each way, no loss, playout `none`.
    "constant_delay": ("wall_contact", []),
    # An arm scene (Touch master, UR5e slave), constant 50 ms each way: the arms' tick streams.
    "arm_constant_delay": ("touch_ur5e_wall", []),
    # 10 ms normal jitter (reordering: late packets), Gilbert-Elliott loss forward, playout `none`.
    "jitter_and_loss": (
        "jitter",
        [
            "network.forward.buffer.policy=none",
            "network.backward.buffer.policy=none",
            "network.forward.effects.loss.model=gilbert_elliott",
            "network.forward.effects.loss.p=0.05",
            "network.forward.effects.loss.r=0.25",
        ],
    ),
}
NET_KEYS = (
    "packets_sent_forward", "packets_lost_forward", "packets_late_forward", "packets_sent_backward",
    "packets_lost_backward", "packets_late_backward", "loss_rate_forward", "loss_rate_backward",
    "delay_forward_p50_s", "delay_backward_p50_s",
)  # fmt: skip


def _released(r, direction: str) -> np.ndarray:
    """(release tick, sample tick) of every release of a direction's buffer, in ticks from the
    bag's first row."""
    rx = r.read(f"/{direction}/received")
    t0 = r.read("/master/joint_states").log_ns[0]
    return np.column_stack(((rx.log_ns - t0) // P_NS, (rx.stamp_ns - t0) // P_NS))


@pytest.mark.parametrize("case", sorted(CASES))
def test_live_composed_bag_equals_the_engine_bag_stream_by_stream(tmp_path, case):
    from haptic_teleop.record.reader import BagReader

    scene, sets = CASES[case]
    args = [f"--set={s}" for s in sets]
    eng, live = tmp_path / "engine", tmp_path / "live"
    r = subprocess.run([*CLI, "run", scene, "--set", f"scene.duration_s={DURATION}", *args, "--out", str(eng),
                        "--no-plots", "--quiet"], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    launch = Launch(scene, "--single-process", "--duration", DURATION, "--record", str(live), "--no-plots",
                    "--sim-time-rate", "0.25", *args, cwd=tmp_path)  # fmt: skip
    assert launch.finish(600) == 0, launch.failure
    info = json.loads((live / "live_run.json").read_text())
    # Nothing reached its sync buffer after its due tick (else the streams could not be equal).
    assert info["packets_late_by_scheduling"] == {"forward": 0, "backward": 0}, launch.loop_table()
    with BagReader(eng / "bag") as e, BagReader(live / "bag") as lv:
        for d in ("forward", "backward"):
            pe, pl = e.packets(f"/{d}/packets"), lv.packets(f"/{d}/packets")
            assert pe.shape == pl.shape, d
            assert np.array_equal(pe[:, [0, 3, 4, 5]], pl[:, [0, 3, 4, 5]]), d  # seq, fate, duplicate, size
            assert np.allclose(pe[:, 1:3], pl[:, 1:3], rtol=0, atol=1e-12, equal_nan=True), d  # send, arrival
            assert np.array_equal(_released(e, d), _released(lv, d)), d
            se, sl = e.read(f"/{d}/sent").stamp_ns, lv.read(f"/{d}/sent").stamp_ns
            assert np.array_equal(se - se[0], sl - sl[0]), d
        oe, ol = e.read("/operator/joint_states").values, lv.read("/operator/joint_states").values
        assert oe.shape == ol.shape
        assert np.allclose(oe[:, :2], ol[:, :2], rtol=0, atol=1e-12)  # hand position, velocity: scene time only
    se, sl = (json.loads((p / "summary.json").read_text()) for p in (eng, live))
    assert {k: se[k] for k in NET_KEYS} == {k: sl[k] for k in NET_KEYS}
