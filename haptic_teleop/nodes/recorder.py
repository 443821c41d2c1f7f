"""recorder: every teleop topic into a rosbag2 (MCAP, through rosbags), closed cleanly on SIGINT
or SIGTERM.

Subscriptions are raw (serialized bytes: no message object per sample) with a deep reader
history, taken by the node's loop thread (no executor in the path, no wake-up per message): a
quarter of the topics per recorder tick, each topic every 16 ms; four times a second their queues
are decoded in bulk, one topic per tick, with bag.py's fixed layouts onto the tick grid (index =
stamp / period; the EBA arrays, which have no header, by arrival time). On close the grid from the
operator's first sample (scene time 0) to the last tick every stream reached, at most
scene.duration_s, is written by `bag.write_run`: the same layout the engine writes, so
`haptic-teleop analyze` and every metric work on live bags unchanged. A sample lost between a
node and the recorder holds the previous value; how many were filled is in run_info.
"""

from __future__ import annotations

import json
import struct
import time
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.nodes import SCENE_SECTIONS
from haptic_teleop.nodes.common import (
    MASTER_EBA,
    MASTER_STATE,
    OPERATOR_STATE,
    SLAVE_CONTACT,
    SLAVE_EBA,
    SLAVE_STATE,
    LiveNode,
    declare_scene,
    declare_value,
    node_main,
    packets_topic,
    received_topic,
    reliable_qos,
    stream_qos,
    take_all,
    take_all_published_ns,
)

# Topic -> engine columns it fills (in the topic layout's value order).
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
_STAMP = struct.Struct("<iI")


def _stamp_ns(sec_nsec: tuple[int, int]) -> int:
    return sec_nsec[0] * 1_000_000_000 + sec_nsec[1]


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
END_TOLERANCE_TICKS = 20  # header.stamp right after the 4-byte CDR encapsulation header


class _Series:
    """Absolute tick indices and values of one topic, appended in decoded chunks."""

    def __init__(self, width: int) -> None:
        self.width = width
        self.idx: list[np.ndarray] = []
        self.val: list[np.ndarray] = []
        self.extra: list[np.ndarray] = []

    def add(self, idx: np.ndarray, val: np.ndarray, extra: np.ndarray | None = None) -> None:
        self.idx.append(idx)
        self.val.append(val)
        if extra is not None:
            self.extra.append(extra)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        if not self.idx:
            return np.zeros(0, dtype=np.int64), np.zeros((0, self.width)), None
        extra = np.concatenate(self.extra) if self.extra else None
        return np.concatenate(self.idx), np.concatenate(self.val), extra


class Recorder(LiveNode):
    default_name = "recorder"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from std_msgs.msg import Float64MultiArray

        from haptic_teleop.bag import topic_specs

        self.cfg = declare_scene(self, SCENE_SECTIONS["recorder"], ("output_dir",))
        out = str(declare_value(self, "output_dir", "", "the bag goes to OUTPUT_DIR/bag (required)"))
        if not out:
            from haptic_teleop.errors import ConfigError

            raise ConfigError(f"parameters of node {self.get_name()}", "output_dir", out, "allowed: a directory path")
        self.bag_dir = Path(out) / "bag"
        if self.bag_dir.exists():
            from haptic_teleop.errors import ConfigError

            raise ConfigError(
                f"parameters of node {self.get_name()}", "output_dir", out, "allowed: a directory without bag/ in it"
            )
        self.grid_ns = round(self.cfg.scene.period_s * 1e9)  # the scene's tick grid
        self._specs = topic_specs()
        # Per topic, what was taken and not yet decoded: times (ns) and raw bytes in two lists, not
        # (time, bytes) tuples: ints and bytes are no work for the garbage collector, thousands of
        # live tuples a second would be (each collection pauses every loop of the process).
        self._queues: dict[str, tuple[list[int], list[bytes]]] = {}
        self._subs: dict[str, Any] = {}
        self._series: dict[str, _Series] = {}
        from sensor_msgs.msg import JointState

        types: dict[str, Any] = {}
        for topic, columns in STATE_COLUMNS.items():
            types[topic] = self._specs[topic].layout.msgtype
            self._series[topic] = _Series(len(columns))
        for topic in RECEIVED:
            self._series[topic] = _Series(1)  # value: arrival index
        self._packets: dict[str, list[np.ndarray]] = {d: [] for d in PACKETS.values()}
        for topic in list(STATE_COLUMNS) + list(RECEIVED) + list(PACKETS):
            self._queues[topic] = ([], [])
            if topic in PACKETS:
                msg_type, qos = Float64MultiArray, reliable_qos(100)
            elif topic in RECEIVED:
                msg_type, qos = JointState, stream_qos(RECORDER_DEPTH)
            else:
                msg_type, qos = self._ros_type(types[topic]), stream_qos(RECORDER_DEPTH)
            self._subs[topic] = self.create_polled_subscription(msg_type, topic, qos, raw=True)
        self.received_count = {t: 0 for t in self._queues}
        self._closed = False
        topics = list(self._subs)
        self._poll_groups = [topics[i::POLL_GROUPS] for i in range(POLL_GROUPS)]
        # A decoding round (one topic per tick) starts four times a second.
        self._decode_every = max(1, round(0.25 / (self.cfg.scene.period_s * TAKE_EVERY)))
        self._to_decode: list[str] = []
        self.setup_loop(self.grid_ns * TAKE_EVERY)
        self.get_logger().info(f"recording to {self.bag_dir}")

    @staticmethod
    def _ros_type(name: str) -> Any:
        import importlib

        pkg, _, cls = name.split("/")
        return getattr(importlib.import_module(f"{pkg}.msg"), cls)

    def tick(self, index: int, stamp_ns: int) -> None:
        self._take(self._poll_groups[index % POLL_GROUPS])
        if index % self._decode_every == 0 and not self._to_decode:
            self._to_decode = list(self._queues)
        if self._to_decode:
            self._drain_topic(self._to_decode.pop())

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
        # The publisher's write time: for /<dir>/received that is the buffer's release time,
        # for the EBA arrays (no header) the tick that produced them; not when this loop took them.
        for topic in topics if topics is not None else list(subs):
            times, q = queues[topic]
            take_all_published_ns(subs[topic], times, q)

    def _drain(self) -> None:
        for topic in self._queues:
            self._drain_topic(topic)

    def _drain_topic(self, topic: str) -> None:
        """Decode what `topic`'s queue holds onto its series."""
        period = self.grid_ns
        times, q = self._queues[topic]
        n = len(q)
        if n == 0:
            return
        raws = q[:n]
        recv = np.array(times[:n], dtype=np.int64)
        del q[:n], times[:n]
        self.received_count[topic] += n
        if topic in PACKETS:
            self._decode_packets(PACKETS[topic], raws)
        elif topic in RECEIVED:
            stamps = np.fromiter((_stamp_ns(_STAMP.unpack_from(r, 4)) for r in raws), dtype=np.int64, count=n)
            self._series[topic].add(stamps // period, (recv // period).reshape(-1, 1).astype(np.float64))
        else:
            vals, stamps = self._decode_fixed(topic, raws)
            idx = (stamps if stamps is not None else recv) // period
            self._series[topic].add(idx, vals)

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
        for i, r in enumerate(raws):
            m = deserialize_message(r, msg_type)
            if hasattr(m, "header"):
                stamps[i] = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            if layout.msgtype.endswith("JointState"):
                vals[i] = [float(getattr(m, f)[0]) for f in fields]
            elif layout.msgtype.endswith("WrenchStamped"):
                vals[i] = [m.wrench.force.x]
            else:
                vals[i] = list(m.data[: layout.nfloats])
        return vals, (stamps if layout.sec_offset >= 0 else None)

    def _decode_packets(self, direction: str, raws: list[bytes]) -> None:
        from rclpy.serialization import deserialize_message
        from std_msgs.msg import Float64MultiArray

        from haptic_teleop.bag import PACKET_FIELDS

        for r in raws:
            m = deserialize_message(r, Float64MultiArray)
            labels = m.layout.dim[1].label.split(",") if len(m.layout.dim) > 1 else list(PACKET_FIELDS)
            rows = np.asarray(m.data, dtype=np.float64).reshape(-1, len(labels))
            # Columns by name, so a relay of another version still records what it has.
            cols = [rows[:, labels.index(f)] if f in labels else np.zeros(rows.shape[0]) for f in PACKET_FIELDS]
            self._packets[direction].append(np.column_stack(cols))

    # -- writing
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
        self._drain()
        try:
            path = self.write()
        except Exception as exc:
            import traceback

            self.get_logger().error(f"could not write the bag: {exc}\n{traceback.format_exc()}")
            raise
        if path is not None:
            self.get_logger().info(f"bag written: {path}")

    def write(self) -> Path | None:
        """Write the bag; returns its directory, or None when nothing usable was recorded."""
        from haptic_teleop.bag import PACKET_FIELDS, write_run
        from haptic_teleop.core.network import Packet
        from haptic_teleop.engine import COL, COLUMNS, RunResult
        from haptic_teleop.scene import LoadedScene

        cfg = self.cfg
        period = self.grid_ns
        duration_ticks = round(cfg.scene.duration_s / cfg.scene.period_s)
        data_of = {t: self._series[t].arrays() for t in STATE_COLUMNS}
        main = (OPERATOR_STATE, MASTER_STATE, SLAVE_STATE, SLAVE_CONTACT)
        if any(data_of[t][0].size == 0 for t in main):
            missing = [t for t in main if data_of[t][0].size == 0]
            self.get_logger().error(f"nothing to write: no samples on {', '.join(missing)}")
            self.exit_code = 1
            return None
        start = int(data_of[OPERATOR_STATE][0].min())  # scene time 0: the operator's first sample
        end = min(int(data_of[t][0].max()) for t in main) + 1
        end = min(end, start + duration_ticks)
        n = end - start
        if n < 2:
            self.get_logger().error("nothing to write: fewer than two common ticks")
            self.exit_code = 1
            return None
        # The last samples of a run are still in flight when the operator ends it: a bag a few
        # ticks short of the duration is complete.
        interrupted = n < duration_ticks - END_TOLERANCE_TICKS
        data = np.zeros((n, len(COLUMNS)))
        filled: dict[str, int] = {}
        for topic, cols in STATE_COLUMNS.items():
            idx, vals, _ = data_of[topic]
            grid, missing = _on_grid(idx - start, vals, n)
            filled[topic] = missing
            for j, c in enumerate(cols):
                data[:, COL[c]] = grid[:, j]
        for topic, col in RECEIVED.items():
            seq_abs, arrive, _ = self._series[topic].arrays()
            column = np.full(n, -1.0)
            if seq_abs.size:
                seq = seq_abs - start
                at = arrive[:, 0].astype(np.int64) - start
                ok = (seq >= 0) & (seq < n) & (at >= 0) & (at < n) & (seq <= at)
                order = np.argsort(at[ok], kind="stable")  # the last release in a tick wins
                column[at[ok][order]] = seq[ok][order]
            data[:, COL[col]] = column
        start_ns = start * period
        logs: dict[str, list[Packet]] = {}
        f = {name: i for i, name in enumerate(PACKET_FIELDS)}
        size_col = f.get("size_bytes")
        for direction, chunks in self._packets.items():
            rows = np.concatenate(chunks) if chunks else np.zeros((0, len(PACKET_FIELDS)))
            keep = (rows[:, f["seq"]] >= start) & (rows[:, f["seq"]] < end)
            logs[direction] = [
                Packet(
                    seq=int(r[f["seq"]]) - start,
                    send_time_ns=int(round(r[f["send_time_s"]] * 1e9)) - start_ns,
                    payload=(),
                    size_bytes=int(r[size_col]) if size_col is not None else 0,
                    arrival_time_ns=(int(round(r[f["arrival_time_s"]] * 1e9)) - start_ns)
                    if np.isfinite(r[f["arrival_time_s"]])
                    else 0,
                    fate=int(r[f["fate"]]),
                    duplicate=bool(r[f["duplicate"]]),
                )
                for r in rows[keep]
            ]
        scene = LoadedScene(config=cfg, source=f"live: node {self.get_name()}", raw={})
        result = RunResult(
            scene=scene,
            ticks=n,
            period_ns=period,
            data=data,
            forward_log=logs["forward"],
            backward_log=logs["backward"],
            loop_wall_s=n * period * 1e-9,
            interrupted=interrupted,
        )
        info = {
            "mode": "live",
            "realtime_factor": 1.0,
            "ticks": n,
            "interrupted": interrupted,
            "start_stamp_ns": start_ns,
            "samples_filled": filled,
            "messages_received": dict(self.received_count),
            "written_at_unix_s": round(time.time(), 3),
        }
        self.bag_dir.parent.mkdir(parents=True, exist_ok=True)
        path = write_run(result, self.bag_dir, run_info=info)
        (self.bag_dir.parent / "live_run.json").write_text(json.dumps(info, indent=2, sort_keys=True) + "\n")
        return path


def _on_grid(idx: np.ndarray, vals: np.ndarray, n: int) -> tuple[np.ndarray, int]:
    """Samples at tick indices -> an (n, k) grid; a tick with no sample holds the previous value
    (the first value before the first sample). Returns the grid and how many ticks were filled."""
    k = vals.shape[1]
    ok = (idx >= 0) & (idx < n)
    have = np.zeros(n, dtype=bool)
    grid = np.zeros((n, k))
    if np.any(ok):
        grid[idx[ok]] = vals[ok]
        have[idx[ok]] = True
    if not have.any():
        return grid, n
    pos = np.where(have, np.arange(n), -1)
    pos = np.maximum.accumulate(pos)
    pos[pos < 0] = int(np.argmax(have))
    return grid[pos], int(n - np.count_nonzero(have))


def main() -> None:
    node_main(Recorder)


if __name__ == "__main__":
    main()
