"""`haptic-teleop report RESULTS_OR_BAGS ...`: the report's sections from the runs, then the files.

Sections, each only when its data exists (docs/report.md):

1. Overview (always): the inputs, the swept keys and their values, the seeds, a table of the runs.
2. Predicted against measured: every metric pair `<stem>_predicted_<unit>` / `<stem>_measured_<unit>`.
3. Metrics against parameters: per numeric swept key, the chosen metrics' mean and spread over
   seeds, one line per value of a second swept key.
4. Comparisons per category: per categorical swept key (a buffer policy, a law), each metric per
   category and the differences to a baseline category paired by seed.
5. Per-run drill-down: the time plots of analysis/plots.py for the first `--max-runs` runs that have
   a bag (or a run directory's plots/).
"""

from __future__ import annotations

import argparse
import math
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from haptic_teleop.errors import HapticTeleopError, InputError
from haptic_teleop.studies.document.document import Block, Document, Image, Para, Section, Table
from haptic_teleop.studies.document.inputs import Inputs, Run
from haptic_teleop.studies.document.stats import (
    Key,
    Paired,
    fmt,
    fmt_spread,
    fmt_value,
    group_by,
    label_of,
    metric_names,
    paired_difference,
    prediction_error,
    prediction_pairs,
    spread,
    swept_keys,
)

MAX_RUNS = 12
MAX_TABLE_ROWS = 200
FALLBACK_METRICS = 6
DRILL_PLOTS = ("forces.png", "positions.png", "paths.png", "network.png")


def choose_metrics(
    requested: str | None, available: Sequence[str], runs: Sequence[Run], sweep_metrics: Sequence[str] = ()
) -> tuple[list[str], str]:
    """The metrics of sections 3 and 4 and a sentence saying where they came from: `--metrics`,
    else the sweep file's own (`sweep_metrics`, from sweep.json beside a sweep's table), else the
    sweeps' defaults, else the first that vary."""
    from haptic_teleop.studies.batch.aggregate import DEFAULT_METRICS
    from haptic_teleop.studies.batch.plan import split_values

    if requested:
        chosen = [m.strip() for m in split_values(requested) if m.strip()]
        for m in chosen:
            if m not in available:
                raise InputError(f"--metrics {m}: not a metric of the inputs; allowed: {', '.join(available)}")
        return list(dict.fromkeys(chosen)), "the metrics given by --metrics"
    chosen = [m for m in sweep_metrics if m in available]
    if chosen:
        return chosen, "the metrics the sweep file lists (`--metrics` chooses others)"
    chosen = [m for m in DEFAULT_METRICS if m in available]
    if chosen:
        return chosen, "the sweep's default metrics (`--metrics` chooses others)"
    varying = [m for m in available if len({r.metrics.get(m) for r in runs if math.isfinite(r.metrics[m])}) > 1]
    chosen = (varying or list(available))[:FALLBACK_METRICS]
    return chosen, (
        f"none of the sweep's default metrics is in the inputs: the first {len(chosen)} metrics that vary "
        "(`--metrics` chooses others)"
    )


def category_baselines(keys: Sequence[Key], requested: str | None) -> dict[str, Any]:
    """Each categorical key's baseline: `--baseline` where it is one of its values, else its first."""
    cats = [k for k in keys if not k.numeric]
    out = {}
    found = requested is None
    for k in cats:
        match = [v for v in k.values if requested is not None and fmt_value(v) == requested]
        found = found or bool(match)
        out[k.name] = match[0] if match else k.values[0]
    if not found:
        values = sorted({fmt_value(v) for k in cats for v in k.values})
        allowed = f"one of {', '.join(values)}" if values else "nothing (no categorical key varies in the inputs)"
        raise InputError(f"--baseline {requested}: not a value of a categorical swept key; allowed: {allowed}")
    return out


# ------------------------------------------------------------------------------------------------
# sections


def short_names(names: Sequence[str]) -> dict[str, str]:
    """Each dotted key path's shortest ending (whole dotted parts) that no other of `names` ends in:
    the column headers of wide tables, with the full paths in the swept keys' legend
    ("network.backward.effects.delay.delay_s" -> "delay_s" beside "network.backward.buffer.policy"
    -> "policy"; two "delay_s" keys keep as many parts as they need to differ)."""
    parts = {n: n.split(".") for n in names}
    out = {}
    for n, p in parts.items():
        for k in range(1, len(p) + 1):
            end = ".".join(p[-k:])
            if not any(o != n and (o == end or o.endswith("." + end)) for o in names):
                break
        out[n] = end
    return out


def _values(values: Sequence[Any]) -> str:
    return ", ".join(fmt_value(v) for v in values)


def overview(inputs: Inputs, keys: Sequence[Key], metrics: Sequence[str], why: str) -> Section:
    runs = inputs.runs
    s = Section("overview", "Overview")
    s.blocks.append(Para(f"{len(runs)} runs from {len(inputs.sources)} input(s):"))
    s.blocks.append(Table(("input", "read as"), tuple(tuple(_split_source(x)) for x in inputs.sources)))
    short = short_names([k.name for k in keys])
    if keys:
        s.blocks.append(
            Table(
                ("column", "swept key", "kind", "values"),
                tuple((short[k.name], k.name, "number" if k.numeric else "category", _values(k.values)) for k in keys),
                caption="Scene keys whose value differs between the runs (the tables name each by its column)",
            )
        )
        if any(k.paths == ("scene.name",) for k in keys):
            s.blocks.append(
                Para(
                    "The runs come from different scenes: every key in which those scenes differ is "
                    "listed as swept, and the sections below treat each as a parameter."
                )
            )
    else:
        s.blocks.append(Para("No scene key differs between the runs."))
    seeds = sorted({r.seed for r in runs if r.seed is not None})
    if seeds:
        s.blocks.append(Para(f"Seeds: {', '.join(map(str, seeds))}."))
    s.blocks.append(Para(f"Metrics shown: {', '.join(f'`{m}`' for m in metrics)}: {why}."))
    header = ("run", *(short[k.name] for k in keys), "seed", *(label_of(m) for m in metrics))
    rows = [
        (
            r.label,
            *(fmt_value(k.of(r)) for k in keys),
            "" if r.seed is None else str(r.seed),
            *(fmt(r.metrics.get(m, math.nan)) for m in metrics),
        )
        for r in runs[:MAX_TABLE_ROWS]
    ]
    cap = "Every run" if len(runs) <= MAX_TABLE_ROWS else f"The first {MAX_TABLE_ROWS} of {len(runs)} runs"
    s.blocks.append(Table(header, tuple(rows), caption=cap))
    for note in inputs.notes:
        s.blocks.append(Para(note))
    return s


def _split_source(text: str) -> list[str]:
    path, _, what = text.rpartition(": ")
    return [f"`{path}`", what]


def prediction_section(runs: Sequence[Run], keys: Sequence[Key], metrics: Sequence[str]) -> Section | None:
    from haptic_teleop.studies.document.figures import png, prediction_figure

    pairs = prediction_pairs(metrics)
    pairs = [p for p in pairs if prediction_error(runs, p).n > 0]
    if not pairs:
        return None
    s = Section("predicted-against-measured", "Predicted against measured")
    s.blocks.append(
        Para(
            "Each summary key pair `<stem>_predicted_<unit>` / `<stem>_measured_<unit>`: every run's "
            "measured value against the theory's prediction for it. On the dashed line the prediction "
            "is exact; error = measured - predicted."
        )
    )
    color = keys[0] if keys else None
    caption = f"Points coloured by `{color.name}`." if color else ""
    s.blocks.append(
        Image("predicted-measured", png(prediction_figure(runs, pairs, color)), "measured against predicted", caption)
    )
    rows = []
    for p in pairs:
        e = prediction_error(runs, p)
        rel = "n/a" if math.isnan(e.mean_abs_relative_pct) else f"{e.mean_abs_relative_pct:.3g} %"
        rows.append(
            (
                p.label,
                str(e.n),
                fmt(e.predicted_mean),
                fmt(e.measured_mean),
                fmt(e.mean_error),
                fmt(e.rms_error),
                fmt(e.max_abs_error),
                rel,
            )
        )
    s.blocks.append(
        Table(
            (
                "quantity (unit)",
                "runs",
                "mean predicted",
                "mean measured",
                "mean error",
                "RMS error",
                "max abs error",
                "mean abs relative error",
            ),
            tuple(rows),
            caption="Prediction error over the runs that have both numbers (relative: |error| / |predicted|, "
            "runs with a non-zero prediction)",
        )
    )
    if keys:  # the error per value of the first swept key: where theory and simulation part
        k = keys[0]
        groups = group_by(runs, [k])
        head = ("quantity (unit)", *(f"= {fmt_value(c[0])}" for c in groups))
        body = []
        for p in pairs:
            cells = [p.label]
            for members in groups.values():
                err = prediction_error(members, p)
                cells.append(fmt(err.mean_error) if err.n else "n/a")
            body.append(tuple(cells))
        s.blocks.append(Table(head, tuple(body), caption=f"Mean error (measured - predicted) per value of {k.name}"))
    return s


def _line_key(key: Key, keys: Sequence[Key]) -> Key | None:
    others = [k for k in keys if k is not key]
    cats = [k for k in others if not k.numeric]
    pick = cats or others
    return pick[0] if pick else None


def parameter_section(runs: Sequence[Run], keys: Sequence[Key], metrics: Sequence[str]) -> Section | None:
    from haptic_teleop.studies.document.figures import parameter_figure, png

    numeric = [k for k in keys if k.numeric]
    if not numeric or not metrics:
        return None
    s = Section("metrics-against-parameters", "Metrics against parameters")
    s.blocks.append(
        Para(
            "Per swept number: each chosen metric's mean over the runs at each value (the seeds, and the "
            "values of any swept key not drawn as a line), with error bars of one sample standard "
            "deviation and a shaded band from the minimum to the maximum."
        )
    )
    drawn = _drawn_metrics(runs, metrics, s)
    for k in numeric if drawn else ():
        line = _line_key(k, keys)
        rest = [o.name for o in keys if o is not k and o is not line]
        over = "seeds" + (f" and {', '.join(rest)}" if rest else "")
        sub = Section(f"against-{_anchor(k.name)}", f"Against {k.name}")
        lines = f"; one line per value of `{line.name}`" if line is not None else ""
        sub.blocks.append(
            Image(
                f"against-{k.name}",
                png(parameter_figure(runs, k, line, drawn)),
                f"metrics against {k.name}",
                f"Mean over {over}{lines}.",
            )
        )
        s.subsections.append(sub)
    groups = group_by(runs, keys)
    rows = [
        (
            *(fmt_value(v) for v in combo),
            str(len(members)),
            *(fmt_spread(spread([r.metrics.get(m, math.nan) for r in members])) for m in metrics),
        )
        for combo, members in list(groups.items())[:MAX_TABLE_ROWS]
    ]
    cap = "Per combination of the swept keys: mean ± sample std [min, max] over its runs"
    if len(groups) > MAX_TABLE_ROWS:
        cap += f" (the first {MAX_TABLE_ROWS} of {len(groups)} combinations)"
    table = Section("metrics-per-combination", "Per combination")
    short = short_names([k.name for k in keys])
    table.blocks.append(
        Table((*(short[k.name] for k in keys), "runs", *(label_of(m) for m in metrics)), tuple(rows), cap)
    )
    s.subsections.append(table)
    return s


def _drawn_metrics(runs: Sequence[Run], metrics: Sequence[str], s: Section) -> list[str]:
    """The metrics worth a panel: those whose value differs between runs; the others (equal in
    every run, or computed in none) are named in one line of `s` and stay in its tables."""
    drawn, same = [], []
    for m in metrics:
        values = [r.metrics.get(m, math.nan) for r in runs]
        finite = {v for v in values if math.isfinite(v)}
        if not finite:
            same.append(f"`{m}` (n/a)")
        elif len(finite) == 1 and all(math.isfinite(v) for v in values):
            same.append(f"`{m}` = {fmt(finite.pop())}")
        else:
            drawn.append(m)
    if same:
        s.blocks.append(Para(f"Equal in every run, so not plotted: {', '.join(same)}."))
    return drawn


def _anchor(text: str) -> str:
    from haptic_teleop.studies.document.document import slug

    return slug(text)


def category_section(
    runs: Sequence[Run], keys: Sequence[Key], metrics: Sequence[str], baselines: dict[str, Any]
) -> Section | None:
    from haptic_teleop.studies.document.figures import category_figure, png

    cats = [k for k in keys if not k.numeric]
    if not cats or not metrics:
        return None
    s = Section("comparisons-per-category", "Comparisons per category")
    s.blocks.append(
        Para(
            "Per swept key whose values are names (a buffer policy, a law): each metric per category, "
            "and each category's difference to the baseline paired run by run: two runs pair when "
            "they have the same seed and the same values of every other swept key; the table gives "
            "the mean and sample std of those differences (category - baseline) and their number."
        )
    )
    seeded = any(r.seed is not None for r in runs)
    drawn = _drawn_metrics(runs, metrics, s)
    for k in cats:
        base = baselines[k.name]
        others = [o for o in keys if o is not k]
        sub = Section(f"per-{_anchor(k.name)}", f"Per {k.name} (baseline {fmt_value(base)})")
        if drawn:
            sub.blocks.append(
                Image(
                    f"per-{k.name}",
                    png(category_figure(runs, k, drawn, base)),
                    f"per {k.name}",
                    "Bars: mean over the category's runs"
                    + (f" (all values of {', '.join(o.name for o in others)})" if others else "")
                    + "; error bars: ± 1 sample std; dots: the runs.",
                )
            )
        rows = []
        for c in k.values:
            members = [r for r in runs if k.of(r) == c]
            rows.append(
                (
                    fmt_value(c),
                    str(len(members)),
                    *(fmt_spread(spread([r.metrics.get(m, math.nan) for r in members])) for m in metrics),
                )
            )
        sub.blocks.append(
            Table(
                (k.name, "runs", *(label_of(m) for m in metrics)),
                tuple(rows),
                caption="Per category: mean ± sample std [min, max]",
            )
        )
        diffs = []
        for c in k.values:
            if c == base:
                continue
            for m in metrics:
                d = paired_difference(runs, k, others, c, base, m)
                rel = d.mean / abs(d.mean_baseline) * 100.0 if d.n and d.mean_baseline else math.nan
                diffs.append(
                    (
                        fmt_value(c),
                        label_of(m),
                        str(d.n),
                        _fmt_paired(d),
                        "n/a" if math.isnan(rel) else f"{rel:+.3g} %",
                    )
                )
        if diffs:
            how = "seed" if seeded else "run (no seeds in the inputs)"
            sub.blocks.append(
                Table(
                    (
                        "category",
                        "metric",
                        "pairs",
                        f"mean ± std of (category - {fmt_value(base)})",
                        "relative to the baseline's mean",
                    ),
                    tuple(diffs),
                    caption=f"Paired by {how} and the other swept keys' values, against {fmt_value(base)}",
                )
            )
        s.subsections.append(sub)
    return s


def _fmt_paired(d: Paired) -> str:
    if d.n == 0:
        return "n/a"
    if d.n == 1:
        return fmt(d.mean)
    std = 0.0 if d.std <= 1e-12 * max(abs(d.mean), abs(d.mean_baseline)) else d.std
    return f"{fmt(d.mean)} ± {fmt(std)}"


def drill_section(runs: Sequence[Run], keys: Sequence[Key], metrics: Sequence[str], max_runs: int) -> Section | None:
    have = [r for r in runs if r.bag is not None or r.plots_dir is not None]
    if not have or max_runs == 0:
        return None
    shown = have[:max_runs]
    s = Section("per-run-drill-down", "Per-run drill-down")
    more = f" (the first {len(shown)} of {len(have)}; `--max-runs` shows more)" if len(have) > len(shown) else ""
    s.blocks.append(
        Para(
            f"The time plots of each run with a bag or plots{more}: forces (felt by the operator against "
            "the wall force, and their difference), positions, and the network timeline (one-way "
            "delays, losses, skips and releases, playout buffer occupancy), the same figures "
            "`haptic-teleop run` writes."
        )
    )
    for r in shown:
        values = ", ".join(f"{k.name} = {fmt_value(k.of(r))}" for k in keys)
        title = f"{r.label}" + (f": {values}" if values else "") + (f", seed {r.seed}" if r.seed is not None else "")
        sub = Section(f"run-{_anchor(r.label)}", title)
        sub.blocks.append(
            Table(("metric", "value"), tuple((label_of(m), fmt(r.metrics.get(m, math.nan))) for m in metrics))
        )
        sub.blocks.extend(_run_images(r))
        s.subsections.append(sub)
    return s


def _run_images(r: Run) -> list[Block]:
    if r.bag is not None:
        try:
            return [Image(f"{r.label}-{name}", data, f"{r.label}: {name}") for name, data in _bag_figures(r)]
        except HapticTeleopError as exc:
            return [Para(f"The bag {r.bag} could not be drawn: {exc}")]
    assert r.plots_dir is not None
    files = [r.plots_dir / n for n in DRILL_PLOTS if (r.plots_dir / n).is_file()]
    files = files or sorted(r.plots_dir.glob("*.png"))
    return [Image(f"{r.label}-{f.stem}", f.read_bytes(), f"{r.label}: {f.stem}") for f in files]


def _bag_figures(r: Run) -> list[tuple[str, bytes]]:
    """The drill-down figures of a bag: analysis/plots.py's forces, positions (n-DoF: paths) and
    network timeline; an NVE bag's own plots (analysis/nve_summary.py)."""
    from haptic_teleop.analysis.bag_plotdata import from_bag
    from haptic_teleop.analysis.plotdata import TaskPlotData
    from haptic_teleop.analysis.plots import (
        forces_figure,
        network_figure,
        positions_figure,
        task_forces_figure,
        task_path_figure,
    )
    from haptic_teleop.record.reader import BagReader
    from haptic_teleop.studies.document.figures import png

    assert r.bag is not None
    with BagReader(r.bag) as reader:
        nve = reader.nve_schema is not None
    if nve:
        from haptic_teleop.analysis.nve_summary import write_nve_plots

        with tempfile.TemporaryDirectory() as tmp:
            return [(p.stem, p.read_bytes()) for p in write_nve_plots(r.bag, Path(tmp))]
    data = from_bag(r.bag, r.lag_s)
    if isinstance(data, TaskPlotData):
        return [("forces", png(task_forces_figure(data))), ("paths", png(task_path_figure(data)))]
    return [
        ("forces", png(forces_figure(data))),
        ("positions", png(positions_figure(data))),
        ("network", png(network_figure(data))),
    ]


# ------------------------------------------------------------------------------------------------
# the command


def _command_line(args: argparse.Namespace) -> str:
    parts = ["haptic-teleop report", *map(str, args.inputs)]
    for flag in ("metrics", "baseline", "title"):
        v = getattr(args, flag)
        if v is not None:
            parts.append(f"--{flag} {v}")
    if args.max_runs != MAX_RUNS:
        parts.append(f"--max-runs {args.max_runs}")
    return " ".join(parts)


def build(inputs: Inputs, args: argparse.Namespace) -> Document:
    runs = inputs.runs
    available = metric_names(runs)
    if not available:
        raise InputError(f"{', '.join(map(str, args.inputs))}: no metric in the inputs; allowed: runs with a summary")
    metrics, why = choose_metrics(args.metrics, available, runs, inputs.sweep_metrics)
    keys = swept_keys(runs)
    baselines = category_baselines(keys, args.baseline)
    sections = [overview(inputs, keys, metrics, why)]
    for sec in (
        prediction_section(runs, keys, available),
        parameter_section(runs, keys, metrics),
        category_section(runs, keys, metrics, baselines),
        drill_section(runs, keys, metrics, args.max_runs),
    ):
        if sec is not None:
            sections.append(sec)
    scenes = sorted({str(r.info.get("scene") or r.params.get("scene.name") or "") for r in runs} - {""})
    title = args.title or f"haptic_teleop report: {', '.join(scenes) or 'runs'} ({len(runs)} runs)"
    intro: list[Block] = [Para(f"Made by `{_command_line(args)}`.")]
    return Document(title, intro, sections)
