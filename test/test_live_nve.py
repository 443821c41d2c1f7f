"""NVE scenes live: the server, the clients, their relays and sync buffers as real processes over
real DDS on localhost (conftest: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, own ROS_DOMAIN_ID).

An independent subscriber in this process watches the nodes' topics; every check is on what the
nodes published (message values and stamps), never on wall-clock rates.
"""

from __future__ import annotations

import math
import signal
import threading
import time

import numpy as np
import pytest
from launched import Launch

rclpy = pytest.importorskip("rclpy")

PERIOD_NS = 1_000_000
DELAY_S = 0.05  # one way, each direction
DURATION_S = 3.0
K_H = 0.5  # nve_push: client_stiffness_n_per_m
PUSH_START_S = 0.5  # nve_push: operator.start_s
# A client tick run late takes samples its buffer released after the tick's deadline, so R reads
# short by as much as the tick was late; a server tick run late takes a HIP sample released after
# its deadline and echoes it in a down sample stamped with that earlier stamp, which the down relay
# may then release as much earlier. The relays release a sample no earlier than its stamp plus the
# link's delay and the buffers hold it no shorter, so R >= the links' delay - (how late after its
# stamp the server took its input) - (the same for the client). A tick takes its inputs no later
# than its work ends: the loop table's "latest end" (after the deadline, preemption inside the tick
# included; a CI run's client and server were 25 ms late between them) plus the node's loop phase
# (one process per node: the deadline is the stamp plus the phase) bounds it, whatever the
# machine's load (docs/live_nve.md, "NVE scenes live"). R is a whole number of ticks, as a float
# in s: compare with a nanosecond of slack.


def r_floor_s(launch: Launch, rtt_s: float, client: str, phases: bool) -> float:
    """The least R the client can measure in this run (above): the links' round trip less how late
    after its stamp the server and the client took their inputs at the latest."""
    from haptic_teleop.nodes.nve_client import NveClientNode
    from haptic_teleop.nodes.nve_server import NveServer

    late = launch.end_late_s("nve_server") + launch.end_late_s(f"nve_client_{client}")
    if phases:
        late += (NveServer.loop_phase + NveClientNode.loop_phase) * PERIOD_NS * 1e-9
    return rtt_s - late - 1e-9


# This test's own subscriber is best effort (as the nodes' streams are): on a busy 2-core machine it
# saw 1,000 of the 3,000 samples of a topic, and 262-283 in a CI run beside another test run. The
# checks on what it saw need a hundred.
MIN_SEEN = 100
DELAYS = ("--set", f"nve.clients.0.up.effects.delay.delay_s={DELAY_S}",
          "--set", f"nve.clients.0.down.effects.delay.delay_s={DELAY_S}")  # fmt: skip


def _types() -> dict[str, type]:
    from geometry_msgs.msg import PoseStamped, WrenchStamped
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    return {"joint": JointState, "pose": PoseStamped, "wrench": WrenchStamped, "array": Float64MultiArray}


class Watcher:
    """Raw subscriptions to the given topics (deep reader history), taken by a polling thread and
    decoded at the end (a callback per message would fall behind on a loaded machine)."""

    def __init__(self, topics: dict[str, str]) -> None:
        from haptic_teleop.nodes.messages import _polled_group_class, take_all
        from haptic_teleop.nodes.topics import stream_qos

        self.kinds = topics
        types = _types()
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("test_nve_watcher", context=self.context)
        group = _polled_group_class()()
        self.subs = {
            t: self.node.create_subscription(types[k], t, lambda m: None, stream_qos(5000), callback_group=group,
                                             raw=True)
            for t, k in topics.items()
        }  # fmt: skip
        self.raw: dict[str, list[bytes]] = {t: [] for t in topics}
        self._stop = threading.Event()
        self._take = take_all
        self.thread = threading.Thread(target=self._poll, daemon=True)
        self.thread.start()

    def _poll(self) -> None:
        while not self._stop.is_set():
            for topic, sub in self.subs.items():
                self.raw[topic].extend(self._take(sub))
            time.sleep(0.002)

    def messages(self, topic: str) -> list:
        from rclpy.serialization import deserialize_message

        t = _types()[self.kinds[topic]]
        return [deserialize_message(r, t) for r in list(self.raw[topic])]

    def close(self) -> None:
        self._stop.set()
        self.thread.join(2.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _stamp(m) -> int:
    return int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)


def _by_stamp(msgs, values) -> dict[int, tuple[float, ...]]:
    return {_stamp(m): values(m) for m in msgs}


PUSH_TOPICS = {
    "/nve/client/hip/joint_states": "joint",
    "/nve/client/object_pose": "pose",
    "/nve/client/feedback_wrench": "wrench",
    "/nve/client/coupling": "array",
    "/nve/object/joint_states": "joint",
    "/client/down/received": "joint",
}


@pytest.fixture(scope="module")
def push_run(tmp_path_factory):
    """nve_push live for 3 s of scene time, 50 ms each way, one process per node, recorded."""
    cwd = tmp_path_factory.mktemp("nve_live")
    w = Watcher(PUSH_TOPICS)
    try:
        launch = Launch("nve_push", "--duration", str(DURATION_S), *DELAYS, "--record", str(cwd / "run"), cwd=cwd)
        stamp0 = int(launch.wait_for(r"\[nve_server\].*scene time 0 at stamp (\d+) ns", 60).group(1))
        code = launch.finish(90)
        time.sleep(0.2)  # the last messages reach this subscriber
        data = {t: w.messages(t) for t in PUSH_TOPICS}
    finally:
        w.close()
    return {"code": code, "launch": launch, "stamp0": stamp0, "data": data, "bag": cwd / "run" / "bag"}


def test_push_runs_live_and_every_process_exits_0(push_run):
    launch = push_run["launch"]
    assert push_run["code"] == 0, launch.failure
    codes = launch.exit_codes()
    expected = {"nve_server", "nve_client_client", "client_up_relay", "client_up_buffer",
                "client_down_relay", "client_down_buffer", "recorder"}  # fmt: skip
    assert set(codes) == expected and all(c == 0 for c in codes.values()), codes
    assert "Traceback" not in launch.text
    print(launch.loop_table())


def test_client_measures_the_round_trip_of_the_links_plus_a_few_ticks(push_run):
    """R = t - echo, as the client measured it: the 0.1 s the two links delay by, plus a few ticks
    (relay, buffer and server each wait for their phase of a tick)."""
    rows = np.array([m.data for m in push_run["data"]["/nve/client/coupling"]])
    assert rows.shape[0] > MIN_SEEN
    rtt = rows[:, 1]
    measured = rtt[~np.isnan(rtt)]
    assert measured.size > MIN_SEEN
    print(
        f"measured R: min {measured.min():.4f} median {np.median(measured):.4f} "
        f"p99 {np.percentile(measured, 99):.4f} max {measured.max():.4f} s"
    )
    floor = r_floor_s(push_run["launch"], 2 * DELAY_S, "client", phases=True)
    assert measured.min() >= floor, (measured.min(), floor)
    # How far above the links' delay R reads is the machine's scheduling (median 0.110-0.132 s, p99
    # up to 0.239 s seen on a busy 2-core machine): real time asserts no physics, so it is printed,
    # and the lockstep engine's R is asserted in test_nve_engine. What the client reports must be
    # what it measured: the coupling's R is its tick's stamp less the echo it used.
    # the echo the server carried is the client's own send stamp: an up sample's tick in scene time
    echo = np.array([m.position[1] for m in push_run["data"]["/client/down/received"]])
    echo = echo[~np.isnan(echo)]
    assert echo.size > MIN_SEEN and np.allclose(echo * 1e3, np.round(echo * 1e3), atol=1e-6)


def test_force_is_the_clients_spring_toward_the_object_it_received(push_run):
    """F = k_h (x_h - x_o') from the messages themselves: the HIP (hip/joint_states), the object
    as the client used it (object_pose), the force (feedback_wrench and the HIP's effort)."""
    d = push_run["data"]
    hip = _by_stamp(d["/nve/client/hip/joint_states"], lambda m: (m.position[0], m.effort[0]))
    pose = _by_stamp(d["/nve/client/object_pose"], lambda m: (m.pose.position.x,))
    wrench = _by_stamp(d["/nve/client/feedback_wrench"], lambda m: (m.wrench.force.x,))
    stamps = sorted(set(hip) & set(pose) & set(wrench))
    assert len(stamps) > MIN_SEEN
    xh = np.array([hip[s][0] for s in stamps])
    fh = np.array([hip[s][1] for s in stamps])
    xo = np.array([pose[s][0] for s in stamps])
    f = np.array([wrench[s][0] for s in stamps])
    t = (np.array(stamps) - push_run["stamp0"]) * 1e-9
    assert np.all(np.isfinite(f)) and np.array_equal(f, fh)
    before = np.isnan(xo)  # no object sample yet: no force
    assert np.all(f[before] == 0.0)
    assert np.all(before[t < DELAY_S])  # the down link delays the first object sample (if seen)
    # The spring k_h each tick used is the scheme's (nve_push: seed 000's transparency scheme) at the
    # R measured: both are in each coupling message. Below the allowable delay (0.195 s) it is k_h.
    from haptic_teleop.assembly.nve import build_schedule
    from haptic_teleop.scene.load import find_scene, load_scene

    nve = load_scene(find_scene("nve_push")).config.nve
    schedule = build_schedule(nve, nve.clients[0])
    coupling = np.array([m.data[:2] for m in d["/nve/client/coupling"]])
    assert np.array_equal(coupling[:, 0], [schedule.spring_n_per_m(r) for r in coupling[:, 1]])
    springs = set(coupling[:, 0].tolist())
    # below the allowable delay the spring is k_h; how often a stall pushed R past it is the machine's
    print(f"ticks on k_h: {np.mean(coupling[:, 0] == K_H):.3f}")
    assert K_H in springs
    got = ~before
    # Each force used one of the schedule's springs: k_h, or (a stall made R pass the allowable delay)
    # the spring at that R, a whole number of ticks. This best-effort subscriber may miss the few
    # coupling messages of a spring a stall used, so the table is the schedule's at every R to 5 s.
    period_s = PERIOD_NS * 1e-9
    table = np.array(sorted(springs | {schedule.spring_n_per_m(n * period_s) for n in range(int(5.0 / period_s))}))
    dx = xh[got] - xo[got]
    k = f[got][np.abs(dx) > 1e-9] / dx[np.abs(dx) > 1e-9]
    near = table[np.clip(np.searchsorted(table, k), 1, table.size - 1) - np.array([[1], [0]])]
    assert np.all(np.min(np.abs(near - k), axis=0) <= 1e-9 * np.abs(k)), k
    assert np.all(f[t < PUSH_START_S] == 0.0)  # the HIP rests until the push: no force
    assert np.any(f[t > PUSH_START_S] > 0.0)  # the push reached the client's spring
    # every object position the client used is one the server sent and the client's buffer released
    released = {float(m.position[0]) for m in d["/client/down/received"]}
    used = [float(x) for x in xo[got]]
    # (this best-effort subscriber misses some under load: a third in one of four runs here; a force
    # computed from anything but released samples would match almost none)
    assert sum(x in released for x in used) >= 0.5 * len(used)


def test_object_moves_toward_the_hip(push_run):
    d = push_run["data"]
    obj = _by_stamp(d["/nve/object/joint_states"], lambda m: (m.position[0], m.velocity[0], m.effort[0]))
    hip = _by_stamp(d["/nve/client/hip/joint_states"], lambda m: (m.position[0],))
    stamps = sorted(set(obj) & set(hip))
    assert len(stamps) > MIN_SEEN
    t = (np.array(stamps) - push_run["stamp0"]) * 1e-9
    xo = np.array([obj[s][0] for s in stamps])
    xh = np.array([hip[s][0] for s in stamps])
    assert np.all(np.isfinite(xo))
    assert np.all(xo[t < PUSH_START_S] == 0.0)  # at rest until the HIP (and its 50 ms) reach it
    # How it follows (it lags the HIP, then overshoots) is physics, asserted in lockstep time
    # (test_nve_engine); live, the server must have taken the client's forces and moved it forward.
    print(f"object at {t[-1]:.3f} s: {xo[-1]:.4f} m, HIP {xh[-1]:.4f} m")
    assert xo[-1] > 0.0


def test_live_push_follows_the_engine(push_run):
    """The same scene in the engine (lockstep, simulated time): the live client's force tracks it
    (the live round trip is a few ticks longer: a generous band)."""
    from haptic_teleop.engine.nve_loop import NveEngine
    from haptic_teleop.scene.load import find_scene, load_scene

    sets = [DELAYS[1], DELAYS[3], f"scene.duration_s={DURATION_S}"]
    engine = NveEngine(load_scene(find_scene("nve_push"), overrides=sets))
    engine.run(handle_sigint=False)
    assert engine.data is not None
    f_engine = engine.data[:, 3 + 4]  # client.force_n (server: 3 columns; client: hip x, v, obj x, v, force)
    d = push_run["data"]
    wrench = _by_stamp(d["/nve/client/feedback_wrench"], lambda m: (m.wrench.force.x,))
    n = np.array(sorted(wrench)) - push_run["stamp0"]
    ticks = n // PERIOD_NS
    ok = (ticks >= 0) & (ticks < engine.data.shape[0])
    f_live = np.array([wrench[s][0] for s in sorted(wrench)])[ok]
    ref = f_engine[ticks[ok]]
    err = np.abs(f_live - ref).max()
    print(f"live vs engine force: max |error| {err:.2e} N of max {np.abs(ref).max():.3e} N")
    # A busy machine lengthens the live round trip, and the force lags the engine's more: 0.12 and
    # 0.26 of the peak seen on a busy 2-core machine, 0.02 on an idle one. Real time asserts no
    # physics: this only catches a force of the wrong sign or scale, which misses by the peak or more.
    assert err < np.abs(ref).max()


def test_sigint_stops_every_nve_process_cleanly(tmp_path):
    """Ctrl-C (SIGINT to the launcher) mid-run: each node stops and exits 0, the launch 130."""
    launch = Launch("nve_push", "--duration", "60", *DELAYS, cwd=tmp_path)
    launch.wait_for(r"\[nve_server\].*scene time 0 at stamp", 60)
    time.sleep(0.5)
    launch.proc.send_signal(signal.SIGINT)
    code = launch.finish(60)
    assert code == 130, launch.failure
    codes = launch.exit_codes()
    assert len(codes) == 6 and all(c == 0 for c in codes.values()), codes
    assert "Traceback" not in launch.text


def test_two_clients_in_three_axes_composed_each_measure_their_own_round_trip(tmp_path):
    """nve_two_clients, all nodes in one process (--single-process), SIGTERM ends it: each client
    measures its own links' round trip (near: 20 ms, far: 300 ms), in 3 axes."""
    topics = {"/nve/near/coupling": "array", "/nve/far/coupling": "array", "/nve/object/joint_states": "joint"}
    w = Watcher(topics)
    try:
        launch = Launch("nve_two_clients", "--duration", "60", "--single-process", cwd=tmp_path)
        launch.wait_for(r"\[nve_server\].*scene time 0 at stamp", 60)
        end = time.monotonic() + 60
        while time.monotonic() < end:  # until the far client has measured a while
            far = [m.data[1] for m in w.messages("/nve/far/coupling")]
            if sum(1 for r in far if not math.isnan(r)) > 300:
                break
            time.sleep(0.1)
        launch.proc.send_signal(signal.SIGTERM)
        code = launch.finish(60)
        data = {t: w.messages(t) for t in topics}
    finally:
        w.close()
    assert code == 143, launch.failure
    assert "Traceback" not in launch.text
    medians = {}
    for name, rtt in (("near", 0.02), ("far", 0.3)):
        r = np.array([m.data[1] for m in data[f"/nve/{name}/coupling"]])
        r = r[~np.isnan(r)]
        assert r.size > 100, name
        print(f"{name}: measured R median {np.median(r):.4f} s")
        print(f"{name}: measured R min {r.min():.4f} s")
        assert r.min() >= r_floor_s(launch, rtt, name, phases=False), name  # its own links' delays, less lateness
        medians[name] = float(np.median(r))
    assert medians["near"] < medians["far"]  # each client measured its own links
    obj = data["/nve/object/joint_states"]
    assert obj and all(len(m.position) == 3 and len(m.effort) == 3 for m in obj)


def test_wire_layouts_carry_the_engines_payloads():
    """The NVE wire (docs/live_nve.md, "NVE scenes live"): up = (x.., v..) as position, velocity; down = position
    (x_o.., echo_s), velocity (v_o.., 0), both ways; teleoperation's wires as before."""
    from haptic_teleop.nodes.wire import direction_problem, wire_of

    down = wire_of("c1/down", 3)
    assert down.names == ("object_x", "object_y", "object_z", "hip_echo_s") and down.fields == ("position", "velocity")
    payload = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.25)  # x_o, v_o, echo_s
    assert down.values(payload) == [1.0, 2.0, 3.0, 0.25, 4.0, 5.0, 6.0, 0.0]
    assert down.payload(down.values(payload)) == payload
    up = wire_of("c1/up", 1)
    assert up.names == ("c1_hip_x",) and up.values((0.1, 0.2)) == [0.1, 0.2] and up.payload((0.1, 0.2)) == (0.1, 0.2)
    back = wire_of("backward", 1)  # payload (f_env, x_s, v_s) -> JointState position, velocity, effort
    assert back.names == "slave_x" and back.values((9.0, 1.0, 2.0)) == [1.0, 2.0, 9.0]
    assert direction_problem("c1/sideways") is not None and direction_problem("forward") is None


def _node(context, cls, params):
    from rclpy.parameter import Parameter

    return cls(
        context=context,
        node_name="test_nve_node",
        parameter_overrides=[Parameter(k, value=v) for k, v in params.items()],
    )


def test_relay_of_a_down_link_runs_the_nve_link_and_forwards_the_sample_unchanged(context):
    """A `<client>/down` relay runs the link of that direction from its client's scene section (in
    scene time) and reads the down layout into the engine's payload (x_o, v_o, echo_s)."""
    from haptic_teleop.nodes.cdr import JointStateCodec
    from haptic_teleop.nodes.network_relay import NetworkRelay

    params = {"direction": "c1/down", "scene.period_s": 0.001, "nve.client_names": ["c1"],
              "nve.clients.c1.down.effects.delay.delay_s": 0.002, "scene_start": "first_sample",
              "lookahead_s": 0.0}  # fmt: skip  # held in the link until its delivery, not handed on ahead
    relay = _node(context, NetworkRelay, params)
    try:
        raw = JointStateCodec(("object_x", "hip_echo_s"), ("position", "velocity")).encode(
            5_000_000, (0.3, 0.001, 0.7, 0.0)
        )
        relay._on_sent(raw, 5_100_000)
        assert relay.link.sent == 1 and relay.link.in_flight == 1
        p = relay.link.log[0]
        assert tuple(p.payload) == (0.3, 0.7, 0.001)  # x_o, v_o, echo_s
        # Sent at its stamp, scene time 0 (from the first sample; it came within a period of it), + the delay.
        assert p.send_time_ns == 0 and p.arrival_time_ns == 2_000_000
        assert [e.name for e in relay.link.effects] == ["delay"]
    finally:
        relay.destroy_node()


@pytest.mark.parametrize(
    ("cls", "params", "key"),
    [
        ("nve_client", {"client": "nobody", "nve.client_names": ["c1"]}, "client"),
        ("network_relay", {"direction": "c1/sideways"}, "direction"),
        ("sync_buffer", {"direction": "c2/up", "nve.client_names": ["c1"]}, "nve.client_names"),
    ],
)
def test_bad_nve_parameters_name_what_is_wrong(context, cls, params, key):
    import importlib

    from haptic_teleop.errors import ConfigError
    from haptic_teleop.nodes import EXECUTABLES

    module = importlib.import_module(EXECUTABLES[cls])
    node_cls = {"nve_client": "NveClientNode", "network_relay": "NetworkRelay", "sync_buffer": "SyncBuffer"}[cls]
    with pytest.raises(ConfigError) as err:
        _node(context, getattr(module, node_cls), params)
    assert key in str(err.value)


def test_live_bag_holds_what_the_nodes_published(push_run):
    """The recorder's NVE bag (record/nve_columns.py, read back with BagReader.read_nve): one row
    per tick of the scene from the server's scene time 0, holding at each tick exactly the values
    this test's own subscriber saw stamped at it; the clients' links' packet records in scene time,
    delayed by the 50 ms of each link; the buffers' release ticks."""
    import json

    from haptic_teleop.core.link import DELIVERED, LOST_LATE
    from haptic_teleop.record.reader import BagReader

    r = BagReader(push_run["bag"])
    s = r.nve_schema
    assert s is not None and s.clients == ("client",) and s.axes == 1
    rows = r.read_nve().values
    ticks = round(DURATION_S * 1e9 / PERIOD_NS)
    info = json.loads(r.string("/haptic_teleop/run_info"))
    # a loaded machine starts the recorder's grid late (2,854 of 3,000 rows seen): the bag holds the
    # ticks its run facts say it does
    assert MIN_SEEN < rows.shape[0] <= ticks and rows.shape[0] == info["ticks"]
    assert info["start_stamp_ns"] == push_run["stamp0"] and info["nve_schema"]["clients"] == ["client"]
    d = push_run["data"]
    hip: dict[int, list[tuple[float, ...]]] = {}
    obj: dict[int, list[tuple[float, ...]]] = {}
    for seen, topic in ((hip, "/nve/client/hip/joint_states"), (obj, "/nve/object/joint_states")):
        for m in d[topic]:  # all of a stamp's messages (a node seen publishing a stamp twice under load)
            seen.setdefault(_stamp(m), []).append((m.position[0], m.velocity[0], m.effort[0]))
    twice = sum(len(v) > 1 for v in hip.values()) + sum(len(v) > 1 for v in obj.values())
    print(f"stamps published more than once: {twice}")
    # A sample that never reached the recorder (best effort, a busy machine) leaves its columns
    # holding the row before: the recorder counts those per topic (samples_filled; a row's columns
    # may come from several topics, the client's force from its wrench topic). Every other value is
    # the sample's.
    most_filled = max(info["samples_filled"].values())
    n_seen = 0
    for topic, seen, names in (
        ("/nve/client/hip/joint_states", hip, ("client.hip_x_m", "client.hip_v_m_per_s", "client.force_n")),
        ("/nve/object/joint_states", obj, ("obj_x_m", "obj_v_m_per_s", "obj_force_n")),
    ):
        cols = [s.index(n) for n in names]
        held = []
        for stamp, vals in seen.items():
            k = (stamp - push_run["stamp0"]) // PERIOD_NS
            if 0 <= k < rows.shape[0]:
                got = tuple(rows[k, cols])
                if got not in vals:
                    before = tuple(rows[k - 1, cols]) if k > 0 else ()
                    assert k > 0 and all(any(g == v[i] for v in vals) or g == before[i] for i, g in enumerate(got)), (
                        topic,
                        k,
                        got,
                        vals,
                        before,
                    )
                    held.append(k)
                n_seen += 1
        assert len(held) <= most_filled, (topic, held[:10], info["samples_filled"])
    assert n_seen > MIN_SEEN
    rtt = rows[:, s.index("client.rtt_s")]
    assert np.nanmin(rtt) >= r_floor_s(push_run["launch"], 2 * DELAY_S, "client", phases=True) and np.isnan(rtt[0])
    # release ticks: a sample released at tick k was sent at least the link's delay before it
    for link in ("up", "down"):
        seq = rows[:, s.index(f"client.{link}_rx_seq")]
        k = np.flatnonzero(seq >= 0)
        print(f"{link}: a release recorded on {k.size} of {rows.shape[0]} rows")
        # how many releases a busy machine's buffer makes and its recorder sees varies (962 of 2,900
        # rows in one CI run); every one seen must respect the delay
        assert k.size > MIN_SEEN and np.all(k - seq[k] >= DELAY_S * 1e9 / PERIOD_NS), link
        pk = r.packets(f"/nve/client/{link}/packets")
        print(f"{link}: {pk.shape[0]} packet records; recorder: {info['packets_written']}")
        assert pk.shape[0] > MIN_SEEN and np.array_equal(pk[:, 0], np.sort(pk[:, 0]))
        assert pk.shape[0] == info["packets_written"][f"client/{link}"]
        ok = (pk[:, 3] == DELIVERED) | (pk[:, 3] == LOST_LATE)
        assert np.all(ok)
        # Delays as delivered (scene seconds): the link's, but for the packets the buffer took a
        # tick or more late (this machine, counted apart), which carry the tick they were taken at.
        delay = pk[:, 2] - pk[:, 1]
        on_time = np.isclose(delay, DELAY_S, rtol=0, atol=1e-9)
        assert np.all(delay[~on_time] > DELAY_S)
        assert np.count_nonzero(~on_time) == info["packets_late_by_scheduling"][f"client/{link}"]


def test_recorded_live_run_ends_with_its_summary_from_the_bag(push_run):
    """`launch --record` writes the NVE summary from the live bag: the measured round trip and the
    server's energy balance from the recorded signals (passive at every step)."""
    import json

    summary = json.loads((push_run["bag"].parent / "summary.json").read_text())
    assert summary["kind"] == "nve" and summary["finite"]
    # The recorder takes the 1 kHz streams best effort: under load it may miss messages, and then
    # the energy balance is not judged (rows out of step with their ticks), never judged wrongly.
    if summary["messages_missing"]:
        assert summary["server_energy"] is None and all(k > 0 for k in summary["messages_missing"].values())
    else:
        assert summary["server_energy"] is not None and summary["server_energy"]["passive"]
    # at least the links' 0.1 s; how much more is the machine's scheduling (0.103 idle, 0.165 s in a CI
    # run beside another test run): printed, not asserted
    r = summary["clients"]["client"]["round_trip_s"]["median"]
    print(f"summary's round trip median: {r:.4f} s")
    assert r >= 0.1
