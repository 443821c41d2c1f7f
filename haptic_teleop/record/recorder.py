"""RunRecorder: a run streamed into a bag at bounded memory, by a writer process that never outlives its parent.

The engine (or the live recorder) appends tick rows and packet records as they come; a writer
process (or the calling process, `parallel=False`) turns them into MCAP records and writes
chunks as they fill. Tick rows go through a ring of a few blocks in memory both processes map,
with flow control (a slot is reused only after the writer has encoded it), so memory does not
grow with the run. `flush` puts everything appended so far into the file as complete chunks;
`close` writes the summary, footer and metadata.yaml.

The writer process closes the bag (complete and readable) and exits when its parent dies: it
closes its copy of the parent's end of the pipe (so the parent's death is an end of file), asks
Linux for a signal on the parent's death (prctl PR_SET_PDEATHSIG) and checks its parent id while
it waits.
"""

from __future__ import annotations

import contextlib
import gc
import os
import signal
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from haptic_teleop.errors import BagError
from haptic_teleop.lifetime import die_with_parent, signals_held
from haptic_teleop.record.columns import ONE_DOF, TickSchema
from haptic_teleop.record.layouts import PACKET_BATCH, PACKET_FIELDS, packet_batch_head, packet_rows
from haptic_teleop.record.mcap import BagSink
from haptic_teleop.record.nve_columns import NveSchema
from haptic_teleop.record.streams import BLOCK_TICKS, NveStreams, RunStreams, make_streams

COMPRESSIONS = ("none", "zstd", "lz4")
RING_SLOTS = 4  # blocks of BLOCK_TICKS rows the parent may be ahead of the writer
# Packet records go through a ring of their own (two directions a block): a pickled array on the
# pipe filled the socket's buffer while the writer encoded a block, and the loop waited, 270 us a
# call (docs/recording_costs.md, "In the loop"). A larger hand-over goes on the pipe.
PACKET_SLOTS = 2 * RING_SLOTS
PACKET_SLOT_ROWS = 2 * BLOCK_TICKS
_WAIT_S = 0.5  # the writer checks on its parent at least this often while it waits


def _write_rows(sink: BagSink, streams: RunStreams | NveStreams, rows: np.ndarray) -> None:
    """The next ticks into the bag, as ready records."""
    for recs in streams.records(rows, sink.cids):
        sink.append(recs)


def _write_packets(sink: BagSink, streams: RunStreams | NveStreams, direction: str, rows: np.ndarray) -> None:
    stream = streams.packet_stream(direction, rows)
    if stream is not None:
        sink.write([stream])


def _writer_process(
    conn: Any,
    parent_end: Any,
    parent_pid: int,
    bag_dir: str,
    topics: list[tuple[str, str]],
    args: tuple[Any, ...],
    sink_args: tuple[str, Any],
    ring: np.ndarray | None,
    free: Any,
    sink: BagSink | None = None,
    packet_ring: np.ndarray | None = None,
    packet_free: Any = None,
) -> None:
    """Child process: write what arrives; close the bag however the parent ends.

    Messages: ("slot", (i, k)) k tick rows in ring slot i; ("rows", rows); ("packet_slot", (i,
    direction, k)) k packet records in packet ring slot i; ("packets", (direction, rows));
    ("flush", None), answered ("flushed", None); ("close", run_info), answered ("done",
    None). Any failure is answered ("error", text) after the bag is closed. With fork, the parent
    opens the bag (`sink`) and the child inherits it."""
    # A forked child holds a copy of everything its parent had made: the garbage collector's
    # passes over those objects (and the copy-on-write their headers' writes force) made the
    # writer 1.7 times slower than the loop in a process that had run much before (`bench speed`).
    # Frozen, they are left out of every collection here.
    gc.freeze()
    if parent_end is not None:
        parent_end.close()  # else the parent's death is no end of file here
    died = False

    def on_parent_death(signum: int, frame: Any) -> None:
        nonlocal died
        died = os.getppid() != parent_pid  # SIGTERM from elsewhere while the parent lives: ignored

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and closes the bag
    signal.signal(signal.SIGTERM, on_parent_death)
    die_with_parent(signal.SIGTERM)
    if os.getppid() != parent_pid:
        died = True  # the parent ended before the signal was asked for
    streams = make_streams(*args)
    if sink is None:
        sink = BagSink(Path(bag_dir), topics, *sink_args)
    run_info: dict[str, Any] = {}
    reply: tuple[str, str | None] = ("done", None)
    try:
        while True:
            if not conn.poll(_WAIT_S):
                if died or os.getppid() != parent_pid:
                    raise EOFError
                continue
            kind, payload = conn.recv()
            if kind == "slot":
                assert ring is not None
                i, k = payload
                try:
                    _write_rows(sink, streams, ring[i, :k])
                finally:
                    free.release()
            elif kind == "packet_slot":
                assert packet_ring is not None
                i, direction, k = payload
                try:
                    _write_packets(sink, streams, direction, packet_ring[i, :k])
                finally:
                    packet_free.release()
            elif kind == "rows":
                _write_rows(sink, streams, payload)
            elif kind == "packets":
                _write_packets(sink, streams, *payload)
            elif kind == "flush":
                sink.flush()
                conn.send(("flushed", None))
            elif kind == "close":
                run_info = payload
                break
    except EOFError:  # the parent died: close the bag with what it handed over
        run_info = {"ticks": streams.ticks, "interrupted": True, "failed": True, "recorder_parent_died": True}
        reply = ("error", "the recording process ended before closing the bag")
    except BaseException as exc:  # noqa: BLE001 - report any failure, then still close the bag
        reply = ("error", f"{type(exc).__name__}: {exc}")
    try:
        sink.write(streams.final(run_info))
    except BaseException as exc:  # noqa: BLE001 - still close the bag
        reply = reply if reply[0] == "error" else ("error", f"{type(exc).__name__}: {exc}")
    try:
        sink.close()
    except BaseException as exc:  # noqa: BLE001 - report it
        reply = ("error", f"{type(exc).__name__}: {exc}")
    with contextlib.suppress(OSError):
        conn.send(reply)


def _offered_qos(qos: dict[str, list[dict[str, Any]]] | None) -> dict[str, list[dict[str, Any]]] | None:
    """Per-topic offered QoS profiles (fields rosbag2 v9 names; unnamed fields take ROS 2's defaults)."""
    if qos is None:
        return None
    from haptic_teleop.record.metadata import qos_profile

    out = {}
    for topic, profiles in qos.items():
        try:
            out[topic] = [qos_profile(**p) for p in profiles]
        except (TypeError, ValueError) as exc:
            raise BagError(f"offered QoS of {topic}: {exc}") from None
    return out


class RunRecorder:
    """Records a run into a bag as it goes, in a second process by default so writing overlaps the loop.

    `append` takes the next tick rows, `append_packets` packet records of one direction (any seq
    order across calls), `flush` puts everything appended into the file as complete chunks, and
    `close` completes the bag. Whatever ends the run, calling `close` leaves a complete, readable
    bag; if this process dies, the writer process closes the bag on its own. The same calls in
    the same order give the same bytes, in process or not.
    """

    def __init__(
        self,
        bag_dir: Path,
        scene_yaml: str,
        period_ns: int,
        eba_internals: bool,
        packets: bool,
        n_columns: int,
        *,
        parallel: bool = True,
        compression: str = "none",
        qos: dict[str, list[dict[str, Any]]] | None = None,
        schema: TickSchema | NveSchema = ONE_DOF,
        view: Any = None,
    ) -> None:
        """`view`: also hand every appended block of rows and packet records to it (`rows(rows)`,
        `packets(direction, rows)`; record/foxglove_view.py) as it is appended, and close it with the
        bag."""
        self.bag_dir = Path(bag_dir)
        self._view = view
        if n_columns != schema.width:
            kind = "NVE" if isinstance(schema, NveSchema) else "tick"
            raise BagError(f"n_columns {n_columns} is not the {kind} schema's width {schema.width}")
        if compression not in COMPRESSIONS:
            raise BagError(f"compression {compression!r} is not one of {', '.join(COMPRESSIONS)}")
        self.compression = compression
        self.qos = _offered_qos(qos)
        if self.bag_dir.exists():
            raise BagError(f"{self.bag_dir} exists already; choose a new --out directory or remove it")
        self.n_columns = n_columns
        args = (scene_yaml, period_ns, eba_internals, packets, n_columns, schema)
        self._streams = make_streams(*args)
        # Topics the defaults (metadata.DEFAULT_QOS) do not name, offered as their kind is (NVE packet batches).
        offered = {**self._streams.default_qos(), **(self.qos or {})} or None
        sink_args = (compression, offered)
        topics = self._streams.topics()
        self._proc: Any = None
        self._conn: Any = None
        self._sink: BagSink | None = None
        self._ring: np.ndarray | None = None
        self._free: Any = None
        self._slot = 0
        self._packet_ring: np.ndarray | None = None
        self._packet_free: Any = None
        self._packet_slot = 0
        self._sent = 0  # ticks handed over through `block`
        self._closed = False
        self._error: str | None = None
        if not parallel:
            self._sink = BagSink(self.bag_dir, topics, *sink_args)
            return
        import multiprocessing as mp

        fork = "fork" in mp.get_all_start_methods()
        ctx: Any = mp.get_context("fork" if fork else "spawn")
        opened = None
        if fork:
            # Open the bag here and let the child inherit it: importing the writer, adding the
            # connections and the packet batch head were the child's first work while the loop ran.
            opened = BagSink(self.bag_dir, topics, *sink_args)
            opened.file.flush()  # nothing buffered may be written twice
            packet_batch_head(PACKET_BATCH)
            # Tick rows go through memory both processes map (inherited at fork): a ring of a few
            # blocks; the pipe carries only slot numbers. A slot is free again once encoded.
            import mmap

            buf = mmap.mmap(-1, RING_SLOTS * BLOCK_TICKS * n_columns * 8)
            self._ring = np.frombuffer(buf, dtype=np.float64).reshape(RING_SLOTS, BLOCK_TICKS, n_columns)
            self._free = ctx.Semaphore(RING_SLOTS)
            width = len(PACKET_FIELDS)
            pbuf = mmap.mmap(-1, PACKET_SLOTS * PACKET_SLOT_ROWS * width * 8)
            self._packet_ring = np.frombuffer(pbuf, dtype=np.float64).reshape(PACKET_SLOTS, PACKET_SLOT_ROWS, width)
            self._packet_free = ctx.Semaphore(PACKET_SLOTS)
        parent, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_writer_process,
            args=(
                child,
                parent if fork else None,
                os.getpid(),
                str(self.bag_dir),
                topics,
                args,
                sink_args,
                self._ring,
                self._free,
                opened,
                self._packet_ring,
                self._packet_free,
            ),
            daemon=True,
            name="bag-writer",
        )
        try:
            self._proc.start()
        except BaseException:
            if opened is not None:
                opened.close()  # a complete, empty bag rather than a dangling file
            raise
        child.close()
        if opened is not None:
            opened.file.close()  # the parent's copy of the descriptor; the child writes
        self._conn = parent

    # -- the streaming API
    def append(self, rows: np.ndarray) -> None:
        """The next k ticks: float64 (k, n_columns), in order. The rows are copied; this may wait
        for the writer (at most RING_SLOTS blocks are in flight)."""
        rows = np.asarray(rows)
        if rows.ndim != 2 or rows.shape[1] != self.n_columns or rows.dtype != np.float64:
            raise BagError(
                f"tick rows must be a float64 array of shape (ticks, {self.n_columns}); got {rows.dtype} {rows.shape}"
            )
        self._check_open()
        if self._view is not None:
            self._view.rows(rows)
        for a in range(0, rows.shape[0], BLOCK_TICKS):
            part = rows[a : a + BLOCK_TICKS]
            if self._sink is not None:
                _write_rows(self._sink, self._streams, part)
            elif self._ring is not None:
                self._wait_for_slot(self._free)
                with signals_held():  # the slot filled, named to the writer and passed, or none of it
                    k = part.shape[0]
                    self._ring[self._slot, :k] = part
                    self._send(("slot", (self._slot, k)))
                    self._slot = (self._slot + 1) % RING_SLOTS
            else:
                self._send(("rows", np.array(part)))

    def append_packets(self, direction: str, rows: np.ndarray) -> None:
        """Packet records of one direction ("forward" or "backward"; an NVE run's "<client>/up" or
        "<client>/down"): float64 (k, len(PACKET_FIELDS)) or a list of `Packet`s, written as batch
        messages of up to PACKET_BATCH records, logged at the time the recording has reached (the
        end of the ticks appended so far)."""
        self._streams.packet_topic(direction)  # BagError naming the allowed directions
        rows = packet_rows(rows)
        self._check_open()
        if self._view is not None:
            self._view.packets(direction, rows)
        if self._sink is not None:
            _write_packets(self._sink, self._streams, direction, rows)
        elif self._packet_ring is not None and rows.shape[0] <= PACKET_SLOT_ROWS:
            self._wait_for_slot(self._packet_free)
            with signals_held():  # the slot filled, named to the writer and passed, or none of it
                k = rows.shape[0]
                self._packet_ring[self._packet_slot, :k] = rows
                self._send(("packet_slot", (self._packet_slot, direction, k)))
                self._packet_slot = (self._packet_slot + 1) % PACKET_SLOTS
        else:
            self._send(("packets", (direction, np.array(rows))))

    def flush(self) -> None:
        """Everything appended so far is in the file as complete chunks (a kill after this loses none of it)."""
        self._check_open()
        if self._sink is not None:
            self._sink.flush()
            return
        self._send(("flush", None))
        kind, msg = self._recv()
        if kind != "flushed":
            self._fail(msg)

    def close(self, run_info: dict[str, Any]) -> Path:
        """Write the run facts, the summary section, footer and metadata.yaml: the bag is complete."""
        if self._closed:
            return self.bag_dir
        self._closed = True
        if self._view is not None:  # the live view ends with the recording
            self._view.close()
        if self._sink is not None:
            try:
                self._sink.write(self._streams.final(run_info))
            finally:
                self._sink.close()
            return self.bag_dir
        if self._error is None:
            with contextlib.suppress(BagError):
                self._send(("close", run_info))
        kind, msg = ("error", self._error) if self._error is not None else self._recv()
        # "done" comes after the bag is complete: the writer only has to exit, which took 2 to 6 ms
        # of the run's wall time when waited for here. multiprocessing reaps it at the next start
        # of a process or at this one's exit.
        self._proc.join(timeout=0 if kind == "done" else 60)
        if kind == "error":
            raise BagError(f"{self.bag_dir}: writing the bag failed: {msg}")
        return self.bag_dir

    # -- the engine's older calls, on top of the streaming API
    def block(self, data: np.ndarray, stop: int) -> None:
        """Hand over ticks [last stop, stop) of the engine's column array."""
        start = self._sent
        if stop <= start:
            return
        self._sent = stop
        self.append(data[start:stop])

    def finish(
        self,
        data: np.ndarray,
        ticks: int,
        forward_log: Sequence[Any] | np.ndarray,
        backward_log: Sequence[Any] | np.ndarray,
        run_info: dict[str, Any],
    ) -> Path:
        """Write the ticks not handed over yet, the packet records and the run facts; close the bag.

        Each log is a link's list of packets, or their records ready made (float64, shape
        (packets, len(PACKET_FIELDS))). If a log cannot be turned into records, the bag is still
        closed (without packet records) before the error is raised."""
        try:
            self.block(data, ticks)
            rows = (packet_rows(forward_log), packet_rows(backward_log))
        except BaseException:
            with contextlib.suppress(BagError):
                self.close(run_info)
            raise
        self.append_packets("forward", rows[0])
        self.append_packets("backward", rows[1])
        return self.close(run_info)

    # -- the writer process
    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f"{self.bag_dir}: the recorder is closed")
        if self._error is not None:
            self._fail(self._error)

    def _fail(self, msg: str | None) -> None:
        self._error = msg
        raise BagError(f"{self.bag_dir}: writing the bag failed: {msg}")

    def _send(self, message: tuple[str, Any]) -> None:
        try:
            with signals_held():  # a message cut in half by Ctrl-C would leave the pipe out of step
                self._conn.send(message)
        except OSError:
            self._fail(self._pending_error() or "the bag writer process ended")

    def _recv(self) -> tuple[str, Any]:
        try:
            while not self._conn.poll(_WAIT_S):
                if not self._proc.is_alive():
                    return ("error", f"the bag writer process ended (exit code {self._proc.exitcode})")
            kind, msg = self._conn.recv()
        except (EOFError, OSError):
            return ("error", f"the bag writer process ended (exit code {self._proc.exitcode})")
        return kind, msg

    def _pending_error(self) -> str | None:
        with contextlib.suppress(EOFError, OSError):
            if self._conn.poll(0):
                kind, msg = self._conn.recv()
                if kind == "error":
                    return str(msg)
        return None

    def _wait_for_slot(self, free: Any) -> None:
        while not free.acquire(timeout=_WAIT_S):
            if not self._proc.is_alive():
                self._fail(self._pending_error() or f"the bag writer process ended (exit code {self._proc.exitcode})")


class FinishedRun(Protocol):
    """What `write_run` reads of a finished run (the engine's RunResult)."""

    scene: Any  # the loaded scene: to_yaml() and config.recording
    ticks: int
    period_ns: int
    data: np.ndarray
    forward_log: np.ndarray
    backward_log: np.ndarray


def write_run(
    result: FinishedRun,
    bag_dir: Path,
    run_info: dict[str, Any],
    parallel: bool = False,
    compression: str | None = None,
) -> Path:
    """Write a finished run as a rosbag2 directory with MCAP storage, in the same blocks as live recording.

    The run's tick schema is its `schema` attribute (the 1-DoF schema if it has none).
    Compression: as given, else the scene's recording.compression."""
    schema: TickSchema = getattr(result, "schema", None) or ONE_DOF
    rec = RunRecorder(
        bag_dir,
        result.scene.to_yaml(),
        result.period_ns,
        result.scene.config.recording.eba_internals,
        result.scene.config.recording.packets,
        schema.width,
        parallel=parallel,
        compression=compression or str(getattr(result.scene.config.recording, "compression", "none")),
        schema=schema,
    )
    for stop in range(BLOCK_TICKS, result.ticks, BLOCK_TICKS):
        rec.block(result.data, stop)
    return rec.finish(result.data, result.ticks, result.forward_log, result.backward_log, run_info)
