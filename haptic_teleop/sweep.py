"""`haptic-teleop sweep`: run every combination of scene parameters and seeds, tabulate the metrics.

Each run goes through the same path as `haptic-teleop run` (engine.record_run, then
analysis.outputs.write_outputs on the bag just written), so a row of sweep.csv holds the numbers
`run` would print for that combination and seed.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import itertools
import json
import math
import shutil
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from haptic_teleop import interrupt
from haptic_teleop.errors import ConfigError

DEFAULT_METRICS = (
    "force_rms_error_n",
    "buffering_delay_backward_mean_s",
    "late_loss_rate_backward",
    "buffering_delay_forward_mean_s",
    "late_loss_rate_forward",
)
_KEY_JOIN = "+"


@dataclass(frozen=True)
class Param:
    """One swept parameter: the key paths it sets (all to the same value) and the values as typed."""

    keys: tuple[str, ...]
    values: tuple[str, ...]

    @property
    def label(self) -> str:
        return _KEY_JOIN.join(self.keys)


def split_values(text: str) -> list[str]:
    """`a,b,[1, 2],{x: 1}` -> ["a", "b", "[1, 2]", "{x: 1}"]: commas inside brackets stay."""
    out: list[str] = []
    depth = 0
    cur: list[str] = []
    for ch in text:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur).strip())
    return out


def parse_param(text: str) -> Param:
    """`KEY.PATH[+KEY.PATH...]=v1,v2,...` -> Param; ConfigError (exit 2) when it is malformed."""
    allowed = "allowed: KEY.PATH=v1,v2,... (join keys with + to set them together), e.g. scene.seed=1,2"
    key, eq, values = text.partition("=")
    if not eq:
        raise ConfigError("--param", text, text, allowed)
    keys = tuple(k.strip() for k in key.split(_KEY_JOIN))
    for k in keys:
        if not k or any(not part for part in k.split(".")):
            raise ConfigError("--param", key, text, allowed)
    vals = tuple(split_values(values))
    if any(v == "" for v in vals):
        raise ConfigError("--param", key, values, "allowed: a comma-separated list of non-empty values")
    if len(set(vals)) != len(vals):
        raise ConfigError("--param", key, values, "allowed: each value once")
    return Param(keys, vals)


def parse_seeds(text: str | None) -> list[int] | None:
    if text is None:
        return None
    seeds: list[int] = []
    for part in split_values(text):
        try:
            seed = int(part)
        except ValueError:
            raise ConfigError(
                "--seeds", "scene.seed", part, "allowed: comma-separated integers from 0 to 2**63 - 1"
            ) from None
        if not 0 <= seed <= 2**63 - 1:
            raise ConfigError("--seeds", "scene.seed", part, "allowed: comma-separated integers from 0 to 2**63 - 1")
        seeds.append(seed)
    if len(set(seeds)) != len(seeds):
        raise ConfigError("--seeds", "scene.seed", text, "allowed: each seed once")
    return seeds


def combinations(params: Sequence[Param]) -> list[tuple[str, ...]]:
    """Every combination of the parameters' values, the first parameter varying slowest."""
    return list(itertools.product(*(p.values for p in params)))


def overrides_for(params: Sequence[Param], combo: Sequence[str]) -> list[str]:
    return [f"{k}={v}" for p, v in zip(params, combo, strict=True) for k in p.keys]


def _mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (n - 1); std is nan for a single value."""
    finite = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)]
    if not finite:
        return math.nan, math.nan
    n = len(finite)
    mean = sum(finite) / n
    if n < 2:
        return mean, math.nan
    return mean, math.sqrt(sum((v - mean) ** 2 for v in finite) / (n - 1))


def _fmt(x: float) -> str:
    return f"{x:.4g}" if math.isfinite(x) else "n/a"


def _fmt_pm(mean: float, std: float) -> str:
    if not math.isfinite(std):
        return _fmt(mean)
    if std <= 1e-12 * abs(mean):
        std = 0.0  # equal values whose mean rounded
    return f"{_fmt(mean)} ± {_fmt(std)}"


def _scalar(v: Any) -> bool:
    return isinstance(v, (int, float, str, bool)) or v is None


def write_csv(path: Path, params: Sequence[Param], rows: Sequence[dict[str, Any]]) -> None:
    """One row per run: run, the parameters' values, seed, then every scalar summary key (sorted)."""
    fixed = ["run", *(p.label for p in params), "seed"]
    keys = sorted({k for r in rows for k, v in r["summary"].items() if _scalar(v)} - set(fixed))
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([*fixed, *keys])
        for r in rows:
            s = r["summary"]
            w.writerow([r["run"], *r["combo"], r["seed"], *(_csv_value(s.get(k)) for k in keys)])


def _csv_value(v: Any) -> Any:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    return v


def aggregate(
    params: Sequence[Param], rows: Sequence[dict[str, Any]], metrics: Sequence[str]
) -> list[tuple[tuple[str, ...], int, dict[str, tuple[float, float]]]]:
    """Per combination (in sweep order): seeds run and (mean, std) of each metric over them."""
    out = []
    for combo in combinations(params):
        group = [r for r in rows if tuple(r["combo"]) == combo]
        if not group:
            continue
        stats = {m: _mean_std([r["summary"].get(m, math.nan) for r in group]) for m in metrics}
        out.append((combo, len(group), stats))
    return out


def write_markdown(
    path: Path,
    command: str,
    params: Sequence[Param],
    agg: Sequence[tuple[tuple[str, ...], int, dict[str, tuple[float, float]]]],
    metrics: Sequence[str],
    seeds: Sequence[int],
) -> str:
    lines = [
        f"`{command}`",
        "",
        f"Mean ± sample standard deviation over seeds {', '.join(map(str, seeds))}.",
        "",
        "| " + " | ".join([*(p.label for p in params), "runs", *metrics]) + " |",
        "|" + "---|" * (len(params) + 1 + len(metrics)),
    ]
    for combo, n, stats in agg:
        cells = [*combo, str(n), *(_fmt_pm(*stats[m]) for m in metrics)]
        lines.append("| " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    path.write_text(text)
    return text


def write_plot(
    path: Path,
    params: Sequence[Param],
    rows: Sequence[dict[str, Any]],
    agg: Sequence[tuple[tuple[str, ...], int, dict[str, tuple[float, float]]]],
    metrics: Sequence[str],
) -> None:
    """sweep.png: one panel per metric, every run a dot, the mean over seeds with its std as an error
    bar; layouts and labels in haptic_teleop.analysis.sweep_plot."""
    from haptic_teleop.analysis.sweep_plot import sweep_figure

    fig = sweep_figure([p.keys for p in params], [p.values for p in params], rows, agg, metrics)
    fig.savefig(path, dpi=100)


def _command(args: argparse.Namespace) -> str:
    parts = ["haptic-teleop sweep", str(args.scene)]
    parts += [f"--param {p}" for p in args.param]
    if args.seeds:
        parts.append(f"--seeds {args.seeds}")
    parts += [f"--set {s}" for s in (args.set or ())]
    if args.metrics:
        parts.append(f"--metrics {args.metrics}")
    return " ".join(parts)


def run_sweep(args: argparse.Namespace) -> int:
    from haptic_teleop.analysis.outputs import check_out_dir, default_out
    from haptic_teleop.scene.load import find_scene, load_scene

    params = [parse_param(t) for t in args.param]
    labels = [p.label for p in params]
    if len(set(labels)) != len(labels):
        raise ConfigError("--param", labels[0], labels, "allowed: each key swept once")
    seeds_arg = parse_seeds(args.seeds)
    metrics = split_values(args.metrics) if args.metrics else list(DEFAULT_METRICS)
    path = find_scene(args.scene)
    base = list(args.set or ())
    # Every combination is loaded (validated) before anything runs: a bad key or value exits 2 now.
    first = load_scene(path, overrides=base)
    seeds = seeds_arg if seeds_arg is not None else [first.config.scene.seed]
    plan = []
    for ci, combo in enumerate(combinations(params)):
        ov = [*base, *overrides_for(params, combo)]
        for seed in seeds:
            plan.append((ci, combo, seed, load_scene(path, overrides=ov, seed=seed)))
    out = Path(args.out) if args.out else default_out(f"sweep-{first.config.scene.name}")
    check_out_dir(out)
    # From here on: a first Ctrl-C / SIGTERM stops the current run's loop, finishes its outputs,
    # starts no other run and writes the table, CSV and plot of the runs done; a second aborts.
    with interrupt.finishing():
        return _run_plan(args, out, params, plan, metrics, seeds, first.config.scene.name)


def _run_plan(
    args: argparse.Namespace,
    out: Path,
    params: Sequence[Param],
    plan: Sequence[tuple[int, tuple[str, ...], int, Any]],
    metrics: Sequence[str],
    seeds: Sequence[int],
    name: str,
) -> int:
    from haptic_teleop.analysis.outputs import TIMING_FILE, write_atomic, write_outputs
    from haptic_teleop.engine.lockstep import record_run

    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(total=len(plan), unit="run", desc=f"sweep {name}", file=sys.stderr)
    rows: list[dict[str, Any]] = []
    try:
        for ci, combo, seed, scene in plan:
            if interrupt.received() is not None:
                break
            run_name = f"{ci:03d}-seed{seed}"
            if bar is not None:
                bar.set_postfix_str(", ".join(combo) + f", seed {seed}", refresh=False)
            run_dir = out / "runs" / run_name
            run_dir.mkdir(parents=True)
            bag_dir = run_dir / "bag"
            with contextlib.ExitStack() as stack:

                def on_engine(engine: Any, stack: contextlib.ExitStack = stack) -> None:
                    stack.enter_context(interrupt.on_stop(engine.request_stop))

                _, timing = record_run(scene, bag_dir, handle_sigint=False, on_engine=on_engine)
            write_atomic(run_dir / TIMING_FILE, json.dumps(timing.as_dict(), indent=2, sort_keys=True) + "\n")
            summary = write_outputs(bag_dir, run_dir, plots=args.run_plots)
            if timing.interrupted:
                break  # its outputs stay in runs/; a part of a run is not a row of the table
            if not rows:
                _check_metrics(metrics, summary)
            if not args.keep_bags:
                shutil.rmtree(bag_dir)
            rows.append({"run": run_name, "combo": combo, "seed": seed, "summary": summary})
            if bar is not None:
                bar.update(1)
            interrupt.pause_for_test("sweep-run")
    finally:
        if bar is not None:
            bar.close()
    if len(rows) < len(plan):
        print(f"haptic-teleop: sweep interrupted after {len(rows)} of {len(plan)} runs", file=sys.stderr)
    if not rows:
        return 130
    write_csv(out / "sweep.csv", params, rows)
    agg = aggregate(params, rows, metrics)
    table = write_markdown(out / "sweep.md", _command(args), params, agg, metrics, seeds)
    if not args.no_plots:
        write_plot(out / "sweep.png", params, rows, agg, metrics)
    if not args.quiet:
        print(table)
        print(
            f"csv:   {out / 'sweep.csv'}\ntable: {out / 'sweep.md'}"
            + ("" if args.no_plots else f"\nplot:  {out / 'sweep.png'}")
        )
    return 0 if len(rows) == len(plan) else 130


def _check_metrics(metrics: Sequence[str], summary: dict[str, Any]) -> None:
    numeric = sorted(k for k, v in summary.items() if isinstance(v, (int, float)) and not isinstance(v, bool))
    for m in metrics:
        if m not in numeric:
            raise ConfigError("--metrics", m, m, f"allowed: numeric summary keys: {', '.join(numeric)}")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene YAML path, or a bundled scene name (e.g. varying_delay)")
    p.add_argument(
        "--param",
        action="append",
        required=True,
        metavar="KEY.PATH=V1,V2,...",
        help="a swept key and its values (repeatable: every combination runs); "
        "KEY1+KEY2=... sets several keys to the same value",
    )
    p.add_argument("--seeds", metavar="S1,S2,...", help="seeds to run each combination with (default: scene.seed)")
    p.add_argument("--out", help="output directory (default runs/sweep-<scene>-NNN)")
    p.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="fixed override for every run (repeatable)")
    p.add_argument(
        "--metrics",
        metavar="K1,K2,...",
        help=f"summary keys in the table and plot (default: {','.join(DEFAULT_METRICS)})",
    )
    p.add_argument("--keep-bags", action="store_true", help="keep every run's bag (about 1.3 MB per simulated second)")
    p.add_argument("--run-plots", action="store_true", help="also write each run's plots/")
    p.add_argument("--no-plots", action="store_true", help="skip sweep.png")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors (no progress bar, no table)")


def main(args: argparse.Namespace) -> int:
    return run_sweep(args)
