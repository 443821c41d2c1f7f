"""The Foxglove live view (record/foxglove_view.py, docs/foxglove.md), seen through a protocol-level
client (foxglove_client.py): its channels are advertised, a subscriber receives each group's values
of the newest row at that row's scene time and the running packet counts; `run --foxglove` serves a
run as it is recorded and ends with it; `launch --foxglove` needs --record. Ports: 0 (any free one)."""

from __future__ import annotations

import math
import re
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("foxglove")
pytest.importorskip("websockets")

from foxglove_client import FoxgloveClient

from haptic_teleop.core.link import FATE_NAMES
from haptic_teleop.record.columns import ONE_DOF
from haptic_teleop.record.foxglove_view import FoxgloveView, column_groups
from haptic_teleop.record.layouts import PACKET_FIELDS

GROUPS = {"/view/op", "/view/m", "/view/s", "/view/fwd", "/view/bwd", "/view/packets"}


def test_columns_group_by_their_prefix():
    groups = column_groups(ONE_DOF.columns)
    assert set(groups) == {"op", "m", "s", "fwd", "bwd"}
    assert [ONE_DOF.columns[i] for i in groups["fwd"]] == ["fwd_rx_seq", "fwd_occupancy"]
    assert sum(len(v) for v in groups.values()) == len(ONE_DOF.columns)


def test_a_subscriber_gets_the_newest_row_of_each_group_and_the_packet_counts():
    view = FoxgloveView(ONE_DOF.columns, 1_000_000, FATE_NAMES, port=0, rate_hz=1e9)  # every block goes out
    client = FoxgloveClient(f"ws://127.0.0.1:{view.port}")
    try:
        client.wait_for_channels(GROUPS)
        assert all(client.channels[t]["encoding"] == "json" for t in GROUPS)
        client.subscribe(["/view/m", "/view/fwd", "/view/packets"])
        time.sleep(0.5)  # the subscription reaches the server before anything is logged
        rows = np.arange(3 * len(ONE_DOF.columns), dtype=float).reshape(3, -1)
        rows[2, ONE_DOF.col["m_force_n"]] = math.nan  # no number: null in JSON
        view.rows(rows[:2])  # ticks 0 and 1: tick 1 goes out
        view.rows(rows[2:])  # tick 2
        packets = np.zeros((4, len(PACKET_FIELDS)))
        packets[:, PACKET_FIELDS.index("fate")] = [0, 1, 4, 0]  # delivered, lost, late, delivered
        view.packets("forward", packets)
        got = client.messages(5)
    finally:
        client.close()
        view.close()
    by = {}
    for topic, log_ns, msg in got:
        by.setdefault(topic, []).append((log_ns, msg))
    (t1, m1), (t2, m2) = by["/view/m"]
    assert (t1, t2) == (1_000_000, 2_000_000) and m1["t_s"] == pytest.approx(0.001)
    assert m1["m_x_m"] == rows[1, ONE_DOF.col["m_x_m"]] and m2["m_x_m"] == rows[2, ONE_DOF.col["m_x_m"]]
    assert m2["m_force_n"] is None and set(m1) == {"t_s", *(c for c in ONE_DOF.columns if c.startswith("m_"))}
    assert [m["fwd_occupancy"] for _, m in by["/view/fwd"]] == [rows[k, ONE_DOF.col["fwd_occupancy"]] for k in (1, 2)]
    ((_, counts),) = by["/view/packets"]
    assert counts["forward"] == {"sent": 4, "delivered": 2, "network": 1, "queue_overflow": 0, "corruption": 0,
                                 "late": 1}  # fmt: skip


def test_rows_faster_than_the_rate_send_only_the_newest():
    view = FoxgloveView(ONE_DOF.columns, 1_000_000, FATE_NAMES, port=0, rate_hz=0.001)  # one message in 1000 s
    client = FoxgloveClient(f"ws://127.0.0.1:{view.port}")
    try:
        client.wait_for_channels(GROUPS)
        client.subscribe(["/view/s"])
        time.sleep(0.5)
        rows = np.ones((10, len(ONE_DOF.columns)))
        for _ in range(5):
            view.rows(rows)
        got = client.messages(1)
        with pytest.raises(TimeoutError):
            client.messages(1, timeout_s=1.0)  # the other four blocks were not sent
    finally:
        client.close()
        view.close()
    assert got[0][1] == 9 * 1_000_000  # the first block's newest tick


def test_run_foxglove_serves_the_run_as_it_is_recorded(tmp_path):
    """`haptic-teleop run --foxglove 0` (the Python loop on a long scene, so there is time to
    connect): the port is printed, the channels come, the master's values arrive as numbers at
    increasing scene times, and the run still ends 0 with its bag."""
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "haptic_teleop.cli", "run", "wall_contact", "--foxglove", "0", "--loop", "python",
           "--set", "scene.duration_s=600", "--no-plots", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    try:
        assert proc.stderr is not None
        port = None
        lines = []
        while port is None:
            line = proc.stderr.readline()
            assert line, "".join(lines)
            lines.append(line)
            m = re.search(r"Foxglove live view on ws://127\.0\.0\.1:(\d+)", line)
            port = int(m.group(1)) if m else None
        client = FoxgloveClient(f"ws://127.0.0.1:{port}")
        try:
            client.wait_for_channels(GROUPS)
            client.subscribe(["/view/m"])
            got = client.messages(3, timeout_s=120)
        finally:
            client.close()
    finally:
        proc.send_signal(2)  # Ctrl-C: the run stops, its bag is closed
        proc.communicate(timeout=300)
    times = [log_ns for _, log_ns, _ in got]
    assert times == sorted(times) and len(set(times)) == 3
    assert all(isinstance(m["m_x_m"], float) and m["t_s"] == log_ns * 1e-9 for _, log_ns, m in got)
    assert proc.returncode == 130 and (out / "bag" / "metadata.yaml").exists()


def test_launch_foxglove_needs_record(capsys):
    from haptic_teleop.cli.main import main

    assert main(["launch", "wall_contact", "--foxglove"]) == 2
    err = capsys.readouterr().err
    assert "--foxglove" in err and "--record" in err and "Traceback" not in err


def test_launch_foxglove_serves_the_recorder_s_grid_live(tmp_path):
    """`haptic-teleop launch --single-process --record DIR --foxglove 0`: the recorder says where it
    serves, a subscriber gets the master's values at increasing scene times while the nodes run,
    and the launch ends as it would without the view (exit 0, a bag)."""
    from launched import Launch

    launch = Launch("wall_contact", "--single-process", "--duration", "6", "--record", str(tmp_path / "run"),
                    "--no-plots", "--foxglove", "0", cwd=tmp_path)  # fmt: skip
    try:
        port = int(launch.wait_for(r"Foxglove live view on ws://127\.0\.0\.1:(\d+)", 120).group(1))
        client = FoxgloveClient(f"ws://127.0.0.1:{port}")
        try:
            client.wait_for_channels(GROUPS)
            client.subscribe(["/view/m", "/view/packets"])
            got = client.messages(4, timeout_s=120)
        finally:
            client.close()
    finally:
        code = launch.finish(240)
    assert code == 0, launch.text[-3000:]
    master = [(log_ns, m) for topic, log_ns, m in got if topic == "/view/m"]
    assert master and all(isinstance(m["m_x_m"], float) for _, m in master)
    assert [t for t, _ in master] == sorted(t for t, _ in master)
    assert (tmp_path / "run" / "bag" / "metadata.yaml").exists()


def _paths(layout: dict) -> list[str]:
    out: list[str] = []

    def walk(node: object) -> None:
        if isinstance(node, dict):
            if node.get("panelType") == "Plot":
                out.extend(p["value"] for p in node["config"]["paths"])
            for v in node.values():
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    walk(layout)
    return out


def _field(msg: object, path: str) -> object:
    """`msg` followed along a Foxglove message path's fields ("wrench.force.x", "position[0]")."""
    for part in path.split("."):
        name, _, index = part.partition("[")
        msg = getattr(msg, name)
        if index:
            msg = msg[int(index.rstrip("]"))]
    return msg


def test_the_shipped_layouts_are_the_built_ones_and_name_what_the_bags_and_the_view_have(tmp_path):
    """config/foxglove/*.json are what record/foxglove_layouts.py builds with the SDK (regenerate them
    with `python -m haptic_teleop.record.foxglove_layouts config/foxglove`); every plotted path of a
    bag layout is a topic of a real bag of that kind with that field in its first message (read with
    rosbags), and every path of the live layout a channel and column of the view."""
    import json

    from haptic_teleop.record.foxglove_layouts import layouts
    from haptic_teleop.resources import foxglove_dir

    built = layouts()
    assert {p.name: p.read_text() for p in foxglove_dir().glob("*.json")} == built
    from rosbags.highlevel import AnyReader

    from haptic_teleop.engine.run import record_run
    from haptic_teleop.scene.load import find_scene, load_scene

    for name, scene in (("bag_one_axis.json", "wall_contact"), ("bag_arm.json", "touch_ur5e_wall")):
        bag = tmp_path / scene
        record_run(load_scene(find_scene(scene), ["scene.duration_s=0.3"]), bag, parallel=False,
                   handle_sigint=False)  # fmt: skip
        paths = _paths(json.loads(built[name]))
        assert paths
        with AnyReader([bag]) as reader:
            for path in paths:
                topic, _, field = path.partition(".")
                conns = [c for c in reader.connections if c.topic == topic]
                assert conns, f"{name}: {topic} is not in a {scene} bag"
                _, _, raw = next(reader.messages(connections=conns), (None, None, None))
                assert raw is not None, f"{name}: no message on {topic} in 0.3 s of {scene}"
                value = _field(reader.deserialize(raw, conns[0].msgtype), field)
                assert isinstance(value, float), (path, value)
    for path in _paths(json.loads(built["live.json"])):
        channel, _, column = path.partition(".")
        assert channel in GROUPS and column in ONE_DOF.columns and column.startswith(channel.rsplit("/", 1)[1])
