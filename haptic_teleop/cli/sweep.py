"""`haptic-teleop sweep`: run a grid or a random sample of scene keys and seeds; tabulate every metric.

`haptic-teleop sweep SWEEP.yaml` (a sweep file, docs/sweep.md) or `haptic-teleop sweep SCENE
--param KEY=V1,V2 ...` (today's flags). Each point runs through the same path as `haptic-teleop
run` (haptic_teleop/studies/batch/runner.py: `record_run`, then `write_outputs` on the bag just written),
in local worker processes (`--workers`, default the CPU count) or on a Dask cluster
(`--scheduler`). Finished points are kept in OUT/points.jsonl the moment they finish; a rerun into
the same --out skips them (haptic_teleop/studies/batch/store.py). Outputs: sweep.parquet and sweep.csv
(every point, every scalar metric), sweep.md (mean ± std over seeds per combination) and sweep.png.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from haptic_teleop import interrupt
from haptic_teleop.errors import ConfigError
from haptic_teleop.studies.batch.aggregate import (
    DEFAULT_METRICS,
    MAX_PLOT_COMBOS,
    aggregate,
    check_metrics,
    default_metrics,
    write_markdown,
    write_plot,
)
from haptic_teleop.studies.batch.plan import (
    Point,
    Spec,
    combinations,
    find_sweep,
    load_sweep_file,
    parse_param,
    parse_seeds,
    resolve,
    spec_from_flags,
    split_values,
)


def _command(args: argparse.Namespace) -> str:
    parts = ["haptic-teleop sweep", str(args.scene)]
    parts += [f"--param {p}" for p in args.param or ()]
    if args.seeds:
        parts.append(f"--seeds {args.seeds}")
    parts += [f"--set {s}" for s in (args.set or ())]
    if args.metrics:
        parts.append(f"--metrics {args.metrics}")
    return " ".join(parts)


def build_spec(args: argparse.Namespace) -> Spec:
    """The sweep file the positional names (with --param/--set adding to it), or a scene and --param."""
    import dataclasses

    sweep_file = find_sweep(args.scene)
    extra = [parse_param(t) for t in args.param or ()]
    if sweep_file is None:
        if not extra:
            raise ConfigError(
                "--param",
                "",
                args.scene,
                "required with a scene; allowed: --param KEY.PATH=V1,V2,..., or a sweep file "
                "(a YAML file with a grid or random section, docs/sweep.md) in place of the scene",
            )
        spec = spec_from_flags(args.scene, args.param)
    else:
        spec = load_sweep_file(sweep_file)
        if extra:  # --param on a sweep file: more grid axes, crossed with the file's points
            params = (*spec.params, *extra)
            combos = tuple(c + e for c in spec.combos for e in combinations(extra))
            spec = dataclasses.replace(spec, params=params, combos=combos)
    sets = (*spec.sets, *(args.set or ()))
    return dataclasses.replace(spec, sets=sets)


def run_sweep(args: argparse.Namespace) -> int:
    from haptic_teleop.analysis.outputs import check_out_dir, default_out
    from haptic_teleop.studies.batch.runner import RUNS, Task, make_runner
    from haptic_teleop.studies.batch.store import Store, check_format, is_sweep_dir

    spec = build_spec(args)
    seeds_arg = parse_seeds(args.seeds)
    keep_bags = bool(args.keep_bags or spec.keep_bags)
    parquet = check_format(args.format)
    if not parquet and args.format == "auto" and not args.quiet:
        print(
            "haptic-teleop: pyarrow is not installed: sweep.csv only (pip install 'haptic_teleop[sweep]' "
            "for sweep.parquet)",
            file=sys.stderr,
        )
    # Every point is loaded (validated) before anything runs: a bad key or value exits 2 now.
    points = resolve(spec, seeds_arg)
    name = points[0].scene.config.scene.name
    metrics = (
        split_values(args.metrics) if args.metrics else list(spec.metrics or default_metrics(points[0].scene.config))
    )
    out = Path(args.out) if args.out else default_out(f"sweep-{name}")
    resuming = is_sweep_dir(out)
    store = Store(out, parquet)
    done = store.load() if resuming else {}
    todo = list({p.run_hash: p for p in points if p.run_hash not in done}.values())  # equal scenes run once
    skipped = sum(p.run_hash in done for p in points)
    # The cluster is reached (or refused, exit 2) before the output directory is made.
    runner = make_runner(args.workers, args.scheduler, len(todo)) if todo else None
    try:
        check_out_dir(out, empty=not resuming)
    except BaseException:
        if runner is not None:
            runner.close()
        raise
    if resuming and not args.quiet:
        print(
            f"haptic-teleop: sweep: {skipped} of {len(points)} points already done in {out}, skipped; "
            f"{len(todo)} to run",
            file=sys.stderr,
        )
    tasks = [Task(p.run_hash, p.scene.to_yaml(), str(out / RUNS / p.run_hash), keep_bags, args.run_plots) for p in todo]
    by_hash = {p.run_hash: p for p in points}
    # From here on: a first Ctrl-C / SIGTERM starts no other point, stops the running ones' loops
    # (they are not results) and writes the tables of every point finished; a second aborts.
    failures: list[tuple[Point, str]] = []
    t0 = time.perf_counter()
    with interrupt.finishing():
        bar = None
        try:
            if runner is not None:
                if not args.quiet:
                    from tqdm import tqdm

                    where = f"{runner.workers} worker" + ("s" if runner.workers != 1 else "")
                    bar = tqdm(total=len(tasks), unit="run", desc=f"sweep {name} ({where})", file=sys.stderr)
                runner.submit(tasks)
                with interrupt.on_stop(runner.stop):
                    for task, result, exc in runner.results(lambda: interrupt.received() is not None):
                        point = by_hash[task.run_hash]
                        if exc is not None:
                            failures.append((point, f"{type(exc).__name__}: {exc}"))
                            continue
                        assert result is not None
                        if result.get("error"):
                            failures.append((point, str(result["error"])))
                            continue
                        if result["interrupted"]:
                            continue
                        if len(store.records) == 0:
                            check_metrics(metrics, result["summary"])
                        store.append(_record(point, result["summary"], result["bag_path"]))
                        if bar is not None:
                            bar.set_postfix_str(", ".join(point.combo) + f", seed {point.seed}", refresh=False)
                            bar.update(1)
                        if interrupt.received() is None:
                            interrupt.pause_for_test("sweep-run")
        except interrupt.Interrupted:
            if runner is not None:
                runner.abort()
            raise
        finally:
            if bar is not None:
                bar.close()
            if runner is not None and interrupt.received() is None:
                runner.close()
            elif runner is not None:
                runner.abort()
            store.close()
        wall_s = time.perf_counter() - t0
        return _finish(args, out, spec, points, store, metrics, skipped, failures, wall_s, name)


def _record(point: Point, summary: dict[str, Any], bag: str | None) -> dict[str, Any]:
    from haptic_teleop.studies.batch.store import record

    return record(point.run_hash, point.seed, point.keys, summary, bag)


def _finish(
    args: argparse.Namespace,
    out: Path,
    spec: Spec,
    points: Sequence[Point],
    store: Any,
    metrics: Sequence[str],
    skipped: int,
    failures: Sequence[tuple[Point, str]],
    wall_s: float,
    name: str,
) -> int:
    finished = [p for p in points if p.run_hash in store.records]
    for point, why in failures[:3]:
        print(
            f"haptic-teleop: sweep point {point.run_hash} ({', '.join(point.combo)}, seed {point.seed}) failed: {why}",
            file=sys.stderr,
        )
    if len(failures) > 3:
        print(f"haptic-teleop: ... and {len(failures) - 3} more points failed", file=sys.stderr)
    if len(finished) < len(points) and not failures:
        print(f"haptic-teleop: sweep interrupted after {len(finished)} of {len(points)} runs", file=sys.stderr)
    if not store.records:
        return 130 if interrupt.received() is not None else 1
    written = store.write_tables([p.run_hash for p in points])
    # What `haptic-teleop report` reads beside the table: the metrics this sweep was asked for.
    from haptic_teleop.studies.batch.store import write_meta

    write_meta(out, metrics)
    rows = [
        {"run": p.run_hash, "combo": p.combo, "seed": p.seed, "summary": store.records[p.run_hash]["summary"]}
        for p in finished
    ]
    seeds = sorted({p.seed for p in points})
    agg = aggregate(spec.params, rows, metrics) if rows else []
    table = write_markdown(out / "sweep.md", _command(args), spec.params, agg, metrics, seeds) if rows else ""
    # A random sample over several keys is no grid: its points would be one series each.
    plot = bool(rows) and not args.no_plots and len(agg) <= MAX_PLOT_COMBOS
    plot = plot and not (spec.random and len(spec.params) > 1)
    if plot:
        write_plot(out / "sweep.png", spec.params, rows, agg, metrics)
    if not args.quiet:
        print(table)
        ran = len(finished) - skipped
        print(f"{ran} runs in {wall_s:.1f} s" + (f", {skipped} skipped (done before)" if skipped else ""))
        for path in written:
            print(f"{path.suffix[1:]:<8} {path}")
        print(f"table:   {out / 'sweep.md'}" + (f"\nplot:    {out / 'sweep.png'}" if plot else ""))
    if failures:
        return 1
    return 0 if len(finished) == len(points) else 130


def add_arguments(p: argparse.ArgumentParser) -> None:
    from haptic_teleop.studies.benchmarks import positive

    p.add_argument(
        "scene",
        help="a sweep file (YAML with grid/random, docs/sweep.md) or a bundled sweep's name; "
        "or a scene YAML path or bundled scene name with --param",
    )
    p.add_argument(
        "--param",
        action="append",
        metavar="KEY.PATH=V1,V2,...",
        help="a swept key and its values (repeatable: every combination runs); "
        "KEY1+KEY2=... sets several keys to the same value",
    )
    p.add_argument("--seeds", metavar="S1,S2,...", help="seeds to run each combination with (default: scene.seed)")
    p.add_argument("--out", help="output directory (default runs/sweep-<scene>-NNN); an earlier sweep's: resume it")
    p.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="fixed override for every run (repeatable)")
    p.add_argument(
        "--metrics",
        metavar="K1,K2,...",
        help=f"summary keys in sweep.md and sweep.png (default: {','.join(DEFAULT_METRICS)}); "
        "sweep.parquet/csv hold every scalar",
    )
    p.add_argument("--keep-bags", action="store_true", help="keep every run's bag (about 1.3 MB per simulated second)")
    p.add_argument("--run-plots", action="store_true", help="also write each run's plots/")
    p.add_argument("--no-plots", action="store_true", help="skip sweep.png")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors (no progress bar, no table)")
    p.add_argument(
        "--workers",
        type=positive(int),
        metavar="N",
        help="local worker processes (default: the CPU count; 1: in this process)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run the points on this Dask distributed scheduler (e.g. tcp://scheduler.example:8786) instead of locally",
    )
    p.add_argument(
        "--format",
        choices=("auto", "parquet", "csv"),
        default="auto",
        help="results table: sweep.parquet and sweep.csv (parquet; auto: if pyarrow is installed) or sweep.csv only",
    )


def main(args: argparse.Namespace) -> int:
    return run_sweep(args)
