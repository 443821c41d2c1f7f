"""The base of every live node (`LiveNode`: the loop, diagnostics, the remote-data watchdog, an
exit code) and the process entry points (`run_nodes`, `node_main`).

Nothing here computes teleoperation: the nodes wire the core objects (controllers, links,
buffers, operator, plants) exactly as the engine does, and this package only carries time,
messages and parameters to and from them.
"""

from __future__ import annotations

import contextlib
import faulthandler
import gc
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from haptic_teleop.errors import ConfigError, HapticTeleopError
from haptic_teleop.lifetime import deadline
from haptic_teleop.nodes import LOOP_FIGURES_MARK
from haptic_teleop.nodes.messages import _polled_group_class, take_all
from haptic_teleop.nodes.params import (
    DEFAULT_REALTIME_PRIORITY,
    LOOP_CATCH_UP_PARAM,
    LOOP_PRIORITY_PARAM,
    declare_value,
)
from haptic_teleop.nodes.rtloop import (
    DEFAULT_MAX_CATCH_UP,
    REPORT_OVERDUE_S,
    REPORT_PERIOD_S,
    LoopThread,
    SharedLoop,
)
from haptic_teleop.nodes.topics import DIAGNOSTICS, ensure_local_discovery, reliable_qos

# ---------------------------------------------------------------------------------------------
# Base node and process entry point.


_SHARED_LOOP: SharedLoop | None = None  # set by run_nodes(shared_loop=True) while nodes are built
# Its counterpart for the nodes on simulated time (use_sim_time): made by the first such node, on
# that node's ROS clock (every node of the process follows the same /clock).
_SIM_LOOP: SharedLoop | None = None


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
        if group is not None and self.simulated_time:
            global _SIM_LOOP  # noqa: PLW0603 - one per composed process, made by its first simulated node
            if _SIM_LOOP is None:
                _SIM_LOOP = SharedLoop(now_ns=self._clock_fn(), simulated=True)
            group = _SIM_LOOP
        if group is not None:
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

    def normal_scheduling(self, why: str) -> None:
        """Run this node's loop with normal scheduling, not SCHED_FIFO (call after `setup_loop`, before
        the loop starts; composed, the shared loop of every node in the process). For a loop that
        busy-waits inside a vendor SDK: at real-time priority it starves the kernel's own threads of
        its CPU, the serial port's among them, and then waits for a reply that cannot arrive."""
        loop = self.loop
        if loop is None:
            return
        if isinstance(loop, SharedLoop.Member):
            loop.group.realtime_priority = 0
        else:
            loop.realtime_priority = 0
        self.get_logger().info(f"loop with normal scheduling: {why}")

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
        elif isinstance(exc, HapticTeleopError):
            # A failure the package raised on purpose (a device's HardwareError, a refused start, a
            # safety stop): its message names what happened and what to do; one line, no traceback.
            # The node then closes (its plant's torque off) and exits with the error's code.
            print(f"{self.get_name()}: {exc}", file=sys.stderr, flush=True)
            self.exit_code = max(1, exc.exit_code)
        else:
            import traceback

            self.get_logger().error("loop failed: " + "".join(traceback.format_exception(exc)).rstrip())
            self.exit_code = 1
        self.stop_event.set()

    def loop_figures(self) -> dict[str, Any] | None:
        """The loop's figures over its whole life (for the table at the end of a launch), or None
        for a node without a loop: ticks run, ticks per second of wall time, late ticks (run a
        period or more after their deadline), skipped ticks (overruns) and the most a tick's work
        ended after its deadline (us: its inputs were taken no later, preemption inside it included)."""
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
            "end_late_max_us": round(st.end_late_max_ns * 1e-3, 1),
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


def _construction_failure(who: str, exc: BaseException) -> tuple[str, int]:
    """The line and exit code of a node whose constructor failed: a parameter (exit 2), or a failure
    the package raised on purpose while building its parts (a plant, a device: its own code)."""
    if isinstance(exc, HapticTeleopError) and not isinstance(exc, ConfigError):
        return f"{who}: {exc}", exc.exit_code
    return f"{who}: bad parameter: {exc}", BAD_PARAMETER_EXIT


TEARDOWN_S = 5.0  # the middleware's teardown after the nodes closed; the launcher kills at 10 s


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
    from haptic_teleop.nodes.entry import EARLY

    if EARLY:  # stopped while it was still starting (nodes/entry.py): nothing was built
        name = signal.Signals(EARLY[0]).name
        print(f"{', '.join(_names(factories, node_args))}: {name} before start; exiting", file=sys.stderr, flush=True)
        return 0
    rclpy.init(args=list(args) if args is not None else sys.argv, signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[LiveNode] = []
    kwargs_list = list(node_args) if node_args is not None else [{} for _ in factories]
    global _SHARED_LOOP, _SIM_LOOP  # noqa: PLW0603 - read by LiveNode.setup_loop while the nodes are built
    group = SharedLoop(realtime_priority=DEFAULT_REALTIME_PRIORITY) if shared_loop else None
    _SHARED_LOOP, _SIM_LOOP = group, None
    try:
        for factory, kw in zip(factories, kwargs_list, strict=True):
            nodes.append(factory(stop_event=stop, **kw))
    except _bad_parameter_errors() as exc:
        _SHARED_LOOP = _SIM_LOOP = None
        who = kwargs_list[len(nodes)].get("node_name", getattr(factories[len(nodes)], "default_name", "node"))
        line, failed = _construction_failure(who, exc)
        print(line, file=sys.stderr, flush=True)
        for n in nodes:
            n.close()
            n.destroy_node()
        rclpy.try_shutdown()
        return failed
    sim_group = _SIM_LOOP
    _SHARED_LOOP = _SIM_LOOP = None
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
    try:
        for n in nodes:
            n.start()
    except BaseException:
        stop.set()
        for n in nodes:  # every exit path closes the nodes (a hardware plant's torque off with them)
            with contextlib.suppress(Exception):
                n.close()
        raise
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
    for g in (group, sim_group):
        if g is not None:
            g.stop()
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
    names = ", ".join(n.get_name() for n in nodes)

    def stuck() -> None:
        # The nodes are closed (the recorder's bag with them): only the middleware's teardown is
        # left, and under load it has blocked for good inside DDS. End the process as the launcher
        # would (it kills a node after 10 s), but first say where it was stuck.
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        print(
            f"{names}: ROS 2 teardown still running {TEARDOWN_S:g} s after the nodes closed (thread "
            "stacks above); exiting without it",
            file=sys.stderr,
            flush=True,
        )
        os._exit(code)

    with deadline(TEARDOWN_S, stuck):
        executor.shutdown(timeout_sec=2.0)
        spinner.join(2.0)
        if spinner.is_alive():
            # The executor's thread is still inside a C++ wait: destroying the nodes or the context
            # under it, or the interpreter's exit, aborts the process (SIGABRT after a complete run:
            # CI, a live arm recorder on a loaded machine). The nodes are closed (a bag with them):
            # end here, without the middleware's teardown, with the nodes' own code.
            print(f"{names}: executor still waiting 2 s after its shutdown; exiting without the ROS 2 teardown",
                  file=sys.stderr, flush=True)  # fmt: skip
            sys.stdout.flush()
            os._exit(code)
        for n in nodes:
            if n.loop is not None and n.loop.running:
                # Its loop did not stop in time: it may still publish or take, straight on the C++
                # handles (raw_publish_fn), so those must outlive it; the process ends anyway.
                print(
                    f"{n.get_name()}: loop still running at exit; not destroying the node", file=sys.stderr, flush=True
                )
                code = max(code, 1)
                continue
            n.destroy_node()
        rclpy.try_shutdown()
    return code


def _names(factories: Sequence[Callable[..., LiveNode]], node_args: Sequence[dict[str, Any]] | None) -> list[str]:
    """The names the nodes would have (their `node_name`, else their class's default)."""
    args = list(node_args) if node_args is not None else [{} for _ in factories]
    return [kw.get("node_name", getattr(f, "default_name", "node")) for f, kw in zip(factories, args, strict=True)]


def node_main(factory: Callable[..., LiveNode]) -> None:
    """console_scripts entry point of one node. A crash in native code (Fast DDS, MuJoCo) prints
    the Python stack of every thread to stderr first, under `ros2 run` as under the launcher
    (which also sets PYTHONFAULTHANDLER, so a crash while importing is covered too)."""
    faulthandler.enable(all_threads=True)
    sys.exit(run_nodes([factory]))
