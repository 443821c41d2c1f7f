"""`haptic-teleop report RESULTS_OR_BAGS ...`: one self-contained HTML report (and a Markdown twin)
of sweeps, runs and bags; its sections are studies/document/compose.py's (docs/report.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from haptic_teleop.errors import InputError
from haptic_teleop.studies.document.compose import MAX_RUNS, build, category_baselines, choose_metrics
from haptic_teleop.studies.document.inputs import read_inputs
from haptic_teleop.studies.document.stats import metric_names, swept_keys


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "inputs",
        nargs="+",
        metavar="RESULTS_OR_BAGS",
        help="results tables (sweep.csv, .parquet), sweep output directories, run directories or bags (any mix)",
    )
    p.add_argument("--out", help="output directory (default runs/report-NNN): report.html, report.md, figures/")
    p.add_argument(
        "--metrics",
        metavar="K1,K2,...",
        help="metrics against parameters and per category (default: the sweep's defaults the table has)",
    )
    p.add_argument(
        "--baseline",
        metavar="VALUE",
        help="the category the others are compared with, paired by seed (default: each categorical key's first value)",
    )
    p.add_argument(
        "--max-runs",
        type=_count,
        default=MAX_RUNS,
        metavar="N",
        help=f"per-run drill-down plots for at most N runs (default {MAX_RUNS}; 0: none)",
    )
    p.add_argument("--title", help="the report's title (default: from the inputs)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def _count(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: an integer >= 0")
    return n


def main(args: argparse.Namespace) -> int:
    from haptic_teleop.analysis.outputs import check_out_dir, default_out
    from haptic_teleop.studies.document.document import write

    inputs = read_inputs(args.inputs)
    if not inputs.runs:
        raise InputError(f"{', '.join(map(str, args.inputs))}: no runs in the inputs")
    # every flag is checked against the inputs before the output directory is made
    available = metric_names(inputs.runs)
    choose_metrics(args.metrics, available, inputs.runs)
    category_baselines(swept_keys(inputs.runs), args.baseline)
    out = Path(args.out) if args.out else default_out("report")
    check_out_dir(out)
    doc = build(inputs, args)
    html_path, md_path = write(doc, out)
    if not args.quiet:
        print(f"report:   {html_path}\nmarkdown: {md_path}\nsections: {', '.join(s.title for s in doc.sections)}")
    return 0
