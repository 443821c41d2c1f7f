"""`haptic-teleop launch`: the live node set of a scene, each node its own OS process.

The plan (which nodes, their names, executables and parameters) comes from the scene file alone
(`node_plan`), and parameter files are written as ROS 2 expects them (`node: ros__parameters:`,
doubles with a decimal point), so `ros2 launch haptic_teleop teleop_launch.py` builds the very
same processes from the same plan. No ROS 2 install is needed here: each node is started as
`python -m haptic_teleop.nodes.X --ros-args -r __node:=NAME --params-file FILE`.

Supervision: every output line is prefixed with the node name; SIGINT and SIGTERM are forwarded
(nodes first, the recorder last so the bag holds everything); a node that exits 0 by itself (the
operator source, after the scene's duration) ends the run; the first node that exits non-zero is
a crash: the others get the watchdog bound to reach their safe state, then are stopped, and the
launcher exits 1.
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from haptic_teleop.lifetime import LAUNCHER_PID_ENV
from haptic_teleop.nodes import (
    DEVICE_SOURCES,
    EXECUTABLES,
    LOOP_FIGURES_MARK,
    SCENE_SECTIONS,
    WATCHDOG_FADE_S,
    WATCHDOG_TIMEOUT_S,
)
from haptic_teleop.scene.schema import LoadedScene

SIDES = ("all", "master", "slave")
DEVICES = DEVICE_SOURCES
# Which side of a two-host setup each node belongs to: relays sit on the sending side, sync
# buffers on the receiving side.
# An ack relay (ARQ) sits on the side that sends the acknowledgements: the receiving side's.
MASTER_SIDE = (
    "clock_source", "operator_source", "master_eba", "forward_relay", "backward_buffer", "backward_ack_relay",
    "recorder",
)  # fmt: skip
SLAVE_SIDE = ("slave_eba", "backward_relay", "forward_buffer", "forward_ack_relay")
# A node's stop may wait up to twice messages.FINAL_ACK_S (4 s) for a reader's acknowledgements, and
# a dead recorder (SIGKILL) never acknowledges: its writers wait the whole time. With the
# middleware's teardown on a busy machine that came close to 10 s (CI: a node aborted after the
# recorder's kill), so a stop has 2 x 4 s plus 12 s for everything else.
STOP_TIMEOUT_S = 20.0
RECORDER_STOP_TIMEOUT_S = 60.0
ABORT_WAIT_S = 5.0  # a node that did not stop: its stacks printed on SIGABRT within this, then SIGKILL
EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_SIGNAL = {signal.SIGINT: 130, signal.SIGTERM: 143}  # 128 + the signal that stopped the launch
# A node killed by SIGSEGV/SIGBUS at start is most often Fast DDS reopening a shared-memory port
# segment that a killed process of the same ROS domain left in /dev/shm (docs/live_launch.md).
SHM_HINT = (
    "a node crashed in native code; if it was at start after a process of this ROS domain was killed, "
    "stale Fast DDS segments are the usual cause: see 'Native crashes at start' in docs/live_launch.md"
)


@dataclass(frozen=True)
class NodeSpec:
    """One process of the live node set."""

    name: str  # ROS node name
    executable: str  # console script in lib/haptic_teleop, and key of EXECUTABLES
    params: Mapping[str, Any]  # nested, as under ros__parameters
    remaps: tuple[tuple[str, str], ...] = ()  # topic remappings (from, to)

    @property
    def module(self) -> str:
        return EXECUTABLES[self.executable]


def local_discovery_env(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """`env` (default os.environ) with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless already set."""
    out = dict(os.environ if env is None else env)
    out.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return out


def _nest(path: str, value: Any) -> dict[str, Any]:
    out: Any = value
    for part in reversed([p for p in path.split(".") if p]):
        out = {part: out}
    nested: dict[str, Any] = out
    return nested


def _merge(into: dict[str, Any], other: Mapping[str, Any]) -> dict[str, Any]:
    for k, v in other.items():
        if isinstance(v, Mapping) and isinstance(into.get(k), dict):
            _merge(into[k], v)
        else:
            into[k] = dict(v) if isinstance(v, Mapping) else v
    return into


def _drop_none(d: Any) -> Any:
    if isinstance(d, Mapping):
        return {k: _drop_none(v) for k, v in d.items() if v is not None and v not in ((), [])}
    return d


def scene_params(scene: LoadedScene, executable: str, direction: str | None = None) -> dict[str, Any]:
    """The scene sections `executable` reads, as nested parameters (every leaf explicit). An NVE
    direction (`<client>/up|down`) reads its client's link section; an NVE scene's clients are
    sections named by the client, listed in `nve.client_names` (nodes/params.py)."""
    from haptic_teleop.nodes import NVE_SCENE_SECTIONS
    from haptic_teleop.nodes.params import scene_section
    from haptic_teleop.nodes.wire import nve_direction

    nd = nve_direction(direction) if direction is not None else None
    if nd is not None:
        templates = [t.format(client=nd[0], link=nd[1]) for t in NVE_SCENE_SECTIONS[executable]]
    else:
        templates = [t.format(direction=direction) for t in SCENE_SECTIONS[executable]]
    params: dict[str, Any] = {}
    for path in templates:
        obj = scene_section(scene.config, path)
        if obj is None:  # an optional section the scene leaves out (`mapping` of a one-axis scene)
            continue
        if path.endswith(".effects"):
            from haptic_teleop.scene.traces import resolve_trace_paths

            obj = resolve_trace_paths(obj, Path(scene.source).parent)  # nodes run elsewhere
        section = dataclasses.asdict(obj)
        nve = section if path == "nve" else section.get("nve") if path == "" else None
        if nve:  # the clients: a section per client, named by it
            names = [c.pop("name") for c in nve["clients"]]
            nve["clients"] = dict(zip(names, nve["clients"], strict=True))
            nve["client_names"] = names
        elif path.startswith("nve.clients."):
            _merge(params, {"nve": {"client_names": [path.split(".")[2]]}})
        _merge(params, _nest(path, section) if path else section)
    params = _drop_none(params)
    op = params.get("operator")
    if op is not None and op.get("trace_file"):
        tp = Path(op["trace_file"])
        if not tp.is_absolute():  # relative to the scene file, as load_scene reads it
            op["trace_file"] = str((Path(scene.source).parent / tp).resolve())
    return params


def node_plan(
    scene: LoadedScene,
    record_dir: str | Path | None = None,
    side: str = "all",
    device: str = "plant",
    watchdog_timeout_s: float = WATCHDOG_TIMEOUT_S,
    watchdog_fade_s: float = WATCHDOG_FADE_S,
    sim_time_rate: float | None = None,
    device_topics: tuple[str, str] | None = None,
    command_qos: tuple[str, int] | None = None,
) -> list[NodeSpec]:
    """The node set of a scene. `device="topic"` is the hardware variant: the master reads a haptic
    device driver's topics (`device_topics` = (state, command); default the node's) and there is
    no simulated operator; `command_qos` = (reliability, depth) of its force command (default the
    node's: reliable, 10). `sim_time_rate` (simulated s per wall s) adds a clock_source and sets
    use_sim_time on every node."""
    if side not in SIDES:
        raise ValueError(f"side must be one of {SIDES}, got {side!r}")
    if scene.config.is_nve:
        return nve_plan(scene, record_dir, side, device, sim_time_rate)
    if device not in DEVICES:
        raise ValueError(f"device must be one of {DEVICES}, got {device!r}")
    # The codec stage live (docs/live_network.md, "Codecs live"): what the nodes do not run is refused here,
    # one line, before anything starts.
    from haptic_teleop.nodes.codec_stage import check_live_codec

    codecs = {d: check_live_codec(scene.source, scene.config, d) for d in ("forward", "backward")}
    # The seed scenario (docs/transparency.md) runs in the engine only: its position source puts
    # the handle on the trajectory inside the tick, and its in-contact start sets both sides' state.
    from haptic_teleop.errors import ConfigError as _ConfigError

    if scene.config.operator.profile == "imposed":
        raise _ConfigError(
            scene.source,
            "operator.profile",
            "imposed",
            "runs in `haptic-teleop run` only; allowed live: push, sinusoid, hold, trace",
        )
    if scene.config.slave.in_contact:
        raise _ConfigError(
            scene.source, "slave.start", "in_contact", "runs in `haptic-teleop run` only; allowed live: free"
        )
    if device != "plant" and scene.config.is_arm:
        from haptic_teleop.errors import ConfigError

        raise ConfigError(
            scene.source, "device", device, "an arm scene runs its simulated arms only for now; allowed: plant"
        )
    if scene.config.is_arm:
        # A side's own period (<side>.period_s: whole scene periods, docs/arms.md): its node's loop
        # ticks at it (nodes/arm_side.py). Checked here for one clear line before any node starts; a
        # one-axis scene with the key never gets here (load_scene: "only for arm models").
        from haptic_teleop.scene.load import side_period_ticks

        for role in ("master", "slave"):
            side_period_ticks(scene.config, role, scene.source)
    if sim_time_rate is not None and not 0.01 <= sim_time_rate <= 10.0:
        raise ValueError(f"sim_time_rate must be in [0.01, 10] simulated s per wall s, got {sim_time_rate}")
    watchdog = {"watchdog": {"timeout_s": float(watchdog_timeout_s), "fade_s": float(watchdog_fade_s)}}
    plan: list[NodeSpec] = []
    if device == "plant":
        start = {"start": {"min_subscribers": 2 if record_dir is not None else 1}}
        plan.append(
            NodeSpec("operator_source", "operator_source", _merge(scene_params(scene, "operator_source"), start))
        )
    master = _merge(scene_params(scene, "master_eba"), watchdog)
    master["device"] = {"source": device}
    if device == "topic" and record_dir is not None:  # scene time 0 once the recorder takes every stream
        master["device"].update(min_subscribers=1, wait_for_recorder=True)
    if device_topics is not None:
        master["device"].update(state_topic=device_topics[0], command_topic=device_topics[1])
    if command_qos is not None:
        master["device"].update(command_reliability=str(command_qos[0]), command_depth=int(command_qos[1]))
    plan.append(NodeSpec("master_eba", "master_eba", master))
    plan.append(NodeSpec("slave_eba", "slave_eba", _merge(scene_params(scene, "slave_eba"), watchdog)))
    # Without an operator source master_eba publishes the scene start (device.start_delay_s after its device answered):
    # the relays and the recorder take it from there as they do the operator source's.
    # An arm scene's payloads carry one value per task axis and field (docs/live_arms.md, "Arm scenes").
    axes = {"task_axes": 3} if scene.config.is_arm else {}
    reverse = {"forward": "backward", "backward": "forward"}
    for d in ("forward", "backward"):
        carries = {"carries": "codec"} if codecs[d] is not None else {}
        relay = {"direction": d, **carries, **axes, **scene_params(scene, "network_relay", d)}
        plan.append(NodeSpec(f"{d}_relay", "network_relay", relay))
        buffer = {"direction": d, **axes, **scene_params(scene, "sync_buffer", d)}
        plan.append(NodeSpec(f"{d}_buffer", "sync_buffer", buffer))
        if codecs[d] == "arq":  # its acknowledgements, over the reverse direction's effects
            effects = scene_params(scene, "network_relay", reverse[d])
            ack = {"direction": d, "carries": "ack", **axes, **effects}
            plan.append(NodeSpec(f"{d}_ack_relay", "network_relay", ack))
    if record_dir is not None:
        recorder = {**scene_params(scene, "recorder"), "output_dir": str(Path(record_dir).resolve())}
        if device == "topic":  # no operator source: no /operator/joint_states (nodes/recorder.py)
            recorder["device"] = {"source": device}
        plan.append(NodeSpec("recorder", "recorder", recorder))
    if sim_time_rate is not None:
        plan = [dataclasses.replace(s, params={**s.params, "use_sim_time": True}) for s in plan]
        clock = {"scene": {"period_s": scene.config.scene.period_s}, "rate": float(sim_time_rate)}
        plan.insert(0, NodeSpec("clock_source", "clock_source", clock))
    if side != "all":
        keep = MASTER_SIDE if side == "master" else SLAVE_SIDE
        plan = [s for s in plan if s.name in keep]
    return plan


def nve_client_node(client: str) -> str:
    """The node name of an NVE client."""
    return f"nve_client_{client}"


def nve_plan(
    scene: LoadedScene,
    record_dir: str | Path | None = None,
    side: str = "all",
    device: str = "plant",
    sim_time_rate: float | None = None,
) -> list[NodeSpec]:
    """The node set of an NVE scene (docs/live_nve.md, "NVE scenes live"): the server, one node per
    client, and per client a relay and a sync buffer for each direction of its link pair
    (`<client>/up`, `<client>/down`), in pipeline order."""
    from haptic_teleop.errors import ConfigError

    nve = scene.config.nve
    assert nve is not None
    if side != "all":
        raise ConfigError(scene.source, "--side", side, "an NVE scene runs on one host for now; allowed: all")
    if device != "plant":
        raise ConfigError(scene.source, "device", device, "an NVE scene's HIPs are operator profiles; allowed: plant")
    if sim_time_rate is not None and not 0.01 <= sim_time_rate <= 10.0:
        raise ValueError(f"sim_time_rate must be in [0.01, 10] simulated s per wall s, got {sim_time_rate}")
    axes = {"task_axes": nve.axes}
    # Recording: scene time 0 waits for the recorder too (it subscribes to the object's state).
    start = {"start": {"min_subscribers": 1 if record_dir is not None else 0}}
    plan = [NodeSpec("nve_server", "nve_server", _merge(scene_params(scene, "nve_server"), start))]
    for c in nve.clients:
        plan.append(
            NodeSpec(nve_client_node(c.name), "nve_client", {"client": c.name, **scene_params(scene, "nve_client")})
        )
    for c in nve.clients:
        for link in ("up", "down"):
            d = f"{c.name}/{link}"
            relay = {"direction": d, **axes, **scene_params(scene, "network_relay", d)}
            plan.append(NodeSpec(f"{c.name}_{link}_relay", "network_relay", relay))
            buffer = {"direction": d, **axes, **scene_params(scene, "sync_buffer", d)}
            plan.append(NodeSpec(f"{c.name}_{link}_buffer", "sync_buffer", buffer))
    if record_dir is not None:
        params = {**scene_params(scene, "recorder"), "output_dir": str(Path(record_dir).resolve())}
        plan.append(NodeSpec("recorder", "recorder", params))
    if sim_time_rate is not None:
        plan = [dataclasses.replace(s, params={**s.params, "use_sim_time": True}) for s in plan]
        clock = {"scene": {"period_s": scene.config.scene.period_s}, "rate": float(sim_time_rate)}
        plan.insert(0, NodeSpec("clock_source", "clock_source", clock))
    return plan


# ---------------------------------------------------------------------------------------------
# Parameter files.


def format_double(x: float) -> str:
    """A YAML double that ROS 2 reads as a double: always with a decimal point (`1.0`, `1.0e-08`)."""
    if not math.isfinite(x):
        raise ValueError(f"parameters must be finite, got {x}")
    r = repr(float(x))
    if "e" in r:
        mant, _, exp = r.partition("e")
        if "." not in mant:
            mant += ".0"
        return f"{mant}e{exp}"
    return r if "." in r else r + ".0"


def _scalar(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return format_double(v)
    if isinstance(v, str):
        return json.dumps(v)  # a double-quoted YAML string
    raise TypeError(f"unsupported parameter value {v!r}")


def _emit(d: Mapping[str, Any], indent: int, lines: list[str]) -> None:
    pad = "  " * indent
    for k, v in d.items():
        if isinstance(v, Mapping):
            if not v:
                continue
            lines.append(f"{pad}{k}:")
            _emit(v, indent + 1, lines)
        elif isinstance(v, (list, tuple)):
            if v:
                lines.append(f"{pad}{k}: [{', '.join(_scalar(x) for x in v)}]")
        elif v is not None:
            lines.append(f"{pad}{k}: {_scalar(v)}")


def params_yaml(spec: NodeSpec) -> str:
    lines = [f"{spec.name}:", "  ros__parameters:"]
    _emit(spec.params, 2, lines)
    return "\n".join(lines) + "\n"


PARAMS_PREFIX = "haptic_teleop_params_"


def temporary_params_dir() -> Path:
    """A temporary folder for the nodes' parameter files, removed when this process exits (the
    nodes read their file when they start; a launch killed by SIGKILL leaves it behind)."""
    path = tempfile.mkdtemp(prefix=PARAMS_PREFIX)
    atexit.register(shutil.rmtree, path, True)
    return Path(path)


def write_params_files(plan: Sequence[NodeSpec], directory: str | Path) -> dict[str, Path]:
    """One `NAME.yaml` per node; returns name -> path."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out = {}
    for spec in plan:
        p = d / f"{spec.name}.yaml"
        p.write_text(params_yaml(spec))
        out[spec.name] = p
    return out


def node_command(spec: NodeSpec, params_file: Path, python: str = sys.executable) -> list[str]:
    # Through nodes/entry.py: a signal that lands while the node is still importing is noted (exit 0).
    cmd = [python, "-m", "haptic_teleop.nodes.entry", spec.executable, "--ros-args", "-r", f"__node:={spec.name}"]
    cmd += ["--params-file", str(params_file)]
    for a, b in spec.remaps:
        cmd += ["-r", f"{a}:={b}"]
    return cmd


# ---------------------------------------------------------------------------------------------
# Processes.


@dataclass
class Child:
    spec: NodeSpec
    proc: subprocess.Popen[bytes]
    pump: threading.Thread
    stopped_by_us: bool = False
    returncode: int | None = None
    cpu_s: float = 0.0


@dataclass
class LaunchResult:
    exit_code: int
    reason: str  # finished | interrupted | crashed | timeout
    codes: dict[str, int] = field(default_factory=dict)
    crashed: str | None = None


class Launcher:
    """Starts the plan as processes and supervises them (see module docstring)."""

    def __init__(
        self,
        plan: Sequence[NodeSpec],
        params_dir: str | Path,
        env: Mapping[str, str] | None = None,
        out: IO[str] | None = None,
        crash_grace_s: float = WATCHDOG_TIMEOUT_S + WATCHDOG_FADE_S + 0.5,
        timeout_s: float | None = None,
    ) -> None:
        self.plan = list(plan)
        self.files = write_params_files(self.plan, params_dir)
        self.env = local_discovery_env(env)
        self.env["PYTHONUNBUFFERED"] = "1"
        self.env.setdefault("PYTHONFAULTHANDLER", "1")  # a node that crashes prints where, in its log
        # Each node stops (SIGTERM, a clean stop) when this process dies, even by SIGKILL.
        self.env[LAUNCHER_PID_ENV] = str(os.getpid())
        self.out = out or sys.stdout
        self.crash_grace_s = crash_grace_s
        self.timeout_s = timeout_s
        self.children: list[Child] = []
        self._write_lock = threading.Lock()
        self._interrupt = threading.Event()
        self.signal: int | None = None  # the signal that asked for the stop, if one did
        self.figures: dict[str, dict[str, Any]] = {}  # node -> its loop figures (LOOP_FIGURES_MARK)

    def log(self, text: str) -> None:
        self._line("launcher", text)

    def _line(self, name: str, text: str) -> None:
        with self._write_lock:
            self.out.write(f"[{name}] {text}\n")
            self.out.flush()

    def _pump(self, name: str, stream: IO[bytes]) -> None:
        for raw in iter(stream.readline, b""):
            text = raw.decode(errors="replace").rstrip("\n")
            if text.startswith(LOOP_FIGURES_MARK):
                with contextlib.suppress(ValueError):
                    self.figures[name] = json.loads(text[len(LOOP_FIGURES_MARK) :])
                    continue
            self._line(name, text)
        stream.close()

    def start(self) -> None:
        for spec in self.plan:
            cmd = node_command(spec, self.files[spec.name])
            proc = subprocess.Popen(
                cmd,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=self.env,
                start_new_session=True,  # Ctrl-C reaches the launcher, which forwards it in order
            )
            assert proc.stdout is not None
            pump = threading.Thread(target=self._pump, args=(spec.name, proc.stdout), daemon=True)
            pump.start()
            self.children.append(Child(spec, proc, pump))
            self.log(f"started {spec.name} ({spec.executable}) pid {proc.pid}")

    def pids(self) -> dict[str, int]:
        return {c.spec.name: c.proc.pid for c in self.children}

    def interrupt(self, signum: int | None = None) -> None:
        """Ask for a clean stop (what SIGINT/SIGTERM to the launcher do)."""
        if self.signal is None:
            self.signal = signum
        self._interrupt.set()

    def _poll(self) -> None:
        for c in self.children:
            if c.returncode is None:
                rc = c.proc.poll()
                if rc is not None:
                    c.returncode = rc

    def supervise(self) -> LaunchResult:
        t0 = time.monotonic()
        reason = ""
        crashed: Child | None = None
        while True:
            self._poll()
            if self._interrupt.is_set():
                reason = "interrupted"
                self.log("interrupt: stopping every node")
                break
            done = [c for c in self.children if c.returncode is not None]
            bad = [c for c in done if c.returncode != 0]
            if bad:
                crashed = bad[0]
                reason = "crashed"
                self.log(
                    f"{crashed.spec.name} exited with code {crashed.returncode}; stopping the rest in "
                    f"{self.crash_grace_s:.2f} s (watchdog bound)"
                )
                if crashed.returncode in (-signal.SIGSEGV, -signal.SIGBUS):
                    self.log(SHM_HINT)
                end = time.monotonic() + self.crash_grace_s
                while time.monotonic() < end and not self._interrupt.is_set():
                    time.sleep(0.02)
                break
            if done:
                reason = "finished"
                self.log(f"{done[0].spec.name} finished; stopping the rest")
                break
            if self.timeout_s is not None and time.monotonic() - t0 > self.timeout_s:
                reason = "timeout"
                self.log(f"no node finished within {self.timeout_s:.0f} s; stopping every node")
                break
            time.sleep(0.02)
        self.stop()
        codes = {c.spec.name: int(c.returncode if c.returncode is not None else -1) for c in self.children}
        for name, code in codes.items():
            self.log(f"{name} exited {code}")
        with self._write_lock:
            self.out.write(format_loop_table([c.spec.name for c in self.children], self.figures) + "\n")
            self.out.flush()
        ok = reason in ("finished", "interrupted") and all(v == 0 for v in codes.values())
        code = EXIT_OK if ok else EXIT_FAILURE
        if ok and reason == "interrupted" and self.signal is not None:
            code = EXIT_SIGNAL.get(signal.Signals(self.signal), EXIT_FAILURE)
        return LaunchResult(code, reason, codes, crashed.spec.name if crashed else None)

    def _stop_group(self, group: list[Child], timeout_s: float) -> None:
        for c in group:
            if c.returncode is None and c.proc.poll() is None:
                c.stopped_by_us = True
                with contextlib.suppress(ProcessLookupError):
                    c.proc.send_signal(signal.SIGINT)
        end = time.monotonic() + timeout_s
        for c in group:
            try:
                c.proc.wait(max(0.0, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                # SIGABRT first: the node's fault handler (PYTHONFAULTHANDLER) prints every thread's
                # stack into its log, so a hang says where it hangs; then it is killed
                self.log(f"{c.spec.name} did not stop within {timeout_s:.0f} s; its stacks follow, then it is killed")
                with contextlib.suppress(ProcessLookupError):
                    c.proc.send_signal(signal.SIGABRT)
                try:
                    c.proc.wait(ABORT_WAIT_S)
                except subprocess.TimeoutExpired:
                    c.proc.kill()
                    c.proc.wait()
            c.returncode = c.proc.returncode

    def stop(self) -> None:
        """SIGINT to every node but the recorder, wait; then the recorder (it writes the bag)."""
        nodes = [c for c in self.children if c.spec.executable != "recorder"]
        recorders = [c for c in self.children if c.spec.executable == "recorder"]
        self._stop_group(nodes, STOP_TIMEOUT_S)
        self._stop_group(recorders, RECORDER_STOP_TIMEOUT_S)
        for c in self.children:
            c.pump.join(2.0)

    def run(self) -> LaunchResult:
        """start + supervise, with SIGINT/SIGTERM to this process forwarded as a clean stop."""
        previous = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                previous[sig] = signal.signal(sig, lambda s, f: self.interrupt(s))
        try:
            self.start()
            return self.supervise()
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


def format_loop_table(names: Sequence[str], figures: Mapping[str, Mapping[str, Any]]) -> str:
    """The loops of the node set over their whole life, one row per node (`-`: no figures, e.g. a
    node that was killed or has no loop): ticks run, loop rate (ticks per second of wall time),
    late ticks (run a period or more after their deadline), skipped ticks (overruns), the most a
    tick's work ended after its deadline (ms: whatever it took, it took no later); and what a
    relay lost and a sync buffer skipped as late, and those that came after their due tick (this
    machine's lateness, not the network's: docs/live_network.md, "Deliveries on the stamp grid") (packets)."""
    head = ("node", "ticks", "rate Hz", "late ticks", "skipped ticks", "latest end ms", "packets")
    rows = [head]
    for name in names:
        f = figures.get(name)
        if f is None:
            rows.append((name, "-", "-", "-", "-", "-", ""))
            continue
        rate = f"{float(f['loop_rate_hz']):.1f}"
        notes = []
        if "delivered" in f:
            notes.append(f"{f['delivered']} delivered, {f.get('lost', 0)} lost")
            if int(f.get("late_to_relay", 0)):
                notes.append(f"{f['late_to_relay']} came after their due tick")
        if "released" in f:
            notes.append(f"{f['released']} released, {f.get('late', 0)} late")
            if int(f.get("late_by_scheduling", 0)):
                notes.append(f"{f['late_by_scheduling']} late by scheduling")
        end = f.get("end_late_max_us")
        end_ms = "-" if end is None else f"{float(end) * 1e-3:.3f}"
        counts = (str(f["ticks"]), rate, str(f["late_ticks"]), str(f["skipped_ticks"]), end_ms)
        rows.append((name, *counts, "; ".join(notes)))
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    lines = ["loops (whole run):"]
    for r in rows:
        cells = [
            c.ljust(w) if i in (0, len(head) - 1) else c.rjust(w)
            for i, (c, w) in enumerate(zip(r, widths, strict=True))
        ]
        lines.append("  " + "  ".join(cells).rstrip())
    if any("delivered" in f or "released" in f for f in figures.values()):
        lines.append(LOOP_TABLE_LEGEND)
    return "\n".join(lines)


# What the loop table's packet counts are, beside the summary's (docs/live_measured.md).
LOOP_TABLE_LEGEND = (
    "  (packets: a relay's delivered and lost are its scene link's, from scene time 0 on; a buffer's\n"
    "   released (samples it released, one a tick at most) and late (packets it skipped as late) count from\n"
    "   its start, the settling before scene time 0 too; the summary counts packets sent from scene time 0\n"
    "   to the recording's end)"
)


# ---------------------------------------------------------------------------------------------
# Single process.


def run_single_process(plan: Sequence[NodeSpec], params_dir: str | Path, out: IO[str] | None = None) -> int:
    """Every node of the plan in this process: one executor, one shared loop thread ticking every
    node in pipeline order (nodes.rtloop.SharedLoop); the recorder is closed last. Prints the loop
    table at the end; a SIGINT/SIGTERM that stopped the nodes gives exit 130/143."""
    import importlib

    from haptic_teleop.nodes.base import run_nodes

    files = write_params_files(plan, params_dir)
    ordered = sorted(plan, key=lambda s: s.executable == "recorder")
    factories = []
    node_args = []
    for spec in ordered:
        module = importlib.import_module(spec.module)
        cls = next(
            v
            for v in vars(module).values()
            if isinstance(v, type) and getattr(v, "__module__", "") == spec.module and hasattr(v, "default_name")
        )
        factories.append(cls)
        node_args.append(
            {
                "node_name": spec.name,
                "cli_args": ["--ros-args", "--params-file", str(files[spec.name])],
                "use_global_arguments": False,
            }
        )
    figures: list[dict[str, Any]] = []
    signals: list[int] = []
    code = run_nodes(factories, node_args, args=[], shared_loop=True, figures_out=figures, signals_out=signals)
    stream = out or sys.stdout
    stream.write(format_loop_table([s.name for s in plan], {f["node"]: f for f in figures}) + "\n")
    stream.flush()
    if code == 0 and signals:
        code = EXIT_SIGNAL.get(signal.Signals(signals[0]), EXIT_FAILURE)
    return code
