"""1-DoF bags keep their bytes through the n-DoF recording layer.

Two code paths: the recorder's bulk encoder (record/streams.py, with the topics the tick schema
derives) against each message built on its own with rosbags' typestore from the layout the 1-DoF
bag has always had, written down literally here (topics and their order, message types, joint
names, frames, which column goes where). Every message of a real run's bag, read back with
rosbags' Reader, must have those bytes, log time and topic, in that topic order."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.record.recorder import write_run
from haptic_teleop.scene.load import find_scene, load_scene

# The 1-DoF layout as it was before the tick schema: column order, then per topic its type,
# JointState name (or frame, or labels) and columns.
LEGACY_COLUMNS = (
    "op_x_m", "op_v_m_per_s", "op_force_n",
    "m_x_m", "m_v_m_per_s", "m_force_n", "m_force_desired_n", "m_energy_j",
    "s_x_m", "s_v_m_per_s", "s_force_n", "s_force_desired_n", "s_energy_j", "s_contact_n",
    "fwd_rx_seq", "bwd_rx_seq", "fwd_occupancy", "bwd_occupancy",
)  # fmt: skip
C = {c: i for i, c in enumerate(LEGACY_COLUMNS)}
JS, WR, MA, ST = (
    "sensor_msgs/msg/JointState",
    "geometry_msgs/msg/WrenchStamped",
    "std_msgs/msg/Float64MultiArray",
    "std_msgs/msg/String",
)
TICK = [
    ("/operator/joint_states", JS, "operator_x", ("op_x_m", "op_v_m_per_s", "op_force_n")),
    ("/master/joint_states", JS, "master_x", ("m_x_m", "m_v_m_per_s", "m_force_n")),
    ("/slave/joint_states", JS, "slave_x", ("s_x_m", "s_v_m_per_s", "s_force_n")),
    ("/slave/contact_wrench", WR, "wall", ("s_contact_n",)),
    ("/master/eba", MA, ("reservoir_j", "force_desired_n"), ("m_energy_j", "m_force_desired_n")),
    ("/slave/eba", MA, ("reservoir_j", "force_desired_n"), ("s_energy_j", "s_force_desired_n")),
    ("/forward/sent", JS, "master_x", ("m_x_m", "m_v_m_per_s")),
    ("/backward/sent", JS, "slave_x", ("s_x_m", "s_v_m_per_s", "s_contact_n")),
]
RECEIVED = [("/forward/received", "fwd_rx_seq", TICK[6]), ("/backward/received", "bwd_rx_seq", TICK[7])]


def _message(ts, msgtype, name, values, stamp_ns):
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    if msgtype == JS:
        arr = [np.array([v]) for v in values] + [np.array([])] * (3 - len(values))
        hdr = t["std_msgs/msg/Header"](stamp=stamp, frame_id="")
        return t[JS](header=hdr, name=[name], position=arr[0], velocity=arr[1], effort=arr[2])
    if msgtype == WR:
        v3 = t["geometry_msgs/msg/Vector3"]
        w = t["geometry_msgs/msg/Wrench"](force=v3(x=values[0], y=0.0, z=0.0), torque=v3(x=0.0, y=0.0, z=0.0))
        return t[WR](header=t["std_msgs/msg/Header"](stamp=stamp, frame_id=name), wrench=w)
    dims = [t["std_msgs/msg/MultiArrayDimension"](label=lab, size=1, stride=1) for lab in name]
    return t[MA](layout=t["std_msgs/msg/MultiArrayLayout"](dim=dims, data_offset=0), data=np.array(values))


@pytest.mark.parametrize(
    "scene", [("wall_contact", ["scene.duration_s=1.5"]), ("bursty_loss", ["scene.duration_s=1.5"])], ids=str
)
def test_one_dof_bag_messages_keep_their_bytes(tmp_path, scene):
    name, overrides = scene
    loaded = load_scene(find_scene(name), overrides=[*overrides, "recording.eba_internals=true"])
    run = Engine(loaded).run(handle_sigint=False)
    bag = write_run(run, tmp_path / "bag", {"ticks": run.ticks})
    data = run.data[: run.ticks]
    period = run.period_ns
    ts = get_typestore(getattr(Stores, "ROS2_KILTED", Stores.LATEST))
    with Reader(bag) as r:
        topics = [(c.topic, c.msgtype) for c in r.connections]
        got: dict[str, list[tuple[int, bytes]]] = {t: [] for t, _ in topics}
        for c, t, raw in r.messages():
            got[c.topic].append((t, bytes(raw)))
    packets = [("/forward/packets", MA), ("/backward/packets", MA)] if loaded.config.recording.packets else []
    assert topics == [
        ("/haptic_teleop/scene", ST),
        *[(t, m) for t, m, _, _ in TICK],
        *[(t, JS) for t, _, _ in RECEIVED],
        *packets,
        ("/haptic_teleop/run_info", ST),
    ]
    times = np.arange(run.ticks, dtype=np.int64) * period
    for topic, msgtype, label, cols in TICK:
        msgs = got[topic]
        assert [t for t, _ in msgs] == times.tolist(), topic
        for i in range(0, run.ticks, 97):  # every 97th tick, built message by message
            values = [float(data[i, C[c]]) for c in cols]
            expect = bytes(ts.serialize_cdr(_message(ts, msgtype, label, values, int(times[i])), msgtype))
            assert msgs[i][1] == expect, (topic, i)
    for topic, seq_col, (_, msgtype, label, cols) in RECEIVED:
        released = np.flatnonzero(data[:, C[seq_col]] >= 0)
        assert released.size
        msgs = got[topic]
        assert [t for t, _ in msgs] == times[released].tolist(), topic
        for k in range(0, released.size, 89):
            i = released[k]
            src = int(data[i, C[seq_col]])
            values = [float(data[src, C[c]]) for c in cols]
            expect = bytes(ts.serialize_cdr(_message(ts, msgtype, label, values, src * period), msgtype))
            assert msgs[k][1] == expect, (topic, i)
