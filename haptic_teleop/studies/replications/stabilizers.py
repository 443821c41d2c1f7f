"""`haptic-teleop experiment stabilizers`: the stabilizers side by side on one scene, over delay and
loss (docs/stabilizers.md, "Side by side").

Every law (`LAWS`: EBA's reservoir and two-condition laws, TDPA with its ZOH-exact and its velocity
controller, wave variables plain and with a wave filter and drift correction, all on both sides)
runs the one-axis contact scene `wall_contact` (the wall 5 mm ahead, the operator pushing from
0.2 s toward 3 cm, as the hard cases) over every network of the grid:
one-way delay in both directions x loss (none, Bernoulli, bursty Gilbert-Elliott), on paired seeds
(seed k gives every law the same network draws). Each run is recorded to a bag and measured from
that bag alone:

- force RMS error of the master's felt force against the same law's undisturbed run (the scene
  without network effects, deterministic: run once per law) and against the wall force;
- position drift: the master-slave offset at the end against the undisturbed run's;
- the stiffness felt in contact (least-squares slope of the master's force over its position while
  the slave touches the wall) against the wall's;
- the two-port energy margin from the plant signals (both ports, the simulator's damping): passive
  while >= 0;
- the peak wall force (a law whose slave pushes the wall less feels, and errs by, less force).

Writes stabilizers_runs.csv (every run), stabilizers.csv (per law and network: mean and sample std
over seeds), stabilizers.md and stabilizers.png; the bags under bags/ (`--discard-bags`: each is
measured, then deleted).
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.replications.args import number, subset
from haptic_teleop.studies.replications.tables import finish_figure, markdown, rms, write_csv

HELP = (
    "the stabilizers side by side (EBA's two laws, TDPA with its ZOH-exact and velocity controllers, wave "
    "variables) on the "
    "one-axis contact scene over delay and loss (Bernoulli, bursty), paired seeds, every run a bag: force error, "
    "drift, felt stiffness, two-port energy margin; CSV, table, plot"
)
BASE_SCENE = "wall_contact"
GEOMETRY = (
    "slave.wall.position_m=0.005",
    "operator.start_s=0.2",
    "operator.speed_m_per_s=0.05",
    "operator.distance_m=0.03",
)
_TDPA = ("controllers.master.eba.law=tdpa", "controllers.slave.eba.law=tdpa")
LAWS: dict[str, tuple[str, tuple[str, ...]]] = {
    "reservoir": ("EBA, reservoir", ()),
    "two_condition": (
        "EBA, two conditions",
        ("controllers.master.eba.law=two_condition", "controllers.slave.eba.law=two_condition"),
    ),
    "tdpa_zoh": (
        "TDPA, ZOH-exact controller",
        (*_TDPA, "controllers.master.eba.tdpa_controller=zoh", "controllers.slave.eba.tdpa_controller=zoh"),
    ),
    "tdpa_velocity": ("TDPA, velocity controller", _TDPA),
    "wave": ("wave variables, b 20 N s/m", ("controllers.master.eba.law=wave", "controllers.slave.eba.law=wave")),
    "wave_filtered": (
        "wave variables, 50 Hz wave filter, drift 5/s",
        (
            "controllers.master.eba.law=wave",
            "controllers.slave.eba.law=wave",
            "controllers.master.eba.wave_filter_hz=50",
            "controllers.slave.eba.wave_filter_hz=50",
            "controllers.slave.eba.wave_drift_gain_per_s=5",
        ),
    ),
}
DIRS = ("forward", "backward")
DELAYS_S = (0.0, 0.05, 0.1, 0.2, 0.5)
# name -> the loss effect's YAML (both directions); None: no loss.
LOSSES: dict[str, str | None] = {
    "none": None,
    "bernoulli_10": "{model: bernoulli, probability: 0.1}",
    "bernoulli_30": "{model: bernoulli, probability: 0.3}",
    # Gilbert-Elliott, stationary loss 30 %: p = 0.03, r = 0.07, all lost in the bad state.
    "bursty_30": "{model: gilbert_elliott, p: 0.03, r: 0.07, one_minus_h: 1.0, one_minus_k: 0.0}",
}
METRICS = (
    "force_rms_error_vs_reference_n",
    "force_rms_error_vs_wall_n",
    "position_drift_m",
    "felt_stiffness_n_per_m",
    "two_port_margin_min_j",
    "contact_force_max_n",
)
RUNS_HEADER = ["law", "delay_s", "loss", "seed", *METRICS]
CONTACT_N = 0.1  # the slave touches the wall while its contact force exceeds this


def _scene(overrides: Sequence[str]) -> Any:
    from haptic_teleop.scene.load import find_scene, load_scene

    return load_scene(find_scene(BASE_SCENE), overrides=list(overrides))


def network_overrides(delay_s: float, loss: str) -> list[str]:
    """The grid's network, both directions: no other effect than this delay and this loss."""
    out = [f"network.{d}.effects={{}}" for d in DIRS]
    if delay_s > 0.0:
        out += [f"network.{d}.effects.delay={{delay_s: {delay_s}}}" for d in DIRS]
    spec = LOSSES[loss]
    if spec is not None:
        out += [f"network.{d}.effects.loss={spec}" for d in DIRS]
    return out


def _measure(bag: Path) -> dict[str, Any]:
    """What the comparison needs of one run, from its bag alone."""
    from haptic_teleop.analysis.metrics import analyze_bag

    summary, sig = analyze_bag(bag)
    return {
        "felt_n": np.asarray(sig.master_force_n, dtype=float),
        "offset_m": float(sig.master_x_m[-1] - sig.slave_x_m[-1]),
        "wall_rms_n": float(summary["force_rms_error_n"]),
        "margin_j": float(summary["two_port_energy_margin_min_j"]),
        "stiffness": felt_stiffness(sig.master_x_m, sig.master_force_n, sig.contact_n),
        "contact_max_n": float(summary["contact_force_max_n"]),
    }


def felt_stiffness(x_m: np.ndarray, force_n: np.ndarray, contact_n: np.ndarray) -> float:
    """Least-squares slope of the master's force magnitude over its position while the slave
    touches the wall (N/m; NaN with fewer than 10 such ticks)."""
    touching = np.abs(np.asarray(contact_n)) > CONTACT_N
    if np.count_nonzero(touching) < 10:
        return math.nan
    x = np.asarray(x_m)[touching]
    f = np.abs(np.asarray(force_n)[touching])
    if np.ptp(x) <= 0.0:
        return math.nan
    return float(np.polyfit(x, f, 1)[0])


def _record(overrides: Sequence[str], bag: Path) -> dict[str, Any]:
    from haptic_teleop.engine.run import record_run

    bag.parent.mkdir(parents=True, exist_ok=True)
    record_run(_scene(overrides), bag, parallel=False, handle_sigint=False)
    return _measure(bag)


def run_grid(
    laws: Sequence[str],
    delays: Sequence[float],
    losses: Sequence[str],
    seeds: Sequence[int],
    extra: Sequence[str],
    bags: Path,
    discard: bool,
    progress: Any = None,
) -> list[list[Any]]:
    """Every law over every network and seed: rows of RUNS_HEADER."""
    rows: list[list[Any]] = []
    for law in laws:
        base = (*GEOMETRY, *LAWS[law][1], *extra)
        ref_bag = bags / law / "undisturbed" / "bag"
        ref = _record((*base, *network_overrides(0.0, "none")), ref_bag)
        if discard:
            shutil.rmtree(ref_bag.parent)
        if progress is not None:
            progress.update(1)
        for delay in delays:
            for loss in losses:
                for seed in seeds:
                    bag = bags / law / f"delay_{delay * 1e3:g}ms-{loss}" / f"seed_{seed}" / "bag"
                    m = _record((*base, *network_overrides(delay, loss), f"scene.seed={seed}"), bag)
                    if discard:
                        shutil.rmtree(bag.parent)
                    rows.append(
                        [
                            law, delay, loss, seed,
                            rms(m["felt_n"] - ref["felt_n"]),
                            m["wall_rms_n"],
                            m["offset_m"] - ref["offset_m"],
                            m["stiffness"],
                            m["margin_j"],
                            m["contact_max_n"],
                        ]
                    )  # fmt: skip
                    if progress is not None:
                        progress.update(1)
    return rows


def summarize(rows: Sequence[Sequence[Any]]) -> list[list[Any]]:
    """Per law and network: mean and sample std over the seeds of every metric, and the passive
    share (runs whose two-port margin stayed >= 0)."""
    groups: dict[tuple[str, float, str], list[Sequence[Any]]] = {}
    for r in rows:
        groups.setdefault((r[0], r[1], r[2]), []).append(r)
    out = []
    for (law, delay, loss), rs in groups.items():
        cells: list[Any] = [law, delay, loss, len(rs)]
        for j in range(len(METRICS)):
            v = np.array([r[4 + j] for r in rs], dtype=float)
            v = v[np.isfinite(v)]
            cells += [float(np.mean(v)) if v.size else math.nan, float(np.std(v, ddof=1)) if v.size > 1 else math.nan]
        cells.append(sum(1 for r in rs if r[4 + METRICS.index("two_port_margin_min_j")] >= 0.0) / len(rs))
        out.append(cells)
    return out


TABLE_HEADER = (
    ["law", "delay_s", "loss", "seeds"] + [f"{m}_{s}" for m in METRICS for s in ("mean", "std")] + ["passive_share"]
)


def markdown_table(table: Sequence[Sequence[Any]], wall_stiffness: float) -> str:
    head = [
        "law", "one-way delay (ms)", "loss", "force error vs undisturbed (N)", "force error vs wall (N)",
        "drift (mm)", f"felt stiffness (N/m; wall {wall_stiffness:g})", "two-port margin min (J)",
        "peak wall force (N)", "passive",
    ]  # fmt: skip
    body = []
    for r in table:
        cells = []
        for j, scale in ((0, 1.0), (1, 1.0), (2, 1e3), (3, 1.0), (4, 1.0), (5, 1.0)):
            mean, std = r[4 + 2 * j], r[5 + 2 * j]
            if not math.isfinite(mean):
                cells.append("n/a")
            else:
                cells.append(f"{mean * scale:.3g}" + (f" ± {std * scale:.2g}" if math.isfinite(std) else ""))
        body.append([LAWS[r[0]][0], f"{r[1] * 1e3:g}", r[2], *cells, f"{r[-1]:.0%}"])
    return markdown(head, body)


def plot(table: Sequence[Sequence[Any]], laws: Sequence[str], losses: Sequence[str], path: Path) -> None:
    """Per loss: the force error against the undisturbed run, the peak wall force and the two-port
    margin over the delay, one line per law (mean over seeds, the std as a band)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, len(losses), figsize=(4.2 * len(losses), 10.5), squeeze=False)
    for li, loss in enumerate(losses):
        panels = ((0, "force error vs undisturbed [N]"), (5, "peak wall force [N]"), (4, "two-port margin min [J]"))
        for row, (j, label) in enumerate(panels):
            ax = axes[row][li]
            for k, law in enumerate(laws):
                rs = sorted((r for r in table if r[0] == law and r[2] == loss), key=lambda r: r[1])
                d = np.array([r[1] * 1e3 for r in rs])
                m = np.array([r[4 + 2 * j] for r in rs])
                s = np.nan_to_num(np.array([r[5 + 2 * j] for r in rs]))
                ax.plot(d, m, "o-", color=f"C{k}", label=LAWS[law][0], ms=4)
                ax.fill_between(d, m - s, m + s, color=f"C{k}", alpha=0.15)
            if j == 4:
                ax.axhline(0.0, color="k", lw=0.8)
            ax.set_xlabel("one-way delay [ms]")
            ax.set_ylabel(label)
            ax.set_title(f"loss: {loss}", fontsize=10)
    finish_figure(fig, [a for row in axes for a in row], path, fontsize=7)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="output directory, new or empty (default runs/stabilizers-NNN)")
    p.add_argument("--seeds", type=number(1, 1000, kind=int), default=2, help="seeds 1..N (paired across laws)")
    p.add_argument("--laws", default=",".join(LAWS), help=f"which laws ({', '.join(LAWS)})")
    p.add_argument("--losses", default=",".join(LOSSES), help=f"which losses ({', '.join(LOSSES)})")
    p.add_argument(
        "--delays-ms", default=",".join(f"{d * 1e3:g}" for d in DELAYS_S), help="one-way delays (ms), both ways"
    )
    p.add_argument("--duration-s", type=number(0.5, 60.0), default=3.0, help="each run's length (s)")
    p.add_argument("--discard-bags", action="store_true", help="measure each bag, then delete it")
    p.add_argument("--quick", action="store_true", help="1 seed, delays 0 and 100 ms, no loss and bursty, 1.5 s")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key of the base scene")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def _delays(text: str) -> list[float]:
    from haptic_teleop.errors import InputError

    try:
        ms = [float(c) for c in text.split(",") if c.strip()]
    except ValueError:
        ms = []
    if not ms or any(not 0.0 <= d <= 2000.0 for d in ms):
        raise InputError(f"--delays-ms {text}: allowed: comma-separated numbers from 0 to 2000")
    return [d * 1e-3 for d in ms]


def main(args: argparse.Namespace) -> int:
    from haptic_teleop.analysis.outputs import check_out_dir, default_out

    laws = subset(args.laws, list(LAWS), "--laws")
    losses = subset(args.losses, list(LOSSES), "--losses")
    delays = _delays(args.delays_ms)
    seeds = int(args.seeds)
    duration = float(args.duration_s)
    if args.quick:
        seeds, duration, delays = 1, 1.5, [0.0, 0.1]
        losses = [x for x in losses if x in ("none", "bursty_30")] or losses[:1]
    extra = (f"scene.duration_s={duration}", *(args.set or ()))
    for law in laws:  # a bad --set fails here, before anything is written
        _scene((*GEOMETRY, *LAWS[law][1], *extra, *network_overrides(delays[-1], losses[-1])))
    out = Path(args.out) if args.out else default_out("stabilizers")
    check_out_dir(out)
    total = len(laws) * (1 + len(delays) * len(losses) * seeds)
    from tqdm import tqdm

    with tqdm(total=total, unit="run", disable=args.quiet, desc="stabilizers") as bar:
        rows = run_grid(laws, delays, losses, range(1, seeds + 1), extra, out / "bags", args.discard_bags, bar)
    if args.discard_bags:
        shutil.rmtree(out / "bags", ignore_errors=True)
    table = summarize(rows)
    wall = float(_scene((*GEOMETRY, *extra)).config.slave.wall.stiffness_n_per_m)
    text = markdown_table(table, wall)
    write_csv(out / "stabilizers_runs.csv", RUNS_HEADER, rows)
    write_csv(out / "stabilizers.csv", TABLE_HEADER, table)
    (out / "stabilizers.md").write_text(text)
    plot(table, laws, losses, out / "stabilizers.png")
    if not args.quiet:
        sys.stdout.write(text)
        sys.stdout.write(f"{out / 'stabilizers.png'}\n")
    return 0
