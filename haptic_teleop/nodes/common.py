"""Plumbing shared by the live nodes: QoS, parameters from the scene schema, the 1 kHz loop thread,
the remote-data watchdog, message helpers, diagnostics and the process entry point.

Nothing here computes teleoperation: the nodes wire the core objects (controllers, links,
buffers, operator, plants) exactly as the engine does, and this module only carries time,
messages and parameters to and from them.
"""

from __future__ import annotations

import array
import ctypes
import dataclasses
import gc
import math
import os
import signal
import sys
import threading
import time
import types
import typing
from collections.abc import Callable, Sequence
from typing import Any, Union, get_args, get_origin

from haptic_teleop.errors import ConfigError, HapticTeleopError
from haptic_teleop.nodes import LOOP_FIGURES_MARK

# ---------------------------------------------------------------------------------------------
# Environment: DDS stays on this host unless the user chose otherwise.


def ensure_local_discovery() -> None:
    """Nodes started by hand keep DDS on this host too, unless the user chose a range."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


# ---------------------------------------------------------------------------------------------
# Topics. Names match the bag (haptic_teleop.record) where the meaning is the same.

OPERATOR_STATE = "/operator/joint_states"
MASTER_STATE = "/master/joint_states"
SLAVE_STATE = "/slave/joint_states"
SLAVE_CONTACT = "/slave/contact_wrench"
MASTER_EBA = "/master/eba"
SLAVE_EBA = "/slave/eba"
DIAGNOSTICS = "/diagnostics"
DIRECTIONS = ("forward", "backward")
EBA_LABELS = ("reservoir_j", "force_desired_n")
# Joint names and frame: the recorder decodes raw bytes with bag.py's fixed layouts, which
# were made with exactly these strings.
OPERATOR_JOINT = "operator_x"
MASTER_JOINT = "master_x"
SLAVE_JOINT = "slave_x"
WALL_FRAME = "wall"


def sent_topic(direction: str) -> str:
    return f"/{direction}/sent"


def delivered_topic(direction: str) -> str:
    """Relay -> sync buffer: what the network delivered, in arrival order."""
    return f"/{direction}/delivered"


def received_topic(direction: str) -> str:
    """Sync buffer -> controller: the sample released for this tick (as in the bag)."""
    return f"/{direction}/received"


READER_DEPTH = 50  # local history of readers that must not drop samples while busy


def packets_topic(direction: str) -> str:
    return f"/{direction}/packets"


def playout_topic(direction: str) -> str:
    """Sync buffer -> recorder: what the buffer decided for each packet it received (played or late)."""
    return f"/{direction}/playout"


SCENE_TOPIC = "/haptic_teleop/scene"  # the resolved scene (std_msgs/String, YAML), latched
# The operator source's scene time 0 (std_msgs/Header, stamp = the tick it started at), latched: the
# recorder's grid starts there even if the operator's first samples did not reach it.
SCENE_START_TOPIC = "/haptic_teleop/scene_start"


def scene_start_ns(header: Any, period_ns: int) -> int:
    """Scene time 0 on the node clock, from a SCENE_START_TOPIC message: its stamp, on the tick
    grid (a whole number of periods). The one definition the relays (their links run in scene
    time, node clock - this) and the recorder (its grid starts here) share."""
    st = header.stamp
    return (int(st.sec) * 1_000_000_000 + int(st.nanosec)) // period_ns * period_ns


def latched_qos() -> Any:
    """Reliable, keep last 1, transient local: a subscriber that joins later gets the last message."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


# A direction's payload, in the order the core controllers expect (TeleopController docstring),
# and where each value sits in the sensor_msgs/JointState that carries it.
PAYLOAD_FIELDS = {
    "forward": ("position", "velocity"),  # master -> slave: (x_m, v_m)
    "backward": ("effort", "position", "velocity"),  # slave -> master: (f_env, x_s, v_s)
}
DIRECTION_JOINT = {"forward": MASTER_JOINT, "backward": SLAVE_JOINT}
JOINT_ORDER = ("position", "velocity", "effort")  # JointState's value arrays
# The JointState fields a direction's messages fill, on /<dir>/sent, /delivered and /received
# alike (JointState order; PAYLOAD_FIELDS says which value is which).
WIRE_FIELDS = {"forward": ("position", "velocity"), "backward": ("position", "velocity", "effort")}


def stream_qos(depth: int = 1) -> Any:
    """1 kHz streams: best effort, keep last, depth 1, volatile (docs/architecture.md, "Live mode").

    A reader that must see every sample rather than the newest (relay, sync buffer, recorder)
    keeps a deeper local history: still compatible with depth-1 writers.
    """
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def reliable_qos(depth: int = 100) -> Any:
    """Commands and batched logs: reliable, keep last `depth`, volatile."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


# ---------------------------------------------------------------------------------------------
# Parameters: the scene schema (haptic_teleop.scene) is the one source of names, types, ranges.

LOOP_PRIORITY_PARAM = "loop.realtime_priority"
DEFAULT_REALTIME_PRIORITY = 40
_INT64_MIN = -(2**63)
_INT64_MAX = 2**63 - 1


@dataclasses.dataclass(frozen=True)
class ParamSpec:
    """One scene leaf as a ROS parameter."""

    name: str  # dotted key path, e.g. controllers.master.stiffness_n_per_m
    kind: type  # bool, int, float, str, or tuple (array)
    inner: type | None  # element type of an array
    metadata: typing.Mapping[str, Any]
    default: Any


def _unwrap_optional(tp: Any) -> Any:
    if get_origin(tp) in (Union, types.UnionType):
        args = [a for a in get_args(tp) if a is not type(None)]
        return args[0]
    return tp


def section_type(path: str) -> type:
    """The config dataclass at a dotted path of the scene (`""` is the whole scene)."""
    from haptic_teleop.scene import Scene

    cls: Any = Scene
    for part in [p for p in path.split(".") if p]:
        hints = typing.get_type_hints(cls)
        if part not in hints:
            raise KeyError(f"{path}: no section {part!r} in {cls.__name__}")
        cls = _unwrap_optional(hints[part])
        if not dataclasses.is_dataclass(cls):
            raise KeyError(f"{path}: {part!r} is a value, not a section")
    return typing.cast(type, cls)


def scene_param_specs(path: str) -> list[ParamSpec]:
    """Every leaf below the scene section at `path`, as parameter specs."""
    out: list[ParamSpec] = []

    def walk(cls: Any, prefix: str) -> None:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            name = f"{prefix}.{f.name}" if prefix else f.name
            tp = _unwrap_optional(hints[f.name])
            if dataclasses.is_dataclass(tp):
                walk(tp, name)
                continue
            inner = None
            kind = tp
            if get_origin(tp) is tuple:
                kind, inner = tuple, get_args(tp)[0]
            default = f.default if f.default is not dataclasses.MISSING else None
            out.append(ParamSpec(name, kind, inner, f.metadata, default))

    walk(section_type(path), path)
    return out


def _descriptor(spec: ParamSpec) -> Any:
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    meta = spec.metadata
    lo = meta.get("min", meta.get("gt"))
    hi = meta.get("max", meta.get("lt"))
    parts = [str(meta.get("help", ""))]
    if meta.get("gt") is not None:
        parts.append(f"> {meta['gt']}")
    if meta.get("lt") is not None:
        parts.append(f"< {meta['lt']}")
    d = ParameterDescriptor(description="; ".join(p for p in parts if p))
    if meta.get("choices"):
        d.additional_constraints = "one of: " + ", ".join(map(str, meta["choices"]))
    element = spec.inner if spec.kind is tuple else spec.kind
    if element is float and (lo is not None or hi is not None):
        d.floating_point_range = [
            FloatingPointRange(
                from_value=float(lo) if lo is not None else -math.inf,
                to_value=float(hi) if hi is not None else math.inf,
                step=0.0,
            )
        ]
    elif element is int and spec.kind is int and (lo is not None or hi is not None):
        d.integer_range = [
            IntegerRange(
                from_value=int(lo) if lo is not None else _INT64_MIN,
                to_value=int(hi) if hi is not None else _INT64_MAX,
                step=0,
            )
        ]
    return d


def _param_type(spec: ParamSpec) -> Any:
    from rclpy.parameter import Parameter

    element = spec.inner if spec.kind is tuple else spec.kind
    if spec.kind is tuple:
        return {
            float: Parameter.Type.DOUBLE_ARRAY,
            int: Parameter.Type.INTEGER_ARRAY,
            str: Parameter.Type.STRING_ARRAY,
        }[typing.cast(type, element)]
    return {
        bool: Parameter.Type.BOOL,
        int: Parameter.Type.INTEGER,
        float: Parameter.Type.DOUBLE,
        str: Parameter.Type.STRING,
    }[typing.cast(type, element)]


def declare_scene(node: Any, sections: Sequence[str], extra_names: Sequence[str] = ()) -> Any:
    """Declare every leaf of `sections` (dotted scene paths) as a typed parameter with its range,
    read those that are set, and validate them as a scene.

    Returns the validated `haptic_teleop.scene.Scene` (sections not declared keep their defaults).
    ROS rejects a wrong type or an out-of-range value at declaration; the schema then checks what
    ROS cannot (exclusive bounds, choices, cross-field contradictions). Every error names the
    parameter. Parameters in the file that no section or `extra_names` declares are errors too.
    """
    from haptic_teleop.scene import Scene
    from haptic_teleop.schema import build

    raw: dict[str, Any] = {}
    declared: set[str] = set(extra_names) | {LOOP_PRIORITY_PARAM, LOOP_CATCH_UP_PARAM}
    for section in sections:
        for spec in scene_param_specs(section):
            declared.add(spec.name)
            p = node.declare_parameter(spec.name, _param_type(spec), _descriptor(spec))
            if int(p.type_) == 0:  # NOT_SET: not in the parameter file, the schema default applies
                continue
            value = p.value
            if spec.kind is tuple:
                value = list(value)
            cur = raw
            parts = spec.name.split(".")
            for part in parts[:-1]:
                cur = cur.setdefault(part, {})
            cur[parts[-1]] = value
    overrides = getattr(node, "_parameter_overrides", {})  # rclpy keeps the file's values here
    unknown = sorted(
        n for n in overrides if n not in declared and n != "use_sim_time" and not n.startswith("qos_overrides.")
    )
    if unknown:
        raise ConfigError(
            f"parameters of node {node.get_name()}",
            unknown[0],
            overrides[unknown[0]].value,
            "unknown parameter for this node; it reads " + ", ".join(sections),
        )
    return build(Scene, raw, "", f"parameters of node {node.get_name()}")


def declare_value(
    node: Any,
    name: str,
    default: Any,
    description: str,
    lo: float | None = None,
    hi: float | None = None,
    choices: Sequence[str] | None = None,
) -> Any:
    """Declare one node-specific parameter with a descriptor (range or choices) and return its value."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    d = ParameterDescriptor(description=description)
    if isinstance(default, float) and (lo is not None or hi is not None):
        d.floating_point_range = [
            FloatingPointRange(
                from_value=-math.inf if lo is None else float(lo),
                to_value=math.inf if hi is None else float(hi),
                step=0.0,
            )
        ]
    elif isinstance(default, int) and not isinstance(default, bool) and (lo is not None or hi is not None):
        d.integer_range = [
            IntegerRange(
                from_value=_INT64_MIN if lo is None else int(lo), to_value=_INT64_MAX if hi is None else int(hi), step=0
            )
        ]
    if choices:
        d.additional_constraints = "one of: " + ", ".join(choices)
    value = node.declare_parameter(name, default, d).value
    if choices and value not in choices:
        raise ConfigError(f"parameters of node {node.get_name()}", name, value, "allowed: one of " + ", ".join(choices))
    return value


# ---------------------------------------------------------------------------------------------
# The absolute-deadline loop.

_PR_SET_TIMERSLACK = 29
_WAIT_MARGIN_NS = 150_000
LOOP_CATCH_UP_PARAM = "loop.max_catch_up_periods"
# How many whole periods a tick may lag its deadline and still run (late) rather than be skipped.
# 10: a stall of up to 10 ms (a preempted vCPU, a slow pass) is made up by running the backlog at
# once; the cost is lateness, reported (docs/live.md, "Late ticks").
DEFAULT_MAX_CATCH_UP = 10
# Diagnostics are published by the loop thread itself, after a tick, when the next deadline is at
# least this share of a period away (or the report is overdue by REPORT_OVERDUE_S): a reporting
# thread of its own would hold the GIL the loop needs, for milliseconds a second (docs/live.md).
IDLE_SHARE = 0.4
REPORT_PERIOD_S = 1.0
REPORT_OVERDUE_S = 2.0
IdleFn = Callable[[bool], bool]  # idle(room): background work if due (and room, unless overdue); did it?


def next_tick(k: int, now_ns: int, period_ns: int, phase_ns: int, max_catch_up: int | None) -> tuple[int, int]:
    """The tick a loop runs at `now_ns` when tick `k` (deadline k * period + phase) is the next one
    due: `(index, skipped)`.

    A tick less than `max_catch_up` + 1 whole periods past its deadline runs, late if need be, so a
    stall is made up by running the backlog back to back. Further behind, the backlog is dropped:
    the loop runs the newest deadline already passed and the ticks in between are skipped
    (overruns). `max_catch_up` 0 skips whenever a whole period was missed; None never skips
    (simulated time, where a deadline is only a label).
    """
    if max_catch_up is None:
        return k, 0
    late = now_ns - (k * period_ns + phase_ns)
    if late < (max_catch_up + 1) * period_ns:
        return k, 0
    newest = (now_ns - phase_ns) // period_ns
    return newest, newest - k


def _tight_timer_slack() -> None:
    """Ask Linux for 1 us timer slack on this thread (default 50 us): sleeps end closer to the deadline."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_TIMERSLACK, 1000, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _enter_realtime(priority: int, on_warning: Callable[[str], None] | None) -> bool:
    """Tight timer slack, and SCHED_FIFO `priority` for this thread (as ros2_control's control
    thread has) if allowed and > 0. Returns whether the thread runs real-time."""
    _tight_timer_slack()
    if priority <= 0:
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return True
    except (OSError, AttributeError) as exc:
        if on_warning is not None:
            on_warning(
                f"no SCHED_FIFO priority {priority} for the loop ({exc}); running with normal "
                "scheduling, which misses deadlines under load (docs/live.md: real-time priority)"
            )
        return False


# Lateness histogram: bin b counts lateness in [2^(b/8), 2^((b+1)/8)) us (9 % wide), bin 0 also
# everything below 1 us, the last bin everything from 2^(127/8) us = 60 ms up.
LATENESS_BINS = 128
_BINS_PER_OCTAVE = 8


def lateness_bin_edges_us() -> Any:
    """Edges of the lateness histogram's bins in us (LATENESS_BINS + 1 values; the last is open)."""
    import numpy as np

    edges = 2.0 ** (np.arange(LATENESS_BINS + 1) / _BINS_PER_OCTAVE)
    edges[0] = 0.0
    return edges


def lateness_bins(lateness_ns: Any) -> Any:
    """Histogram bin of each lateness (ns, numpy array)."""
    import numpy as np

    us = np.maximum(np.asarray(lateness_ns, dtype=np.float64) * 1e-3, 1.0)
    return np.minimum((np.log2(us) * _BINS_PER_OCTAVE).astype(np.int64), LATENESS_BINS - 1)


def hist_percentiles_us(hist: Sequence[int], qs: Sequence[float] = (50.0, 99.0)) -> list[float]:
    """Percentiles (us) of the lateness a histogram counts, interpolated inside the bin (so to
    within a bin's 9 %); NaN for an empty histogram."""
    import numpy as np

    counts = np.zeros(LATENESS_BINS)
    counts[: len(hist)] = np.asarray(hist, dtype=np.float64)[:LATENESS_BINS]
    n = counts.sum()
    if n <= 0:
        return [math.nan for _ in qs]
    edges = lateness_bin_edges_us()
    cum = np.cumsum(counts)
    out = []
    for q in qs:
        rank = q / 100.0 * n
        b = min(int(np.searchsorted(cum, rank, side="left")), LATENESS_BINS - 1)
        below = cum[b] - counts[b]
        frac = (rank - below) / counts[b] if counts[b] > 0 else 0.0
        out.append(float(edges[b] + frac * (edges[b + 1] - edges[b])))
    return out


class LoopStats:
    """Counters of one loop, written (`record`) and reported (`report`) by the loop's own thread, so
    without locks. Lateness (wake time - deadline) is kept in a ring."""

    RING = 1 << 17  # 131 s at 1 kHz

    def __init__(self, period_ns: int) -> None:
        self.period_ns = period_ns
        self.ticks = 0  # ticks run
        self.overruns = 0  # deadlines skipped (not run at all)
        self.late_ticks = 0  # ticks run a whole period or more after their deadline (caught up)
        self.busy_ns = 0  # wall time spent in this loop's ticks
        self.first_ns = 0
        self.last_ns = 0  # wake time of the newest tick
        self.lateness_ns = array.array("q", bytes(8 * self.RING))
        # The reporting side: the cumulative lateness histogram, and where the previous report was.
        import numpy as np

        self.hist = np.zeros(LATENESS_BINS, dtype=np.int64)
        self._reported = 0
        self._prev_ticks = 0
        self._prev_last_ns = 0
        self._prev_busy_ns = 0

    def record(self, woke_ns: int, deadline_ns: int) -> None:
        """One tick that woke at `woke_ns` for `deadline_ns`."""
        n = self.ticks
        late = woke_ns - deadline_ns
        self.lateness_ns[n & (self.RING - 1)] = late
        if late >= self.period_ns:
            self.late_ticks += 1
        if n == 0:
            self.first_ns = woke_ns
        self.last_ns = woke_ns
        self.ticks = n + 1  # last: the entry is written before it is counted

    def rate_hz(self) -> float:
        """Ticks run per second of wall time since the first."""
        span = self.last_ns - self.first_ns
        return (self.ticks - 1) / (span * 1e-9) if self.ticks > 1 and span > 0 else 0.0

    def report(self) -> dict[str, float | int | str]:
        """Figures since the previous report (rate, lateness p50/p99/max, share of wall time in
        ticks) and cumulative ones (ticks, overruns, late ticks, wake time of the newest tick,
        lateness histogram): two reports' cumulative figures give exact ones over the time between
        them (what `haptic-teleop bench live` does)."""
        import numpy as np

        ticks, last_ns, busy = self.ticks, self.last_ns, self.busy_ns
        start = max(self._reported, ticks - self.RING)
        ring = np.frombuffer(self.lateness_ns, dtype=np.int64)
        i0, i1 = start & (self.RING - 1), ticks & (self.RING - 1)
        if ticks - start == 0:
            late = ring[:0]
        elif i0 < i1:
            late = ring[i0:i1]
        else:  # wrapped around the ring's end
            late = np.concatenate((ring[i0:], ring[:i1]))
        if late.size:
            self.hist += np.bincount(lateness_bins(late), minlength=LATENESS_BINS)
            a = np.sort(late)
            p50, p99 = (_sorted_percentile(a, q) * 1e-3 for q in (50.0, 99.0))
            worst = float(a[-1]) * 1e-3
        else:
            p50 = p99 = worst = math.nan
        if self._prev_ticks > 0:
            span, n = last_ns - self._prev_last_ns, ticks - self._prev_ticks
        else:
            span, n = last_ns - self.first_ns, ticks - 1
        rate = n / (span * 1e-9) if span > 0 else 0.0
        busy_pct = (busy - self._prev_busy_ns) / span * 100.0 if span > 0 else 0.0
        self._reported = ticks
        self._prev_ticks, self._prev_last_ns, self._prev_busy_ns = ticks, last_ns, busy
        used = np.flatnonzero(self.hist)
        top = int(used[-1]) + 1 if used.size else 0
        return {
            "loop_rate_hz": round(rate, 3),
            "lateness_p50_us": round(p50, 1),
            "lateness_p99_us": round(p99, 1),
            "lateness_max_us": round(worst, 1),
            "tick_time_percent": round(busy_pct, 2),
            "ticks": ticks,
            "overruns": self.overruns,
            "late_ticks": self.late_ticks,
            "last_tick_ns": last_ns,
            "tick_time_s": round(busy * 1e-9, 6),
            "lateness_hist": " ".join(map(str, self.hist[:top].tolist())),
        }


def _sorted_percentile(a: Any, q: float) -> float:
    """Percentile q of sorted values `a` (linear interpolation, as numpy's default)."""
    pos = q / 100.0 * (a.size - 1)
    lo = int(pos)
    hi = min(lo + 1, a.size - 1)
    return float(a[lo]) + (pos - lo) * (float(a[hi]) - float(a[lo]))


class LoopThread:
    """Runs `tick(index, stamp_ns)` once per period on the absolute grid stamp = index * period.

    Deadlines are absolute (the grid of the clock), so lateness never accumulates into drift. A
    tick that starts late still runs, up to `max_catch_up` whole periods late (next_tick): the
    backlog of a stall is run back to back; further behind, the missed deadlines are skipped and
    counted as overruns (with simulated time every tick runs, late). With a system clock the
    thread sleeps until the deadline; with simulated time (use_sim_time) it follows the node's
    ROS clock, i.e. /clock.
    """

    def __init__(
        self,
        name: str,
        period_ns: int,
        tick: Callable[[int, int], None],
        now_ns: Callable[[], int] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
        simulated: bool = False,
        waiter: Callable[[int], None] | None = None,
        realtime_priority: int = 0,
        on_warning: Callable[[str], None] | None = None,
        phase_ns: int = 0,
        max_catch_up: int = DEFAULT_MAX_CATCH_UP,
        idle: IdleFn | None = None,
    ) -> None:
        if not 0 <= phase_ns < period_ns:
            raise ValueError(f"phase_ns must be in [0, period_ns), got {phase_ns}")
        if max_catch_up < 0:
            raise ValueError(f"max_catch_up must be >= 0 periods, got {max_catch_up}")
        self.name = name
        self.period_ns = period_ns
        self.phase_ns = phase_ns
        self.max_catch_up = max_catch_up
        self._idle = idle
        self._tick = tick
        self._now = now_ns or time.time_ns
        self._simulated = simulated
        # waiter(timeout_ns): block at most that long for input events and handle them; the
        # loop then waits again until its deadline. Without one, the thread just sleeps.
        self._waiter = waiter
        self.realtime_priority = realtime_priority
        self._on_warning = on_warning
        self.realtime = False
        self._on_error = on_error
        self._stop = threading.Event()
        self.stats = LoopStats(period_ns)
        self._thread = threading.Thread(target=self._run, name=f"{name}-loop", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def _wait_until(self, deadline_ns: int) -> int:
        now = self._now
        waiter = self._waiter
        t = now()
        while t < deadline_ns and not self._stop.is_set():
            # Simulated time moves only with /clock: look again every 0.2 ms of wall time.
            remaining = 200_000 if self._simulated else deadline_ns - t
            if waiter is not None and remaining > _WAIT_MARGIN_NS:
                # A DDS wait wakes later than a sleep does: wait for input until shortly
                # before the deadline, then sleep the rest.
                waiter(remaining - _WAIT_MARGIN_NS)
            else:
                time.sleep(remaining * 1e-9)
            t = now()
        if waiter is not None:
            waiter(0)  # input that came in the last stretch, before the tick
        return now()

    def _run(self) -> None:
        # Simulated time has no wall-clock deadlines, and a loop behind /clock runs its ticks back to
        # back: with SCHED_FIFO that would take a whole CPU from every normal thread, its own
        # process's signal handling and DDS threads included. Real-time priority only on wall time.
        self.realtime = _enter_realtime(0 if self._simulated else self.realtime_priority, self._on_warning)
        period = self.period_ns
        stats = self.stats
        tick = self._tick
        stop = self._stop
        bound = None if self._simulated else self.max_catch_up
        idle = self._idle
        try:
            if self._simulated:
                while self._now() <= 0 and not stop.is_set():  # no /clock yet
                    time.sleep(0.001)
            phase = self.phase_ns
            k = (self._now() - phase) // period + 1
            while not stop.is_set():
                t = self._wait_until(k * period + phase)
                if stop.is_set():
                    break
                k, skipped = next_tick(k, t, period, phase, bound)
                stats.overruns += skipped
                stats.record(t, k * period + phase)
                t0 = time.perf_counter_ns()
                tick(k, k * period)  # the stamp is on the grid; the phase only moves the wake-up
                stats.busy_ns += time.perf_counter_ns() - t0
                k += 1
                if idle is not None:
                    idle(self._simulated or k * period + phase - self._now() >= IDLE_SHARE * period)
        except BaseException as exc:
            if self._on_error is not None:
                self._on_error(exc)
            else:
                raise


TickFn = Callable[[int, int], None]
ErrorFn = Callable[[BaseException], None]


def member_ticks_between(k0: int, k1: int, every: int) -> int:
    """How many of the base deadlines k0 .. k1 - 1 are ticks of a member that ticks every `every`
    of them (those with k % every == 0)."""
    return (k1 - 1) // every - (k0 - 1) // every


class SharedLoop:
    """One thread ticking every node of a process in pipeline order (`--single-process`).

    Each 1 kHz node with its own thread costs a sleep and a wake-up per period, and on a small VM
    a wake-up is tens of microseconds of CPU (docs/live.md, "CPU per node"). Composed in one
    process, the nodes share one thread instead: at each deadline k * base period it drains every
    node's event subscriptions and runs its tick, in order of loop phase (producers, relays,
    buffers, as the engine orders a tick), each node at its own period (a multiple of the base).
    A pass that starts late still runs, up to the members' smallest `max_catch_up` whole periods
    late (next_tick); further behind, the missed deadlines are skipped for every node and counted
    as its overruns. Members look like LoopThreads to their nodes (stats, start, stop, running,
    realtime).
    """

    def __init__(
        self, base_period_ns: int = 1_000_000, realtime_priority: int = 0, now_ns: Callable[[], int] | None = None
    ) -> None:
        self.base_period_ns = base_period_ns
        self._now = now_ns or time.time_ns  # the wall clock (another only in tests)
        self.realtime_priority = realtime_priority
        self.realtime = False
        self.members: list[SharedLoop.Member] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()  # held while a member ticks
        self._thread = threading.Thread(target=self._run, name="shared-loop", daemon=True)
        self._started = False

    class Member:
        def __init__(self, group: SharedLoop, name: str, period_ns: int, phase: float, tick: TickFn,
                     drain: Callable[[], None] | None, on_error: ErrorFn | None,
                     max_catch_up: int = DEFAULT_MAX_CATCH_UP, idle: IdleFn | None = None) -> None:  # fmt: skip
            if period_ns % group.base_period_ns:
                raise ValueError(
                    f"{name}: period {period_ns} ns is not a multiple of the shared loop's {group.base_period_ns}"
                )
            if max_catch_up < 0:
                raise ValueError(f"{name}: max_catch_up must be >= 0 periods, got {max_catch_up}")
            self.group, self.name, self.period_ns, self.phase = group, name, period_ns, phase
            self.every = period_ns // group.base_period_ns
            self.tick, self.drain, self.on_error = tick, drain, on_error
            self.max_catch_up = max_catch_up
            self.idle = idle
            self.stats = LoopStats(period_ns)
            self.active = True

        @property
        def realtime(self) -> bool:
            return self.group.realtime

        @property
        def running(self) -> bool:
            return self.active and self.group._thread.is_alive()

        def start(self) -> None:
            self.group.start()

        def stop(self, timeout_s: float = 2.0) -> None:
            """No more ticks; returns once a tick of this node in progress has finished (its node
            may then release what the tick uses, e.g. its plant)."""
            self.active = False
            if threading.current_thread() is not self.group._thread:
                with self.group._lock:
                    pass

    def add(self, name: str, period_ns: int, phase: float, tick: TickFn,
            drain: Callable[[], None] | None, on_error: ErrorFn | None,
            max_catch_up: int = DEFAULT_MAX_CATCH_UP, idle: IdleFn | None = None) -> SharedLoop.Member:  # fmt: skip
        m = SharedLoop.Member(self, name, period_ns, phase, tick, drain, on_error, max_catch_up, idle)
        self.members.append(m)
        self.members.sort(key=lambda x: x.phase)  # stable: registration order within a phase
        return m

    def start(self) -> None:
        if not self._started:
            self._started = True
            self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)

    def _run(self) -> None:
        self.realtime = _enter_realtime(self.realtime_priority, None)
        base = self.base_period_ns
        bound = min((m.max_catch_up for m in self.members), default=DEFAULT_MAX_CATCH_UP)
        now = self._now
        k = now() // base + 1
        stop = self._stop
        lock = self._lock
        members = self.members
        rr = 0  # whose background work is looked at first after the next pass
        while not stop.is_set():
            deadline = k * base
            t = now()
            while t < deadline and not stop.is_set():
                time.sleep((deadline - t) * 1e-9)
                t = now()
            k_run, skipped = next_tick(k, t, base, 0, bound)
            if skipped:
                for m in members:
                    m.stats.overruns += member_ticks_between(k, k_run, m.every)
                k = k_run
                deadline = k * base
            for m in members:
                if k % m.every:
                    continue
                with lock:
                    if m.active:
                        self._tick(m, deadline)
            k += 1
            if k % 4 == 0:  # background work looked at every few passes: it is due once a second
                rr = self._idle_in_turn(k * base - now() >= IDLE_SHARE * base, rr)

    def _idle_in_turn(self, room: bool, rr: int) -> int:
        """After a pass: at most one member's background work (its due diagnostics), members in
        turn; returns where to start next time."""
        members = self.members
        n = len(members)
        for i in range(n):
            m = members[(rr + i) % n]
            if m.idle is not None and m.active:
                with self._lock:
                    if m.active and m.idle(room):
                        return (rr + i + 1) % n
        return rr

    def _tick(self, m: SharedLoop.Member, deadline: int) -> None:
        st = m.stats
        t0 = self._now()
        st.record(t0, deadline)
        try:
            if m.drain is not None:
                m.drain()
            m.tick(deadline // m.period_ns, deadline)
        except BaseException as exc:  # reported to its node, which exits non-zero
            m.active = False
            if m.on_error is not None:
                m.on_error(exc)
            else:
                raise
        finally:
            st.busy_ns += self._now() - t0


_SHARED_LOOP: SharedLoop | None = None  # set by run_nodes(shared_loop=True) while nodes are built


# ---------------------------------------------------------------------------------------------
# Messages.


def stamp_ns_of(msg: Any) -> int:
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


def raw_publish_fn(pub: Any) -> Callable[[bytes], None]:
    """Publish serialized bytes on `pub`, one call into rclpy's C++ publisher.

    `Publisher.publish` wraps each call in a context manager on the handle (which defers the
    handle's destruction while in use) and a type check: three calls through pybind11 where one
    does, about half the cost of a publish in these loops (measured with callgrind, docs/live.md).
    Safe as the nodes use it: only a node's loop publishes this way, and run_nodes destroys a node
    only once its loop has stopped."""
    return typing.cast(Callable[[bytes], None], pub.handle.publish_raw)


class JointStateOut:
    """Publishes a one-joint sensor_msgs/JointState as CDR bytes patched into a template
    (nodes/cdr.py): no message object per tick."""

    def __init__(self, node: Any, topic: str, joint: str, fields: Sequence[str], qos: Any = None) -> None:
        from sensor_msgs.msg import JointState

        from haptic_teleop.nodes.cdr import JointStateCodec

        self.fields = tuple(fields)
        self.joint = joint
        self._encode = JointStateCodec(joint, fields).encode
        self._pub = node.create_publisher(JointState, topic, qos if qos is not None else stream_qos())
        self._send = raw_publish_fn(self._pub)

    def publish(self, stamp_ns: int, values: Sequence[float]) -> None:
        self._send(self._encode(stamp_ns, values))

    def publish_raw(self, raw: bytes) -> None:
        """Bytes of a JointState as they came (a relay forwarding a message unchanged)."""
        self._send(raw)


class WrenchOut:
    """Publishes geometry_msgs/WrenchStamped with force.x as CDR bytes (nodes/cdr.py)."""

    def __init__(self, node: Any, topic: str, frame: str, qos: Any = None) -> None:
        from geometry_msgs.msg import WrenchStamped

        from haptic_teleop.nodes.cdr import wrench_codec

        self._encode = wrench_codec(frame).encode
        self._pub = node.create_publisher(WrenchStamped, topic, qos if qos is not None else stream_qos())
        self._send = raw_publish_fn(self._pub)

    def publish(self, stamp_ns: int, force_x: float) -> None:
        self._send(self._encode(stamp_ns, (force_x,)))


class EbaOut:
    """Publishes [reservoir_j, force_desired_n] as std_msgs/Float64MultiArray CDR bytes (the bag's
    layout, nodes/cdr.py)."""

    def __init__(self, node: Any, topic: str) -> None:
        from std_msgs.msg import Float64MultiArray

        from haptic_teleop.nodes.cdr import multiarray_codec

        self._encode = multiarray_codec(EBA_LABELS).encode
        self._pub = node.create_publisher(Float64MultiArray, topic, stream_qos())
        self._send = raw_publish_fn(self._pub)

    def publish(self, reservoir_j: float, force_desired_n: float) -> None:
        self._send(self._encode(None, (reservoir_j, force_desired_n)))


def _polled_group_class() -> type:
    from rclpy.callback_groups import CallbackGroup

    class PolledGroup(CallbackGroup):
        """Entities the executor never waits on nor runs: the node's loop thread takes them.

        An executor wakes for every message of every subscription it holds; at 1 kHz that costs
        several times what taking the message from the loop does (docs/live.md)."""

        def can_execute(self, entity: Any) -> bool:
            return False

        def beginning_execution(self, entity: Any) -> bool:
            return False

        def ending_execution(self, entity: Any) -> None:
            return None

    return PolledGroup


def _taken(sub: Any) -> list[tuple[Any, dict[str, Any]]]:
    """Every message waiting in a polled subscription's history with its message info, oldest
    first (what rclpy's executor and wait_for_message do: rclpy has no public take call).

    Called on the C++ subscription directly, without rclpy's context manager on the handle (two
    more calls through pybind11 per poll): only the node's loop takes, and run_nodes destroys a
    node only once its loop has stopped (raw_publish_fn)."""
    out = []
    take = sub.handle.take_message
    msg_type, raw = sub.msg_type, sub.raw
    while True:
        r = take(msg_type, raw)
        if r is None:
            return out
        out.append(r)


def take_all(sub: Any) -> list[Any]:
    """Every waiting message of a polled subscription, oldest first."""
    return [m for m, _ in _taken(sub)]


def take_all_published_ns(sub: Any, times: list[int], msgs: list[Any]) -> int:
    """Append every waiting message of a polled subscription to `msgs`, oldest first, and the time
    its publisher wrote it (DDS source timestamp, system clock, ns) to `times`; returns how many."""
    got = _taken(sub)
    for m, info in got:
        times.append(int(info["source_timestamp"]))
        msgs.append(m)
    return len(got)


def take_latest(sub: Any) -> Any:
    """The newest waiting message of a polled subscription, or None. A keep-last-1 reader holds at
    most one: one take, not a second one to find the history empty."""
    take = sub.handle.take_message
    msg_type, raw = sub.msg_type, sub.raw
    r = take(msg_type, raw)
    if r is None:
        return None
    if getattr(sub, "holds_one", False):
        return r[0]
    while True:
        nxt = take(msg_type, raw)
        if nxt is None:
            return r[0]
        r = nxt


# ---------------------------------------------------------------------------------------------
# Base node and process entry point.


def _ignore(msg: Any) -> None:
    return None


class NodeStopped(HapticTeleopError):
    """Raised inside a tick to end the node cleanly (exit 0)."""


def _base_node_class() -> type:
    from rclpy.node import Node

    return Node


class LiveNode(_base_node_class()):  # type: ignore[misc]
    """A node with an optional 1 kHz loop, diagnostics once a second and an exit code.

    Subclasses build their parts in __init__ (raising ConfigError for bad parameters), implement
    `tick(index, stamp_ns)` if they have a loop, and `close()` to release what they hold.
    """

    default_name = "node"
    has_loop = True
    # Where in the period the loop wakes (fraction of it; stamps stay on the grid). The pipeline
    # stages are staggered so a sample sent at the top of a tick reaches the relay, then the
    # buffer, before they look, instead of racing them: producers 0, relays 1/4, buffers 1/2.
    loop_phase = 0.0

    def __init__(self, stop_event: threading.Event | None = None, **node_kwargs: Any) -> None:
        super().__init__(node_kwargs.pop("node_name", self.default_name), **node_kwargs)
        self.stop_event = stop_event or threading.Event()
        self.exit_code = 0
        self.period_ns = 1_000_000
        self.loop: LoopThread | None = None
        self._cpu0 = (time.process_time(), time.monotonic())
        self._diag_pub: Any = None
        self._next_report = time.monotonic() + REPORT_PERIOD_S
        self._polled_group = _polled_group_class()()
        self._event_subs: list[tuple[Any, Callable[[Any, int], None]]] = []
        self._wait_set: Any = None
        self.simulated_time = bool(self.get_parameter("use_sim_time").value)
        self.now_ns = self._clock_fn()

    def _clock_fn(self) -> Callable[[], int]:
        if self.simulated_time:
            clock = self.get_clock()
            return lambda: int(clock.now().nanoseconds)
        return time.time_ns

    # -- input
    def create_polled_subscription(self, msg_type: Any, topic: str, qos: Any, raw: bool = False) -> Any:
        """A subscription the loop thread takes from (take_latest / take_all), not the executor."""
        from rclpy.qos import HistoryPolicy

        sub = self.create_subscription(msg_type, topic, _ignore, qos, callback_group=self._polled_group, raw=raw)
        sub.holds_one = qos.history == HistoryPolicy.KEEP_LAST and qos.depth == 1  # take_latest: one take
        return sub

    def add_event_subscription(
        self, msg_type: Any, topic: str, qos: Any, handler: Callable[[Any, int], None], raw: bool = False
    ) -> Any:
        """A polled subscription whose messages the loop thread handles as they arrive, between
        ticks: `handler(msg, arrival_ns)` runs in the loop thread, so no lock is needed."""
        sub = self.create_polled_subscription(msg_type, topic, qos, raw)
        self._event_subs.append((sub, handler))
        return sub

    def _wait_events(self, timeout_ns: int) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

        ws = self._wait_set
        if ws is None:
            ws = self._wait_set = _rclpy.WaitSet(len(self._event_subs), 0, 0, 0, 0, 0, self.context.handle)
        ws.clear_entities()
        for sub, _ in self._event_subs:
            ws.add_subscription(sub.handle)
        ws.wait(timeout_ns)
        ready = ws.get_ready_entities("subscription")
        if not ready:
            return
        now = self.now_ns
        for sub, handler in self._event_subs:
            if sub.handle.pointer in ready:
                for msg in take_all(sub):
                    handler(msg, now())

    def _drain_events(self) -> None:
        """Handle what the event subscriptions hold now (the shared loop's stand-in for waiting)."""
        now = self.now_ns
        for sub, handler in self._event_subs:
            for msg in take_all(sub):
                handler(msg, now())

    # -- lifecycle
    def setup_loop(self, period_ns: int) -> None:
        self.period_ns = period_ns
        prio = int(
            declare_value(
                self,
                LOOP_PRIORITY_PARAM,
                DEFAULT_REALTIME_PRIORITY,
                "SCHED_FIFO priority of the loop thread (0: normal scheduling); needs CAP_SYS_NICE or an rtprio limit",
                0,
                98,
            )
        )
        catch_up = int(
            declare_value(
                self,
                LOOP_CATCH_UP_PARAM,
                DEFAULT_MAX_CATCH_UP,
                "a tick up to this many whole periods late still runs (late); further behind, the missed "
                "ticks are skipped and counted as overruns (0: skip whenever a period is missed)",
                0,
                10_000,
            )
        )
        group = _SHARED_LOOP
        if group is not None and not self.simulated_time:
            self.loop = group.add(
                self.get_name(), period_ns, self.loop_phase, self.tick,
                self._drain_events if self._event_subs else None, self._loop_failed, catch_up, self._idle,
            )  # fmt: skip
            self._setup_diagnostics()
            return
        self.loop = LoopThread(
            self.get_name(),
            period_ns,
            self.tick,
            now_ns=self._clock_fn(),
            on_error=self._loop_failed,
            simulated=self.simulated_time,
            waiter=self._wait_events if self._event_subs else None,
            realtime_priority=prio,
            on_warning=self.get_logger().warning,
            phase_ns=round(self.loop_phase * period_ns),
            max_catch_up=catch_up,
            idle=self._idle,
        )
        self._setup_diagnostics()

    def _setup_diagnostics(self) -> None:
        """The /diagnostics publisher. Reports go out once a second from the loop thread, in the
        slack after a tick (`_idle`): not from an executor timer (in a composed process each
        executor wake-up rebuilds its wait set over every node, about 5 ms of Python holding the
        GIL the loop needs) nor from a thread of their own (which holds it too)."""
        from diagnostic_msgs.msg import DiagnosticArray

        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, reliable_qos(10))

    def start(self) -> None:
        if self.loop is not None:
            self.loop.start()

    def _idle(self, room: bool) -> bool:
        """The loop's background work, run after a tick; `room`: the next deadline is at least
        IDLE_SHARE of a period away. Publishes the diagnostics when due, if there is room (or once
        overdue)."""
        now = time.monotonic()
        due = self._next_report
        if now < due or (not room and now < due + REPORT_OVERDUE_S):
            return False
        self._next_report = max(due + REPORT_PERIOD_S, now)
        self.publish_diagnostics()
        return True

    def tick(self, index: int, stamp_ns: int) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def _loop_failed(self, exc: BaseException) -> None:
        if isinstance(exc, NodeStopped):
            self.get_logger().info(str(exc) or "finished")
            self.exit_code = 0
        else:
            import traceback

            self.get_logger().error("loop failed: " + "".join(traceback.format_exception(exc)).rstrip())
            self.exit_code = 1
        self.stop_event.set()

    def loop_figures(self) -> dict[str, Any] | None:
        """The loop's figures over its whole life (for the table at the end of a launch), or None
        for a node without a loop: ticks run, ticks per second of wall time, late ticks (run a
        period or more after their deadline) and skipped ticks (overruns)."""
        loop = self.loop
        if loop is None:
            return None
        st = loop.stats
        return {
            "node": self.get_name(),
            "ticks": st.ticks,
            "loop_rate_hz": round(st.rate_hz(), 1),
            "late_ticks": st.late_ticks,
            "skipped_ticks": st.overruns,
            **{k: v for k, v in self.diagnostic_values().items() if k in FINAL_EXTRAS},
        }

    def request_stop(self, code: int = 0) -> None:
        self.exit_code = code
        self.stop_event.set()

    def close(self) -> None:
        if self.loop is not None:
            self.loop.stop()

    # -- diagnostics
    def diagnostic_values(self) -> dict[str, float | int | str]:
        """Node-specific figures added to the loop's (override)."""
        return {}

    def publish_diagnostics(self) -> None:
        """Publish the loop's figures (LoopStats.report) and the node's own on /diagnostics; called
        by the loop thread (`_idle`) about once a second."""
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        loop = self.loop
        if loop is None or self._diag_pub is None:
            return
        st = loop.stats
        cpu_t, wall_t = time.process_time(), time.monotonic()
        cpu = (cpu_t - self._cpu0[0]) / max(wall_t - self._cpu0[1], 1e-9) * 100.0
        values: dict[str, float | int | str] = {"period_s": self.period_ns * 1e-9}
        values.update(st.report())
        values.update(
            max_catch_up_periods=loop.max_catch_up,
            process_cpu_percent=round(cpu, 1),
            realtime=int(loop.realtime),
        )
        values.update(self.diagnostic_values())
        status = DiagnosticStatus()
        status.name = f"{self.get_name()}: loop"
        status.hardware_id = self.get_name()
        status.level = DiagnosticStatus.OK if st.overruns == 0 else DiagnosticStatus.WARN
        status.message = (
            f"{values['loop_rate_hz']} Hz, {st.overruns} overruns, {st.late_ticks} ticks run a period or more late"
        )
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [status]
        self._diag_pub.publish(msg)


BAD_PARAMETER_EXIT = 2
# Node figures (diagnostic_values) that go with the loop's into the table at the end of a launch.
FINAL_EXTRAS = ("late", "lost", "delivered", "released")


def _bad_parameter_errors() -> tuple[type[BaseException], ...]:
    from rclpy.exceptions import ParameterException

    return (ConfigError, ParameterException, HapticTeleopError, ValueError, KeyError)


def run_nodes(
    factories: Sequence[Callable[..., LiveNode]],
    node_args: Sequence[dict[str, Any]] | None = None,
    args: Sequence[str] | None = None,
    multithreaded: bool = False,
    shared_loop: bool = False,
    figures_out: list[dict[str, Any]] | None = None,
    signals_out: list[int] | None = None,
) -> int:
    """Create nodes, spin them, run their loops until SIGINT/SIGTERM or a node stops; exit code.

    `shared_loop`: the nodes' loops run in one thread (SharedLoop) instead of one thread each.
    Each node's `loop_figures` go to `figures_out` if given, else to stdout (LOOP_FIGURES_MARK
    lines); the signal that stopped the process, if any, to `signals_out`.

    A node's constructor failing on a parameter ends the process with code 2 and a message that
    names the parameter; a loop failing ends it with 1; a signal or a node finishing, with 0.
    """
    import rclpy
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from haptic_teleop.lifetime import follow_launcher

    if not follow_launcher():  # started by a launcher that has died since: start nothing
        return 1
    ensure_local_discovery()
    # The loop thread and the executor thread share the GIL: switch often so a waking loop
    # does not wait for a callback's full default 5 ms slice.
    sys.setswitchinterval(0.0002)
    stop = threading.Event()
    # The handler only notes the signal: `Event.set` takes the event's lock, which the main
    # thread may hold inside `stop.wait` when the signal lands (a deadlock: a node that never
    # stopped on SIGTERM). The main thread turns the note into the stop.
    signalled: list[int] = []

    def on_signal(signum: int, frame: Any) -> None:
        signalled.append(signum)

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    rclpy.init(args=list(args) if args is not None else sys.argv, signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[LiveNode] = []
    kwargs_list = list(node_args) if node_args is not None else [{} for _ in factories]
    global _SHARED_LOOP  # noqa: PLW0603 - read by LiveNode.setup_loop while the nodes are built
    group = SharedLoop(realtime_priority=DEFAULT_REALTIME_PRIORITY) if shared_loop else None
    _SHARED_LOOP = group
    try:
        for factory, kw in zip(factories, kwargs_list, strict=True):
            nodes.append(factory(stop_event=stop, **kw))
    except _bad_parameter_errors() as exc:
        _SHARED_LOOP = None
        who = kwargs_list[len(nodes)].get("node_name", getattr(factories[len(nodes)], "default_name", "node"))
        print(f"{who}: bad parameter: {exc}", file=sys.stderr, flush=True)
        for n in nodes:
            n.close()
            n.destroy_node()
        rclpy.try_shutdown()
        return BAD_PARAMETER_EXIT
    _SHARED_LOOP = None
    executor = MultiThreadedExecutor(num_threads=max(2, len(nodes))) if multithreaded else SingleThreadedExecutor()
    for n in nodes:
        executor.add_node(n)

    def spin() -> None:
        try:
            executor.spin()
        except Exception:
            # Shutting down destroys guard conditions the executor may still be using; an
            # error then is part of stopping. Before that, it is a real failure.
            if not stop.is_set():
                raise

    spinner = threading.Thread(target=spin, name="executor", daemon=True)
    spinner.start()
    # What the nodes built (models, messages, modules) lives to the end: out of the collector's
    # sight, a full collection no longer walks it (measured: 20 to 50 ms pauses of every loop,
    # twice in 15 s, without this; docs/live.md, "Late ticks").
    gc.collect()
    gc.freeze()
    for n in nodes:
        n.start()
    while not stop.wait(0.1) and not signalled:
        pass
    if signalled and not stop.is_set() and signals_out is not None:
        signals_out.append(signalled[0])
    stop.set()
    code = 0
    for n in nodes:
        try:
            n.close()
        except Exception as exc:  # noqa: BLE001 - report, keep closing the others
            print(f"{n.get_name()}: error while closing: {exc}", file=sys.stderr, flush=True)
            code = max(code, 1)
    if group is not None:
        group.stop()
    code = max([code] + [n.exit_code for n in nodes])
    for n in nodes:
        fig = n.loop_figures()
        if fig is None:
            continue
        if figures_out is not None:
            figures_out.append(fig)
        else:
            import json

            print(LOOP_FIGURES_MARK + json.dumps(fig), flush=True)
    executor.shutdown(timeout_sec=2.0)
    spinner.join(2.0)  # a C++ wait still running at exit would abort the process
    for n in nodes:
        if n.loop is not None and n.loop.running:
            # Its loop did not stop in time: it may still publish or take, straight on the C++
            # handles (raw_publish_fn), so those must outlive it; the process ends anyway.
            print(f"{n.get_name()}: loop still running at exit; not destroying the node", file=sys.stderr, flush=True)
            code = max(code, 1)
            continue
        n.destroy_node()
    rclpy.try_shutdown()
    return code


def node_main(factory: Callable[..., LiveNode]) -> None:
    """console_scripts entry point of one node."""
    sys.exit(run_nodes([factory]))
