"""`haptic-teleop bench live`: how the live node set keeps time on this machine.

One run of the scene's full node set (recorder included), plus a measurement hop that shares the
machine with it: a probe process publishes a sensor_msgs/JointState at 1 kHz on two topics, one
straight to this process (a bare rclpy publisher-to-subscriber hop), one through a
network_relay with no configured effects (zero delay) and on to this process. Latency is arrival
time minus the stamp the probe wrote just before publishing (one host: one clock).

Printed: per node the achieved loop rate, overruns, loop lateness (jitter) p50/p99 from the nodes'
own diagnostics, and CPU use from /proc over the measurement window; the two hops' p50/p99; and
whether the targets hold (loop rate >= 99 % of 1/period, relay hop p99 <= 2 x bare hop p99).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

BARE_TOPIC = "/bench/bare"
RELAY_IN = "/bench/relay_in"
RELAY_OUT = "/bench/relay_out"
LOOP_RATE_TARGET = 0.99
HOP_RATIO_TARGET = 2.0


def _probe_classes() -> tuple[type, type]:
    from sensor_msgs.msg import JointState

    from haptic_teleop.nodes.common import DIAGNOSTICS, JointStateOut, LiveNode, reliable_qos, stamp_ns_of, stream_qos

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
        """Arrival minus stamp of both hops (taken as they arrive), and the nodes' diagnostics."""

        default_name = "bench_receiver"

        def __init__(self, **kwargs: Any) -> None:
            super().__init__(**kwargs)
            from diagnostic_msgs.msg import DiagnosticArray

            self.latency_ns: dict[str, list[int]] = {"bare": [], "relay": []}
            self.recording = False
            self.diagnostics: dict[str, dict[str, str]] = {}
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
            for st in msg.status:
                self.diagnostics[st.hardware_id] = {kv.key: kv.value for kv in st.values}

        def tick(self, index: int, stamp_ns: int) -> None:
            return None

    return HopProbe, HopReceiver


def _cpu_s(pid: int) -> float:
    try:
        parts = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")


def _percentiles_us(values: list[int]) -> tuple[float, float, int]:
    if not values:
        return float("nan"), float("nan"), 0
    a = np.asarray(values, dtype=np.float64) * 1e-3
    return float(np.percentile(a, 50)), float(np.percentile(a, 99)), a.size


def run_bench(
    scene_name: str, duration_s: float, out: Any = sys.stdout, single_process: bool = False
) -> dict[str, Any]:
    """Run the bench; returns the figures it printed. `single_process`: the scene's node set runs
    composed in one process with one shared loop thread (`haptic-teleop launch --single-process`);
    the probe and the bench's relay stay processes of their own."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from haptic_teleop.launcher import Launcher, NodeSpec, local_discovery_env, node_plan, scene_params
    from haptic_teleop.scene import find_scene, load_scene

    os.environ.update(local_discovery_env())
    # The scene runs long enough for the startup and the measurement window; ended by the bench.
    scene = load_scene(find_scene(scene_name), overrides=[f"scene.duration_s={duration_s + 60.0}"])
    period_s = scene.config.scene.period_s
    work = Path(tempfile.mkdtemp(prefix="haptic_teleop_bench_"))
    plan = node_plan(scene, record_dir=work / "record")
    composed_names = [spec.name for spec in plan] if single_process else []
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
        [sys.executable, "-m", "haptic_teleop.benchmarks.live", "--probe"],
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
    figures: dict[str, Any] = {}
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
        t0 = time.monotonic()
        receiver.recording = True
        time.sleep(duration_s)
        receiver.recording = False
        wall = time.monotonic() - t0
        cpu = {n: (_cpu_s(p) - cpu0[n]) / wall * 100.0 for n, p in pids.items()}
        time.sleep(1.2)  # one more round of diagnostics
        diags = dict(receiver.diagnostics)
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
    rows = []
    ok_rate = True
    for name in composed_names + list(pids):
        d = diags.get(name, {})
        rate = float(d.get("loop_rate_hz", "nan"))
        period = float(d.get("period_s", period_s))
        is_1khz = abs(period - period_s) < 1e-12 and name not in ("bench_probe", "node set (1 process)")
        if is_1khz and not rate >= LOOP_RATE_TARGET * target_hz:
            ok_rate = False
        rows.append(
            (
                name,
                rate,
                int(d.get("overruns", "0") or 0),
                float(d.get("lateness_p50_us", "nan")),
                float(d.get("lateness_p99_us", "nan")),
                cpu.get(name, float("nan")),
                1.0 / period if period > 0 else float("nan"),
            )
        )
    bare50, bare99, nb = _percentiles_us(receiver.latency_ns["bare"])
    rel50, rel99, nr = _percentiles_us(receiver.latency_ns["relay"])
    ratio = rel99 / bare99 if bare99 > 0 else float("nan")
    p = out.write
    p(
        f"bench live: scene {scene.config.scene.name}, {duration_s:g} s measured, period {period_s * 1e3:g} ms, "
        f"{os.cpu_count()} cores\n\n"
    )
    p(
        f"  {'node':<16} {'loop Hz':>9} {'target':>7} {'overruns':>8} "
        f"{'late p50 us':>11} {'late p99 us':>11} {'CPU %':>6}\n"
    )
    for name, rate, over, l50, l99, c, tgt in rows:
        p(f"  {name:<16} {rate:>9.1f} {tgt:>7.0f} {over:>8d} {l50:>11.1f} {l99:>11.1f} {c:>6.1f}\n")
    total_cpu = sum(r[5] for r in rows if r[5] == r[5])  # NaN: no process of its own
    p(f"  {'total':<16} {'':>9} {'':>7} {'':>8} {'':>11} {'':>11} {total_cpu:>6.1f}\n\n")
    p("  hop latency (us)          p50      p99   samples\n")
    p(f"  bare rclpy pub->sub  {bare50:>8.0f} {bare99:>8.0f} {nb:>9d}\n")
    p(f"  through relay (0 s)  {rel50:>8.0f} {rel99:>8.0f} {nr:>9d}\n\n")
    p(
        f"  loop rate >= {LOOP_RATE_TARGET:.0%} of {target_hz:.0f} Hz on every 1 kHz node: "
        f"{'yes' if ok_rate else 'NO'}\n"
    )
    p(
        f"  relay hop p99 <= {HOP_RATIO_TARGET:g} x bare hop p99: {'yes' if ratio <= HOP_RATIO_TARGET else 'NO'} "
        f"(ratio {ratio:.2f})\n"
    )
    figures.update(
        nodes={
            r[0]: {
                "loop_rate_hz": r[1],
                "overruns": r[2],
                "lateness_p50_us": r[3],
                "lateness_p99_us": r[4],
                "cpu_percent": r[5],
            }
            for r in rows
        },
        bare_hop_us=(bare50, bare99, nb),
        relay_hop_us=(rel50, rel99, nr),
        hop_p99_ratio=ratio,
        loop_rate_ok=ok_rate,
    )
    return figures


HELP = "live node set: loop rate, loop jitter, relay hop vs bare DDS hop, CPU per node"


def add_arguments(p: Any) -> None:
    p.add_argument("--scene", default="wall_contact", help="scene YAML path or bundled name")
    p.add_argument("--duration", type=float, default=10.0, help="seconds of measurement")
    p.add_argument(
        "--single-process",
        action="store_true",
        help="the node set composed in one process with one shared loop thread (launch --single-process)",
    )


def main(args: Any) -> int:
    """`haptic-teleop bench live` (argparse namespace from cli.py)."""
    run_bench(args.scene, float(args.duration), single_process=bool(args.single_process))
    return 0


def _probe_main() -> None:
    from haptic_teleop.nodes.common import run_nodes

    Probe, _ = _probe_classes()
    sys.exit(run_nodes([Probe], args=[]))


if __name__ == "__main__":
    if "--probe" in sys.argv:
        _probe_main()
    else:
        print("usage: haptic-teleop bench live [--scene S] [--duration S]", file=sys.stderr)
        sys.exit(2)
