"""n-DoF runs without the arm engine: synthetic analytic signals (a tool moving along a line into an
oblique wall, a known contact force, constant delays, joints at constant speed) for a 3-joint
master and a 6-joint slave, written through the real RunRecorder into a real bag, read back with
BagReader and rosbags, analysed (streaming and whole-bag) and plotted."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from haptic_teleop.analysis.stream import summarize_bag
from haptic_teleop.analysis.taskmetrics import compute_task_summary, load_task_signals
from haptic_teleop.record.columns import TickSchema
from haptic_teleop.record.reader import BagReader
from haptic_teleop.record.recorder import RunRecorder

SCHEMA = TickSchema(
    ("yaw", "shoulder", "elbow"), ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"), 3
)
T = 0.001
N = 3000
DF, DB = 7, 11  # forward and backward delays (ticks)
P = np.array([0.5, 0.1, 0.3])  # wall point
NORMAL = np.array([-1.0, 0.0, -1.0]) / math.sqrt(2.0)  # out of the wall, into free space
GAP, SPEED, K = 0.02, 0.02, 500.0  # start 2 cm in front, move along -normal at 2 cm/s, wall 500 N/m
BIAS = np.array([0.1, -0.2, 0.05])  # rendered force minus the delayed contact force (N)
OFFSET = np.array([0.003, 0.0, -0.004])  # tool minus the delayed handle (m)
TORQUE = np.array([0.0, 0.25, 0.0])
RATES = {"master": np.array([0.2, -0.1, 0.3]), "slave": np.array([0.1, 0.2, -0.3, 0.4, -0.5, 0.6])}
TAUS = {"master": np.array([0.5, 0.5, 0.5]), "slave": np.array([2.0, -1.0, 1.0, 0.3, 0.3, -0.3])}
# the applied torque alternates TAUS, 2 TAUS, TAUS, ... (tick k's held over [k, k+1])


def absorbed(side: str, m: np.ndarray) -> np.ndarray:
    """Energy each port absorbed by tick m (closed form: sum over k < m of (d r^2 - s_k tau r) T,
    s_k = 1, 2, 1, 2, ...; the sum of s_k is m + m // 2): (len(m), joints)."""
    r, tau, d = RATES[side], TAUS[side], np.array(DAMPING[side])
    m = m[:, None]
    return T * r * (m * d * r - tau * (m + m // 2))


DAMPING = {"master": [0.01, 0.02, 0.03], "slave": [5.0, 5.0, 5.0, 1.0, 1.0, 1.0]}
E0 = {"master": 1.5, "slave": 0.5}


def tool(t: np.ndarray) -> np.ndarray:
    return P + (GAP - SPEED * t)[:, None] * NORMAL


def depth(t: np.ndarray) -> np.ndarray:
    return np.maximum(SPEED * t - GAP, 0.0)


def synthetic_rows() -> np.ndarray:
    s = SCHEMA
    n = np.arange(N)
    t = n * T
    rows = np.zeros((N, s.width))
    contact = K * depth(t)[:, None] * NORMAL
    rows[:, s.group("s_x_m")] = tool(t)
    rows[:, s.group("s_v_m_per_s")] = -SPEED * NORMAL
    rows[:, s.group("s_contact_n")] = contact
    rows[:, s.group("s_contact_torque_nm")] = TORQUE
    rows[:, s.group("s_force_n")] = -contact
    rows[:, s.group("m_x_m")] = tool(t + DF * T) - OFFSET  # tool(t) - handle(t - DF) = OFFSET
    rows[:, s.group("m_v_m_per_s")] = -SPEED * NORMAL
    lag = DB + 1
    rows[:, s.group("m_force_n")] = BIAS + np.where((n >= lag)[:, None], np.roll(contact, lag, axis=0), 0.0)
    rows[:, s.group("op_x_m")] = rows[:, s.group("m_x_m")]
    for side in ("master", "slave"):
        p = side[0]
        rows[:, s.group(f"{p}_q")] = RATES[side] * t[:, None]
        rows[:, s.group(f"{p}_qd")] = RATES[side]
        rows[:, s.group(f"{p}_tau_nm")] = TAUS[side] * (1 + n % 2)[:, None]
        rows[:, s.group(f"{p}_energy_j")] = E0[side]
    rows[:, s.index("fwd_rx_seq")] = np.where(n >= DF, n - DF, -1)
    rows[:, s.index("bwd_rx_seq")] = np.where(n >= DB, n - DB, -1)
    return rows


def packet_records(delay: int) -> np.ndarray:
    seq = np.arange(N, dtype=float)
    arrival = (seq + delay) * T
    return np.column_stack([seq, seq * T, arrival, np.zeros(N), np.zeros(N), np.full(N, 120.0)])


SCENE = {
    "scene": {"name": "synthetic_oblique_wall", "seed": 3, "period_s": T},
    "controllers": {side: {"eba": {"initial_energy_j": E0[side]}} for side in ("master", "slave")},
    "network": {},
}
RUN_INFO = {
    "ticks": N,
    "interrupted": False,
    "wall_point_m": P.tolist(),
    "wall_normal": (3.0 * NORMAL).tolist(),  # any length: the analysis normalises it
    "master_joint_damping": DAMPING["master"],
    "slave_joint_damping": DAMPING["slave"],
}


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    import yaml

    out = tmp_path_factory.mktemp("task") / "bag"
    rec = RunRecorder(out, yaml.safe_dump(SCENE), round(T * 1e9), True, True, SCHEMA.width, schema=SCHEMA)
    rows = synthetic_rows()
    for a in range(0, N, 700):  # blocks that do not fall on the recorder's own
        rec.append(rows[a : a + 700])
    rec.append_packets("forward", packet_records(DF))
    rec.append_packets("backward", packet_records(DB))
    rec.close(RUN_INFO)
    return out


def test_bag_holds_standard_messages_with_joint_names(bag):
    rows = synthetic_rows()
    ts = get_typestore(Stores.LATEST)
    first: dict[str, object] = {}
    with Reader(bag) as r:
        types = {c.topic: c.msgtype for c in r.connections}
        for c, _, raw in r.messages():
            first.setdefault(c.topic, ts.deserialize_cdr(raw, c.msgtype))
    assert types["/slave/joint_states"] == "sensor_msgs/msg/JointState"
    assert types["/slave/tool_pose"] == types["/master/handle_pose"] == "geometry_msgs/msg/PoseStamped"
    assert types["/slave/contact_wrench"] == types["/master/rendered_wrench"] == "geometry_msgs/msg/WrenchStamped"
    js = first["/slave/joint_states"]
    assert list(js.name) == list(SCHEMA.slave_joints)
    assert list(first["/master/joint_states"].name) == list(SCHEMA.master_joints)
    assert np.array_equal(js.effort, TAUS["slave"])
    pose = first["/slave/tool_pose"].pose
    assert [pose.position.x, pose.position.y, pose.position.z] == tool(np.zeros(1))[0].tolist()
    assert [pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w] == [0, 0, 0, 1]
    w = first["/slave/contact_wrench"]
    assert w.header.frame_id == "world"
    assert [w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z] == TORQUE.tolist()
    assert list(first["/backward/sent"].name) == ["slave_x", "slave_y", "slave_z"]
    with BagReader(bag) as r:
        assert r.schema == SCHEMA  # recovered from the bag alone
        c = r.read("/slave/contact_wrench")
        assert c.fields == ("force_x", "force_y", "force_z", "torque_x", "torque_y", "torque_z")
        assert np.array_equal(c.values[:, :3], rows[:, SCHEMA.group("s_contact_n")])
        br = r.read("/backward/received")
        assert np.array_equal(br.values[:, 6:9], rows[: N - DB, SCHEMA.group("s_contact_n")])
        assert np.array_equal(br.log_ns - br.stamp_ns, np.full(N - DB, DB * round(T * 1e9)))
        info = json.loads(r.string("/haptic_teleop/run_info"))
        assert info["tick_schema"] == SCHEMA.facts()


def expected() -> dict[str, float]:
    t_end = (N - 1) * T
    out = {
        "force_rms_error_n": float(np.linalg.norm(BIAS)),
        "force_peak_error_n": float(np.linalg.norm(BIAS)),
        "position_rms_error_m": float(np.linalg.norm(OFFSET)),
        "penetration_max_m": SPEED * t_end - GAP,
        "contact_force_max_n": K * (SPEED * t_end - GAP),
        "contact_torque_max_nm": float(np.linalg.norm(TORQUE)),
        "force_alignment_lag_s": (DB + 1) * T,
        "force_network_lag_s": (DB + 1) * T,
    }
    for k, a in enumerate("xyz"):
        out[f"force_rms_error_{a}_n"] = abs(float(BIAS[k]))
        out[f"force_peak_error_{a}_n"] = abs(float(BIAS[k]))
        out[f"contact_force_max_{a}_n"] = abs(K * (SPEED * t_end - GAP) * NORMAL[k])
    for side in ("master", "slave"):
        # joints at constant rate r, the torque alternating: the closed form at every tick
        every = absorbed(side, np.arange(N))
        ports = np.min(every, axis=0)
        pooled = float(np.min(np.sum(every, axis=1)))
        out[f"{side}_port_energy_min_j"] = pooled
        out[f"{side}_energy_margin_min_j"] = E0[side] + pooled
        for j, v in zip(SCHEMA.joints(side), ports, strict=True):
            out[f"{side}_joint_energy_min_j.{j}"] = float(v)
    return out


def _flat(summary):
    out = dict(summary)
    for side in ("master", "slave"):
        for j, v in summary[f"{side}_joint_energy_min_j"].items():
            out[f"{side}_joint_energy_min_j.{j}"] = v
    return out


def test_summary_equals_the_analytic_values(bag):
    streamed = _flat(summarize_bag(bag))
    whole = _flat(compute_task_summary(load_task_signals(bag)))
    want = expected()
    assert any(v < 0 for k, v in want.items() if "joint_energy" in k)  # some ports gave energy
    assert want["master_port_energy_min_j"] < 0 < want["master_energy_margin_min_j"]  # pooled, within budget
    for key, value in want.items():
        assert streamed[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
        assert whole[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
    assert streamed["wall_normal"] == pytest.approx(NORMAL.tolist())
    assert streamed["ticks"] == whole["ticks"] == N
    assert streamed["all_finite"] and whole["all_finite"]
    assert streamed["master_joints"] == list(SCHEMA.master_joints)
    # every key the two paths give agrees (sums to round-off)
    assert streamed.keys() == whole.keys()
    for key, value in whole.items():
        if isinstance(value, float) and not math.isnan(value):
            assert streamed[key] == pytest.approx(value, rel=1e-12, abs=1e-15), key


def test_plots_draw_paths_wall_forces_and_ports(bag, tmp_path):
    from haptic_teleop.analysis.bag_plotdata import from_bag
    from haptic_teleop.analysis.plotdata import TaskPlotData
    from haptic_teleop.analysis.plots import task_energy_figure, task_forces_figure, task_path_figure, write_plots

    data = from_bag(bag)
    assert isinstance(data, TaskPlotData)
    written = write_plots(data, tmp_path / "plots")
    assert [p.name for p in written] == ["paths.png", "forces.png", "energy.png"]
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in written)
    t_end = (N - 1) * T
    # paths: the tool's line from its start to its end, in mm; the wall's trace in the front view
    # (x-z) lies in the plane
    fig = task_path_figure(data)
    front = next(ax for ax in fig.axes if ax.get_title().startswith("front (x-z)"))
    # each projection is zoomed to what moved in it (equal scales, at least 1 mm across), with both
    # paths whole in view
    for name in ("top (x-y)", "front (x-z)", "side (y-z)"):
        ax = next(a for a in fig.axes if a.get_title().startswith(name))
        paths = [ln for ln in ax.get_lines() if ln.get_label() in ("master handle", "slave tool")]
        assert len(paths) == 2
        xs = np.concatenate([ln.get_xdata() for ln in paths])
        ys = np.concatenate([ln.get_ydata() for ln in paths])
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        assert x0 <= xs.min() and xs.max() <= x1 and y0 <= ys.min() and ys.max() <= y1
        assert x1 - x0 == pytest.approx(y1 - y0)
        assert x1 - x0 <= max(1.1 * max(np.ptp(xs), np.ptp(ys)), 1.0) + 1e-9
    lines = {ln.get_label(): ln for ln in front.get_lines()}
    tool_line = lines["slave tool"]
    ends = np.array([[tool_line.get_xdata()[k], tool_line.get_ydata()[k]] for k in (0, -1)])
    assert ends == pytest.approx(tool(np.array([0.0, t_end]))[:, [0, 2]] * 1e3)
    wall = lines["wall (cut at the contact)"]
    for x_mm, z_mm in zip(wall.get_xdata(), wall.get_ydata(), strict=True):
        point = np.array([x_mm, P[1] * 1e3, z_mm]) * 1e-3
        assert float((P - point) @ NORMAL) == pytest.approx(0.0, abs=1e-12)
    # forces: per axis, the contact force reaches K * depth * n; the rendered force holds the bias
    fig = task_forces_figure(data)
    for k, ax in enumerate(fig.axes[:3]):
        got = {ln.get_label(): np.asarray(ln.get_ydata()) for ln in ax.get_lines()}
        c = got["contact force at the tool"]
        assert c[np.argmax(np.abs(c))] == pytest.approx(K * (SPEED * t_end - GAP) * NORMAL[k])
        assert got["force rendered at the handle"][0] == pytest.approx(BIAS[k])
    depth_line = fig.axes[3].get_lines()[0]
    assert max(depth_line.get_ydata()) == pytest.approx((SPEED * t_end - GAP) * 1e3)
    # energy: the pooled margin ends at E0 plus what every port absorbed
    fig = task_energy_figure(data)
    for ax, side in zip(fig.axes, ("master", "slave"), strict=True):
        pooled = next(ln for ln in ax.get_lines() if ln.get_label() == "pooled margin")
        end = float(np.sum(absorbed(side, np.array([N - 1]))))
        assert pooled.get_ydata()[-1] == pytest.approx(E0[side] + end)


def test_cli_analyze_of_an_n_dof_bag(bag, tmp_path):
    import subprocess
    import sys

    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "haptic_teleop.cli", "analyze", str(bag), "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["penetration_max_m"] == pytest.approx(SPEED * (N - 1) * T - GAP)
    assert summary["slave_joints"] == list(SCHEMA.slave_joints)
    assert {p.name for p in (out / "plots").iterdir()} == {"paths.png", "forces.png", "energy.png"}


def test_summary_streams_chunk_by_chunk(bag, monkeypatch):
    """The summary of an n-DoF bag comes from the streaming pass (never the whole-bag arrays),
    across the bag's chunks."""
    from haptic_teleop.analysis import taskmetrics

    with BagReader(bag) as r:
        blocks = list(r.log_blocks("/slave/joint_states"))
    assert len(blocks) > 3  # the topic spans several chunks

    def whole(*_a, **_k):
        raise AssertionError("the whole-bag path was taken")

    monkeypatch.setattr(taskmetrics, "load_task_signals", whole)
    s = summarize_bag(bag)
    assert s["penetration_max_m"] == pytest.approx(expected()["penetration_max_m"])


def test_reader_decodes_n_dof_messages_of_other_tools(tmp_path):
    """Another tool's n-DoF bag (other frames, so other byte layouts; sqlite3 storage) reads back by
    field names: the schema from its joint states, poses and wrenches per axis."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = get_typestore(Stores.LATEST)
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=0, nanosec=0)
    hdr = t["std_msgs/msg/Header"](stamp=stamp, frame_id="base_link_of_another_robot")
    v3 = t["geometry_msgs/msg/Vector3"]
    msgs = {
        "/operator/joint_states": t["sensor_msgs/msg/JointState"](
            header=hdr, name=["hx", "hy", "hz"], position=np.zeros(3), velocity=np.zeros(3), effort=np.zeros(3)
        ),
        "/master/joint_states": t["sensor_msgs/msg/JointState"](
            header=hdr, name=list(SCHEMA.master_joints), position=np.array([1.0, 2.0, 3.0]),
            velocity=np.zeros(3), effort=np.array([4.0, 5.0, 6.0]),
        ),
        "/slave/joint_states": t["sensor_msgs/msg/JointState"](
            header=hdr, name=list(SCHEMA.slave_joints), position=np.arange(6.0), velocity=np.zeros(6),
            effort=np.arange(6.0) + 10,
        ),
        "/slave/tool_pose": t["geometry_msgs/msg/PoseStamped"](
            header=hdr,
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=0.1, y=0.2, z=0.3),
                orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            ),
        ),
        "/slave/contact_wrench": t["geometry_msgs/msg/WrenchStamped"](
            header=hdr,
            wrench=t["geometry_msgs/msg/Wrench"](force=v3(x=1.0, y=2.0, z=3.0), torque=v3(x=4.0, y=5.0, z=6.0)),
        ),
    }  # fmt: skip
    with Writer(tmp_path / "other", version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        for topic, msg in msgs.items():
            c = w.add_connection(topic, msg.__msgtype__, typestore=ts)
            w.write(c, 0, bytes(ts.serialize_cdr(msg, msg.__msgtype__)))
    with BagReader(tmp_path / "other") as r:
        assert r.schema == SCHEMA
        assert r.read("/slave/tool_pose").values.tolist() == [[0.1, 0.2, 0.3]]
        assert r.read("/slave/contact_wrench").values.tolist() == [[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]]
        js = r.read("/slave/joint_states")
        assert js.field("effort[wrist_3]").tolist() == [15.0]
        assert r.read("/master/joint_states").field("position[elbow]").tolist() == [3.0]
