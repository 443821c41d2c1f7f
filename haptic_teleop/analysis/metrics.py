"""Transparency and passivity metrics computed from a bag alone (keys documented in docs/outputs.md, "Metrics")."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from haptic_teleop.analysis.energy import energy_margins
from haptic_teleop.core.link import DEFAULT_OVERHEAD_BYTES
from haptic_teleop.errors import BagError
from haptic_teleop.record.reader import BagReader

FATE_LOST = (1.0, 2.0, 3.0)
FATE_LATE = 4.0


@dataclass
class Signals:
    """The per-tick signals analysis and plots use, on the tick grid t = n T."""

    period_s: float
    t_s: np.ndarray
    operator_x_m: np.ndarray
    operator_force_n: np.ndarray
    master_x_m: np.ndarray
    master_v_m_per_s: np.ndarray
    master_force_n: np.ndarray
    slave_x_m: np.ndarray
    slave_force_n: np.ndarray
    contact_n: np.ndarray
    master_reservoir_j: np.ndarray | None
    slave_reservoir_j: np.ndarray | None
    forward_lag_ticks: int
    backward_lag_ticks: int
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


def port_energy(x_m: np.ndarray, force_n: np.ndarray, damping: float, period_s: float) -> np.ndarray:
    """Cumulative energy absorbed at an actuator port, per tick (J), starting at 0.

    absorbed(n) = sum_{k<n} (b/T) (x[k+1]-x[k])^2 - F[k] (x[k+1]-x[k]); F[k] is held over [t_k, t_k+1].
    (b/T) dx^2 is the least the physical damping b can have dissipated over a period (Cauchy-Schwarz),
    so this is a conservative (lower) estimate of what the device absorbed.
    """
    dx = np.diff(x_m)
    step = (damping / period_s) * dx * dx - force_n[:-1] * dx
    return np.concatenate([[0.0], np.cumsum(step)])


def simulator_damping(run_info: dict[str, Any], side: str) -> list[float] | None:
    """The damping per joint of a side's plant as the simulator had it (`<side>_joint_damping` in
    the run facts, from the compiled MjModel's dof_damping); None for bags written without it."""
    d = run_info.get(f"{side}_joint_damping")
    return [float(v) for v in d] if d is not None else None


def wall_plane(sc: dict[str, Any], run_info: dict[str, Any], axes: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(point, unit normal) of the wall in the task frame, the normal pointing out of the wall into
    free space: the run facts `wall_point_m`, `wall_normal`; for one axis without them, the
    scene's slave.wall.position_m with normal -x (the robot meets the wall moving toward +x);
    else None."""
    p, n = run_info.get("wall_point_m"), run_info.get("wall_normal")
    if p is not None and n is not None:
        point = np.asarray(p, dtype=float).reshape(-1)[:axes]
        normal = np.asarray(n, dtype=float).reshape(-1)[:axes]
        norm = float(np.linalg.norm(normal)) if normal.size == axes else 0.0
        if point.size != axes or not norm > 0.0 or not np.all(np.isfinite(point)):
            raise BagError(f"run facts: wall_point_m {p!r} and wall_normal {n!r} are not a plane in {axes} axes")
        return point, normal / norm
    wall = ((sc.get("slave") or {}).get("wall") or {}).get("position_m")
    if axes == 1 and wall is not None:
        return np.array([float(wall)]), np.array([-1.0])
    return None


def penetration(x: np.ndarray, plane: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """Depth of each of the (N, axes) points behind the wall plane, 0 in front of it (m): (p - x) . n."""
    if plane is None:
        return np.zeros(x.shape[0])
    p, n = plane
    depth: np.ndarray = np.maximum((p - x) @ n, 0.0)
    return depth


def initial_energy(sc: dict[str, Any], run_info: dict[str, Any], side: str) -> float:
    """A side's reservoir at the start: the run fact `<side>_initial_energy_j` when the run wrote one
    (an in-contact start adds the holding energy, docs/transparency.md), else the scene's E0."""
    got = run_info.get(f"{side}_initial_energy_j")
    return float(got) if got is not None else float(sc["controllers"][side]["eba"]["initial_energy_j"])


def _lag_ticks(delays_s: np.ndarray, period_s: float) -> int:
    if delays_s.size == 0:
        return 0
    return int(round(float(np.median(delays_s)) / period_s))


def read_run_info(r: BagReader) -> dict[str, Any]:
    """The run facts the recorder wrote last. A bag without the topic (another tool's) has none;
    one whose topic holds no message was cut before it closed (a killed run, recovered): then
    the run counts as interrupted."""
    topic = "/haptic_teleop/run_info"
    if not r.has(topic):
        return {}
    try:
        return dict(json.loads(r.string(topic)))
    except BagError:
        return {"interrupted": True}


def load_signals(bag: str | Path) -> Signals:
    with BagReader(bag) as r:
        scene = yaml.safe_load(r.string("/haptic_teleop/scene"))
        run_info = read_run_info(r)
        period = float(scene["scene"]["period_s"])
        op = r.read("/operator/joint_states")
        m = r.read("/master/joint_states")
        s = r.read("/slave/joint_states")
        c = r.read("/slave/contact_wrench")
        n = min(len(op.log_ns), len(m.log_ns), len(s.log_ns), len(c.log_ns))
        if n < 2:
            raise BagError(f"{bag}: fewer than two ticks recorded; nothing to analyse")
        me = r.read("/master/eba") if r.has("/master/eba") else None
        se = r.read("/slave/eba") if r.has("/slave/eba") else None
        fr = r.read("/forward/received")
        br = r.read("/backward/received")
        fpk = r.packets("/forward/packets") if r.has("/forward/packets") else np.zeros((0, 6))
        bpk = r.packets("/backward/packets") if r.has("/backward/packets") else np.zeros((0, 6))
    fdel = (fr.log_ns - fr.stamp_ns) * 1e-9 if fr.stamp_ns is not None else np.zeros(0)
    bdel = (br.log_ns - br.stamp_ns) * 1e-9 if br.stamp_ns is not None else np.zeros(0)
    return Signals(
        period_s=period,
        t_s=m.log_ns[:n] * 1e-9,
        operator_x_m=op.field("position")[:n],
        operator_force_n=op.field("effort")[:n],
        master_x_m=m.field("position")[:n],
        master_v_m_per_s=m.field("velocity")[:n],
        master_force_n=m.field("effort")[:n],
        slave_x_m=s.field("position")[:n],
        slave_force_n=s.field("effort")[:n],
        contact_n=c.field("force_x")[:n],
        master_reservoir_j=me.field("reservoir_j")[:n] if me is not None else None,
        slave_reservoir_j=se.field("reservoir_j")[:n] if se is not None else None,
        # The master uses a backward sample from the tick after it is released: +1 tick.
        forward_lag_ticks=_lag_ticks(fdel, period),
        backward_lag_ticks=_lag_ticks(bdel, period) + 1,
        forward_delays_s=fdel,
        backward_delays_s=bdel,
        forward_packets=fpk,
        backward_packets=bpk,
        forward_played_seq=(fr.stamp_ns // round(period * 1e9)) if fr.stamp_ns is not None else np.zeros(0),
        forward_release_s=fr.log_ns * 1e-9,
        backward_played_seq=(br.stamp_ns // round(period * 1e9)) if br.stamp_ns is not None else np.zeros(0),
        backward_release_s=br.log_ns * 1e-9,
        scene=scene,
        run_info=run_info,
    )


def run_counts(run_info: dict[str, Any]) -> dict[str, int]:
    """The summary's counts from a bag's run facts: remote samples the receiving controller
    rejected (NaN, Inf, beyond the scene's limits: docs/eba.md; 0 for bags written without them),
    and in a live bag the packets the sync buffers took a tick or more after the network delivered
    them (late by scheduling: the machine, not the network; their records carry the time taken, so
    the delays are as delivered: nodes/recorder.py; 0 in an engine's bag)."""
    late = run_info.get("packets_late_by_scheduling")
    late = late if isinstance(late, dict) else {}  # an engine's bag: none (lockstep)
    out = {f"rejected_samples_{d}": int(run_info.get(f"rejected_samples_{d}", 0)) for d in ("forward", "backward")}
    out.update({f"packets_late_by_scheduling_{d}": int(late.get(d, 0)) for d in ("forward", "backward")})
    return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x))) if x.size else math.nan


def _aligned_error(felt: np.ndarray, source: np.ndarray, lag: int) -> np.ndarray:
    if lag <= 0:
        out: np.ndarray = felt - source
    elif lag >= felt.size:
        out = np.zeros(0)
    else:
        out = felt[lag:] - source[:-lag]
    return out


def _packet_counts(rows: np.ndarray) -> tuple[int, int, int]:
    if rows.size == 0:
        return 0, 0, 0
    original = rows[:, 4] == 0.0
    sent = int(np.count_nonzero(original))
    lost = int(np.count_nonzero(original & np.isin(rows[:, 3], FATE_LOST)))
    late = int(np.count_nonzero(rows[:, 3] == FATE_LATE))
    return sent, lost, late


def _loss_bursts(rows: np.ndarray) -> float:
    """Mean length of runs of consecutive lost packets (original packets in seq order)."""
    orig = rows[rows[:, 4] == 0.0]
    if orig.size == 0:
        return math.nan
    lost = np.isin(orig[np.argsort(orig[:, 0], kind="stable"), 3], FATE_LOST).astype(np.int8)
    edges = np.diff(np.concatenate([[0], lost, [0]]))
    starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
    return float(np.mean(ends - starts)) if starts.size else 0.0


def _reordered(rows: np.ndarray) -> int:
    """Arrivals whose seq is below the highest seq that arrived before them (RFC 4737 style)."""
    arrived = rows[~np.isnan(rows[:, 2]) & (rows[:, 4] == 0.0)]
    if arrived.size == 0:
        return 0
    order = np.lexsort((arrived[:, 0], arrived[:, 2]))
    seq = arrived[order, 0]
    running = np.maximum.accumulate(seq)
    return int(np.count_nonzero(seq[1:] < running[:-1]))


def direction_stats(
    rows: np.ndarray,
    played_seq: np.ndarray,
    played_release_s: np.ndarray,
    duration_s: float,
    overhead_bytes: float,
    prefix: str,
) -> dict[str, float | int]:
    """Per-direction network and playout statistics from packet records and played samples."""
    sent, lost, late = _packet_counts(rows)
    delivered = rows[~np.isnan(rows[:, 2]) & (rows[:, 2] <= duration_s)]
    net_delay = delivered[:, 2] - delivered[:, 1]
    mean, p50, p99 = _quantiles(net_delay)
    # Buffering: release time minus arrival time of the first copy of each played sample.
    first_arrival: dict[int, float] = {}
    for seq, arr in sorted(zip(delivered[:, 0].tolist(), delivered[:, 2].tolist(), strict=True), key=lambda x: -x[1]):
        first_arrival[int(seq)] = arr
    buffering = [
        rel - first_arrival[int(sq)]
        for sq, rel in zip(played_seq.tolist(), played_release_s.tolist(), strict=True)
        if int(sq) in first_arrival
    ]
    # On the wire: packets that arrived by the end, and those lost on the way. Queue drops never
    # left the sender; packets still queued or in flight at the end have not finished crossing.
    on_wire = rows[(rows[:, 3] == 1.0) | (rows[:, 3] == 3.0) | (rows[:, 2] <= duration_s)] if rows.size else rows
    wire_bits = float(np.sum(on_wire[:, 5] + overhead_bytes) * 8.0) if rows.size else 0.0
    return {
        f"loss_rate_{prefix}": lost / sent if sent else math.nan,
        f"loss_burst_mean_{prefix}_packets": _loss_bursts(rows),
        f"delay_{prefix}_mean_s": mean,
        f"delay_{prefix}_p50_s": p50,
        f"delay_{prefix}_p99_s": p99,
        f"reorder_count_{prefix}": _reordered(rows),
        f"duplicates_{prefix}": int(np.count_nonzero(rows[:, 4] == 1.0)) if rows.size else 0,
        f"late_loss_{prefix}": late,
        f"late_loss_rate_{prefix}": late / sent if sent else math.nan,
        f"buffering_delay_{prefix}_mean_s": float(np.mean(buffering)) if buffering else math.nan,
        f"wire_bits_per_s_{prefix}": wire_bits / duration_s if duration_s > 0 else math.nan,
    }


def _quantiles(d: np.ndarray) -> tuple[float, float, float]:
    if d.size == 0:
        return math.nan, math.nan, math.nan
    return float(np.mean(d)), float(np.percentile(d, 50)), float(np.percentile(d, 99))


def compute_summary(sig: Signals) -> dict[str, Any]:
    """Every metric of summary.json from the signals of one bag."""
    sc = sig.scene
    T = sig.period_s
    e = _aligned_error(sig.master_force_n, sig.contact_n, sig.backward_lag_ticks)
    e0 = sig.master_force_n - sig.contact_n
    pos = _aligned_error(sig.slave_x_m, sig.master_x_m, sig.forward_lag_ticks)
    mb = float(sc["master"]["damping_n_s_per_m"])
    sb = float(sc["slave"]["damping_n_s_per_m"])
    me0 = initial_energy(sc, sig.run_info, "master")
    se0 = initial_energy(sc, sig.run_info, "slave")
    m_abs = port_energy(sig.master_x_m, sig.master_force_n, mb, T)
    s_abs = port_energy(sig.slave_x_m, sig.slave_force_n, sb, T)
    # The true margins: the same ledger with the damping the simulator really has (run facts).
    true_margins: dict[str, Any] = {}
    for side, x, f, e0_j in (
        ("master", sig.master_x_m, sig.master_force_n, me0),
        ("slave", sig.slave_x_m, sig.slave_force_n, se0),
    ):
        d_sim = simulator_damping(sig.run_info, side)
        true_margins[f"{side}_energy_margin_simulator_min_j"] = (
            energy_margins(x, f, d_sim, T, [e0_j] * len(d_sim)).pooled_min_j if d_sim is not None else math.nan
        )
        true_margins[f"{side}_joint_damping_simulator"] = d_sim
    fs, fl, flate = _packet_counts(sig.forward_packets)
    bs, bl, blate = _packet_counts(sig.backward_packets)
    duration = float(sig.t_s[-1] + T)
    net = sc.get("network", {})
    nets: dict[str, Any] = {}
    for prefix, rows, played_seq, released in (
        ("forward", sig.forward_packets, sig.forward_played_seq, sig.forward_release_s),
        ("backward", sig.backward_packets, sig.backward_played_seq, sig.backward_release_s),
    ):
        rl = (net.get(prefix) or {}).get("effects", {}).get("rate_limit") or {}
        overhead = float(rl.get("overhead_bytes", DEFAULT_OVERHEAD_BYTES))
        nets.update(direction_stats(rows, played_seq, released, duration, overhead, prefix))
    # One lag for every playout policy: the median one-way *network* delay of the backward packets
    # delivered within the run (delay_backward_p50_s: arrival minus send, before any playout buffer)
    # + 1 tick. Policies release different samples, so the release-based lag of force_rms_error_n
    # differs between them; this one depends only on the network draws (the same for every policy
    # with the same seed).
    p50 = nets.get("delay_backward_p50_s", math.nan)
    net_lag = int(round(p50 / T)) + 1 if math.isfinite(p50) else sig.backward_lag_ticks
    e_net = _aligned_error(sig.master_force_n, sig.contact_n, net_lag)
    lat_f = _quantiles(sig.forward_delays_s)
    lat_b = _quantiles(sig.backward_delays_s)
    finite = all(
        bool(np.all(np.isfinite(a)))
        for a in (sig.master_x_m, sig.slave_x_m, sig.master_force_n, sig.slave_force_n, sig.contact_n)
    )
    summary: dict[str, Any] = {
        "scene": sc["scene"]["name"],
        "seed": sc["scene"]["seed"],
        "duration_s": duration,
        "ticks": int(sig.t_s.size),
        "interrupted": bool(sig.run_info.get("interrupted", False)),
        "realtime_factor": sig.run_info.get("realtime_factor", math.nan),
        "force_rms_error_n": _rms(e),
        "force_peak_error_n": float(np.max(np.abs(e))) if e.size else math.nan,
        "force_rms_error_unaligned_n": _rms(e0),
        "force_alignment_lag_s": sig.backward_lag_ticks * T,
        "force_rms_error_network_lag_n": _rms(e_net),
        "force_network_lag_s": net_lag * T,
        "position_rms_error_m": _rms(pos),
        "contact_force_max_n": float(np.max(np.abs(sig.contact_n))),
        "master_force_max_n": float(np.max(np.abs(sig.master_force_n))),
        "penetration_max_m": float(np.max(penetration(sig.slave_x_m[:, None], wall_plane(sc, sig.run_info, 1)))),
        "packets_sent_forward": fs,
        "packets_lost_forward": fl,
        "packets_late_forward": flate,
        "packets_sent_backward": bs,
        "packets_lost_backward": bl,
        "packets_late_backward": blate,
        "playout_latency_forward_mean_s": lat_f[0],
        "playout_latency_forward_p99_s": lat_f[2],
        "playout_latency_backward_mean_s": lat_b[0],
        "playout_latency_backward_p99_s": lat_b[2],
        **nets,
        "master_energy_margin_min_j": float(me0 + np.min(m_abs)),
        "slave_energy_margin_min_j": float(se0 + np.min(s_abs)),
        # Both ports together (the two-port of controllers and channel): what TDPA keeps >= 0;
        # EBA keeps each side's, hence this too (docs/stabilizers.md).
        "two_port_energy_margin_min_j": float(me0 + se0 + np.min(m_abs + s_abs)),
        "master_port_energy_min_j": float(np.min(m_abs)),
        "slave_port_energy_min_j": float(np.min(s_abs)),
        "master_initial_energy_j": me0,
        "slave_initial_energy_j": se0,
        **true_margins,
        "all_finite": finite,
        **run_counts(sig.run_info),
    }
    return summary


def analyze_bag(bag: str | Path) -> tuple[dict[str, Any], Signals]:
    sig = load_signals(bag)
    return compute_summary(sig), sig
