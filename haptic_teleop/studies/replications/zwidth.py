"""The Z-width part of `haptic-teleop experiment stabilizers`: the range of walls each stabilizer
renders without losing passivity or oscillating.

Every law (stabilizer_runs.LAWS) runs the experiment's one-axis contact scene (stabilizer_runs.GEOMETRY:
the wall 5 mm ahead, the operator pushing from 0.2 s toward 3 cm, then holding) over a grid of
walls, wall stiffness x wall damping (`slave.wall.stiffness_n_per_m`, `slave.wall.damping_n_s_per_m`),
at every one-way delay of the sweep (both directions, no loss), seed 1. Each run is recorded to a
bag and measured from that bag alone:

- the two-port energy margin from the plant signals (both ports, the simulator's damping, the
  initial energies included): passive while >= -PASSIVE_TOLERANCE_J;
- the stiffness felt at rest against the wall: the master's mean force magnitude over the late
  window divided by its mean position there beyond the wall (the wall's place mapped to the
  master, 1:1 here), the static stiffness the operator holds against (NaN when the master is not
  beyond the wall); beside it the slope of stabilizer_runs.felt_stiffness over the whole contact,
  which at long delays takes in the force still building while the master moves;
- the oscillation: the RMS of the master's velocity over the late window (the last LATE_WINDOW_S
  of the run, from the end of the operator's push at the earliest: the hand holds still there), and
  the contact breaks in that window (the slave's contact force magnitude falling from >
  stabilizer_runs.CONTACT_N to <= CONTACT_N: the hand holds the tool against the wall there, so a
  break is a bounce that has not died out; the impact's own bounces, before it, do not count).

A run is "ok" when passive, the late velocity RMS < VELOCITY_RMS_LIMIT_M_PER_S and the contact
breaks in the late window <= MAX_LATE_CONTACT_BREAKS; "active" when the margin falls below -PASSIVE_TOLERANCE_J; else
"oscillating". A law's Z-width at a delay is the range of static felt stiffness over its ok cells,
and per wall damping the stiffest wall up to which every softer wall of the sweep is ok.

Writes zwidth_runs.csv (every run), zwidth.md (per delay: status and felt stiffness per law and
wall; the Z-width and the stiffest wall rendered ok per damping) and zwidth.png; the bags under
zwidth_bags/ (`--discard-bags`: each is measured, then deleted).
"""

from __future__ import annotations

import argparse
import math
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.replications.stabilizer_runs import (
    ARM_SCENE,
    BASE_SCENE,
    CONTACT_N,
    GEOMETRY,
    LAWS,
    felt_stiffness,
    network_overrides,
    number_list,
    record,
    scene,
)
from haptic_teleop.studies.replications.tables import finish_figure, markdown, write_csv

STIFFNESS_N_PER_M = (300.0, 1000.0, 3000.0, 10000.0, 30000.0, 100000.0)
DAMPING_N_S_PER_M = (0.0, 10.0, 100.0)
DELAYS_S = (0.0, 0.1)
QUICK_STIFFNESS_N_PER_M = (1000.0, 30000.0)
QUICK_DAMPING_N_S_PER_M = (0.0, 10.0)
QUICK_DELAYS_S = (0.1,)
SEED = 1
# (wall stiffnesses N/m, wall dampings N s/m, one-way delays s)
Sweep = tuple[list[float], list[float], list[float]]
# The scene's own limits (scene/schema.py, WallConfig); a wall too stiff for the simulator's step
# is refused by the scene loader before anything runs.
STIFFNESS_RANGE_N_PER_M = (1.0, 1e7)
DAMPING_RANGE_N_S_PER_M = (0.0, 1e5)
DELAY_RANGE_MS = (0.0, 2000.0)

PASSIVE_TOLERANCE_J = 1e-9  # passive while the two-port margin stays >= -this
VELOCITY_RMS_LIMIT_M_PER_S = 2e-3  # the master still in the late window: RMS velocity below this
MAX_LATE_CONTACT_BREAKS = 0  # held against the wall, the tool must not bounce off it in the late window
LATE_WINDOW_S = 1.0  # the late window: the run's last second ...
MIN_LATE_WINDOW_S = 0.2  # ... from the end of the push at the earliest, but never shorter than this
STATUSES = ("ok", "oscillating", "active")
SYMBOLS = {"ok": "✓", "oscillating": "≈", "active": "✗"}
COLOURS = {"ok": "#a6dba0", "oscillating": "#fee08b", "active": "#f46d43"}

RUNS_HEADER = [
    "law", "delay_s", "wall_stiffness_n_per_m", "wall_damping_n_s_per_m", "seed",
    "two_port_margin_min_j", "felt_static_stiffness_n_per_m", "late_master_velocity_rms_m_per_s", "contact_breaks",
    "late_window_start_s", "contact_force_max_n", "felt_slope_n_per_m", "status",
]  # fmt: skip


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The sweep's options of `haptic-teleop experiment stabilizers`."""
    p.add_argument("--no-z-width", action="store_true", help="skip the Z-width sweep (wall stiffness x damping)")
    p.add_argument(
        "--z-width-stiffness",
        default=",".join(f"{k:g}" for k in STIFFNESS_N_PER_M),
        help="the Z-width sweep's wall stiffnesses (N/m, comma-separated, 1 to 1e7; default %(default)s)",
    )
    p.add_argument(
        "--z-width-damping",
        default=",".join(f"{b:g}" for b in DAMPING_N_S_PER_M),
        help="the Z-width sweep's wall dampings (N s/m, comma-separated, 0 to 1e5; default %(default)s)",
    )
    p.add_argument(
        "--z-width-delays-ms",
        default=",".join(f"{d * 1e3:g}" for d in DELAYS_S),
        help="the Z-width sweep's one-way delays (ms, both ways, no loss; 0 to 2000; default %(default)s)",
    )


def grid(args: argparse.Namespace) -> Sweep | None:
    """The sweep's walls and delays from the command line: (stiffnesses N/m, dampings N s/m,
    delays s), the walls ascending without repeats; None with --no-z-width. --quick: its grid."""
    if args.no_z_width:
        return None
    stiffness = number_list(args.z_width_stiffness, "--z-width-stiffness", *STIFFNESS_RANGE_N_PER_M, "N/m")
    damping = number_list(args.z_width_damping, "--z-width-damping", *DAMPING_RANGE_N_S_PER_M, "N s/m")
    delays = [d * 1e-3 for d in number_list(args.z_width_delays_ms, "--z-width-delays-ms", *DELAY_RANGE_MS)]
    if args.quick:
        stiffness, damping, delays = list(QUICK_STIFFNESS_N_PER_M), list(QUICK_DAMPING_N_S_PER_M), list(QUICK_DELAYS_S)
    return sorted(set(stiffness)), sorted(set(damping)), list(dict.fromkeys(delays))


def scene_overrides(
    law: str, stiffness_n_per_m: float, damping_n_s_per_m: float, delay_s: float, extra: Sequence[str],
    arm: bool = False,
) -> list[str]:  # fmt: skip
    """One run's overrides of the base scene: the geometry (the one-axis scene's; an arm scene keeps
    its own), the law, `extra` (duration, --set), then the sweep's wall, network and seed (these win
    over a --set of the same keys)."""
    return [
        *(() if arm else GEOMETRY), *LAWS[law][1], *extra,
        f"slave.wall.stiffness_n_per_m={stiffness_n_per_m!r}", f"slave.wall.damping_n_s_per_m={damping_n_s_per_m!r}",
        *network_overrides(delay_s, "none"), f"scene.seed={SEED}",
    ]  # fmt: skip


def push_end_s(scene: dict[str, Any]) -> float:
    """When the operator's push ends and the hand holds still (s; 0 for another profile)."""
    op = scene.get("operator", {})
    speed = abs(float(op.get("speed_m_per_s", 0.0)))
    if op.get("profile") != "push" or speed == 0.0:
        return 0.0
    return float(op.get("start_s", 0.0)) + float(op.get("distance_m", 0.0)) / speed


def classify(margin_j: float, velocity_rms_m_per_s: float, contact_breaks: int) -> str:
    """A run's status from its measures: "active", "oscillating" or "ok" (STATUSES)."""
    if not margin_j >= -PASSIVE_TOLERANCE_J:
        return "active"
    if not velocity_rms_m_per_s < VELOCITY_RMS_LIMIT_M_PER_S or contact_breaks > MAX_LATE_CONTACT_BREAKS:
        return "oscillating"
    return "ok"


def judge(
    t_s: np.ndarray, master_v_m_per_s: np.ndarray, contact_n: np.ndarray, margin_j: float, still_from_s: float
) -> dict[str, Any]:
    """A run's oscillation measures and status from its signals: the master's velocity RMS over the
    late window (the last LATE_WINDOW_S, from `still_from_s` at the earliest, at least
    MIN_LATE_WINDOW_S), the contact breaks in it, and `classify` of these with the two-port margin."""
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(master_v_m_per_s, dtype=float)
    start = min(max(t[-1] - LATE_WINDOW_S, still_from_s), t[-1] - MIN_LATE_WINDOW_S)
    late = v[t >= start]
    velocity_rms = float(np.sqrt(np.mean(late * late))) if late.size else math.nan
    touching = np.abs(np.asarray(contact_n, dtype=float)) > CONTACT_N
    late_pair = t[1:] >= start  # a break whose second tick is in the late window
    breaks = int(np.count_nonzero(touching[:-1] & ~touching[1:] & late_pair))
    return {
        "late_start_s": float(start),
        "velocity_rms_m_per_s": velocity_rms,
        "contact_breaks": breaks,
        "status": classify(margin_j, velocity_rms, breaks),
    }


def static_stiffness(sig: Any, late_start_s: float) -> float:
    """The stiffness felt at rest against the wall (N/m): the master's mean force magnitude over
    the late window (from `late_start_s`) over its mean position there beyond the wall
    (slave.wall.position_m: the mapping is 1:1 in the one-axis scene); NaN unless the master is
    at least 0.1 mm beyond it."""
    late = np.asarray(sig.t_s) >= late_start_s
    depth = float(np.mean(np.asarray(sig.master_x_m)[late])) - float(sig.scene["slave"]["wall"]["position_m"])
    if not depth >= 1e-4:
        return math.nan
    return float(np.mean(np.abs(np.asarray(sig.master_force_n)[late]))) / depth


def measure(bag: Path) -> dict[str, Any]:
    """What the sweep needs of one run, from its bag alone."""
    from haptic_teleop.analysis.metrics import analyze_bag

    summary, sig = analyze_bag(bag)
    margin = float(summary["two_port_energy_margin_min_j"])
    judged = judge(sig.t_s, sig.master_v_m_per_s, sig.contact_n, margin, push_end_s(sig.scene))
    return {
        "margin_j": margin,
        "slope": felt_stiffness(sig.master_x_m, sig.master_force_n, sig.contact_n),
        "stiffness": static_stiffness(sig, judged["late_start_s"]),
        "contact_max_n": float(summary["contact_force_max_n"]),
        **judged,
    }


def measure_arm(bag: Path) -> dict[str, Any]:
    """`measure` for an arm scene's bag, along the wall's normal n (task frame): the master's speed
    (the norm of its handle's velocity, from its positions), the contact force's norm, the static
    felt stiffness (the master's mean force along n over its mean depth beyond the wall's point
    along -n, in the late window; the mapping is 1:1 on the bundled arm scene) and the slope over
    the whole contact."""
    from haptic_teleop.analysis.stream import summarize_bag
    from haptic_teleop.analysis.taskmetrics import load_task_signals

    summary = summarize_bag(bag)
    sig = load_task_signals(bag)
    wall = sig.scene["slave"]["wall"]
    n = np.asarray(wall["normal"], dtype=float)
    n = n / np.linalg.norm(n)
    t = np.asarray(sig.t_s, dtype=float)
    x = np.asarray(sig.master_x_m, dtype=float)
    force = np.asarray(sig.master_force_n, dtype=float) @ n
    speed = np.linalg.norm(np.gradient(x, t, axis=0), axis=1)
    contact = np.linalg.norm(np.asarray(sig.contact_n, dtype=float), axis=1)
    margin = float(summary["two_port_energy_margin_min_j"])
    judged = judge(t, speed, contact, margin, push_end_s(sig.scene))
    late = t >= judged["late_start_s"]
    depth = float(np.mean((np.asarray(wall["point_m"], dtype=float) - x[late]) @ n))
    stiffness = float(np.mean(np.abs(force[late]))) / depth if depth >= 1e-4 else math.nan
    return {
        "margin_j": margin,
        "slope": felt_stiffness(-(x @ n), force, contact),
        "stiffness": stiffness,
        "contact_max_n": float(summary["contact_force_max_n"]),
        **judged,
    }


def bag_path(bags: Path, law: str, delay_s: float, stiffness: float, damping: float) -> Path:
    return bags / law / f"delay_{delay_s * 1e3:g}ms" / f"k_{stiffness:g}-b_{damping:g}" / "bag"


def run_sweep(
    laws: Sequence[str],
    stiffness: Sequence[float],
    damping: Sequence[float],
    delays: Sequence[float],
    extra: Sequence[str],
    bags: Path,
    discard: bool,
    progress: Any = None,
    arm: bool = False,
) -> list[list[Any]]:
    """Every law over every delay and wall: rows of RUNS_HEADER (`arm`: on the arm scene ARM_SCENE)."""
    rows: list[list[Any]] = []
    base, measure_bag = (ARM_SCENE, measure_arm) if arm else (BASE_SCENE, measure)
    for law in laws:
        for delay in delays:
            for k in stiffness:
                for b in damping:
                    bag = bag_path(bags, law, delay, k, b)
                    m = record(scene_overrides(law, k, b, delay, extra, arm), bag, measure_bag, base)
                    if discard:
                        shutil.rmtree(bag.parent)
                    rows.append(
                        [
                            law, delay, k, b, SEED, m["margin_j"], m["stiffness"], m["velocity_rms_m_per_s"],
                            m["contact_breaks"], m["late_start_s"], m["contact_max_n"], m["slope"], m["status"],
                        ]
                    )  # fmt: skip
                    if progress is not None:
                        progress.update(1)
    if discard:
        shutil.rmtree(bags, ignore_errors=True)
    return rows


def count(laws: Sequence[str], sweep: Sweep) -> int:
    """How many runs the sweep makes."""
    return len(laws) * len(sweep[0]) * len(sweep[1]) * len(sweep[2])


def check_scenes(laws: Sequence[str], sweep: Sweep, extra: Sequence[str], arm: bool = False) -> None:
    """Load every wall of the sweep with every law (at its last delay): a wall the scene refuses
    (too stiff for the simulator's step) fails here, in one line naming the options, before
    anything is written."""
    from haptic_teleop.errors import ConfigError, InputError

    for law in laws:
        for k in sweep[0]:
            for b in sweep[1]:
                try:
                    scene(scene_overrides(law, k, b, sweep[2][-1], extra, arm), ARM_SCENE if arm else BASE_SCENE)
                except ConfigError as exc:
                    where = f" on {ARM_SCENE}" if arm else ""
                    raise InputError(
                        f"--z-width-stiffness {k:g} with --z-width-damping {b:g}: the scene{where} refuses this wall: "
                        f"{exc.allowed}"
                    ) from None


def _index(rows: Sequence[Sequence[Any]]) -> dict[tuple[str, float, float, float], Sequence[Any]]:
    return {(r[0], r[1], r[2], r[3]): r for r in rows}


def z_width(rows: Sequence[Sequence[Any]], law: str, delay_s: float) -> tuple[float, float]:
    """A law's Z-width at a delay: the felt stiffness's (min, max) over its ok cells (N/m; NaN, NaN
    without any with a finite felt stiffness)."""
    felt = [r[6] for r in rows if r[0] == law and r[1] == delay_s and r[-1] == "ok" and math.isfinite(r[6])]
    return (min(felt), max(felt)) if felt else (math.nan, math.nan)


def stiffest_ok(rows: Sequence[Sequence[Any]], law: str, delay_s: float, damping: float) -> float:
    """The stiffest wall (N/m) up to which a law renders every wall of the sweep ok at a delay and
    wall damping (the upper end of its Z-width there); NaN if the softest is not ok."""
    cells = sorted((r[2], r[-1]) for r in rows if r[0] == law and r[1] == delay_s and r[3] == damping)
    best = math.nan
    for k, status in cells:
        if status != "ok":
            break
        best = k
    return best


def markdown_text(
    rows: Sequence[Sequence[Any]],
    laws: Sequence[str],
    sweep: Sweep,
    duration_s: float,
    where: str = "",
) -> str:
    stiffness, damping, delays = sweep
    at = _index(rows)
    out = [
        f"## Z-width{where}: wall stiffness x wall damping\n\n",
        f"Seed {SEED}, {duration_s:g} s runs, no loss. A cell: the status and the static felt stiffness (N/m); "
        "a column: wall stiffness (N/m) / wall damping (N s/m). "
        f"{SYMBOLS['ok']} ok: passive (two-port margin min >= {-PASSIVE_TOLERANCE_J:g} J), the master's late "
        f"velocity RMS < {VELOCITY_RMS_LIMIT_M_PER_S * 1e3:g} mm/s and at most {MAX_LATE_CONTACT_BREAKS} contact "
        f"breaks in the late window (contact force falling to <= {CONTACT_N:g} N; the impact's bounces "
        f"before it do not count); {SYMBOLS['oscillating']} oscillating: passive, "
        f"but not still or breaking contact more often; {SYMBOLS['active']} active: the margin below "
        f"{-PASSIVE_TOLERANCE_J:g} J. Late: the last {LATE_WINDOW_S:g} s, from the end of the operator's push "
        f"at the earliest (at least {MIN_LATE_WINDOW_S:g} s).\n",
    ]
    cells = [(k, b) for k in stiffness for b in damping]
    for delay in delays:
        out.append(f"\n### One-way delay {delay * 1e3:g} ms\n\n")
        body = []
        for law in laws:
            row: list[Any] = [LAWS[law][0]]
            for k, b in cells:
                r = at[(law, delay, k, b)]
                row.append(f"{SYMBOLS[r[-1]]} {_felt(r[6], 1.0)}")
            body.append(row)
        out.append(markdown(["law", *(f"{k:g} / {b:g}" for k, b in cells)], body))
        body = []
        for law in laws:
            lo, hi = z_width(rows, law, delay)
            span = f"{lo:.3g}..{hi:.3g}" if math.isfinite(lo) else "none"
            ok = sum(1 for r in rows if r[0] == law and r[1] == delay and r[-1] == "ok")
            body.append(
                [LAWS[law][0], span, f"{ok}/{len(cells)}", *(_wall(stiffest_ok(rows, law, delay, b)) for b in damping)]
            )
        head = ["law", "Z-width: static felt stiffness over ok cells (N/m)", "ok cells"]
        out.append("\n" + markdown([*head, *(f"stiffest wall ok, damping {b:g} (N/m)" for b in damping)], body))
    return "".join(out)


def _felt(stiffness_n_per_m: float, scale: float) -> str:
    return f"{stiffness_n_per_m * scale:.3g}" if math.isfinite(stiffness_n_per_m) else "n/a"


def _wall(stiffness_n_per_m: float) -> str:
    return f"{stiffness_n_per_m:g}" if math.isfinite(stiffness_n_per_m) else "none"


def _edges(values: Sequence[float]) -> np.ndarray:
    """Cell edges on a log axis around ascending positive `values` (half a decade across for one)."""
    lv = np.log10(np.asarray(values, dtype=float))
    if lv.size == 1:
        return 10.0 ** np.array([lv[0] - 0.25, lv[0] + 0.25])
    mid = (lv[1:] + lv[:-1]) / 2.0
    return 10.0 ** np.concatenate([[2 * lv[0] - mid[0]], mid, [2 * lv[-1] - mid[-1]]])


def plot(
    rows: Sequence[Sequence[Any]],
    laws: Sequence[str],
    sweep: Sweep,
    path: Path,
) -> None:
    """Per delay a row of panels, per law a panel: the walls, stiffness (log) x damping, coloured by
    status and annotated with the felt stiffness (kN/m)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    stiffness, damping, delays = sweep
    at = _index(rows)
    xe = _edges(stiffness)
    cols = min(len(laws), 3)
    per = math.ceil(len(laws) / cols)
    width = max(3.6, 0.62 * len(stiffness) + 1.0)
    height = max(2.0, 0.42 * len(damping) + 1.3)
    fig = plt.figure(figsize=(width * cols, height * per * len(delays) + 0.5))
    spec = fig.add_gridspec(per * len(delays) + 1, cols, height_ratios=[*([height] * per * len(delays)), 0.5])
    for di, delay in enumerate(delays):
        for li, law in enumerate(laws):
            ax = fig.add_subplot(spec[di * per + li // cols, li % cols])
            for yi, b in enumerate(damping):
                for xi, k in enumerate(stiffness):
                    r = at[(law, delay, k, b)]
                    ax.add_patch(
                        Rectangle((xe[xi], yi - 0.5), xe[xi + 1] - xe[xi], 1.0, color=COLOURS[r[-1]], ec="white")
                    )
                    text = f"{SYMBOLS[r[-1]]} {_felt(r[6], 1e-3)}"
                    ax.text(math.sqrt(xe[xi] * xe[xi + 1]), yi, text, ha="center", va="center", fontsize=7)
            ax.set_xscale("log")
            ax.set_xlim(xe[0], xe[-1])
            ax.set_ylim(-0.5, len(damping) - 0.5)
            ax.set_xticks(stiffness, [f"{k:g}" for k in stiffness], fontsize=7)
            ax.minorticks_off()
            ax.set_yticks(range(len(damping)), [f"{b:g}" for b in damping], fontsize=7)
            ax.set_xlabel("wall stiffness [N/m]", fontsize=8)
            ax.set_ylabel("wall damping [N s/m]", fontsize=8)
            ax.set_title(f"{LAWS[law][0]}\none-way delay {delay * 1e3:g} ms", fontsize=8)
    key = fig.add_subplot(spec[-1, :])
    key.axis("off")
    for s in STATUSES:  # the legend's entries: empty cells of each status
        key.add_patch(Rectangle((0.0, 0.0), 0.0, 0.0, color=COLOURS[s], label=f"{SYMBOLS[s]} {s}"))
    key.set_title("a cell: its status and the static felt stiffness [kN/m]", fontsize=8)
    finish_figure(fig, [key], path, loc="center", ncol=len(STATUSES), fontsize=8, frameon=False)


def write(
    rows: Sequence[Sequence[Any]],
    laws: Sequence[str],
    sweep: Sweep,
    duration_s: float,
    out: Path,
    arm: bool = False,
) -> str:
    """STEM_runs.csv, STEM.md and STEM.png into `out` (STEM: zwidth, or zwidth_arm for the arm
    scene); returns the markdown."""
    stem = "zwidth_arm" if arm else "zwidth"
    text = markdown_text(rows, laws, sweep, duration_s, f" on {ARM_SCENE}" if arm else "")
    write_csv(out / f"{stem}_runs.csv", RUNS_HEADER, rows)
    (out / f"{stem}.md").write_text(text)
    plot(rows, laws, sweep, out / f"{stem}.png")
    return text
