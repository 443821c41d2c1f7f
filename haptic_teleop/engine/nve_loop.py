"""The NVE scene's deterministic lockstep loop in simulated time (docs/nve.md, "One tick").

Per tick n (t = n T), for every client in scene order where it applies:
  1. each client's HIP at t from its operator profile; its sample (x, v) into its `up` link;
  2. server: each client's up arrivals by t into its server-side playout buffer; the released
     sample becomes that client's held HIP; the object state at t goes to each client over its
     `down` link with the echo of the newest HIP stamp it reflects; the object steps t -> t + T;
  3. each client: down arrivals by t into its playout buffer; a released sample updates the
     object it sees and its measured round trip (t - echo) and spring; the force it feeds back.
The rows follow the NVE record schema (record/nve_columns.py); packets are handed over per link
("<client>/up", "<client>/down") once their fate is final. Memory does not grow with the run.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.assembly.nve import DOWN, UP, NveParts, build_nve_parts
from haptic_teleop.assembly.stages import settled_records
from haptic_teleop.core.link import Packet
from haptic_teleop.engine.lockstep import RunResult
from haptic_teleop.engine.output import Collector, Output, RunSink, Tee, loop_guard
from haptic_teleop.engine.run import RunTiming
from haptic_teleop.record.layouts import joint_state_size
from haptic_teleop.record.nve_columns import NveSchema
from haptic_teleop.record.streams import BLOCK_TICKS
from haptic_teleop.scene.schema import LoadedScene


class NveEngine:
    """Runs an NVE scene tick by tick; the same interface `haptic-teleop run` uses for teleoperation."""

    pacer = None  # simulated time only (no device)
    compiled_reason = "an NVE scene runs in Python"
    loop_kind = "python"

    def __init__(self, scene: LoadedScene) -> None:
        c = scene.config
        if c.nve is None:
            raise ValueError("not an NVE scene (no nve section)")
        self.scene = scene
        self.period_s = c.scene.period_s
        self.period_ns = int(round(self.period_s * 1e9))
        self.ticks = int(round(c.scene.duration_s / self.period_s))
        self.parts: NveParts = build_nve_parts(c, self.period_ns)
        self.schema = NveSchema(tuple(p.name for p in self.parts.clients), self.parts.axes)
        self.ticks_done = 0
        self._stop = False
        self.data: np.ndarray | None = None
        a = self.parts.axes
        self._up_size = joint_state_size(2, a)
        self._down_size = joint_state_size(3, a)

    def request_stop(self) -> None:
        """Stop at the next tick boundary (the bag is still closed with every finished tick)."""
        self._stop = True

    @property
    def stop_requested(self) -> bool:
        return self._stop

    def close_plants(self) -> None:
        """No plant to stop (the HIPs are profiles)."""

    def directions(self) -> list[str]:
        return [f"{p.name}/{d}" for p in self.parts.clients for d in (UP, DOWN)]

    def run(
        self,
        progress: Callable[[int], None] | None = None,
        handle_sigint: bool = True,
        sink: RunSink | None = None,
    ) -> RunResult:
        """Every tick (or until a stop request), the output handed to `sink` as it is made (or kept
        in `self.data` without one)."""
        collector = Collector(self.schema.width) if sink is None else None
        out = sink if sink is not None else collector
        assert out is not None
        with loop_guard(self.request_stop, handle_sigint):
            result = self._loop(progress, out)
        if collector is not None:
            result.data = self.data = collector.data()
            self.packets = {d: collector.packets(d) for d in self.directions()}
        return result

    def _loop(self, progress: Callable[[int], None] | None, sink: RunSink) -> RunResult:
        parts = self.parts
        server = parts.server
        clients = parts.clients
        a = parts.axes
        period_ns, period_s = self.period_ns, self.period_s
        settled = []
        for p in clients:
            settled.append((f"{p.name}/{UP}", _settler(p.up, p.up_buffer)))
            settled.append((f"{p.name}/{DOWN}", _settler(p.down, p.down_buffer)))
        output = Output(sink, None, None, self.schema.width, directions=tuple(settled))
        block = output.block
        schema = self.schema
        width = schema.width
        obj = (schema.group("obj_x_m"), schema.group("obj_v_m_per_s"), schema.group("obj_force_n"))
        # per client: the slices of its HIP, view, force columns and where its 6 link facts start
        cols = [
            (
                schema.client_group(p.name, "hip_x_m"),
                schema.client_group(p.name, "hip_v_m_per_s"),
                schema.client_group(p.name, "obj_x_m"),
                schema.client_group(p.name, "obj_v_m_per_s"),
                schema.client_group(p.name, "force_n"),
                schema.client_group(p.name, "spring_n_per_m").start,
            )
            for p in clients
        ]
        facts = ("spring_n_per_m", "rtt_s", "up_rx_seq", "down_rx_seq", "up_occupancy", "down_occupancy")
        for p, c in zip(clients, cols, strict=True):  # the facts are adjacent, in this order
            assert [schema.client_group(p.name, f).start for f in facts] == list(range(c[5], c[5] + 6))
        up_size, down_size = self._up_size, self._down_size
        base = 0
        done = 0
        t0 = time.perf_counter()
        hips: list[tuple[np.ndarray, np.ndarray]] = [(np.zeros(a), np.zeros(a))] * len(clients)
        up_rx = [-1] * len(clients)
        try:
            for n in range(self.ticks):
                now_ns = n * period_ns
                t = n * period_s
                # 1. the clients' HIPs go up
                for k, p in enumerate(clients):
                    xh, vh = p.hip.at(t)
                    hips[k] = (xh, vh)
                    p.up.send(Packet(n, now_ns, (*xh.tolist(), *vh.tolist()), up_size))
                # 2. the server: received HIPs, the object state down, one step
                for k, p in enumerate(clients):
                    for pk in p.up.deliver(now_ns):
                        p.up_buffer.push(pk, now_ns)
                    rel = p.up_buffer.release(now_ns)
                    if rel is not None:
                        pl = rel.payload
                        server.receive(k, pl[:a], pl[a : 2 * a], rel.send_time_ns * 1e-9)
                        up_rx[k] = rel.seq
                    else:
                        up_rx[k] = -1
                xo = server.x.tolist()
                vo = server.v.tolist()
                for k, p in enumerate(clients):
                    p.down.send(Packet(n, now_ns, (*xo, *vo, float(server.echo_s[k])), down_size))
                server.step()
                row = block[n - base]
                row[obj[0]] = xo
                row[obj[1]] = vo
                row[obj[2]] = server.coupling_force_n
                # 3. the clients: the object they see, their round trip, the force fed back
                for k, p in enumerate(clients):
                    for pk in p.down.deliver(now_ns):
                        p.down_buffer.push(pk, now_ns)
                    rel = p.down_buffer.release(now_ns)
                    cl = p.client
                    if rel is not None:
                        pl = rel.payload
                        cl.receive(pl[:a], pl[a : 2 * a], pl[2 * a], t)
                    xh, vh = hips[k]
                    f = cl.force(xh, vh)
                    hx, hv, ox, ov, fc, o = cols[k]
                    row[hx] = xh
                    row[hv] = vh
                    row[ox] = cl.obj_x
                    row[ov] = cl.obj_v
                    row[fc] = f
                    row[o : o + 6] = (
                        cl.spring_n_per_m,
                        cl.rtt_s,
                        up_rx[k],
                        -1 if rel is None else rel.seq,
                        p.up_buffer.occupancy,
                        p.down_buffer.occupancy,
                    )
                done = n + 1
                if done % 100 == 0:
                    self.ticks_done = done
                    if progress is not None:
                        progress(done)
                    if done - base == BLOCK_TICKS:
                        output.block_done(done)
                        base = done
                if self._stop:
                    break
        except BaseException:
            self.ticks_done = done
            output.end_after_error(done)
            raise
        self.ticks_done = done
        output.end(done)
        return RunResult(
            scene=self.scene,
            ticks=done,
            period_ns=period_ns,
            data=np.zeros((0, width)),
            forward_log=np.zeros((0, 0)),
            backward_log=np.zeros((0, 0)),
            loop_wall_s=time.perf_counter() - t0,
            interrupted=done < self.ticks,
            schema=None,
        )

    def run_facts(self) -> dict[str, Any]:
        """What the bag's run facts say of the clients' links (counts per fate, the final spring)."""
        out: dict[str, Any] = {}
        for p in self.parts.clients:
            out[p.name] = {
                "up_sent": p.up.sent,
                "up_lost": p.up.lost,
                "down_sent": p.down.sent,
                "down_lost": p.down.lost,
                "schedule": p.client.schedule.name,
                "final_spring_n_per_m": p.client.spring_n_per_m,
                "final_rtt_s": None if math.isnan(p.client.rtt_s) else p.client.rtt_s,
            }
        return out


def _settler(link: Any, buf: Any) -> Callable[[int, bool], np.ndarray | None]:
    return lambda sent, final: settled_records(link, buf, sent, final)


def record_nve_run(
    scene: LoadedScene,
    bag_dir: Path,
    progress: Callable[[int], None] | None = None,
    parallel: bool = True,
    handle_sigint: bool = True,
    on_engine: Callable[[NveEngine], None] | None = None,
    keep: bool = False,
) -> tuple[NveEngine, RunTiming]:
    """Run an NVE scene and record it (the same guarantees as `run.record_run`: a closed,
    readable bag with every finished tick, whatever ends the run)."""
    from haptic_teleop.record.recorder import RunRecorder

    engine = NveEngine(scene)
    c = scene.config
    if on_engine is not None:
        on_engine(engine)
    rec = RunRecorder(
        bag_dir,
        scene.to_yaml(),
        engine.period_ns,
        False,
        c.recording.packets,
        engine.schema.width,
        parallel=parallel,
        compression=c.recording.compression,
        schema=engine.schema,
    )
    collector = Collector(engine.schema.width) if keep else None
    sink: RunSink = rec if collector is None else Tee(rec, collector)
    t0 = time.perf_counter()
    result: RunResult | None = None
    try:
        result = engine.run(progress=progress, handle_sigint=handle_sigint, sink=sink)
    finally:
        done = engine.ticks_done
        info = {
            "ticks": done,
            "interrupted": done < engine.ticks,
            "failed": result is None,
            "nve_clients": engine.run_facts(),
        }
        if collector is not None:
            engine.data = collector.data()
            engine.packets = {d: collector.packets(d) for d in engine.directions()}
        rec.close(info)
    wall = time.perf_counter() - t0
    loop_wall = result.loop_wall_s if result is not None else wall
    return engine, RunTiming(done * engine.period_s, loop_wall, wall, done < engine.ticks, "python", None)
