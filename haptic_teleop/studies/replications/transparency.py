"""`haptic-teleop experiment transparency`: seed 000's EBA transparency analysis, predicted against
measured (docs/transparency.md).

The base is the bundled scene seed_contact (the robot at rest against the wall with F0, the master
driven toward it at v_m: the seed's premise), run in four configurations: the master's law
(position-position or force reflection) by whether its energy bound binds (2 b_m / T below the
law's stiffness) or not. For each one:

1. over one-way delays (the same both ways): the force slope in contact and the force drop at the
   ramp's end against the undelayed run, each predicted (core/transparency.py) and measured;
2. over backward loss bursts (a blackout of the backward link in the middle of the ramp): the
   transparent loss time (how long the felt force still rises while the master holds its last
   sample), predicted and measured;
3. the free start the issue measured (the default scene with a stiff hand, the bound binding or
   not): the master's reservoir and lead at the robot's first contact and the felt and wall forces
   a fixed time after it, over delay: why delay raises the felt force there.

Every run is the engine in memory (deterministic); the measurements are the analysis'
(analysis/transparency.py) on the runs' columns. Writes transparency_delay.csv,
transparency_loss.csv, transparency_free_start.csv, transparency.png and the markdown tables.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.replications.args import number
from haptic_teleop.studies.replications.recorded import BagRuns, bags_line, compression, record_ticks
from haptic_teleop.studies.replications.tables import finish_figure, markdown, write_csv

HELP = (
    "seed 000's EBA transparency analysis: force slope, force drop over delay and transparent loss time over "
    "loss bursts, predicted against measured, on the seed's premise (scene seed_contact); plot, CSV and tables"
)
BASE_SCENE = "seed_contact"
# The ramp long enough for the longest round trip, slow enough that no configuration saturates.
BASE = (
    "operator.speed_m_per_s=0.01",
    "operator.duration_s=3.0",
    "scene.duration_s=3.6",
    "controllers.master.force_limit_n=30",
)
CONFIGS = {
    "pp_binding": ("position-position, bound binding", ("master.damping_n_s_per_m=0.1",)),
    "pp_free": ("position-position, bound not binding", ("master.damping_n_s_per_m=1.0",)),
    "fr_binding": (
        "force reflection (g 0.5), bound binding",
        ("controllers.master.law=force", "controllers.master.force_gain=0.5", "master.damping_n_s_per_m=0.1"),
    ),
    "fr_binding_two_condition": (
        "force reflection (g 0.5), bound binding, two-condition law",
        (
            "controllers.master.law=force",
            "controllers.master.force_gain=0.5",
            "master.damping_n_s_per_m=0.1",
            "controllers.master.eba.law=two_condition",
        ),
    ),
    "fr_free": (
        "force reflection, bound not binding",
        ("controllers.master.law=force", "master.damping_n_s_per_m=1.0"),
    ),
}
BURST_AT_S = 1.0  # after the ramp starts: the blackout's start on the backward link


@dataclass(frozen=True)
class Run:
    t_s: np.ndarray
    felt_n: np.ndarray
    desired_n: np.ndarray
    x_m: np.ndarray
    bwd_rx: np.ndarray
    energy_j: np.ndarray
    contact_n: np.ndarray


def _scene(overrides: Sequence[str]) -> Any:
    from haptic_teleop.scene.load import find_scene, load_scene

    return load_scene(find_scene(BASE_SCENE), overrides=list(overrides))


def _run(overrides: Sequence[str], runs: BagRuns, key: str) -> tuple[Run, Any]:
    """One run recorded to its bag; what the tables use read back from the bag."""
    scene = _scene(overrides)
    with runs.bag(key, overrides=overrides) as bag:
        t = record_ticks(scene, bag)
    return (
        Run(
            t_s=np.arange(t.rows.shape[0]) * scene.config.scene.period_s,
            felt_n=np.abs(t.column("m_force_n")),
            desired_n=np.abs(t.column("m_force_desired_n")),
            x_m=t.column("m_x_m"),
            bwd_rx=t.column("bwd_rx_seq"),
            energy_j=t.column("m_energy_j"),
            contact_n=np.abs(t.column("s_contact_n")),
        ),
        scene,
    )


def _delay(d: float) -> tuple[str, ...]:
    return tuple(f"network.{k}.effects={{delay: {{delay_s: {d!r}}}}}" for k in ("forward", "backward"))


def _model(scene: Any) -> Any:
    """The analysis' contact model of a scene (the master's damping: the scene's, as the plant has it)."""

    from haptic_teleop.analysis.transparency import contact_model

    run_info = {"master_joint_damping": [scene.config.master.damping_n_s_per_m]}
    return contact_model(scene.config, run_info, scene.config.operator.speed_m_per_s)


def _ramp(scene: Any) -> tuple[int, int]:
    op, T = scene.config.operator, scene.config.scene.period_s
    return round(op.start_s / T), round((op.start_s + (op.duration_s or 0.0)) / T)


def delay_table(
    configs: Sequence[str], delays_s: Sequence[float], extra: Sequence[str], runs: BagRuns
) -> list[list[Any]]:
    from haptic_teleop.core.transparency import force_drop, force_slope_between

    rows = []
    for key in configs:
        label, ov = CONFIGS[key]
        ref: Run | None = None
        for d in delays_s:
            run, scene = _run((*BASE, *ov, *_delay(d), *extra), runs, f"delay_{key}_{d * 1e3:g}ms")
            first, last = _ramp(scene)
            w0 = first + (last - first) // 2
            slope = float(np.polyfit(run.t_s[w0 : last + 1], run.felt_n[w0 : last + 1], 1)[0])
            if ref is None:
                ref = run  # the first delay is 0: the undisturbed run
            m = _model(scene)
            law = scene.config.controllers.master.eba.law
            T = scene.config.scene.period_s
            s_pred = force_slope_between(m, d, d, (w0 - first) * T, (last - first) * T, law)
            drop = force_drop(m, d, d, law, at_s=(last - first) * T)
            drop_meas = float(ref.felt_n[last] - run.felt_n[last])
            rows.append(
                [
                    label,
                    d * 1e3,
                    s_pred,
                    slope,
                    (slope - s_pred) / s_pred * 100.0,
                    drop.drop_n,
                    drop_meas,
                    drop_meas - drop.drop_n,
                    "binding" if m.binding else "not binding",
                ]
            )
    return rows


DELAY_HEADER = [
    "configuration",
    "delay_each_way_ms",
    "force_slope_predicted_n_per_s",
    "force_slope_measured_n_per_s",
    "slope_error_pct",
    "force_drop_predicted_n",
    "force_drop_measured_n",
    "drop_error_n",
    "bound",
]


def loss_table(
    configs: Sequence[str], bursts_s: Sequence[float], extra: Sequence[str], runs: BagRuns
) -> list[list[Any]]:
    from haptic_teleop.analysis.transparency import longest_hold, rise_ticks
    from haptic_teleop.core.transparency import transparent_loss_time

    rows = []
    for key in configs:
        label, ov = CONFIGS[key]
        for burst in bursts_s:
            scene = _scene((*BASE, *ov, *extra))
            start = scene.config.operator.start_s + BURST_AT_S
            blackout = f"network.backward.effects.blackout={{starts_s: [{start!r}], ends_s: [{start + burst!r}]}}"
            run, scene = _run((*BASE, *ov, blackout, *extra), runs, f"loss_{key}_{burst * 1e3:g}ms")
            first, last = _ramp(scene)
            T = scene.config.scene.period_s
            released = np.flatnonzero(run.bwd_rx >= 0) * T
            hold = longest_hold(released, T, first, last)
            if hold is None:
                continue
            a, b = hold
            held = (b - a - 1) * T
            m = _model(scene)
            gap = float(run.desired_n[a + 1] - run.felt_n[a + 1])
            t_tr = transparent_loss_time(m, gap, float(run.felt_n[a + 1]), scene.config.controllers.master.eba.law)
            pred = min(held, t_tr)
            meas = rise_ticks(run.felt_n, a, b) * T
            rows.append([label, burst * 1e3, held * 1e3, gap, t_tr * 1e3, pred * 1e3, meas * 1e3, (meas - pred) * 1e3])
    return rows


LOSS_HEADER = [
    "configuration",
    "burst_ms",
    "hold_ms",
    "desired_minus_felt_at_onset_n",
    "transparent_loss_time_formula_ms",
    "transparent_loss_time_predicted_ms",
    "transparent_loss_time_measured_ms",
    "error_ms",
]


def free_start_table(delays_s: Sequence[float], after_s: float, runs: BagRuns) -> list[list[Any]]:
    """The issue's free start: wall_contact with a stiff hand, the bound binding (b_m 0.1) or not
    (1.0); each run recorded to its bag and measured from it."""
    from haptic_teleop.scene.load import find_scene, load_scene

    rows = []
    for b_m in (0.1, 1.0):
        ref_f = None
        for d in delays_s:
            ov = [
                compression(runs.discard),
                "scene.duration_s=4.0",
                "operator.stiffness_n_per_m=100000",
                "operator.damping_n_s_per_m=500",
                f"master.damping_n_s_per_m={b_m!r}",
                *_delay(d),
            ]
            scene = load_scene(find_scene("wall_contact"), overrides=ov)
            with runs.bag(f"free_start_{b_m:g}_{d * 1e3:g}ms", overrides=ov) as bag:
                t = record_ticks(scene, bag)
            T = scene.config.scene.period_s
            contact_n = t.column("s_contact_n")
            contact = np.flatnonzero(np.abs(contact_n) > 0.0)
            if not contact.size:
                continue
            c = int(contact[0])
            k = min(c + round(after_s / T), t.rows.shape[0] - 1)
            felt = float(abs(t.column("m_force_n")[k]))
            if ref_f is None:
                ref_f = felt
            rows.append(
                [
                    b_m,
                    d * 1e3,
                    c * T,
                    float(t.column("m_energy_j")[c]),
                    float(t.column("m_x_m")[c] - t.column("s_x_m")[c]),
                    felt,
                    felt - ref_f,
                    float(abs(contact_n[k])),
                ]
            )
    return rows


FREE_HEADER = [
    "master_damping_n_s_per_m",
    "delay_each_way_ms",
    "slave_contact_s",
    "master_reservoir_at_contact_j",
    "master_ahead_of_slave_at_contact_m",
    "felt_force_after_n",
    "felt_minus_undelayed_n",
    "wall_force_after_n",
]


def _plot(delay_rows: list[list[Any]], loss_rows: list[list[Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    labels = list(dict.fromkeys(r[0] for r in delay_rows))
    for i, label in enumerate(labels):
        rows = [r for r in delay_rows if r[0] == label]
        colour = f"C{i}"
        a1.plot([r[1] for r in rows], [r[5] for r in rows], "-", color=colour, label=f"{label}: predicted")
        a1.plot([r[1] for r in rows], [r[6] for r in rows], "o", color=colour, label=f"{label}: measured")
    a1.set(xlabel="one-way delay, each way [ms]", ylabel="force drop at the ramp's end [N]", title="force drop")
    for i, label in enumerate(dict.fromkeys(r[0] for r in loss_rows)):
        rows = [r for r in loss_rows if r[0] == label]
        colour = f"C{i}"
        a2.plot([r[2] for r in rows], [r[5] for r in rows], "-", color=colour, label=f"{label}: predicted")
        a2.plot([r[2] for r in rows], [r[6] for r in rows], "o", color=colour, label=f"{label}: measured")
    a2.set(
        xlabel="hold of the master's sample [ms]", ylabel="felt force still rising [ms]", title="transparent loss time"
    )
    finish_figure(fig, (a1, a2), path, fontsize=6)


def _list(text: str) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: comma-separated numbers of ms") from None
    if not vals or any(not 0.0 <= v <= 2000.0 for v in vals):
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: comma-separated numbers of ms in [0, 2000]")
    return vals


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="output directory, new or empty (default runs/transparency-NNN)")
    p.add_argument("--delays-ms", type=_list, default=[0, 50, 100, 200, 300, 500], help="one-way delays (ms)")
    p.add_argument("--bursts-ms", type=_list, default=[5, 10, 20, 50, 100, 200], help="backward blackouts (ms)")
    p.add_argument("--configs", default=",".join(CONFIGS), help=f"which configurations ({', '.join(CONFIGS)})")
    p.add_argument(
        "--after-s", type=number(0.01, 2.0), default=0.5, help="free start: the felt force this long after contact"
    )
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key of the base scene")
    p.add_argument("--discard-bags", action="store_true", help="measure each run's bag, then delete it")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def main(args: argparse.Namespace) -> int:
    from haptic_teleop.analysis.outputs import check_out_dir, default_out
    from haptic_teleop.errors import InputError

    configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    bad = [c for c in configs if c not in CONFIGS]
    if bad or not configs:
        raise InputError(f"--configs {args.configs}: allowed: a comma-separated subset of {', '.join(CONFIGS)}")
    delays = sorted({d / 1e3 for d in args.delays_ms} | {0.0})
    extra = (compression(args.discard_bags), *(args.set or ()))
    for _, ov in (CONFIGS[c] for c in configs):  # a bad --set fails here, before anything is written
        _scene((*BASE, *ov, *extra))
    out = Path(args.out) if args.out else default_out("transparency")
    check_out_dir(out)
    runs = BagRuns(out / "bags", args.discard_bags)
    delay_rows = delay_table(configs, delays, extra, runs)
    loss_rows = loss_table(configs, [b / 1e3 for b in args.bursts_ms], extra, runs)
    free_rows = free_start_table(delays, args.after_s, runs)
    tables = []
    for name, header, rows in (
        ("transparency_delay", DELAY_HEADER, delay_rows),
        ("transparency_loss", LOSS_HEADER, loss_rows),
        ("transparency_free_start", FREE_HEADER, free_rows),
    ):
        write_csv(out / f"{name}.csv", header, rows)
        table = markdown(header, rows)
        (out / f"{name}.md").write_text(table)
        tables.append(table)
    _plot(delay_rows, loss_rows, out / "transparency.png")
    if not args.quiet:
        sys.stdout.write("\n".join(tables))
        sys.stdout.write(f"\n{out / 'transparency.png'}\n{bags_line(out, args.discard_bags)}\n")
    return 0
