"""An NVE run's summary and plots, from its bag only (docs/nve_scenes.md, "what a run writes").

Per client: the round trip it measured, the force it fed back, the spring its schedule set, what
its links lost, and the transparency analysis at the round trip it measured (the distorted mass
and damping, the spring distortions, which applies); for the object: where it went and whether
everything stayed finite.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from haptic_teleop.analysis.nve_energy import ClientPort, step_dissipation_j
from haptic_teleop.core.nve_transparency import (
    NveModel,
    damping_based_spring_n_per_m,
    distorted_damping_n_s_per_m,
    distorted_mass_kg,
    dominant_distortion,
    mass_based_spring_n_per_m,
    with_partners,
)
from haptic_teleop.errors import BagError
from haptic_teleop.record.layouts import PACKET_FIELDS
from haptic_teleop.record.nve_columns import NveSchema, nve_topics
from haptic_teleop.record.reader import BagReader, TopicData

PLOT_FILES = ("nve_forces.png", "nve_positions.png", "nve_round_trip.png")


def nve_rows(reader: BagReader) -> tuple[NveSchema, np.ndarray, np.ndarray]:
    """(schema, tick times in s, the run's tick rows rebuilt from its per-tick topics: the k-th
    message of each topic is tick k's; `missing_messages` says where that does not hold)."""
    schema = reader.nve_schema
    if schema is None:
        raise BagError(f"{reader.path} is not an NVE run's bag")
    rows: np.ndarray | None = None
    times = np.zeros(0)
    for topic in nve_topics(schema):
        data = reader.read(topic.topic)
        n = len(data.log_ns)
        if rows is None:
            rows = np.full((n, schema.width), math.nan)
            times = data.log_ns * 1e-9
        k = min(n, rows.shape[0])  # a killed run's last tick may lack its later topics
        rows = rows[:k]
        times = times[:k]
        rows[:, topic.columns(schema)] = data.values[:k, : len(topic.columns(schema))]
    if rows is None:
        rows = np.zeros((0, schema.width))
    return schema, times, rows


def missing_messages(reader: BagReader, schema: NveSchema) -> dict[str, int]:
    """Per-tick topics of the bag that lack messages of ticks the run recorded, and how many: a
    live run's recorder takes the 1 kHz streams best effort, so under load it may miss some, and
    then a topic's k-th message is no longer tick k's (`nve_rows`). `topics_missing` on the bag's
    per-tick topics."""
    return topics_missing([(t.topic, reader.read(t.topic)) for t in nve_topics(schema)])


def topics_missing(topics: list[tuple[str, TopicData]]) -> dict[str, int]:
    """`missing_messages` of (topic, data) pairs, the first the reference: judged against its ticks
    (its own gaps in stamps are ticks it lacks), a topic with a header by the stamps, one without
    by its count (one message short at the end is a killed run's last tick, not a loss)."""
    (name0, ref), rest = topics[0], topics[1:]
    n = len(ref.log_ns)  # ticks the run recorded: the reference's, and the ones it lacks
    expected = ref.stamp_ns
    out: dict[str, int] = {}
    if ref.stamp_ns is not None and n > 1:
        step = int(np.min(np.diff(ref.stamp_ns)))
        if step > 0:
            expected = ref.stamp_ns[0] + step * np.arange((int(ref.stamp_ns[-1] - ref.stamp_ns[0])) // step + 1)
            if len(expected) > n:
                out[name0] = len(expected) - n
                n = len(expected)
    for name, data in rest:
        if data.stamp_ns is not None and expected is not None:
            k = min(len(data.stamp_ns), n)
            lost = int(np.count_nonzero(~np.isin(expected[: max(k, n - 1)], data.stamp_ns)))
        else:  # (one short is taken for a killed run's last tick: a single lost message is not seen)
            lost = n - len(data.log_ns) if len(data.log_ns) < n - 1 else 0
        if lost:
            out[name] = lost
    return out


def samples_missing(absent: dict[str, int], info: dict[str, Any]) -> dict[str, int]:
    """Per topic, the ticks whose sample the bag does not hold as it was sent: messages absent
    (`missing_messages`) and, in a live run's bag, the ticks its recorder filled by holding the
    previous value (run_info `samples_filled`: it takes the 1 kHz streams best effort)."""
    out = dict(absent)
    for topic, k in (info.get("samples_filled") or {}).items():
        if isinstance(k, int) and k > 0:
            out[topic] = max(out.get(topic, 0), k)
    return out


def _scene(reader: BagReader) -> dict[str, Any]:
    try:
        scene = yaml.safe_load(reader.string("/haptic_teleop/scene"))
    except BagError:
        return {}
    return scene if isinstance(scene, dict) else {}


def _run_info(reader: BagReader) -> dict[str, Any]:
    import json

    try:
        info = json.loads(reader.string("/haptic_teleop/run_info"))
    except (BagError, ValueError):
        return {}
    return info if isinstance(info, dict) else {}


def _model(scene: dict[str, Any], client: str) -> tuple[NveModel, float] | None:
    """The client's transparency model and interaction frequency from the bag's scene."""
    nve = scene.get("nve") or {}
    obj = nve.get("object") or {}
    for c in nve.get("clients") or ():
        if c.get("name") == client:
            k = c.get("coupling") or {}
            comp = c.get("compensation") or {}
            try:
                model = NveModel(
                    float(obj["mass_kg"]),
                    float(obj["damping_n_s_per_m"]),
                    float(k["client_stiffness_n_per_m"]),
                    float(k["server_stiffness_n_per_m"]),
                    float(k.get("client_damping_n_s_per_m", 0.0)),
                    float(k.get("server_damping_n_s_per_m", 0.0)),
                )
            except (KeyError, TypeError, ValueError):
                return None
            # the other clients' couplings hold the object too (docs/nve.md, "Several clients")
            others = [o.get("coupling") or {} for o in nve.get("clients") or () if o.get("name") != client]
            try:
                model = with_partners(
                    model,
                    [float(o.get("server_stiffness_n_per_m", 0.0)) for o in others],
                    [float(o.get("server_damping_n_s_per_m", 0.0)) for o in others],
                )
            except (TypeError, ValueError):
                return None
            return model, float(comp.get("interaction_rad_per_s", 1.0))
    return None


def _stats(x: np.ndarray) -> dict[str, float | None]:
    x = x[np.isfinite(x)]
    if not x.size:
        return {"min": None, "median": None, "max": None}
    return {"min": float(x.min()), "median": float(np.median(x)), "max": float(x.max())}


def summarize_nve(bag_dir: Path) -> dict[str, Any]:
    """The summary of an NVE run (summary.json)."""
    with BagReader(bag_dir) as reader:
        schema, t, rows = nve_rows(reader)
        scene = _scene(reader)
        info = _run_info(reader)
        missing = samples_missing(missing_messages(reader, schema), info)
        packets = {
            d: reader.packets(schema.packet_topic(d)) for d in schema.directions if reader.has(schema.packet_topic(d))
        }
    a = schema.axes
    out: dict[str, Any] = {
        "kind": "nve",
        "scene": (scene.get("scene") or {}).get("name", ""),
        "seed": (scene.get("scene") or {}).get("seed"),
        "interrupted": bool(info.get("interrupted", False)),
        "ticks": int(rows.shape[0]),
        "duration_s": float(t[-1] - t[0]) + (float(t[1] - t[0]) if len(t) > 1 else 0.0) if len(t) else 0.0,
        "axes": a,
        "finite": bool(np.all(np.isfinite(rows[:, : 3 * a]))),
    }
    obj = rows[:, schema.group("obj_x_m")]
    out["object"] = {
        "start_m": obj[0].tolist() if len(obj) else None,
        "end_m": obj[-1].tolist() if len(obj) else None,
        "peak_speed_m_per_s": float(np.max(np.linalg.norm(rows[:, schema.group("obj_v_m_per_s")], axis=1)))
        if len(obj)
        else 0.0,
    }
    clients: dict[str, Any] = {}
    for c in schema.clients:
        force = rows[:, schema.client_group(c, "force_n")]
        fnorm = np.linalg.norm(force, axis=1)
        rtt = rows[:, schema.client_group(c, "rtt_s")][:, 0]
        spring = rows[:, schema.client_group(c, "spring_n_per_m")][:, 0]
        seen = rows[:, schema.client_group(c, "obj_x_m")]
        lag = np.linalg.norm(seen - obj, axis=1)
        entry: dict[str, Any] = {
            "round_trip_s": _stats(rtt),
            "force_rms_n": float(np.sqrt(np.mean(fnorm**2))) if len(fnorm) else 0.0,
            "force_peak_n": float(fnorm.max()) if len(fnorm) else 0.0,
            "spring_n_per_m": _stats(spring),
            "view_error_rms_m": float(np.sqrt(np.nanmean(lag**2))) if np.isfinite(lag).any() else None,
            "finite": bool(np.all(np.isfinite(force)) and np.all(np.isfinite(spring))),
        }
        for d in schema.directions:
            if not d.startswith(f"{c}/"):
                continue
            p = packets.get(d)
            if p is not None and len(p):
                original = p[:, PACKET_FIELDS.index("duplicate")] == 0
                fate = p[original, PACKET_FIELDS.index("fate")]
                entry[f"{d.split('/')[1]}_packets"] = {
                    "sent": int(original.sum()),
                    "lost": int(np.count_nonzero(fate != 0)),
                }
        r = entry["round_trip_s"]["median"]
        got = _model(scene, c)
        if r is not None and got is not None:
            model, w = got
            rule = dominant_distortion(model, w)
            entry["analysis_at_median_round_trip"] = {
                "round_trip_s": r,
                "distorted_mass_kg": distorted_mass_kg(model, r),
                "distorted_damping_n_s_per_m": distorted_damping_n_s_per_m(model, r),
                "mass_based_spring_n_per_m": mass_based_spring_n_per_m(model, r),
                "damping_based_spring_n_per_m": damping_based_spring_n_per_m(model, r)
                if model.damping_n_s_per_m > 0
                else None,
                "distortion_that_applies": rule,
            }
        clients[c] = entry
    out["clients"] = clients
    out["finite"] = out["finite"] and all(e["finite"] for e in clients.values())
    # (rows out of step with their ticks would make up or hide energy: not judged then)
    out["messages_missing"] = missing
    out["server_energy"] = None if missing else server_energy(schema, rows, scene)
    return out


def server_energy(schema: NveSchema, rows: np.ndarray, scene: dict[str, Any]) -> dict[str, Any] | None:
    """The server's energy balance from the rows (analysis/nve_energy.py): the energy its object and
    couplings dissipated, and the smallest one step dissipated (< 0: the server made energy). None
    when the scene's couplings are not in the bag or a server-side buffer extrapolates (the held
    HIP is then not a recorded sample)."""
    nve = scene.get("nve") or {}
    by_name = {c.get("name"): c for c in nve.get("clients") or ()}
    try:
        mass = float((nve.get("object") or {})["mass_kg"])
        ports = []
        for c in schema.clients:
            cfg = by_name[c]
            if ((cfg.get("up") or {}).get("buffer") or {}).get("gap") == "extrapolate":
                return None
            k = cfg["coupling"]
            rx = rows[:, schema.client_group(c, "up_rx_seq")][:, 0]
            if not np.isfinite(rx).all():  # the server's releases are not in this bag
                return None
            ports.append(
                ClientPort(
                    float(k["server_stiffness_n_per_m"]),
                    float(k["server_damping_n_s_per_m"]),
                    rows[:, schema.client_group(c, "hip_x_m")],
                    rows[:, schema.client_group(c, "hip_v_m_per_s")],
                    rows[:, schema.client_group(c, "up_rx_seq")][:, 0],
                )
            )
    except (KeyError, TypeError, ValueError):
        return None
    d, stored = step_dissipation_j(
        mass, rows[:, schema.group("obj_x_m")], rows[:, schema.group("obj_v_m_per_s")], ports
    )
    d = d[:-1]  # the last tick's step has no recorded end
    if not len(d):
        return None
    # roundoff: a few units of float64 on the energies each step's difference is made of
    tolerance = 64 * 2.0**-53 * float(np.max(stored)) if len(stored) else 0.0
    return {
        "dissipated_j": float(np.sum(d)),
        "min_step_dissipation_j": float(np.min(d)),
        "tolerance_j": tolerance,
        "passive": bool(np.min(d) >= -tolerance),
        "stored_max_j": float(np.max(stored)),
    }


def format_nve_summary(s: dict[str, Any]) -> str:
    """The summary as the few lines `haptic-teleop run` prints."""
    lines = [
        f"NVE run {s.get('scene', '')}: {s['ticks']} ticks ({s['duration_s']:.3f} s), {s['axes']} axis/axes, "
        + ("all finite" if s["finite"] else "NOT FINITE")
        + ("  (interrupted)" if s.get("interrupted") else ""),
    ]
    obj = s["object"]
    if obj["end_m"] is not None:
        lines.append(
            f"  object: from {_vec(obj['start_m'])} m to {_vec(obj['end_m'])} m, "
            f"peak speed {obj['peak_speed_m_per_s']:.4g} m/s"
        )
    en = s.get("server_energy")
    if s.get("messages_missing"):
        lost = ", ".join(f"{t} {k}" for t, k in s["messages_missing"].items())
        lines.append(f"  server energy not judged: the bag misses per-tick messages ({lost})")
    if en is not None:
        lines.append(
            f"  server: dissipated {en['dissipated_j']:.4g} J, "
            + (
                "passive at every step"
                if en["passive"]
                else f"NOT PASSIVE: a step made {-en['min_step_dissipation_j']:.3g} J"
            )
        )
    for name, c in s["clients"].items():
        r = c["round_trip_s"]
        rt = "no object sample received" if r["median"] is None else f"round trip {r['median'] * 1e3:.1f} ms"
        sp = c["spring_n_per_m"]
        lines.append(
            f"  {name}: {rt}, force rms {c['force_rms_n']:.4g} N (peak {c['force_peak_n']:.4g} N), "
            f"spring {sp['min']:.4g}..{sp['max']:.4g} N/m"
        )
        an = c.get("analysis_at_median_round_trip")
        if an is not None:
            lines.append(
                f"    feels (seed 000 analysis at {an['round_trip_s'] * 1e3:.0f} ms): "
                f"mass {an['distorted_mass_kg']:.4g} kg, damping {an['distorted_damping_n_s_per_m']:.4g} N s/m, "
                f"spring {an['mass_based_spring_n_per_m']:.4g} N/m (mass-based)"
                + ("" if an["distortion_that_applies"] == "mass" else " / damping-based applies")
            )
    return "\n".join(lines)


def _vec(v: list[float]) -> str:
    return "[" + ", ".join(f"{x:.4g}" for x in v) + "]" if len(v) > 1 else f"{v[0]:.4g}"


def write_nve_plots(bag_dir: Path, out_dir: Path) -> list[Path]:
    """Forces, positions and round trip/spring against time, one line per client (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with BagReader(bag_dir) as reader:
        schema, t, rows = nve_rows(reader)
    out_dir.mkdir(parents=True, exist_ok=True)
    axis = 0  # the first axis (1 axis: the line; 3 axes: x)
    paths = []
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for c in schema.clients:
        ax.plot(t, rows[:, schema.client_group(c, "force_n")][:, axis], label=f"{c}: force fed back")
    ax.plot(t, rows[:, schema.group("obj_force_n")][:, axis], "k:", lw=1, label="net coupling force on the object")
    ax.set(xlabel="time (s)", ylabel="force, x (N)", title="NVE: forces")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    paths.append(_save(fig, out_dir / PLOT_FILES[0]))
    fig, ax = plt.subplots(figsize=(9, 4.5))
    ax.plot(t, rows[:, schema.group("obj_x_m")][:, axis], "k", lw=1.5, label="object (server)")
    for c in schema.clients:
        ax.plot(t, rows[:, schema.client_group(c, "hip_x_m")][:, axis], label=f"{c}: HIP")
        ax.plot(t, rows[:, schema.client_group(c, "obj_x_m")][:, axis], "--", label=f"{c}: object as it sees it")
    ax.set(xlabel="time (s)", ylabel="position, x (m)", title="NVE: HIPs and the object")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    paths.append(_save(fig, out_dir / PLOT_FILES[1]))
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for c in schema.clients:
        a1.plot(t, rows[:, schema.client_group(c, "rtt_s")][:, 0] * 1e3, label=c)
        a2.plot(t, rows[:, schema.client_group(c, "spring_n_per_m")][:, 0], label=c)
    a1.set(ylabel="measured round trip (ms)", title="NVE: what each client measured and set")
    a2.set(xlabel="time (s)", ylabel="spring k_h (N/m)")
    for x in (a1, a2):
        _readable_y(x)
        x.grid(alpha=0.3)
        x.legend(fontsize=8)
    paths.append(_save(fig, out_dir / PLOT_FILES[2]))
    return paths


def _readable_y(ax: Any) -> None:
    """Plain tick labels (no "1e-10+3.01e2" offset), and a signal that stays constant drawn as a
    flat line in a +-10 % range around it rather than its round-off magnified to fill the axis."""
    ax.ticklabel_format(axis="y", useOffset=False, style="plain")
    values = [np.asarray(line.get_ydata(), dtype=float) for line in ax.get_lines()]
    finite = np.concatenate([v[np.isfinite(v)] for v in values]) if values else np.zeros(0)
    if finite.size == 0:
        return
    lo, hi = float(finite.min()), float(finite.max())
    if hi - lo <= 1e-9 * max(1.0, abs(hi)):
        half = 0.1 * abs(hi) if hi else 1.0
        ax.set_ylim(lo - half, hi + half)


def _save(fig: Any, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)
    return path
