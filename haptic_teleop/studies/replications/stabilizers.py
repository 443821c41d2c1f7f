"""`haptic-teleop experiment stabilizers`: the stabilizers side by side over delay and loss, on the
one-axis and the arm scene (docs/stabilizers_compared.md).

Every law (`LAWS`: EBA's reservoir and two-condition laws, TDPA with its ZOH-exact controller,
the same keeping half its input, and its velocity controller, wave variables plain and with a wave
filter and drift correction, all on both sides) runs the one-axis contact scene `wall_contact` (the
wall 5 mm ahead, the operator pushing from 0.2 s toward 3 cm, as the hard cases), and the laws arms
run (`ARM_LAWS`) the arm scene `ARM_SCENE` in its own geometry, over every network of the grid:
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
measured, then deleted). Then, unless --no-z-width, the Z-width sweep (zwidth.py: every law over
wall stiffness x wall damping per delay) into the same directory: zwidth_runs.csv, zwidth.md,
zwidth.png, its bags under zwidth_bags/.
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
from haptic_teleop.studies.replications.recorded import compression
from haptic_teleop.studies.replications.stabilizer_runs import (
    ARM_LAWS,
    ARM_SCENE,
    BASE_SCENE,
    GEOMETRY,
    LAWS,
    LOSSES,
    drift_m,
    measure,
    measure_task,
    network_overrides,
    number_list,
    record,
    scene,
)
from haptic_teleop.studies.replications.tables import finish_figure, markdown, rms, write_csv

HELP = (
    "the stabilizers side by side (EBA's two laws, TDPA with its ZOH-exact and velocity controllers and energy "
    "reflection, wave variables) on a one-axis and an arm contact scene over delay and loss (Bernoulli, bursty), "
    "paired seeds, and the Z-width over walls; every run a bag: force error, drift, felt stiffness, two-port "
    "energy margin; CSV, tables, plots"
)
DELAYS_S = (0.0, 0.05, 0.1, 0.2, 0.5)

METRICS = (
    "force_rms_error_vs_reference_n",
    "force_rms_error_vs_wall_n",
    "position_drift_m",
    "felt_stiffness_n_per_m",
    "two_port_margin_min_j",
    "contact_force_max_n",
)

RUNS_HEADER = ["law", "delay_s", "loss", "seed", *METRICS]


def run_grid(
    laws: Sequence[str],
    delays: Sequence[float],
    losses: Sequence[str],
    seeds: Sequence[int],
    extra: Sequence[str],
    bags: Path,
    discard: bool,
    progress: Any = None,
    arm: bool = False,
) -> list[list[Any]]:
    """Every law over every network and seed on the one-axis scene (`arm`: the arm scene,
    ARM_SCENE in its own geometry): rows of RUNS_HEADER."""
    base_scene, geometry, measure_bag = (ARM_SCENE, (), measure_task) if arm else (BASE_SCENE, GEOMETRY, measure)
    rows: list[list[Any]] = []
    for law in laws:
        base = (*geometry, *LAWS[law][1], *extra)
        ref_bag = bags / law / "undisturbed" / "bag"
        ref = record((*base, *network_overrides(0.0, "none")), ref_bag, measure_bag, base_scene)
        if discard:
            shutil.rmtree(ref_bag.parent)
        if progress is not None:
            progress.update(1)
        for delay in delays:
            for loss in losses:
                for seed in seeds:
                    bag = bags / law / f"delay_{delay * 1e3:g}ms-{loss}" / f"seed_{seed}" / "bag"
                    overrides = (*base, *network_overrides(delay, loss), f"scene.seed={seed}")
                    m = record(overrides, bag, measure_bag, base_scene)
                    if discard:
                        shutil.rmtree(bag.parent)
                    rows.append(
                        [
                            law, delay, loss, seed,
                            force_error_n(m["felt_n"], ref["felt_n"]),
                            m["wall_rms_n"],
                            drift_m(m["offset_m"], ref["offset_m"]),
                            m["stiffness"],
                            m["margin_j"],
                            m["contact_max_n"],
                        ]
                    )  # fmt: skip
                    if progress is not None:
                        progress.update(1)
    return rows


def force_error_n(felt_n: np.ndarray, reference_n: np.ndarray) -> float:
    """RMS over ticks of the felt force's difference from the undisturbed run's (its norm on an arm)."""
    d = felt_n - reference_n
    return rms(d if d.ndim == 1 else np.linalg.norm(d, axis=1))


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
    p.add_argument(
        "--quick",
        action="store_true",
        help="1 seed, delays 0 and 100 ms, no loss and bursty, 1.5 s; Z-width: walls 1000, 30000 N/m x 0, 10 N s/m "
        "at 100 ms",
    )
    p.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a key of the one-axis scene (not the arm's)"
    )
    p.add_argument(
        "--no-arm",
        action="store_true",
        help=f"skip the arm scene ({ARM_SCENE}: the laws of {', '.join(ARM_LAWS)} that --laws names)",
    )
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    from haptic_teleop.studies.replications import zwidth

    zwidth.add_arguments(p)


def _delays(text: str) -> list[float]:
    return [d * 1e-3 for d in number_list(text, "--delays-ms", 0.0, 2000.0)]


def main(args: argparse.Namespace) -> int:
    from haptic_teleop.analysis.outputs import check_out_dir, default_out
    from haptic_teleop.studies.replications import zwidth

    laws = subset(args.laws, list(LAWS), "--laws")
    losses = subset(args.losses, list(LOSSES), "--losses")
    delays = _delays(args.delays_ms)
    seeds = int(args.seeds)
    duration = float(args.duration_s)
    if args.quick:
        seeds, duration, delays = 1, 1.5, [0.0, 0.1]
        losses = [x for x in losses if x in ("none", "bursty_30")] or losses[:1]
    plain = (compression(args.discard_bags),)
    extra = (*plain, f"scene.duration_s={duration}", *(args.set or ()))
    # The arm scene: the laws it runs, its own geometry, only the run's length from the options.
    arm_laws = [] if args.no_arm else [law for law in laws if law in ARM_LAWS]
    arm_extra = (*plain, f"scene.duration_s={duration}")
    sweep = zwidth.grid(args)
    for law in laws:  # a bad --set fails here, before anything is written
        scene((*GEOMETRY, *LAWS[law][1], *extra, *network_overrides(delays[-1], losses[-1])))
    for law in arm_laws:
        scene((*LAWS[law][1], *arm_extra, *network_overrides(delays[-1], losses[-1])), ARM_SCENE)
    if sweep is not None:
        zwidth.check_scenes(laws, sweep, extra)
        zwidth.check_scenes(arm_laws, sweep, arm_extra, arm=True)
    out = Path(args.out) if args.out else default_out("stabilizers")
    check_out_dir(out)
    per_law = 1 + len(delays) * len(losses) * seeds
    total = (len(laws) + len(arm_laws)) * per_law + (zwidth.count([*laws, *arm_laws], sweep) if sweep else 0)
    from tqdm import tqdm

    with tqdm(total=total, unit="run", disable=args.quiet, desc="stabilizers") as bar:
        rows = run_grid(laws, delays, losses, range(1, seeds + 1), extra, out / "bags", args.discard_bags, bar)
        arm_rows = run_grid(
            arm_laws, delays, losses, range(1, seeds + 1), arm_extra, out / "arm_bags", args.discard_bags, bar, True
        )
        z_rows = zwidth.run_sweep(laws, *sweep, extra, out / "zwidth_bags", args.discard_bags, bar) if sweep else []
        z_arm = (
            zwidth.run_sweep(arm_laws, *sweep, arm_extra, out / "zwidth_arm_bags", args.discard_bags, bar, True)
            if sweep
            else []
        )
    if args.discard_bags:
        shutil.rmtree(out / "bags", ignore_errors=True)
        shutil.rmtree(out / "arm_bags", ignore_errors=True)
    texts = [_write(rows, laws, losses, float(scene((*GEOMETRY, *extra)).config.slave.wall.stiffness_n_per_m), out,
                    "stabilizers")]  # fmt: skip
    if arm_laws:
        wall = float(scene(arm_extra, ARM_SCENE).config.slave.wall.stiffness_n_per_m)
        texts.append(_write(arm_rows, arm_laws, losses, wall, out, "stabilizers_arm"))
    if sweep:
        texts.append(zwidth.write(z_rows, laws, sweep, duration, out) + f"{out / 'zwidth.png'}\n")
    if sweep and arm_laws:
        texts.append(zwidth.write(z_arm, arm_laws, sweep, duration, out, arm=True) + f"{out / 'zwidth_arm.png'}\n")
    if not args.quiet:
        sys.stdout.write("\n".join(texts))
    return 0


def _write(
    rows: Sequence[Sequence[Any]], laws: Sequence[str], losses: Sequence[str], wall: float, out: Path, stem: str
) -> str:
    """One scene's grid: STEM_runs.csv, STEM.csv, STEM.md and STEM.png; returns the table and the
    plot's path."""
    table = summarize(rows)
    text = markdown_table(table, wall)
    write_csv(out / f"{stem}_runs.csv", RUNS_HEADER, rows)
    write_csv(out / f"{stem}.csv", TABLE_HEADER, table)
    (out / f"{stem}.md").write_text(text)
    plot(table, laws, losses, out / f"{stem}.png")
    return text + f"{out / f'{stem}.png'}\n"
