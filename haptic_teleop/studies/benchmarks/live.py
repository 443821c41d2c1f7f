"""`haptic-teleop bench live`: how the live node set keeps time on this machine.

One run of the scene's full node set (recorder included) per configuration: one process per node
(what `haptic-teleop launch` starts) and composed in one process with one shared loop thread
(`launch --single-process`); both by default. Each run adds a measurement hop that shares the
machine with it: a probe process publishes a sensor_msgs/JointState at 1 kHz on two topics, one
straight to this process (a bare rclpy publisher-to-subscriber hop), one through a network_relay
with no configured effects (zero delay) and on to this process. Latency is arrival time minus
the stamp the probe wrote just before publishing (one host: one clock).

Printed per node, over the measurement window only (from the difference of two of the node's
own diagnostics reports, which carry cumulative counters; startup is not in it): the loop rate
(ticks run per second of wall time, each on its own deadline of the grid), the ticks skipped,
the ticks run a whole period or more late (caught up, `loop.max_catch_up_periods`), loop
lateness (wake time minus deadline: the jitter) p50/p99/max, the share of wall time spent in the
node's ticks, and CPU use from /proc (per process). Then the two hops' p50/p99 and whether the
targets hold (loop rate >= 99 % of 1/period on every 1 kHz node, relay hop p99 <= 2 x bare hop
p99).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.benchmarks import add_scene_argument, positive

BARE_TOPIC = "/bench/bare"
RELAY_IN = "/bench/relay_in"
RELAY_OUT = "/bench/relay_out"
LOOP_RATE_TARGET = 0.99
HOP_RATIO_TARGET = 2.0
MODES = ("composed", "processes")
MODE_TITLES = {
    "composed": "composed: one process, one shared loop thread (launch --single-process)",
    "processes": "one process per node (launch)",
}
RECOMMENDED = "composed"  # what docs/live.md recommends on a machine this small


def _probe_classes() -> tuple[type, type]:
    from sensor_msgs.msg import JointState

    from haptic_teleop.nodes.base import LiveNode
    from haptic_teleop.nodes.messages import JointStateOut, stamp_ns_of
    from haptic_teleop.nodes.topics import DIAGNOSTICS, reliable_qos, stream_qos

    class HopProbe(LiveNode):
        """Publishes on both hop topics every tick, stamp = the time just before each publish."""

        default_name = "bench_probe"

        def __init__(self, **kwargs: Any) -> None:
            super().__init__(**kwargs)
            self.bare = JointStateOut(self, BARE_TOPIC, "master_x", ("position", "velocity"))
            self.relay = JointStateOut(self, RELAY_IN, "master_x", ("position", "velocity"))
            self.setup_loop(1_000_000)

        def tick(self, index: int, stamp_ns: int) -> None:
            outs = (self.bare, self.relay) if index % 2 else (self.relay, self.bare)  # same share first
            for out in outs:
                out.publish(time.time_ns(), (float(index), 0.0))

    class HopReceiver(LiveNode):
        """Arrival minus stamp of both hops (taken as they arrive), and the nodes' diagnostics
        reports with the time they arrived (monotonic s)."""

        default_name = "bench_receiver"

        def __init__(self, **kwargs: Any) -> None:
            super().__init__(**kwargs)
            from diagnostic_msgs.msg import DiagnosticArray

            self.latency_ns: dict[str, list[int]] = {"bare": [], "relay": []}
            self.recording = False
            self.reports: dict[str, list[tuple[float, dict[str, str]]]] = {}
            for key, topic in (("bare", BARE_TOPIC), ("relay", RELAY_OUT)):
                self.add_event_subscription(JointState, topic, stream_qos(50), self._handler(key))
            self.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diagnostics, reliable_qos(50))
            self.setup_loop(10_000_000)

        def _handler(self, key: str) -> Any:
            out = self.latency_ns[key]

            def handle(msg: Any, arrival_ns: int) -> None:
                if self.recording:
                    out.append(time.time_ns() - stamp_ns_of(msg))

            return handle

        def _on_diagnostics(self, msg: Any) -> None:
            now = time.monotonic()
            for st in msg.status:
                self.reports.setdefault(st.hardware_id, []).append((now, {kv.key: kv.value for kv in st.values}))

        def tick(self, index: int, stamp_ns: int) -> None:
            return None

    return HopProbe, HopReceiver


def _cpu_s(pid: int) -> float:
    try:
        parts = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")


def _machine_busy_s() -> float:
    """CPU seconds the whole machine has spent busy (user, nice, system, irq, softirq, steal)."""
    try:
        v = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:9]]
    except (OSError, ValueError):
        return math.nan
    user, nice, system, _idle, _iowait, irq, softirq, steal = v
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def _percentiles_us(values: list[int]) -> tuple[float, float, int]:
    if not values:
        return float("nan"), float("nan"), 0
    a = np.asarray(values, dtype=np.float64) * 1e-3
    return float(np.percentile(a, 50)), float(np.percentile(a, 99)), a.size


def _hist(text: str) -> np.ndarray:
    from haptic_teleop.nodes.rtloop import LATENESS_BINS

    h = np.zeros(LATENESS_BINS, dtype=np.int64)
    vals = [int(v) for v in text.split()][:LATENESS_BINS]
    h[: len(vals)] = vals
    return h


def window_figures(reports: list[tuple[float, dict[str, str]]], t0: float, t1: float) -> dict[str, float] | None:
    """A node's loop figures between its first diagnostics report at or after `t0` and its last
    at or before `t1` (arrival times, monotonic s), from the reports' cumulative counters; None
    without two such reports."""
    from haptic_teleop.nodes.rtloop import hist_percentiles_us

    inside = [(t, r) for t, r in reports if t0 <= t <= t1 and "last_tick_ns" in r]
    if len(inside) < 2:
        return None
    a, b = inside[0][1], inside[-1][1]
    span_s = (int(b["last_tick_ns"]) - int(a["last_tick_ns"])) * 1e-9
    if span_s <= 0:
        return None
    ticks = int(b["ticks"]) - int(a["ticks"])
    p50, p99 = hist_percentiles_us(_hist(b["lateness_hist"]) - _hist(a["lateness_hist"]))
    worst = max(float(r["lateness_max_us"]) for _, r in inside[1:])
    tick_s = float(b.get("tick_time_s", "nan")) - float(a.get("tick_time_s", "nan"))
    return {
        "span_s": span_s,
        "loop_rate_hz": ticks / span_s,
        "period_s": float(b["period_s"]),
        "ticks": ticks,
        "skipped": int(b["overruns"]) - int(a["overruns"]),
        "late_ticks": int(b["late_ticks"]) - int(a["late_ticks"]),
        "lateness_p50_us": p50,
        "lateness_p99_us": p99,
        "lateness_max_us": worst,
        "tick_time_percent": tick_s / span_s * 100.0,
        "max_catch_up_periods": int(b.get("max_catch_up_periods", "0")),
    }


def run_bench(
    scene_name: str, duration_s: float, out: Any = sys.stdout, single_process: bool = False
) -> dict[str, Any]:
    """Run the bench in one configuration; returns the figures it printed. `single_process`: the
    scene's node set runs composed in one process with one shared loop thread (`haptic-teleop
    launch --single-process`); the probe and the bench's relay stay processes of their own."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from haptic_teleop.live.launcher import Launcher, NodeSpec, local_discovery_env, node_plan, scene_params
    from haptic_teleop.scene.load import find_scene, load_scene

    os.environ.update(local_discovery_env())
    # The scene runs long enough for the startup and the measurement window; ended by the bench.
    scene = load_scene(find_scene(scene_name), overrides=[f"scene.duration_s={duration_s + 60.0}"])
    period_s = scene.config.scene.period_s
    work = Path(tempfile.mkdtemp(prefix="haptic_teleop_bench_"))
    plan = node_plan(scene, record_dir=work / "record")
    node_names = [spec.name for spec in plan]
    if single_process:
        plan = []
    relay_params = {"direction": "forward", "scene": scene_params(scene, "network_relay", "forward")["scene"]}
    plan.append(
        NodeSpec(
            "bench_relay",
            "network_relay",
            relay_params,
            remaps=(
                ("/forward/sent", RELAY_IN),
                ("/forward/delivered", RELAY_OUT),
                ("/forward/packets", "/bench/packets"),
            ),
        )
    )
    log_lines: list[str] = []

    class _Sink:
        def write(self, text: str) -> None:
            log_lines.append(text)

        def flush(self) -> None:
            return None

    launcher = Launcher(plan, work / "params", out=_Sink())  # type: ignore[arg-type]
    composed = None
    if single_process:
        composed = subprocess.Popen(
            [sys.executable, "-m", "haptic_teleop.cli", "launch", scene_name, "--single-process", "--no-plots",
             "--duration", str(duration_s + 60.0), "--record", str(work / "record")],
            env={**local_discovery_env(), "PYTHONUNBUFFERED": "1"},
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, text=True,
            start_new_session=True,
        )  # fmt: skip
        threading.Thread(target=lambda: log_lines.extend(iter(composed.stdout.readline, "")), daemon=True).start()
    probe = subprocess.Popen(
        [sys.executable, "-m", "haptic_teleop.studies.benchmarks.live", "--probe"],
        env={**local_discovery_env(), "PYTHONUNBUFFERED": "1"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    _, Receiver = _probe_classes()
    rclpy.init(args=[])
    receiver = Receiver()
    executor = SingleThreadedExecutor()
    executor.add_node(receiver)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    receiver.start()
    try:
        launcher.start()
        deadline = time.monotonic() + 60.0
        while not any("scene time 0" in line for line in log_lines):
            gone = any(c.proc.poll() is not None for c in launcher.children)
            if time.monotonic() > deadline or gone or (composed is not None and composed.poll() is not None):
                raise RuntimeError("the node set did not start:\n" + "".join(log_lines[-40:]))
            time.sleep(0.05)
        time.sleep(1.0)  # past the operator's first transient
        pids = launcher.pids()
        pids["bench_probe"] = probe.pid
        if composed is not None:
            pids["node set (1 process)"] = composed.pid
        cpu0 = {n: _cpu_s(p) for n, p in pids.items()}
        busy0 = _machine_busy_s()
        t0 = time.monotonic()
        receiver.recording = True
        time.sleep(duration_s)
        receiver.recording = False
        t1 = time.monotonic()
        cpu = {n: (_cpu_s(p) - cpu0[n]) / (t1 - t0) * 100.0 for n, p in pids.items()}
        machine_pct = (_machine_busy_s() - busy0) / (t1 - t0) * 100.0
        time.sleep(0.3)  # reports sent just before t1 are in
        reports = {n: list(r) for n, r in receiver.reports.items()}
    finally:
        probe.send_signal(2)
        if composed is not None:
            composed.send_signal(2)
            try:
                composed.wait(60.0)
            except subprocess.TimeoutExpired:
                composed.kill()
        launcher.interrupt()
        launcher.supervise()
        try:
            probe.wait(5.0)
        except subprocess.TimeoutExpired:
            probe.kill()
        receiver.close()
        executor.shutdown(2.0)
        spinner.join(2.0)
        receiver.destroy_node()
        rclpy.try_shutdown()

    target_hz = 1.0 / period_s
    nodes: dict[str, dict[str, float]] = {}
    lowest = math.inf
    for name in [*node_names, "bench_relay", "bench_probe", "node set (1 process)"]:
        if name not in pids and name not in node_names:
            continue
        f = window_figures(reports.get(name, []), t0, t1) if name != "node set (1 process)" else None
        row: dict[str, float] = dict(f) if f is not None else {}
        row["cpu_percent"] = cpu.get(name, math.nan)
        nodes[name] = row
        scene_node = name in node_names
        if scene_node and abs(row.get("period_s", math.nan) - period_s) < 1e-12:
            lowest = min(lowest, row["loop_rate_hz"])
        elif scene_node and f is None and name != "recorder":
            lowest = -math.inf  # a 1 kHz node without two reports in the window: not measured
    ok_rate = bool(lowest >= LOOP_RATE_TARGET * target_hz)
    bare50, bare99, nb = _percentiles_us(receiver.latency_ns["bare"])
    rel50, rel99, nr = _percentiles_us(receiver.latency_ns["relay"])
    ratio = rel99 / bare99 if bare99 > 0 else float("nan")
    mode = "composed" if single_process else "processes"
    catch_up = max((int(r.get("max_catch_up_periods", 0)) for r in nodes.values()), default=0)
    p = out.write
    p(
        f"bench live, {MODE_TITLES[mode]}: scene {scene.config.scene.name}, {duration_s:g} s measured, "
        f"period {period_s * 1e3:g} ms, {os.cpu_count()} cores, ticks up to {catch_up} periods late run "
        "(loop.max_catch_up_periods), further behind skipped\n\n"
    )
    p(
        f"  {'node':<20} {'loop Hz':>8} {'target':>6} {'skipped':>7} {'late':>6} "
        f"{'lateness p50':>12} {'p99':>7} {'max us':>7} {'in tick %':>9} {'CPU %':>6}\n"
    )
    for name, r in nodes.items():
        g = r.get
        target = f"{1.0 / g('period_s'):.0f}" if "period_s" in r else ""
        p(
            f"  {name:<20} {g('loop_rate_hz', math.nan):>8.1f} {target:>6} {int(g('skipped', 0)):>7d} "
            f"{int(g('late_ticks', 0)):>6d} {g('lateness_p50_us', math.nan):>12.0f} "
            f"{g('lateness_p99_us', math.nan):>7.0f} "
            f"{g('lateness_max_us', math.nan):>7.0f} {g('tick_time_percent', math.nan):>9.1f} "
            f"{g('cpu_percent', math.nan):>6.1f}\n"
        )
    total_cpu = sum(r["cpu_percent"] for r in nodes.values() if r["cpu_percent"] == r["cpu_percent"])
    p(f"  {'total CPU':<20} {'':>8} {'':>6} {'':>7} {'':>6} {'':>12} {'':>7} {'':>7} {'':>9} {total_cpu:>6.1f}\n")
    p(
        f"  the whole machine, every process (/proc/stat): {machine_pct:.0f} % of one CPU busy, of "
        f"{(os.cpu_count() or 1) * 100} %\n"
    )
    p(
        "  (loop Hz: ticks run per wall second; late: ticks run a period or more after their deadline;\n"
        "   lateness: tick start minus deadline; in tick: share of wall time in the node's ticks)\n\n"
    )
    p("  hop latency (us)          p50      p99   samples\n")
    p(f"  bare rclpy pub->sub  {bare50:>8.0f} {bare99:>8.0f} {nb:>9d}\n")
    p(f"  through relay (0 s)  {rel50:>8.0f} {rel99:>8.0f} {nr:>9d}\n\n")
    p(
        f"  loop rate >= {LOOP_RATE_TARGET:.0%} of {target_hz:.0f} Hz on every 1 kHz node: "
        f"{'yes' if ok_rate else 'NO'} "
        + (
            f"(lowest {lowest:.1f} Hz)\n"
            if lowest > -math.inf
            else "(a node sent fewer than two reports in the window)\n"
        )
    )
    p(
        f"  relay hop p99 <= {HOP_RATIO_TARGET:g} x bare hop p99: {'yes' if ratio <= HOP_RATIO_TARGET else 'NO'} "
        f"(ratio {ratio:.2f})\n\n"
    )
    return {
        "mode": mode,
        "nodes": nodes,
        "bare_hop_us": (bare50, bare99, nb),
        "relay_hop_us": (rel50, rel99, nr),
        "hop_p99_ratio": ratio,
        "loop_rate_ok": ok_rate,
        "lowest_rate_hz": lowest,
        "machine_busy_percent": machine_pct,
    }


HELP = "live node set: loop rate, lateness, relay hop vs bare DDS hop, CPU per node (both configurations)"


def add_arguments(p: Any) -> None:
    add_scene_argument(p)
    p.add_argument("--duration", type=positive(float), default=10.0, help="seconds of measurement per configuration")
    p.add_argument(
        "--mode",
        choices=(*MODES, "both"),
        default="both",
        help="composed: the node set in one process with one shared loop thread (launch --single-process); "
        "processes: one process per node (launch); both (default): one after the other",
    )
    p.add_argument("--single-process", action="store_true", help="the same as --mode composed")


def main(args: Any) -> int:
    """`haptic-teleop bench live` (argparse namespace from cli/main.py)."""
    mode = "composed" if args.single_process else args.mode
    results = {}
    for m in MODES if mode == "both" else (mode,):
        results[m] = run_bench(args.scene, float(args.duration), single_process=m == "composed")
    if RECOMMENDED in results:
        r = results[RECOMMENDED]
        print(
            f"loop-rate target (>= {LOOP_RATE_TARGET:.0%} of 1 kHz) in the recommended configuration "
            f"({MODE_TITLES[RECOMMENDED]}): {'met' if r['loop_rate_ok'] else 'NOT met'}"
        )
    return 0


def _probe_main() -> None:
    from haptic_teleop.nodes.base import run_nodes

    Probe, _ = _probe_classes()
    sys.exit(run_nodes([Probe], args=[]))


if __name__ == "__main__":
    if "--probe" in sys.argv:
        _probe_main()
    else:
        print(
            "usage: haptic-teleop bench live [--scene S] [--duration S] [--mode composed|processes|both]",
            file=sys.stderr,
        )
        sys.exit(2)
