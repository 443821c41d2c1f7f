"""Deterministic lockstep runner in simulated time: the default main job.

One tick (period T; docs/architecture.md, "One tick"), in this order:
  1. read both plants (state at t_n); the slave's wall force is MuJoCo's over the last period;
  2. master controller: control law on the latest backward sample, saturation, energy bound;
  3. master packet (x_m, v_m) into the forward link; arrivals by t_n go to the slave's buffer;
  4. slave controller on the sample its buffer releases;
  5. slave packet (f_env, x_s, v_s) into the backward link; arrivals by t_n go to the master's
     buffer and are used from the next tick on;
  6. operator hand force from the master state; both plants step one period with the forces held.
Output streams: each tick's row goes into one block of BLOCK_TICKS rows handed to a sink (the
recorder) when full; each packet's record is handed over once its fate is final. Nothing the loops
hold grows with the run's length (docs/performance_memory.md, "Memory").
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from haptic_teleop import compiling
from haptic_teleop.assembly.channel import LAYOUT_ARM, build_codec_channels
from haptic_teleop.assembly.parts import (
    REMOTE_LIMIT_MARGIN,
    assemble_axis,
    build_network,
    build_operator,
    remote_limits,
)
from haptic_teleop.assembly.stages import (
    ArmOperator,
    ArmRow,
    ArmSideStage,
    AxisOperator,
    AxisRow,
    AxisSide,
    channel_stage,
)
from haptic_teleop.core.link import Link
from haptic_teleop.core.playout import PlayoutBuffer
from haptic_teleop.engine.compiled import axis_host
from haptic_teleop.engine.compiled.windows import CHUNK_TICKS, run_windows
from haptic_teleop.engine.loop import LoopState, Stages, run_ticks
from haptic_teleop.engine.output import NO_PACKETS, Collector, Output, RunSink, loop_guard
from haptic_teleop.errors import InputError
from haptic_teleop.record.columns import ONE_DOF, TickSchema
from haptic_teleop.record.streams import BLOCK_TICKS
from haptic_teleop.scene.schema import LoadedScene

__all__ = ["COL", "COLUMNS", "REMOTE_LIMIT_MARGIN", "Engine", "build_operator", "remote_limits"]

# Per-tick columns, in record order: the 1-DoF tick schema (record/columns.py).
COLUMNS = ONE_DOF.columns
COL = ONE_DOF.col


@dataclass
class RunResult:
    """What the loop produced: timing, and the whole run's columns and packet records if it was
    kept (`Engine.run` without a sink); empty arrays if it went to a sink."""

    scene: LoadedScene
    ticks: int
    period_ns: int
    data: np.ndarray  # (ticks, len(COLUMNS)), or (0, len(COLUMNS))
    forward_log: np.ndarray  # packet records (record.layouts.PACKET_FIELDS rows) in hand-over order
    backward_log: np.ndarray
    loop_wall_s: float
    interrupted: bool
    extra: dict[str, float] = field(default_factory=dict)
    schema: TickSchema = ONE_DOF  # the columns of `data` (record/columns.py)

    def column(self, name: str) -> np.ndarray:
        return self.data[: self.ticks, self.schema.col[name]]


LOOPS = ("auto", "compiled", "python")
VECTORIZED_WINDOW_TICKS = 10 * BLOCK_TICKS  # a vectorized network schedule is decided this far ahead


class Engine:
    """Builds the parts a scene names and runs them in lockstep.

    `loop`: "compiled" runs the tick in machine code (haptic_teleop/axis_host.py), "python" in
    the interpreter, "auto" the compiled loop when the scene allows it. Both give the same
    columns bit for bit; `loop_kind` says which one runs, `compiled_reason` why not compiled.
    """

    def __init__(self, scene: LoadedScene, loop: str = "auto") -> None:
        if loop not in LOOPS:
            raise ValueError(f"loop must be one of {', '.join(LOOPS)}, got {loop!r}")
        self.scene = scene
        c = scene.config
        self.period_s = c.scene.period_s
        self.period_ns = round(c.scene.period_s * 1e9)
        self.ticks = int(round(c.scene.duration_s / c.scene.period_s))
        self.schema: TickSchema = ONE_DOF
        self.pacer: Any = None  # pacer.Pacer when a side is a real device
        self.hardware_master = self.hardware_slave = False
        if c.is_arm:
            self._init_arm(loop)
            return
        self.parts = parts = assemble_axis(c, scene.operator_trace, self.period_ns)
        self.contact_start = parts.contact_start
        self.operator = parts.operator
        self.master, self.slave = parts.master, parts.slave
        self.master_ctrl, self.slave_ctrl = parts.master_ctrl, parts.slave_ctrl
        self.initial_energy = parts.initial_energy
        self.forward, self.backward = parts.forward, parts.backward
        self.forward_buffer, self.backward_buffer = parts.forward_buffer, parts.backward_buffer
        # The codec stage of the directions that name one (docs/codec_channels.md).
        self.codecs = parts.codecs
        # Wire sizes of the two packets (setup: the first call loads the message types).
        self._sizes = (_wire_payload_bytes(2), _wire_payload_bytes(3))
        if self.master_ctrl.tdpa is not None:
            # TDPA's samples carry the observed energy too: a JointState with a second name,
            # "energy_in_j", whose position is the energy (docs/stabilizers.md, "On the wire").
            self._sizes = (_wire_payload_bytes(2, energy=True), _wire_payload_bytes(3, energy=True))
        elif self.master_ctrl.wave is not None:  # (wave, position) both ways
            self._sizes = (_wire_payload_bytes(2), _wire_payload_bytes(2))
        self._stop = False
        self._state: LoopState | None = None  # the Python loop's, while it runs
        self.compiled_reason = axis_host.compiled_reason(self.parts) if loop != "python" else "loop 'python' asked for"
        if loop == "compiled" and self.compiled_reason is not None:
            raise InputError(
                f"--loop compiled: the compiled loop cannot run this scene: {self.compiled_reason}; "
                "use --loop auto or python"
            )
        self.loop_kind = "compiled" if self.compiled_reason is None else "python"
        if self.loop_kind == "compiled":
            codec = self.codecs != (None, None)
            self._kernel = axis_host.codec_kernel() if codec else axis_host.kernel()
            assert self._kernel is not None  # compiled_reason is None only with a kernel
            # Compile (or load from numba's cache) now, not in the timed loop: zero ticks.
            head, tail = self._kernel_args()
            rel, occ = np.full(1, -1, dtype=np.int64), np.zeros(1)
            extra: tuple[np.ndarray, ...] = ()
            if codec:
                from haptic_teleop.engine.compiled.codec_host import no_codec, no_history

                idle = no_codec(self.period_ns)
                extra = (*idle, *idle, np.zeros((3, 3)), *no_history(), *no_history())
            with compiling.first_compile(self._kernel):  # once among processes; said when it compiles
                self._kernel(
                    0,
                    0,
                    *head,
                    rel,
                    occ,
                    rel,
                    occ,
                    np.zeros((1, 2)),
                    np.zeros((1, 3)),
                    *tail,
                    np.zeros((1, len(COLUMNS))),
                    0,
                    0,
                    *extra,
                )

    def _init_arm(self, loop: str) -> None:
        """An arm scene's parts (assembly.build_arm_parts)."""
        from haptic_teleop.assembly.parts import build_arm_parts
        from haptic_teleop.engine.pacer import Pacer
        from haptic_teleop.plants.hardware_arm import HardwareArm

        self.arm = parts = build_arm_parts(self.scene.config)
        try:
            self._init_arm_rest(parts, loop)
        except BaseException:
            self.close_plants()
            raise
        # A real device on a side: the loop keeps to the wall clock (pacer.Pacer).
        self.hardware_master = isinstance(parts.master.plant, HardwareArm)
        self.hardware_slave = isinstance(parts.slave.plant, HardwareArm)
        self.pacer = Pacer(self.period_s) if self.hardware_master or self.hardware_slave else None

    def close_plants(self) -> None:
        """Stop both plants (torque off on a real device; idempotent): every exit path calls it."""
        for plant in (getattr(self, "master", None), getattr(self, "slave", None)):
            if plant is not None:
                plant.close()
        if getattr(self, "arm", None) is not None:
            self.arm.master.plant.close()
            self.arm.slave.plant.close()

    def _init_arm_rest(self, parts: Any, loop: str) -> None:
        from haptic_teleop.assembly.side import side_ticks, wire_payload_bytes
        from haptic_teleop.scene.load import side_period_ticks

        self.arm_ticks = side_ticks(parts)
        # Scene ticks per side tick (<side>.period_s; docs/arms.md, "A side's own period").
        self.side_every = (
            side_period_ticks(self.scene.config, "master"),
            side_period_ticks(self.scene.config, "slave"),
        )
        self.schema = parts.schema
        self.operator = parts.operator
        self.master, self.slave = parts.master.plant, parts.slave.plant
        self.master_ctrl, self.slave_ctrl = parts.master, parts.slave
        self.forward, self.backward, self.forward_buffer, self.backward_buffer = self._network()

        # The codec stage (docs/codec_channels.md, "Wire sizes"): a codec payload's message is the
        # JointState of one name per task axis (more names when the payload needs them).
        from haptic_teleop.assembly.side import arm_message_bytes

        self.codecs = build_codec_channels(
            self.scene.config,
            self.period_ns,
            self.forward,
            self.backward,
            axes=3,
            size_of=arm_message_bytes,
            layout=LAYOUT_ARM,
        )
        # Forward: handle x, v; backward: tool x, v and contact force; one JointState name per axis
        # (with TDPA one more, `energy_in_j`: the sender's pooled input energy, core/tdpa_coupled.py).
        names = 4 if self.scene.config.controllers.master.eba.law == "tdpa" else 3
        self._sizes = (wire_payload_bytes(names, 2), wire_payload_bytes(names, 3))
        self._stop = False
        self._state: LoopState | None = None  # the Python loop's, while it runs
        from haptic_teleop.engine.compiled import arm_host

        codec = self.codecs != (None, None)
        if loop == "python":
            self.compiled_reason = "loop 'python' asked for"
        else:
            # A codec the arm kernel runs (deadband, prediction) on a link it runs (codec_host.codec_reason).
            from haptic_teleop.core.codec_layout import ARM_COMPILED_KINDS
            from haptic_teleop.engine.compiled.codec_host import codec_reason

            reasons = (codec_reason(ch, ARM_COMPILED_KINDS) for ch in self.codecs if ch is not None)
            self.compiled_reason = next((r for r in reasons if r is not None), None)
            if self.compiled_reason is None:
                self.compiled_reason = arm_host.compiled_reason_arm(
                    parts, self.forward, self.backward, self.forward_buffer, self.backward_buffer, self.period_s
                )
            if self.compiled_reason is None and codec:
                self.compiled_reason = arm_host.codec_kernel_error()
        if loop == "compiled" and self.compiled_reason is not None:
            raise InputError(
                f"--loop compiled: the compiled loop cannot run this scene: {self.compiled_reason}; "
                "use --loop auto or python"
            )
        self.loop_kind = "compiled" if self.compiled_reason is None else "python"
        if self.loop_kind == "compiled":
            self._compiled_arm = arm_host.CompiledArm(parts, self.period_s, codec=codec)
            self._compiled_arm.warm_up()  # compile (or load numba's cache) now, not in the timed loop

    def _network(self) -> tuple[Link, Link, PlayoutBuffer, PlayoutBuffer]:
        """Fresh links and playout buffers for both directions, as the scene names them."""
        return build_network(self.scene.config, self.period_ns)

    def request_stop(self) -> None:
        """Stop at the end of the current tick (Ctrl-C)."""
        self._stop = True
        if self._state is not None:  # the Python loop reads its state's flag
            self._state.stop = True

    @property
    def stop_requested(self) -> bool:
        """Whether `request_stop` was called (the compiled loops check it between chunks)."""
        return self._stop

    def run(
        self,
        progress: Callable[[int], None] | None = None,
        handle_sigint: bool = True,
        sink: RunSink | None = None,
    ) -> RunResult:
        """Run every tick (or until a stop request), handing the output to `sink` as it is made.

        The ticks' columns go to `sink.append` in blocks of BLOCK_TICKS rows (the last one
        shorter); each packet's record goes to `sink.append_packets` once its fate is final (see
        `stages.settled_records`), at the end of each block, and the rest at the end. Memory
        does not grow with the run's length. Without a sink the run is kept whole in memory
        (`Collector`; for tests and short runs) and returned in `RunResult.data` and the logs;
        with one, those are empty. If the loop raises, `self.ticks_done` says how many ticks
        finished, and the sink has been given all of them before the exception goes on.
        """
        collector = Collector(self.schema.width) if sink is None else None
        out = sink if sink is not None else collector
        assert out is not None
        with loop_guard(self.request_stop, handle_sigint):
            if self.loop_kind != "compiled":
                result = self._python_loop(progress, out)
            elif self.schema is ONE_DOF:
                result = self._compiled_loop(progress, out)
            else:
                result = self._compiled_arm_loop(progress, out)
        if collector is not None:
            result.data = self.data = collector.data()
            result.forward_log = collector.packets("forward")
            result.backward_log = collector.packets("backward")
        return result

    def _stages(self) -> Stages:
        """The stages of this scene's tick (assembly/stages.py): both sides, the operator, each
        direction's channel (its codec's, or its link and playout buffer), the row."""
        fcodec, bcodec = self.codecs
        fwd = channel_stage(fcodec, self.forward, self.forward_buffer, self._sizes[0], self.period_ns)
        bwd = channel_stage(bcodec, self.backward, self.backward_buffer, self._sizes[1], self.period_ns)
        if self.schema is ONE_DOF:
            m = AxisSide(self.master, self.master_ctrl, True)
            s = AxisSide(self.slave, self.slave_ctrl, False)
            return Stages(AxisOperator(self.operator, m, self.period_s), m, s, fwd, bwd, AxisRow(self.schema))
        parts = self.arm
        mt, st = self.arm_ticks
        km, ks = self.side_every
        # a real master's operator is a real hand: nothing is commanded at the handle
        m_arm = ArmSideStage(parts.master, mt, parts.maps, True, km, self.hardware_master, not self.hardware_master)
        s_arm = ArmSideStage(parts.slave, st, parts.maps, False, ks, self.hardware_slave, False)
        return Stages(ArmOperator(parts, self.period_s), m_arm, s_arm, fwd, bwd, ArmRow(self.schema, parts.maps))

    def _python_loop(self, progress: Callable[[int], None] | None, sink: RunSink) -> RunResult:
        """The tick in the interpreter (engine/loop.py), for every scene the compiled loops do not
        run (or `--loop python`): the same rows and packet records as they give, bit for bit."""
        self.ticks_done = 0
        stages = self._stages()
        output = Output(sink, stages.forward.settled, stages.backward.settled, self.schema.width)
        self._state = state = LoopState()
        state.stop = self._stop
        t0 = time.perf_counter()
        try:
            done = run_ticks(stages, self.ticks, self.period_ns, output, progress, state, self.pacer)
        except BaseException:
            self.ticks_done = state.ticks_done  # the failing tick did not finish: keep the ticks before it
            self.close_plants()
            output.end_after_error(self.ticks_done)
            raise
        self.ticks_done = done
        if self.schema is not ONE_DOF:  # ticks a motor's room scaled the torque down
            self.joint_limit_ticks = {
                "master": stages.master.side_tick.limited_ticks,
                "slave": stages.slave.side_tick.limited_ticks,
            }
        self.close_plants()  # torque off first, then the rest of the bag
        output.end(done)
        return self._streamed(done, time.perf_counter() - t0)

    def codec_facts(self) -> dict[str, Any]:
        """The run facts of the codec stage (`codec_<direction>`, and the plain packet's message
        size per direction, `codec_plain_bytes`: the reference of the wire accounting), for the
        bag's metadata; none without a codec."""
        if self.codecs == (None, None):
            return {}
        out: dict[str, Any] = {f"codec_{ch.direction}": ch.facts() for ch in self.codecs if ch is not None}
        out["codec_plain_bytes"] = {"forward": self._sizes[0], "backward": self._sizes[1]}
        return out

    def _streamed(self, done: int, wall_s: float) -> RunResult:
        """The result of a run whose rows and packets went to a sink: timing and tick count only."""
        return RunResult(
            scene=self.scene,
            ticks=done,
            period_ns=self.period_ns,
            data=np.zeros((0, self.schema.width)),
            forward_log=NO_PACKETS,
            backward_log=NO_PACKETS,
            loop_wall_s=wall_s,
            interrupted=done < self.ticks,
            schema=self.schema,
        )

    def _compiled_arm_loop(self, progress: Callable[[int], None] | None, sink: RunSink) -> RunResult:
        """The compiled arm loop (arm_host.CompiledArm): a codec direction runs in the kernel
        (arm_codec_nets), the other on its schedule."""
        from haptic_teleop.engine.compiled import arm_host

        self.ticks_done = 0
        nets = arm_host.arm_codec_nets(self.codecs, self.period_ns)
        (fwd, bwd), window = self._compiled_network(nets)
        output = Output(sink, (nets[0] or fwd).settled, (nets[1] or bwd).settled, self.schema.width)
        t0 = time.perf_counter()
        done = 0
        try:
            try:
                done = self._compiled_arm.run(self, progress, output, fwd, bwd, window, nets)
            finally:
                self._compiled_arm.store(self)
        except BaseException:
            done = self.ticks_done
            self.close_plants()
            output.end_after_error(done)
            raise
        self.close_plants()  # torque off first, then the rest of the bag
        output.end(done)
        wall = time.perf_counter() - t0
        return self._streamed(done, wall)

    def _schedule(self, direction: str) -> Any:
        """axis_host.schedule of a direction's link and buffer."""
        i = ("forward", "backward").index(direction)
        link, buf = (self.forward, self.forward_buffer) if i == 0 else (self.backward, self.backward_buffer)
        return axis_host.schedule(link, buf, self.period_ns, self._sizes[i])

    def _kernel_args(self) -> tuple[tuple[object, ...], tuple[object, ...]]:
        """The compiled loop's arguments (axis_kernel.run_ticks) around the network's: the plants'
        MuJoCo arrays (after the tick range), the parameters and a fresh state vector (S, last)."""
        from haptic_teleop.engine.compiled import axis_host

        m, s = self.master.data, self.slave.data  # type: ignore[attr-defined]
        head = (
            axis_host.model_addresses(self.parts),
            m.qpos,
            m.qvel,
            m.ctrl,
            s.qpos,
            s.qvel,
            s.ctrl,
            s.qfrc_constraint,
        )
        return head, (axis_host.parameters(self.parts, self.period_s), axis_host.initial_state(self.parts))

    def _compiled_network(self, nets: Sequence[Any]) -> tuple[tuple[Any, Any], int]:
        """Each direction's schedule (None where its net runs the codec in the kernel) and the
        window the network is decided ahead: a vectorized schedule's is long, a ticked one's is
        the loop's chunk, so it never runs ahead of a stop."""
        fwd = None if nets[0] is not None else self._schedule("forward")
        bwd = None if nets[1] is not None else self._schedule("backward")
        vectorized = all(s is None or s.vectorized for s in (fwd, bwd))
        return (fwd, bwd), VECTORIZED_WINDOW_TICKS if vectorized else CHUNK_TICKS

    def _compiled_loop(self, progress: Callable[[int], None] | None, sink: RunSink) -> RunResult:
        """The compiled 1-DoF loop (axis_kernel.run_ticks), or with the codec stage run in the kernel
        on the directions that name a codec (codec_kernel, engine/compiled/codec_host.py); a direction
        without one keeps its schedule."""
        from haptic_teleop.engine.compiled import axis_host
        from haptic_teleop.engine.compiled.codec_host import CodecNet

        period_ns = self.period_ns
        self.ticks_done = 0
        t0 = time.perf_counter()
        nets = [None if ch is None else CodecNet(ch, period_ns) for ch in self.codecs]
        (fwd, bwd), window = self._compiled_network(nets)
        head, (P, S) = self._kernel_args()
        output = Output(sink, (nets[0] or fwd).settled, (nets[1] or bwd).settled)
        block = output.block
        run_ticks = self._kernel
        assert run_ticks is not None
        first = [True]

        def call(c0: int, c1: int, *network: Any) -> None:
            # (network: the schedules' window, rings, w0, then the codec arrays: `codec_tail`)
            w0, tail = network[-2:]
            if first:  # compiled once among processes that start together (compiling.first_compile)
                first.clear()
                with compiling.first_compile(run_ticks):
                    run_ticks(c0, c1, *head, *network[:-2], P, S, block, w0, output.start, *tail)
                return
            run_ticks(c0, c1, *head, *network[:-2], P, S, block, w0, output.start, *tail)

        try:
            done = run_windows(
                self,
                call,
                (fwd, bwd),
                nets,
                axis_host.Rings(axis_host.ring_widths(self.parts)),
                output,
                window,
                progress,
                np.zeros((3, 3)),
            )
        except BaseException:
            axis_host.store_state(self.parts, S)
            self.master.close()
            self.slave.close()
            output.end_after_error(self.ticks_done)
            raise
        axis_host.store_state(self.parts, S)
        output.end(done)
        self.master.close()
        self.slave.close()
        wall = time.perf_counter() - t0
        return self._streamed(done, wall)


def _wire_payload_bytes(floats: int, energy: bool = False) -> int:
    """Serialized size (CDR) of the sensor_msgs/JointState that carries `floats` values of one axis
    (`energy`: and TDPA's energy joint)."""
    from haptic_teleop.record.layouts import joint_state_size

    return joint_state_size(floats, energy=energy)
