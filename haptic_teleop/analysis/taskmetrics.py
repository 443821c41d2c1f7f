"""Task-space metrics of an n-DoF run (a bag whose tick schema has 2 or 3 task axes), from the bag alone.

The keys of a 1-DoF summary keep their names with vector meanings (docs/outputs.md, "Metrics"):
`force_rms_error_n` is the RMS over ticks of the norm |F_m(t) - F_c(t - L)| of the force rendered
at the master handle against the slave's contact force (both in the task frame), the peak its
largest norm, `position_rms_error_m` the RMS norm of x_s(t) - x_m(t - L_f), the maxima norms.
Added: the same errors per axis (`force_rms_error_x_n`, ...), the wall penetration, and the
energy of every port (joint) with the damping the simulator has (run facts `<side>_joint_damping`;
without it, no damping credit: a lower, conservative margin).

The torque each port's energy books: the joint_states effort (the torque the simulated plant
applied; on hardware the torque commanded), held over the motion from its row to the next, or,
for a side whose bag has `/<side>/measured_effort` (a side on hardware: docs/hardware_plant.md,
"Applied, not commanded"), the port torque the device reported, whose row n + 1 holds the torque
of the hold that ended at read n + 1: the motion q[n] -> q[n+1] is booked with it. The summary
names the topic it booked per side (`<side>_energy_torque_topic`).

Penetration: the wall is the plane through `wall_point_m` with unit normal `wall_normal` pointing
out of the wall into free space (run facts; for a 1-DoF run the wall at slave.wall.position_m with
normal -x). The tool is `(p - x) . n` deep in it where that is positive.

Two paths give the same numbers (to round-off in sums): `compute_task_summary(load_task_signals(bag))`
holds every signal at once (the reference, and the fallback for bags not in order), and
`stream.stream_task_summary` goes through the bag chunk by chunk in bounded memory, feeding the
same accumulator (`TaskAccumulator`) block by block.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.analysis.energy import energy_margins
from haptic_teleop.analysis.metrics import (
    direction_stats,
    penetration,
    read_run_info,
    run_counts,
    simulator_damping,
    wall_plane,
)
from haptic_teleop.errors import BagError
from haptic_teleop.record.columns import TickSchema, measured_topic
from haptic_teleop.record.reader import BagReader

# topic -> what the task pass takes from it
HANDLE, TOOL = "/master/handle_pose", "/slave/tool_pose"
RENDERED, APPLIED, CONTACT = "/master/rendered_wrench", "/slave/applied_wrench", "/slave/contact_wrench"
JOINTS = {"master": "/master/joint_states", "slave": "/slave/joint_states"}
TASK_TOPICS = (HANDLE, TOOL, RENDERED, APPLIED, CONTACT, JOINTS["master"], JOINTS["slave"])
SIDES = ("master", "slave")


def measured_topics(schema: TickSchema) -> tuple[str, ...]:
    """The /<side>/measured_effort topics of the sides that have one (on hardware), master first:
    read after TASK_TOPICS, their port torques replace the joint_states effort in the energy."""
    return tuple(measured_topic(side) for side in SIDES if schema.measured(side))


def energy_torque_topic(schema: TickSchema, side: str) -> str:
    """The topic whose effort a side's port energy books (the summary's `<side>_energy_torque_topic`)."""
    return measured_topic(side) if schema.measured(side) else JOINTS[side]


def side_joints(
    schema: TickSchema, master_rows: np.ndarray, slave_rows: np.ndarray, measured: list[np.ndarray]
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Each side's (q, tau) for the energy from its joint_states rows (position, velocity, effort)
    and, in `measured_topics` order, the measured effort rows of the sides that have them (then
    tau is the measured port torque: `_Ports` pairs row n + 1's with the motion q[n] -> q[n+1])."""
    extra = iter(measured)
    out = []
    for side, rows in zip(SIDES, (master_rows, slave_rows), strict=True):
        q, tau = _split_joints(rows, len(schema.joints(side)))
        if schema.measured(side):
            tau = next(extra)[: rows.shape[0]]
        out.append((q, tau))
    return out[0], out[1]


def _side_energy(sc: dict[str, Any], run_info: dict[str, Any], side: str, joints: int) -> tuple[np.ndarray, float]:
    """(damping per joint as the simulator has it, or 0; the side's initial energy)."""
    d = simulator_damping(run_info, side)
    damping = np.asarray(d, dtype=float) if d is not None and len(d) == joints else np.zeros(joints)
    e0 = float((((sc.get("controllers") or {}).get(side) or {}).get("eba") or {}).get("initial_energy_j", 0.0))
    return damping, e0


def _split_joints(values: np.ndarray, joints: int) -> tuple[np.ndarray, np.ndarray]:
    """JointState values (position[j]..., velocity[j]..., effort[j]...) -> (q, tau)."""
    return values[:, :joints], values[:, 2 * joints : 3 * joints]


# ------------------------------------------------------------------------------------------------
# Whole-bag reference


@dataclass
class TaskSignals:
    """Every per-tick task-space and joint signal of an n-DoF bag, and its network records."""

    schema: TickSchema
    period_s: float
    t_s: np.ndarray
    master_x_m: np.ndarray  # (N, axes): handle, task frame
    slave_x_m: np.ndarray  # (N, axes): tool
    master_force_n: np.ndarray  # rendered at the handle, task frame
    slave_force_n: np.ndarray  # the slave's applied task force
    contact_n: np.ndarray  # contact force at the tool
    contact_torque_nm: np.ndarray
    master_q: np.ndarray  # (N, master joints)
    master_tau_nm: np.ndarray  # the torque the energy books: joint_states effort, or the measured effort (schema)
    slave_q: np.ndarray
    slave_tau_nm: np.ndarray
    forward_delays_s: np.ndarray
    backward_delays_s: np.ndarray
    forward_packets: np.ndarray
    backward_packets: np.ndarray
    forward_played_seq: np.ndarray
    forward_release_s: np.ndarray
    backward_played_seq: np.ndarray
    backward_release_s: np.ndarray
    scene: dict[str, Any]
    run_info: dict[str, Any]


def load_task_signals(bag: str | Path) -> TaskSignals:
    import yaml

    with BagReader(bag) as r:
        schema = r.schema
        if schema.single_axis:
            raise BagError(f"{bag}: a 1-DoF bag (analysis.metrics.load_signals reads it)")
        scene = yaml.safe_load(r.string("/haptic_teleop/scene"))
        run_info = read_run_info(r)
        period = float(scene["scene"]["period_s"])
        data = {t: r.read(t) for t in (*TASK_TOPICS, *measured_topics(schema))}
        n = min(len(d.log_ns) for d in data.values())
        if n < 2:
            raise BagError(f"{bag}: fewer than two ticks recorded; nothing to analyse")
        fr = r.read("/forward/received")
        br = r.read("/backward/received")
        fpk = r.packets("/forward/packets") if r.has("/forward/packets") else np.zeros((0, 6))
        bpk = r.packets("/backward/packets") if r.has("/backward/packets") else np.zeros((0, 6))
    a = schema.task_axes
    measured = [data[t].values[:n] for t in measured_topics(schema)]
    (mq, mtau), (sq, stau) = side_joints(
        schema, data[JOINTS["master"]].values[:n], data[JOINTS["slave"]].values[:n], measured
    )
    period_ns = round(period * 1e9)
    fdel = (fr.log_ns - fr.stamp_ns) * 1e-9 if fr.stamp_ns is not None else np.zeros(0)
    bdel = (br.log_ns - br.stamp_ns) * 1e-9 if br.stamp_ns is not None else np.zeros(0)
    return TaskSignals(
        schema=schema,
        period_s=period,
        t_s=data[JOINTS["master"]].log_ns[:n] * 1e-9,
        master_x_m=data[HANDLE].values[:n, :a],
        slave_x_m=data[TOOL].values[:n, :a],
        master_force_n=data[RENDERED].values[:n, :a],
        slave_force_n=data[APPLIED].values[:n, :a],
        contact_n=data[CONTACT].values[:n, :a],
        contact_torque_nm=data[CONTACT].values[:n, a : 2 * a],
        master_q=mq,
        master_tau_nm=mtau,
        slave_q=sq,
        slave_tau_nm=stau,
        forward_delays_s=fdel,
        backward_delays_s=bdel,
        forward_packets=fpk,
        backward_packets=bpk,
        forward_played_seq=fr.stamp_ns // period_ns if fr.stamp_ns is not None else np.zeros(0),
        forward_release_s=fr.log_ns * 1e-9,
        backward_played_seq=br.stamp_ns // period_ns if br.stamp_ns is not None else np.zeros(0),
        backward_release_s=br.log_ns * 1e-9,
        scene=scene,
        run_info=run_info,
    )


def _aligned(felt: np.ndarray, source: np.ndarray, lag: int) -> np.ndarray:
    if lag <= 0:
        out: np.ndarray = felt - source
    elif lag >= felt.shape[0]:
        out = np.zeros((0, felt.shape[1]))
    else:
        out = felt[lag:] - source[:-lag]
    return out


def _lag(delays_s: np.ndarray, period_s: float) -> int:
    return int(round(float(np.median(delays_s)) / period_s)) if delays_s.size else 0


def _quantiles(d: np.ndarray) -> tuple[float, float]:
    return (float(np.mean(d)), float(np.percentile(d, 99))) if d.size else (math.nan, math.nan)


def side_period_s(sc: dict[str, Any], side: str) -> float:
    """A side's own control period from the scene's dict (`<side>.period_s`, else scene.period_s):
    its ledger's T. Between its ticks the rows repeat its last q and torque, so summing the rows'
    steps with this T gives the side's ledger exactly (docs/arms.md, "A side's own period")."""
    p = (sc.get(side) or {}).get("period_s")
    return float(p) if p is not None else float(sc["scene"]["period_s"])


def compute_task_summary(sig: TaskSignals) -> dict[str, Any]:
    """summary.json of an n-DoF run from its whole signals (the reference for `stream_task_summary`)."""
    from haptic_teleop.core.link import DEFAULT_OVERHEAD_BYTES

    sc, T, schema = sig.scene, sig.period_s, sig.schema
    duration = float(sig.t_s[-1] + T)
    net = sc.get("network", {}) or {}
    nets: dict[str, Any] = {}
    for prefix, rows, played, released in (
        ("forward", sig.forward_packets, sig.forward_played_seq, sig.forward_release_s),
        ("backward", sig.backward_packets, sig.backward_played_seq, sig.backward_release_s),
    ):
        rl = (net.get(prefix) or {}).get("effects", {}).get("rate_limit") or {}
        overhead = float(rl.get("overhead_bytes", DEFAULT_OVERHEAD_BYTES))
        nets.update(direction_stats(rows, played, released, duration, overhead, prefix))
    forward_lag = _lag(sig.forward_delays_s, T)
    backward_lag = _lag(sig.backward_delays_s, T) + 1
    p50 = nets.get("delay_backward_p50_s", math.nan)
    net_lag = int(round(p50 / T)) + 1 if math.isfinite(p50) else backward_lag
    acc = TaskAccumulator(schema, sc, sig.run_info, T, forward_lag, backward_lag, net_lag)
    acc.add(
        sig.master_x_m,
        sig.slave_x_m,
        sig.master_force_n,
        sig.slave_force_n,
        sig.contact_n,
        sig.contact_torque_nm,
        (sig.master_q, sig.master_tau_nm),
        (sig.slave_q, sig.slave_tau_nm),
    )
    counts = {}
    for prefix, rows in (("forward", sig.forward_packets), ("backward", sig.backward_packets)):
        from haptic_teleop.analysis.metrics import _packet_counts

        s, lost, late = _packet_counts(rows)
        counts.update({f"packets_sent_{prefix}": s, f"packets_lost_{prefix}": lost, f"packets_late_{prefix}": late})
    lat_f, lat_b = _quantiles(sig.forward_delays_s), _quantiles(sig.backward_delays_s)
    # whole-array energies, from analysis.energy (the stream accumulates the same sums)
    energies = {}
    for side, q, tau in (("master", sig.master_q, sig.master_tau_nm), ("slave", sig.slave_q, sig.slave_tau_nm)):
        damping, e0 = _side_energy(sc, sig.run_info, side, q.shape[1])
        # a measured effort: row n + 1's torque was held over q[n] -> q[n+1]
        held = np.concatenate([tau[1:], tau[-1:]]) if schema.measured(side) else tau
        em = energy_margins(q, held, damping, side_period_s(sc, side), e0)
        energies[side] = (float(np.min(em.pooled_margin_j - e0)), np.min(em.absorbed_j, axis=0), e0)
    return acc.summary(sig.run_info, int(sig.t_s.size), duration, counts, nets, lat_f, lat_b, energies)


# ------------------------------------------------------------------------------------------------
# The tick pass, block by block (the whole path feeds it one block)


class _Lag2:
    """felt[i] - source[i - lag] over blocks of (rows, k) arrays (lag <= 0: felt[i] - source[i])."""

    def __init__(self, lag: int, k: int) -> None:
        self.lag = max(lag, 0)
        self.tail = np.zeros((0, k))

    def feed(self, felt: np.ndarray, source: np.ndarray) -> np.ndarray:
        if self.lag == 0:
            same: np.ndarray = felt - source
            return same
        ext = np.concatenate([self.tail, source])
        p = self.tail.shape[0]
        k0 = max(0, self.lag - p)
        tail = ext[-self.lag :]
        self.tail = tail
        if k0 >= felt.shape[0]:
            return np.zeros((0, felt.shape[1]))
        out: np.ndarray = felt[k0:] - ext[k0 - self.lag + p : felt.shape[0] - self.lag + p]
        return out


@dataclass
class _VecErr:
    """RMS and peak of the norm of a vector error stream, and per axis."""

    axes: int
    n: int = 0
    sums: list[float] = field(default_factory=list)
    axis_sums: list[list[float]] = field(default_factory=list)
    peak: float = -math.inf
    axis_peak: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def add(self, e: np.ndarray) -> None:
        if not e.shape[0]:
            return
        sq = e * e
        self.n += int(e.shape[0])
        self.sums.append(math.fsum(np.sum(sq, axis=1).tolist()))
        self.axis_sums.append([math.fsum(sq[:, k].tolist()) for k in range(self.axes)])
        self.peak = max(self.peak, float(np.max(np.sqrt(np.sum(sq, axis=1)))))
        peak = np.max(np.abs(e), axis=0)
        self.axis_peak = peak if not self.axis_peak.size else np.maximum(self.axis_peak, peak)

    def rms(self) -> float:
        return math.sqrt(math.fsum(self.sums) / self.n) if self.n else math.nan

    def axis_peak_of(self, k: int) -> float:
        return float(self.axis_peak[k]) if self.n else math.nan

    def axis_rms(self, k: int) -> float:
        return math.sqrt(math.fsum(s[k] for s in self.axis_sums) / self.n) if self.n else math.nan


class _Ports:
    """The energy the ports (joints) of one side absorbed since tick 0, per port and pooled:
    analysis.energy.energy_margins' sums, carried between blocks. `measured`: the torques are a
    hardware side's measured effort, row n + 1's held over the motion q[n] -> q[n+1] (else row
    n's, the torque commanded or applied at tick n)."""

    def __init__(self, damping: np.ndarray, period_s: float, measured: bool = False) -> None:
        self.d = damping
        self.T = period_s
        self.measured = measured
        k = damping.size
        self.total = np.zeros(k)
        self.low = np.zeros(k)  # tick 0 absorbed nothing
        self.pooled_low = 0.0
        self.prev: tuple[np.ndarray, np.ndarray] | None = None

    def absorbed(self, q: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The next rows' (q, tau): each row's absorbed energy per port since tick 0 (rows, ports)."""
        first = self.prev is None
        if self.prev is not None:
            q = np.concatenate([self.prev[0], q])
            tau = np.concatenate([self.prev[1], tau])
        if not q.shape[0]:
            return np.zeros((0, self.d.size))
        self.prev = (q[-1:], tau[-1:])
        dq = np.diff(q, axis=0)
        step = (self.d / self.T) * dq * dq - (tau[1:] if self.measured else tau[:-1]) * dq
        cum = np.cumsum(np.concatenate([self.total[None, :], step]), axis=0)
        cum = cum if first else cum[1:]  # tick 0 absorbed nothing; later blocks start after the carry
        if cum.shape[0]:
            self.total = cum[-1].copy()
            self.low = np.minimum(self.low, np.min(cum, axis=0))
            pooled = cum[:, 0] if cum.shape[1] == 1 else np.sum(cum, axis=1)
            self.pooled_low = min(self.pooled_low, float(np.min(pooled)))
        return cum

    def pooled(self, q: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The next rows' pooled absorbed energy since tick 0 (the sum over the ports), per row."""
        cum = self.absorbed(q, tau)
        return cum[:, 0] if cum.shape[1] == 1 else np.sum(cum, axis=1)


class TaskAccumulator:
    def __init__(
        self,
        schema: TickSchema,
        sc: dict[str, Any],
        run_info: dict[str, Any],
        T: float,
        forward_lag: int,
        backward_lag: int,
        net_lag: int,
    ) -> None:
        a = schema.task_axes
        self.schema, self.sc, self.T = schema, sc, T
        self.lags = (forward_lag, backward_lag, net_lag)
        self.e, self.e0, self.en, self.pos = _VecErr(a), _VecErr(a), _VecErr(a), _VecErr(a)
        self.le, self.len_, self.lpos = _Lag2(backward_lag, a), _Lag2(net_lag, a), _Lag2(forward_lag, a)
        self.plane = wall_plane(sc, run_info, a)
        self.depth = 0.0
        self.contact_max = self.master_max = self.torque_max = 0.0
        self.contact_axis_max = np.zeros(a)
        self.finite = True
        self.ports = {}
        self.two_port_low = 0.0  # tick 0: both ports absorbed nothing
        for side, joints in (("master", schema.master_joints), ("slave", schema.slave_joints)):
            damping, _ = _side_energy(sc, run_info, side, len(joints))
            self.ports[side] = _Ports(damping, side_period_s(sc, side), schema.measured(side))

    def add(
        self,
        mx: np.ndarray,
        sx: np.ndarray,
        mf: np.ndarray,
        sf: np.ndarray,
        cf: np.ndarray,
        ct: np.ndarray,
        master: tuple[np.ndarray, np.ndarray],
        slave: tuple[np.ndarray, np.ndarray],
    ) -> None:
        if not mx.shape[0]:
            return
        self.e.add(self.le.feed(mf, cf))
        self.e0.add(mf - cf)
        self.en.add(self.len_.feed(mf, cf))
        self.pos.add(self.lpos.feed(sx, mx))
        self.contact_max = max(self.contact_max, float(np.max(np.linalg.norm(cf, axis=1))))
        self.master_max = max(self.master_max, float(np.max(np.linalg.norm(mf, axis=1))))
        self.torque_max = max(self.torque_max, float(np.max(np.linalg.norm(ct, axis=1))))
        self.contact_axis_max = np.maximum(self.contact_axis_max, np.max(np.abs(cf), axis=0))
        self.depth = max(self.depth, float(np.max(penetration(sx, self.plane))))
        both = self.ports["master"].pooled(*master) + self.ports["slave"].pooled(*slave)
        if both.size:  # the two-port of controllers and channel (docs/stabilizers_arms.md, "Pooled joints")
            self.two_port_low = min(self.two_port_low, float(np.min(both)))
        arrays = (mx, sx, mf, sf, cf, ct, *master, *slave)
        self.finite = self.finite and all(bool(np.all(np.isfinite(x))) for x in arrays)

    def summary(
        self,
        run_info: dict[str, Any],
        ticks: int,
        duration: float,
        counts: dict[str, Any],
        nets: dict[str, Any],
        lat_f: tuple[float, float],
        lat_b: tuple[float, float],
        energies: dict[str, tuple[float, np.ndarray, float]] | None = None,
    ) -> dict[str, Any]:
        sc, T, schema = self.sc, self.T, self.schema
        _, backward_lag, net_lag = self.lags
        axes = schema.axes
        out: dict[str, Any] = {
            "scene": sc["scene"]["name"],
            "seed": sc["scene"]["seed"],
            "duration_s": duration,
            "ticks": ticks,
            "interrupted": bool(run_info.get("interrupted", False)),
            "realtime_factor": run_info.get("realtime_factor", math.nan),
            "task_axes": schema.task_axes,
            "master_joints": list(schema.master_joints),
            "slave_joints": list(schema.slave_joints),
            "force_rms_error_n": self.e.rms(),
            "force_peak_error_n": self.e.peak if self.e.n else math.nan,
            **{f"force_rms_error_{a}_n": self.e.axis_rms(k) for k, a in enumerate(axes)},
            **{f"force_peak_error_{a}_n": self.e.axis_peak_of(k) for k, a in enumerate(axes)},
            "force_rms_error_unaligned_n": self.e0.rms(),
            "force_alignment_lag_s": backward_lag * T,
            "force_rms_error_network_lag_n": self.en.rms(),
            "force_network_lag_s": net_lag * T,
            "position_rms_error_m": self.pos.rms(),
            "contact_force_max_n": self.contact_max,
            **{f"contact_force_max_{a}_n": float(self.contact_axis_max[k]) for k, a in enumerate(axes)},
            "contact_torque_max_nm": self.torque_max,
            "master_force_max_n": self.master_max,
            "penetration_max_m": self.depth,
            "wall_point_m": self.plane[0].tolist() if self.plane is not None else None,
            "wall_normal": self.plane[1].tolist() if self.plane is not None else None,
            **counts,
            "playout_latency_forward_mean_s": lat_f[0],
            "playout_latency_forward_p99_s": lat_f[1],
            "playout_latency_backward_mean_s": lat_b[0],
            "playout_latency_backward_p99_s": lat_b[1],
            **nets,
        }
        for side, joints in (("master", schema.master_joints), ("slave", schema.slave_joints)):
            _, e0 = _side_energy(sc, run_info, side, len(joints))
            p = self.ports[side]
            pooled_low, port_low = (p.pooled_low, p.low) if energies is None else energies[side][:2]
            out[f"{side}_energy_margin_min_j"] = float(e0 + pooled_low)
            out[f"{side}_port_energy_min_j"] = float(pooled_low)
            out[f"{side}_joint_energy_min_j"] = {j: float(v) for j, v in zip(joints, port_low, strict=True)}
            out[f"{side}_initial_energy_j"] = e0
            d_sim = simulator_damping(run_info, side)
            out[f"{side}_energy_margin_simulator_min_j"] = float(e0 + pooled_low) if d_sim is not None else math.nan
            out[f"{side}_joint_damping_simulator"] = d_sim
            out[f"{side}_energy_torque_topic"] = energy_torque_topic(schema, side)
            unmeasured = run_info.get(f"{side}_unmeasured_torque_reads")
            if unmeasured is not None:  # a hardware side's reads whose measured effort is the command (flagged)
                out[f"{side}_unmeasured_torque_reads"] = int(unmeasured)
        # Both sides' ports together: what TDPA keeps >= 0; EBA keeps each side's, hence this too.
        e0s = sum(_side_energy(sc, run_info, side, len(j))[1] for side, j in
                  (("master", schema.master_joints), ("slave", schema.slave_joints)))  # fmt: skip
        out["two_port_energy_margin_min_j"] = float(e0s + self.two_port_low)
        out["all_finite"] = self.finite
        out.update(run_counts(run_info))
        return out
