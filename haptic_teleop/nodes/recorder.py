"""recorder: every teleop topic into a rosbag2 (MCAP) bag, written as the run goes, like `ros2 bag record`.

Subscriptions are raw (serialized bytes: no message object per sample) with a deep reader
history, taken by the node's loop thread (no executor in the path, no wake-up per message): a
quarter of the topics per recorder tick, each topic every 16 ms; four times a second their queues
are decoded in bulk, one topic per tick, with the bag's fixed layouts onto the tick grid (index =
stamp / period; the EBA arrays, which have no header, by the time they were published).

After each decoding round the ticks every stream has passed (less a margin of MARGIN_S = 0.1 s for
samples still on their way) are appended to the bag (`RunRecorder.append`), with the grid from the
operator's first sample (scene time 0; a device session, `device.source: topic`, has no operator
source: a tick master_eba announces, see below), the same layout the engine writes, so `haptic-teleop
analyze` and every metric work on live bags unchanged; a sample lost between a node and the
recorder holds the previous value (counted in run_info). At least once a second what was appended
is flushed as complete chunks, so a kill of any process, the recorder's own included, loses at
most the last second or so (`haptic-teleop bag recover` rebuilds the summary of a bag whose
recorder was killed). Memory stays bounded: only ticks not yet written are kept, and a stream
that stops (its node died) is held at its last value once the others are STALL_S = 2 s ahead.

Packet records come from the relays (/<dir>/packets: times in scene time already, seq the node
clock's tick, less the scene start's here) and the sync buffers' rows (/<dir>/playout,
nodes/sync_buffer.py): their decisions (played or late); a record is written once the buffer has
decided it (or its tick is HOLD_S = 10 s old), with a late decision applied to its first delivered
copy: fate 4, LOST_LATE, as the engine's buffer marks it, and, if the buffer took the packet a
tick or more after the network delivered it (late by scheduling), the tick it took it at as its
arrival (`as_delivered`; counted in run_info's `packets_late_by_scheduling`); a decision on a
packet taken after the recording's end is not applied (the engine's run ends before it). The
release column of each direction (`fwd_rx_seq`, ...) comes from the same rows: the buffer's own
tick of each release, one per tick, so no release is moved or overwritten however late its
message was taken; a tick is written once its buffers' rows say they have passed it, or
RELEASES_WAIT_S (0.5 s) later (a release whose row comes later still is counted, not written).
On close (SIGINT/SIGTERM/end of the scene) the rest is
written, up to the last tick every stream reached (at most scene.duration_s), and the bag closed.

A device session (parameter `device.source: topic`, the hardware variant of the node set: master_eba
reads a device driver's topics, no operator source, docs/live_recording.md "Recording a device session"):
/operator/joint_states is not subscribed, scene time 0 is the one master_eba publishes (its device's
first sample; the relays take it too, so the packet records' times are the bag's), the operator's
columns are NaN, and the session is recorded until it is stopped (no cap at scene.duration_s;
`interrupted` stays false: such a session ends by being stopped).

The resolved scene goes out once on /haptic_teleop/scene (std_msgs/String, reliable, transient
local: a subscriber that starts later still gets it).

An NVE scene (docs/live_nve.md, "NVE scenes live") is recorded the same way with its own topic plan
(`topic_plan`): the NVE bag's per-tick topics (record/nve_columns.py, `nve_topic_specs`) as
state, the releases of each client's up and down sync buffers (`<c>.up_rx_seq`,
`<c>.down_rx_seq`, from their /playout rows as teleoperation's), the packets and buffer
decisions of every `<client>/up|down` direction; the grid's end is set by the object and the
clients' HIP streams, scene time 0 by the server's start.

A direction with a codec (docs/live_network.md, "Codecs live"): its packet records are the encoder's packets
(the relay carries nothing else), decided "played" by the decoder as they arrive; the codec's
counters come from the encoder's and the decoder's nodes (/<direction>/codec/encoder, /decoder:
std_msgs/String, JSON, latched, over the scene's window) and go into the run facts `codec_<direction>`
with `codec_plain_bytes`, as the engine writes them (engine/lockstep.py, `codec_facts`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.core.link import DELIVERED, FATE_NAMES, LOST_LATE
from haptic_teleop.nodes import DEVICE_SOURCES, SCENE_SECTIONS
from haptic_teleop.nodes.base import LiveNode, node_main
from haptic_teleop.nodes.messages import take_all, take_all_published_ns
from haptic_teleop.nodes.params import declare_scene, declare_value
from haptic_teleop.nodes.recorder_facts import schema_and_facts, side_every
from haptic_teleop.nodes.recorder_grid import _on_grid, as_delivered, mark_late
from haptic_teleop.nodes.recorder_placement import WriterTicks
from haptic_teleop.nodes.topics import (
    DIRECTIONS,
    MASTER_EBA,
    MASTER_STATE,
    OPERATOR_STATE,
    RECORDER_LISTENING_TOPIC,
    SCENE_START_TOPIC,
    SCENE_TOPIC,
    SLAVE_CONTACT,
    SLAVE_EBA,
    SLAVE_STATE,
    latched_qos,
    packets_topic,
    playout_topic,
    received_topic,
    reliable_qos,
    sample_topic,
    scene_start_header,
    scene_start_ns,
    sent_topic,
    stream_qos,
)
from haptic_teleop.record.foxglove_view import VIEW_PORT, serve_view

# Topic -> engine columns it fills (in the topic layout's value order): a one-axis scene's. An arm
# scene's come from its tick schema (`state_columns`).
STATE_COLUMNS = {
    OPERATOR_STATE: ("op_x_m", "op_v_m_per_s", "op_force_n"),
    MASTER_STATE: ("m_x_m", "m_v_m_per_s", "m_force_n"),
    SLAVE_STATE: ("s_x_m", "s_v_m_per_s", "s_force_n"),
    SLAVE_CONTACT: ("s_contact_n",),
    MASTER_EBA: ("m_energy_j", "m_force_desired_n"),
    SLAVE_EBA: ("s_energy_j", "s_force_desired_n"),
}
RECEIVED = {received_topic("forward"): "fwd_rx_seq", received_topic("backward"): "bwd_rx_seq"}
PACKETS = {packets_topic("forward"): "forward", packets_topic("backward"): "backward"}
PLAYOUT = {playout_topic("forward"): "forward", playout_topic("backward"): "backward"}
# The QoS the live topics are published with, recorded in the bag's metadata as rosbag2 does
# (fields of rosbag2's offered_qos_profiles; topics not named: the 1 kHz streams' profile).
_STREAM = {"reliability": "best_effort", "depth": 1}
_BATCH = {"reliability": "reliable", "depth": 100}
_LATCHED = {"reliability": "reliable", "durability": "transient_local", "depth": 1}
OFFERED_QOS = {
    "*": [_STREAM],
    SCENE_TOPIC: [_LATCHED],
    "/haptic_teleop/run_info": [_LATCHED],
    **{packets_topic(d): [_BATCH] for d in DIRECTIONS},
}
MASTER_WRENCH_CLOCK, SLAVE_WRENCH_CLOCK = "/master/rendered_wrench", "/slave/applied_wrench"  # (see _clock_of)
MAIN = (OPERATOR_STATE, MASTER_STATE, SLAVE_STATE, SLAVE_CONTACT)  # the streams that define the grid's end
# Per-tick topics of a tick schema the recorder does not take as state: the released samples
# (/<dir>/received: the release column RECEIVED, filled from the buffers' /<dir>/playout rows).
_NOT_STATE = ("/forward/received", "/backward/received")
# The sent samples (/<dir>/sent) fill only the columns no state topic before them fills: an arm's
# handle and tool velocities, which no other live topic carries (the engine's bag has them in its
# /<dir>/sent rows). With a codec on the direction /<dir>/sent carries only the encoder's packets,
# not a sample per tick: the sending arm side then publishes its sample on /<dir>/sample
# (nodes/topics.sample_topic), which the recorder takes in its place.
_SENT = ("/forward/sent", "/backward/sent")


class TopicPlan:
    """What a recorder takes, per run kind: its per-tick state topics (layouts, row columns), the
    sync buffers' released-sample topics (-> the row column of the releases, filled from the
    buffers' /playout rows; the topics themselves are not taken), the packet and
    playout topics (-> their direction), the streams that set the grid's end, the stream whose
    first sample is scene time 0 when no start message came, and the row columns no topic fills
    that are NaN (`unknown`: nothing is known of them) rather than 0."""

    def __init__(
        self,
        specs: dict[str, Any],
        columns: dict[str, tuple[int, ...]],
        received: dict[str, int],
        directions: tuple[str, ...],
        main: tuple[str, ...],
        first: str,
        values: dict[str, tuple[int, ...]] | None = None,
        unknown: tuple[int, ...] = (),
    ) -> None:
        self.specs, self.columns, self.received, self.unknown = specs, columns, received, unknown
        # Per state topic taking part of its message: the positions (in the layout's value order)
        # of the values that fill `columns`; a topic not named takes every value.
        self.values = values or {}
        self.directions, self.main, self.first = directions, main, first
        self.packets = {packets_topic(d): d for d in directions}
        self.playout = {playout_topic(d): d for d in directions}


def topic_plan(schema: Any, plain: tuple[str, ...] = DIRECTIONS, operator: bool = True) -> TopicPlan:
    """The recorder's topics for a run with this schema (a TickSchema, or an NveSchema); `plain`:
    the directions without a codec (their /<dir>/sent carries a sample per tick); `operator`: False
    for a device session (no operator source): no /operator/joint_states, its columns NaN, scene
    time 0 the tick master_eba announces."""
    from haptic_teleop.record.nve_columns import NveSchema

    if isinstance(schema, NveSchema):
        from haptic_teleop.nodes.topics import NVE_OBJECT_STATE, nve_hip_topic
        from haptic_teleop.record.layouts import nve_topic_specs

        specs = nve_topic_specs(schema)
        received = {received_topic(d): schema.index(f"{d.replace('/', '.')}_rx_seq") for d in schema.directions}
        main = (NVE_OBJECT_STATE, *(nve_hip_topic(c) for c in schema.clients))
        columns = {t: spec.columns for t, spec in specs.items()}
        return TopicPlan(specs, columns, received, schema.directions, main, NVE_OBJECT_STATE)
    from haptic_teleop.record.layouts import topic_specs

    received = {t: schema.col[name] for t, name in RECEIVED.items()}
    columns, values = state_columns(schema, plain)
    specs = topic_specs(schema)
    for d in DIRECTIONS:  # a codec's direction: its sender's samples come on /<dir>/sample, in /<dir>/sent's layout
        if sample_topic(d) in columns:
            specs[sample_topic(d)] = dataclasses.replace(specs[sent_topic(d)], name=sample_topic(d))
    if not operator:
        unknown = columns.pop(OPERATOR_STATE)
        main = tuple(t for t in MAIN if t != OPERATOR_STATE)
        return TopicPlan(specs, columns, received, DIRECTIONS, main, MASTER_STATE, values, unknown)
    return TopicPlan(specs, columns, received, DIRECTIONS, MAIN, OPERATOR_STATE, values)


def state_columns(
    schema: Any, plain: tuple[str, ...] = DIRECTIONS
) -> tuple[dict[str, tuple[int, ...]], dict[str, tuple[int, ...]]]:
    """Topic -> the tick row's columns its values fill, in the message's value order, for every
    per-tick state topic of `schema` (record.layouts.topic_specs: the bag's own layouts); and, for
    the /<dir>/sent topics of the `plain` directions (/<dir>/sample of the others: the same
    layout), which fill only the columns no other state topic fills (_SENT), the positions of
    those values in their message."""
    from haptic_teleop.record.layouts import topic_specs

    specs = topic_specs(schema)
    columns = {t: spec.columns for t, spec in specs.items() if t not in _NOT_STATE and t not in _SENT}
    filled = {c for cols in columns.values() for c in cols}
    values: dict[str, tuple[int, ...]] = {}
    for t in _SENT:
        d = t.split("/")[1]
        source = t if d in plain else sample_topic(d)
        keep = tuple(k for k, c in enumerate(specs[t].columns) if c not in filled)
        if keep:
            columns[source] = tuple(specs[t].columns[k] for k in keep)
            values[source] = keep
    return columns, values


TAKE_EVERY = 4  # scene ticks per recorder tick
# Each recorder tick takes one of POLL_GROUPS groups of topics in turn (every topic every
# POLL_GROUPS * TAKE_EVERY = 16 ticks) and decodes at most one topic's queue: its work is spread
# evenly over the ticks rather than coming in one long tick, which in a composed process would
# make the shared loop late for every node (docs/live.md, "Late ticks").
POLL_GROUPS = 4
# The recorder's reader history: samples a 1 kHz topic may send between two takes of it, with room
# for the recorder's loop to run late (16 ms between takes, up to 10 periods of catch-up, a few
# milliseconds of a busy machine; measured here: up to 40 ms late with one process per node).
RECORDER_DEPTH = 200
END_TOLERANCE_TICKS = 20
DECODE_EVERY_S = 0.25  # a decoding round (one topic per recorder tick) starts this often
# Ticks are written once every main stream is this far past them: samples of the other streams
# (EBA arrays, released samples) for those ticks have been taken by then.
MARGIN_S = 0.1
# A main stream this far behind the newest one (its node stopped or died) no longer holds the
# recording back: its ticks are written holding its last value.
STALL_S = 2.0
HOLD_S = 10.0  # a packet record the sync buffer has not decided after this long is written as is
RELEASES_WAIT_S = 0.5  # ticks wait at most this long (behind the main streams) for their releases
FINAL_COUNTERS_S = 3.0  # at close, the longest wait for the codec nodes' last counters
FLUSH_EVERY_S = 0.5  # what was appended is on disk as complete chunks at least this often


class _Pending:
    """Samples of one topic not written yet: absolute tick indices and values, in decoded chunks."""

    def __init__(self, width: int) -> None:
        self.width = width
        self.idx: list[np.ndarray] = []
        self.val: list[np.ndarray] = []
        self.newest = -1  # the highest index decoded so far (absolute)
        self.carry: np.ndarray | None = None  # the last value written (held over a gap)
        self.filled = 0  # ticks written without a sample
        self.dropped = 0  # samples decoded after their tick was written

    def add(self, idx: np.ndarray, val: np.ndarray) -> None:
        if idx.size:
            self.idx.append(idx)
            self.val.append(val)
            self.newest = max(self.newest, int(idx.max()))

    def take(self, a: int, b: int, first: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The samples of ticks [a, b) (dropping older ones, counted unless `first`: before the
        recording's first tick); later ones stay."""
        if not self.idx:
            return np.zeros(0, dtype=np.int64), np.zeros((0, self.width))
        idx = np.concatenate(self.idx)
        val = np.concatenate(self.val)
        if not first:
            self.dropped += int(np.count_nonzero(idx < a))
        now = (idx >= a) & (idx < b)
        later = idx >= b
        self.idx, self.val = ([idx[later]], [val[later]]) if np.any(later) else ([], [])
        return idx[now], val[now]

    def first(self) -> int | None:
        return min(int(i.min()) for i in self.idx) if self.idx else None


class Recorder(LiveNode):
    default_name = "recorder"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from std_msgs.msg import Float64MultiArray, String

        from haptic_teleop.errors import ConfigError
        from haptic_teleop.scene.schema import LoadedScene

        self.cfg = declare_scene(
            self, SCENE_SECTIONS["recorder"], ("output_dir", "device.source", "view.foxglove_port")
        )
        self.schema, self.run_facts = schema_and_facts(self.cfg)
        port = int(declare_value(self, VIEW_PORT, -1, "live view for Foxglove on it (-1: none)", -1, 65535))
        period_ns, say = round(self.cfg.scene.period_s * 1e9), self.get_logger().info
        self._view = serve_view(self.schema.columns, period_ns, FATE_NAMES, port, say) if port >= 0 else None
        out = str(declare_value(self, "output_dir", "", "the bag goes to OUTPUT_DIR/bag (required)"))
        where = f"parameters of node {self.get_name()}"
        if not out:
            raise ConfigError(where, "output_dir", out, "allowed: a directory path")
        self.bag_dir = Path(out) / "bag"
        if self.bag_dir.exists():
            raise ConfigError(where, "output_dir", out, "allowed: a directory without bag/ in it")
        source = declare_value(
            self, "device.source", "plant", "master_eba's device: plant (an operator source publishes "
            "/operator/joint_states) or topic (a driver's topics, no operator source: scene time 0 is the "
            "tick master_eba announces, the operator's columns NaN, recorded until stopped)", choices=DEVICE_SOURCES,
        )  # fmt: skip
        cfg = self.cfg
        if source != "plant" and (cfg.is_nve or cfg.is_arm):
            raise ConfigError(where, "device.source", source, "an arm or NVE scene has an operator; allowed: plant")
        self.operator = source == "plant"
        self.grid_ns = round(cfg.scene.period_s * 1e9)  # the scene's tick grid
        # A device session lasts until it is stopped: no cap (None), and never "interrupted".
        self.duration_ticks = round(cfg.scene.duration_s / cfg.scene.period_s) if self.operator else None
        self.margin_ticks, self.stall_ticks, self.hold_ticks, self.release_wait_ticks = (
            max(1, math.ceil(t / cfg.scene.period_s)) for t in (MARGIN_S, STALL_S, HOLD_S, RELEASES_WAIT_S)
        )
        self.scene_yaml = LoadedScene(config=cfg, source=f"live: node {self.get_name()}", raw={}).to_yaml()
        # /<dir>/sent in the bag's layout, a sample per tick: not with a codec (its packets) nor on
        # an arm with TDPA (the wire's layout, the energy joint last): their sides publish /<dir>/sample
        tdpa_arm = cfg.is_arm and cfg.controllers.master.eba.law == "tdpa"
        plain = tuple(d for d in DIRECTIONS if cfg.is_nve or (getattr(cfg.network, d).codec is None and not tdpa_arm))
        self.plan = plan = topic_plan(self.schema, plain, self.operator)
        self._specs = plan.specs
        self._columns = plan.columns
        # A side with its own period (<side>.period_s = k scene periods) publishes every k-th scene
        # tick: its rows repeat its last values in between (_on_grid), as the engine records them,
        # and only a missed tick of its own counts as a filled sample.
        self._every = {t: side_every(cfg, t) for t in self._columns}
        # Per topic, what was taken and not yet decoded: times (ns) and raw bytes in two lists, not
        # (time, bytes) tuples: ints and bytes are no work for the garbage collector, thousands of
        # live tuples a second would be (each collection pauses every loop of the process).
        self._queues: dict[str, tuple[list[int], list[bytes]]] = {}
        self._subs: dict[str, Any] = {}
        self._pending: dict[str, _Pending] = {t: _Pending(len(c)) for t, c in self._columns.items()}
        for topic in plan.received:  # filled from the buffers' release rows (/<dir>/playout)
            self._pending[topic] = _Pending(1)  # index: the release tick; value: the sample's tick
        self._released_in = {d: received_topic(d) for d in plan.directions}
        self._packets: dict[str, list[np.ndarray]] = {d: [] for d in plan.directions}
        self._decided: dict[str, dict[int, int]] = {d: {} for d in plan.directions}  # seq -> the buffer's fate
        self._arrived: dict[str, dict[int, int]] = {d: {} for d in plan.directions}  # seq -> the tick it took it at
        self.late_by_scheduling = {d: 0 for d in plan.directions}  # records moved to when the buffer took them
        for topic in list(self._columns) + list(plan.packets) + list(plan.playout):
            self._queues[topic] = ([], [])
            if topic in plan.packets or topic in plan.playout:
                msg_type, qos = Float64MultiArray, reliable_qos(100)
            else:
                msg_type, qos = self._ros_type(self._specs[topic].layout.msgtype), stream_qos(RECORDER_DEPTH)
            self._subs[topic] = self.create_polled_subscription(msg_type, topic, qos, raw=True)
        self.received_count = {t: 0 for t in self._queues}
        # The EBA arrays (no header) go on the tick of the stamped state their side wrote just before
        # them (nodes/recorder_placement.py): array topic -> that state's topic, and each side's clock.
        self._written_after = {
            t: state for t, state in ((MASTER_EBA, MASTER_STATE), (SLAVE_EBA, SLAVE_STATE)) if t in self._columns
        }
        self._writers = {s: WriterTicks(self.grid_ns) for s in self._written_after.values()}
        # Each side's clock also reads the stamped wrench an arm side writes just before its array
        self._wrench_clock = {
            s: w for s, w in ((MASTER_STATE, MASTER_WRENCH_CLOCK), (SLAVE_STATE, SLAVE_WRENCH_CLOCK))
            if s in self._writers and w in self._columns
        }  # fmt: skip
        self._clock_of = {**self._writers, **{w: self._writers[s] for s, w in self._wrench_clock.items()}}
        self._closing = False
        self.start_tick: int | None = None  # absolute tick of scene time 0: plan.first's first sample
        self.written = 0  # absolute tick up to which (exclusive) the bag holds the grid
        self.packets_written = {d: 0 for d in plan.directions}
        self.late_marked = {d: 0 for d in plan.directions}
        self._closed = False
        self._last_flush = time.monotonic()
        self.rec = self._open_bag()
        # The resolved scene, latched (transient local): a subscriber that starts later gets it.
        self._scene_pub = self.create_publisher(String, SCENE_TOPIC, latched_qos())
        self._scene_pub.publish(String(data=self.scene_yaml))
        from std_msgs.msg import Header

        self._listening_pub = self.create_publisher(Header, RECORDER_LISTENING_TOPIC, latched_qos())
        self._listening = False
        # Scene time 0: the operator source's, or in a device session master_eba's (after its device answered).
        self._start_sub = self.create_polled_subscription(Header, SCENE_START_TOPIC, latched_qos())
        # The codec stage's counters (nodes/codec_stage.py), latched: taken at close.
        self._codec_subs: dict[tuple[str, str], Any] = {}
        if not cfg.is_nve:
            from haptic_teleop.nodes.codec_stage import counters_topic

            for d in DIRECTIONS:
                if getattr(cfg.network, d).codec is not None:
                    for side in ("encoder", "decoder"):
                        self._codec_subs[(d, side)] = self.create_polled_subscription(
                            String, counters_topic(d, side), latched_qos()
                        )
        topics = list(self._subs)
        self._poll_groups = [topics[i::POLL_GROUPS] for i in range(POLL_GROUPS)]
        # A decoding round starts at the first tick at or past each DECODE_EVERY_S of stamps (not
        # on tick indices: a loop that skips ticks under load could step over those forever).
        self._decode_period_ns = round(DECODE_EVERY_S * 1e9)
        self._next_decode_ns = 0
        self._poll_turn = 0
        self._to_decode: list[str] = []
        self.setup_loop(self.grid_ns * TAKE_EVERY)
        self.get_logger().info(f"recording to {self.bag_dir}")

    def _open_bag(self) -> Any:
        from haptic_teleop.errors import ConfigError
        from haptic_teleop.record.recorder import RunRecorder

        rec = self.cfg.recording
        try:
            self.bag_dir.parent.mkdir(parents=True, exist_ok=True)
            return RunRecorder(
                self.bag_dir, self.scene_yaml, self.grid_ns, rec.eba_internals, rec.packets, self.schema.width,
                parallel=False, compression=getattr(rec, "compression", "none"), qos=OFFERED_QOS, schema=self.schema,
                view=self._view,
            )  # fmt: skip
        except OSError as exc:
            raise ConfigError(
                f"parameters of node {self.get_name()}",
                "output_dir",
                str(self.bag_dir.parent),
                f"cannot be written ({exc.strerror or exc}); allowed: a directory this user can write",
            ) from None

    @staticmethod
    def _ros_type(name: str) -> Any:
        import importlib

        pkg, _, cls = name.split("/")
        return getattr(importlib.import_module(f"{pkg}.msg"), cls)

    def tick(self, index: int, stamp_ns: int) -> None:
        self._take(self._poll_groups[self._poll_turn])  # in turn, whatever ticks the loop skipped
        if not self._listening and all(self._queues[t][1] or self.received_count[t] for t in self.plan.main):
            self._listening = True  # every stream of the grid is coming in (a device session waits for it)
            self._listening_pub.publish(scene_start_header(stamp_ns))
        self._poll_turn = (self._poll_turn + 1) % POLL_GROUPS
        if stamp_ns >= self._next_decode_ns and not self._to_decode:
            self._to_decode = list(self._queues)
            self._next_decode_ns = stamp_ns + self._decode_period_ns
        if self._to_decode:
            self._drain_topic(self._to_decode.pop())
            if not self._to_decode:  # a round is complete: write what every stream has passed
                self._advance(closing=False)

    def _take(self, topics: list[str] | None = None) -> None:
        """Take what `topics` (default: all) hold into their queues."""
        queues = self._queues
        subs = self._subs
        if self.simulated_time:  # source timestamps are wall time: use the take time on /clock
            now = self.now_ns()
            for topic in topics if topics is not None else list(subs):
                raws = take_all(subs[topic])
                if raws:
                    times, q = queues[topic]
                    times.extend([now] * len(raws))
                    q.extend(raws)
            return
        # The publisher's write time: for the EBA arrays (no header) the tick that produced them;
        # not when this loop took them.
        for topic in topics if topics is not None else list(subs):
            times, q = queues[topic]
            take_all_published_ns(subs[topic], times, q)

    def _drain(self) -> None:
        for topic in self._queues:
            self._drain_topic(topic)

    def _drain_topic(self, topic: str) -> None:
        """Decode what `topic`'s queue holds."""
        period = self.grid_ns
        times, q = self._queues[topic]
        writer = self._written_after.get(topic) if not self.simulated_time else None
        if writer is not None:  # its writer's stamped messages first, then those arrays it places
            self._drain_topic(writer)
            if writer in self._wrench_clock:
                self._drain_topic(self._wrench_clock[writer])
            n = self._writers[writer].placeable(times, self._closing)
        else:
            n = len(q)
        if n == 0:
            return
        raws = q[:n]
        recv = np.array(times[:n], dtype=np.int64)
        del q[:n], times[:n]
        self.received_count[topic] += n
        plan = self.plan
        if topic in plan.packets:
            self._decode_packets(plan.packets[topic], raws)
        elif topic in plan.playout:
            self._decode_playout(plan.playout[topic], raws)
        else:
            vals, stamps = self._decode_fixed(topic, raws)
            keep = plan.values.get(topic)
            if keep is not None:
                vals = vals[:, list(keep)]
            if stamps is not None:
                if topic in self._clock_of and not self.simulated_time:
                    self._clock_of[topic].stamped(recv, stamps)
                idx = stamps // period
            elif writer is not None:
                idx = self._writers[writer].ticks_of(recv)
            else:
                idx = recv // period
            self._pending[topic].add(idx, vals)

    def _decode_fixed(self, topic: str, raws: list[bytes]) -> tuple[np.ndarray, np.ndarray | None]:
        layout = self._specs[topic].layout
        size = layout.size
        good = [r for r in raws if len(r) == size]
        if len(good) == len(raws):
            rows = np.frombuffer(b"".join(raws), dtype=np.uint8).reshape(len(raws), size)
            return layout.decode(rows)
        # Another publisher's layout (other joint name, more axes): decode message by message.
        from rclpy.serialization import deserialize_message

        msg_type = self._ros_type(layout.msgtype)
        vals = np.empty((len(raws), layout.nfloats))
        stamps = np.empty(len(raws), dtype=np.int64)
        fields = self._specs[topic].fields
        k = layout.nfloats
        for i, r in enumerate(raws):
            m = deserialize_message(r, msg_type)
            if hasattr(m, "header"):
                stamps[i] = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            single = getattr(self.schema, "single_axis", False)
            if single and layout.msgtype.endswith("JointState"):
                vals[i] = [float(getattr(m, f)[0]) for f in fields]
            elif single and layout.msgtype.endswith("WrenchStamped"):
                vals[i] = [m.wrench.force.x]
            elif layout.msgtype.endswith("JointState"):  # field by field, one value per name
                names = {f.split("[")[0]: None for f in fields}
                vals[i] = [float(x) for f in names for x in getattr(m, f)][:k]
            elif layout.msgtype.endswith("WrenchStamped"):
                w = m.wrench
                vals[i] = [w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z][:k]
            elif layout.msgtype.endswith("PoseStamped"):
                p = m.pose.position
                vals[i] = [p.x, p.y, p.z][:k]
            elif layout.msgtype.endswith("TwistStamped"):
                v = m.twist.linear
                vals[i] = [v.x, v.y, v.z][:k]
            else:
                vals[i] = list(m.data[:k])
        return vals, (stamps if layout.sec_offset >= 0 else None)

    def _decode_packets(self, direction: str, raws: list[bytes]) -> None:
        from rclpy.serialization import deserialize_message
        from std_msgs.msg import Float64MultiArray

        from haptic_teleop.record.layouts import PACKET_FIELDS

        for r in raws:
            m = deserialize_message(r, Float64MultiArray)
            labels = m.layout.dim[1].label.split(",") if len(m.layout.dim) > 1 else list(PACKET_FIELDS)
            rows = np.asarray(m.data, dtype=np.float64).reshape(-1, len(labels))
            # Columns by name, so a relay of another version still records what it has.
            cols = [rows[:, labels.index(f)] if f in labels else np.zeros(rows.shape[0]) for f in PACKET_FIELDS]
            self._packets[direction].append(np.column_stack(cols))

    def _decode_playout(self, direction: str, raws: list[bytes]) -> None:
        """The sync buffer's rows (nodes/sync_buffer.py): decisions by seq; releases into the
        release column's pending samples (index: the buffer's tick; value: the sample's tick); the
        batch's last row (seq -1) says every release up to its tick has come."""
        from rclpy.serialization import deserialize_message
        from std_msgs.msg import Float64MultiArray

        decided = self._decided[direction]
        arrived = self._arrived[direction]
        released = self._pending[self._released_in[direction]]
        for r in raws:
            m = deserialize_message(r, Float64MultiArray)
            labels = m.layout.dim[1].label.split(",") if len(m.layout.dim) > 1 else ["seq", "fate"]
            rows = np.asarray(m.data, dtype=np.float64).reshape(-1, len(labels))
            seq = rows[:, labels.index("seq")].astype(np.int64)
            fate = rows[:, labels.index("fate")].astype(np.int64)
            tick = rows[:, labels.index("tick")].astype(np.int64) if "tick" in labels else np.full(seq.size, -1)
            ok = (seq >= 0) & (fate >= 0)
            decided.update(zip(seq[ok].tolist(), fate[ok].tolist(), strict=True))
            if "arrived" in labels:
                took = rows[:, labels.index("arrived")].astype(np.int64)
                ok &= took >= 0
                arrived.update(zip(seq[ok].tolist(), took[ok].tolist(), strict=True))
            rel = (seq >= 0) & (tick >= 0)
            released.add(tick[rel], seq[rel].reshape(-1, 1).astype(np.float64))
            mark = seq < 0
            if np.any(mark):
                released.newest = max(released.newest, int(tick[mark].max()))

    # -- writing as the run goes
    def _advance(self, closing: bool) -> None:
        """Append the ticks that are complete (all of them when closing) and the packet records
        decided up to there; flush when due."""
        if self.start_tick is None:
            lead = self._pending[self.plan.first]
            first = lead.first()
            told = take_all(self._start_sub)
            if told:  # the scene's time 0, even if its first samples did not get here
                first = scene_start_ns(told[-1], self.grid_ns) // self.grid_ns
            elif first is None or (not closing and lead.newest - first < self.stall_ticks):
                return  # wait for it a little (an operator of another version may not send it)
            self.start_tick = self.written = first
        newest = [self._pending[t].newest for t in self.plan.main]
        if min(newest) < 0 and not closing and max(newest) - self.written < self.stall_ticks:
            return
        if closing:
            end = min(n for n in newest) + 1 if min(newest) >= 0 else self.written
        else:
            end = max(min(newest) + 1 - self.margin_ticks, max(newest) + 1 - self.stall_ticks)
            # The buffers' releases come in reliable batches ten times a second: a tick is written
            # once its releases are in too, or once the main streams are RELEASES_WAIT_S past it.
            # No longer: a reliable stream that lost a message on a busy machine delivers nothing
            # until DDS repairs it, seconds later (3.5 s seen with one process per node here), and a
            # recorder killed meanwhile would lose what it held; releases that come after their
            # tick was written are counted (`samples_after_written` of /<dir>/received).
            released = [self._pending[t].newest for t in self.plan.received]
            if released:
                end = min(end, max(min(released) + 1, max(newest) + 1 - self.release_wait_ticks))
        if self.duration_ticks is not None:
            end = min(end, self.start_tick + self.duration_ticks)
        if end > self.written:
            self._write_ticks(self.written, end)
        self._write_packets(closing)
        now = time.monotonic()
        if closing or now - self._last_flush >= FLUSH_EVERY_S:
            self.rec.flush()
            self._last_flush = now

    def _write_ticks(self, a: int, b: int) -> None:
        n = b - a
        data = np.zeros((n, self.schema.width))
        # No operator source (a device session): nothing is known of the hand, NaN rather than 0.
        data[:, list(self.plan.unknown)] = np.nan
        for topic, cols in self._columns.items():
            pend = self._pending[topic]
            idx, vals = pend.take(a, b, first=a == self.start_tick)
            grid, missing, pend.carry = _on_grid(idx - a, vals, n, pend.carry)
            every = self._every[topic]
            if every > 1:  # its own ticks in [a, b) less the rows that got a sample
                start = self.start_tick or 0
                own = -(-(b - start) // every) - -(-(a - start) // every)
                missing = max(0, own - int(np.unique(idx[(idx >= a) & (idx < b)]).size))
            pend.filled += missing
            data[:, list(cols)] = grid
        start = self.start_tick
        assert start is not None
        for topic, column_index in self.plan.received.items():
            at, seq = self._pending[topic].take(a, b, first=a == start)
            column = np.full(n, -1.0)
            s = seq[:, 0].astype(np.int64) - start
            ok = (s >= 0) & (s <= at - start)
            order = np.argsort(at[ok], kind="stable")  # the last release in a tick wins
            column[(at[ok] - a)[order]] = s[ok][order]
            data[:, column_index] = column
        self.rec.append(data)
        self.written = b

    def _write_packets(self, closing: bool) -> None:
        """Packet records whose tick is written and whose fate is final: lost on the way, or
        decided by the sync buffer (played, or late: the first delivered copy gets LOST_LATE),
        or HOLD_S old; all of them when closing."""
        from haptic_teleop.record.layouts import PACKET_FIELDS

        if not self.cfg.recording.packets or self.start_tick is None:
            for d in self.plan.directions:
                self._packets[d].clear()
            return
        f = {name: i for i, name in enumerate(PACKET_FIELDS)}
        start, written = self.start_tick, self.written
        # The recording's last tick (exclusive), where known: the scene's duration, or (a device
        # session, closing) the last tick written.
        end = start + self.duration_ticks if self.duration_ticks is not None else (written if closing else None)
        for d in self.plan.directions:
            if not self._packets[d]:
                continue
            rows = np.concatenate(self._packets[d])
            seq = rows[:, f["seq"]].astype(np.int64)
            decided = self._decided[d]
            known = np.fromiter((s in decided for s in seq.tolist()), dtype=bool, count=seq.size)
            final = (rows[:, f["fate"]] != DELIVERED) | known | (seq < written - self.hold_ticks) | closing
            ready = final & (seq < written)
            before = seq < start  # sent before scene time 0
            keep = ~ready & ~before & (not closing)  # closing: what is left is past the recording's end
            out = rows[ready & ~before]
            self._packets[d] = [rows[keep]] if np.any(keep) else []
            if out.size:
                # A decision on a packet the buffer took after the recording's end is not applied:
                # the engine's run ends before it takes that packet, whose record stays as sent.
                arrived = self._arrived[d]
                last = end if end is not None else 1 << 62
                late = {s for s, fate in decided.items() if fate == LOST_LATE and arrived.get(s, -1) < last}
                self.late_marked[d] += mark_late(out, late, f)
                out = out.copy()
                out[:, f["seq"]] -= start  # the relays' times are in scene time already (network_relay)
                self.late_by_scheduling[d] += as_delivered(out, arrived, start, last, self.grid_ns, f)
                order = np.argsort(out[:, f["seq"]], kind="stable")
                self.rec.append_packets(d, np.ascontiguousarray(out[order]))
                self.packets_written[d] += out.shape[0]
            horizon = written - self.hold_ticks
            if len(decided) > self.hold_ticks:
                for s in [s for s in decided if s < horizon]:
                    del decided[s]
            arrived = self._arrived[d]
            if len(arrived) > self.hold_ticks:
                for s in [s for s in arrived if s < horizon]:
                    del arrived[s]

    # -- closing
    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        # The last packet batches go out as the relays close: keep taking input a little longer.
        end = time.monotonic() + 0.3
        while self.loop is not None and self.loop.running and time.monotonic() < end:
            time.sleep(0.02)
        super().close()
        self._take()
        self._closing = True  # every array is placed with what is known
        self._drain()
        try:
            path = self.finish()
        except Exception as exc:
            import traceback

            self.get_logger().error(f"could not write the bag: {exc}\n{traceback.format_exc()}")
            raise
        self.get_logger().info(f"bag written: {path}")

    def _codec_facts(self) -> dict[str, Any]:
        """`codec_<direction>` and `codec_plain_bytes` from the codec nodes' last counters."""
        if not self._codec_subs:
            return {}
        from haptic_teleop.nodes.codec_stage import codec_run_facts

        got: dict[str, dict[str, dict[str, Any]]] = {"encoder": {}, "decoder": {}}
        final: dict[tuple[str, str], bool] = {}
        # The codec nodes publish their last counters as they close, which may be after this node
        # was told to stop: wait for each (marked final) a little, then take what came.
        end = time.monotonic() + FINAL_COUNTERS_S
        while True:
            for (d, side), sub in self._codec_subs.items():
                for m in take_all(sub):
                    try:
                        counters = json.loads(m.data)
                    except ValueError:
                        self.get_logger().warning(f"unreadable codec counters of the {d} {side}")
                        continue
                    final[(d, side)] = bool(counters.pop("final", False))
                    got[side][d] = counters
            if all(final.get(k, False) for k in self._codec_subs) or time.monotonic() >= end:
                break
            time.sleep(0.02)
        facts = codec_run_facts(self.cfg, got["encoder"], got["decoder"])
        for d, side in self._codec_subs:
            f = facts.get(f"codec_{d}")
            if f is not None and got[side].get(d) and not final.get((d, side), False):
                # the counters of a node still running at close (or whose last message was lost)
                f["counters_not_final"] = ",".join(filter(None, (f.get("counters_not_final"), side)))
        return facts

    def finish(self) -> Path:
        """Write what is left and close the bag; returns its directory."""
        self._advance(closing=True)
        ticks = self.written - self.start_tick if self.start_tick is not None else 0
        if ticks < 2:
            missing = [t for t in self.plan.main if self._pending[t].newest < 0]
            why = f"no samples on {', '.join(missing)}" if missing else "fewer than two common ticks"
            self.get_logger().error(f"nothing to record: {why}")
            self.exit_code = 1
        # The last samples of a run are still in flight when the operator ends it: a bag a few
        # ticks short of the duration is complete.
        interrupted = self.duration_ticks is not None and ticks < self.duration_ticks - END_TOLERANCE_TICKS
        info = {
            "mode": "live",
            "realtime_factor": 1.0,
            "ticks": ticks,
            "interrupted": interrupted,
            "start_stamp_ns": (self.start_tick or 0) * self.grid_ns,
            "samples_filled": {t: self._pending[t].filled for t in self._columns},
            "samples_after_written": {t: p.dropped for t, p in self._pending.items()},
            "messages_received": dict(self.received_count),
            "packets_written": dict(self.packets_written),
            "packets_late": dict(self.late_marked),
            "packets_late_by_scheduling": dict(self.late_by_scheduling),
            "written_at_unix_s": round(time.time(), 3),
            **self.run_facts,
            **self._codec_facts(),
        }
        path = Path(self.rec.close(info))
        (self.bag_dir.parent / "live_run.json").write_text(json.dumps(info, indent=2, sort_keys=True) + "\n")
        return path


def main() -> None:
    node_main(Recorder)


if __name__ == "__main__":
    main()
