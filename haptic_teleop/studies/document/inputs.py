"""What `haptic-teleop report` reads: results tables, run directories and bags, as one list of runs.

Accepted, in any mix:

- a results table, CSV (always) or Parquet (with pyarrow: `pip install haptic_teleop[sweep]`):
  - today's `sweep.csv` (haptic_teleop/cli/sweep.py `write_csv`): `run`, one column per swept
    parameter (its key path, or several joined with `+`), `seed`, then every scalar summary key;
    the run's directory is `runs/<run>/` beside the table (its `bag/` when the sweep kept bags);
  - the results table of `sweep SWEEP.yaml` (sweep.parquet, sweep.csv): one column per scene key
    named by its key path (`network.backward.effects.delay.delay_s`), `seed`, `run_hash`, every
    scalar metric of the run's summary.json, optional `bag_path` (a relative path is taken from the
    table's directory, else from the working directory); the run's directory is
    `runs/<run_hash>/` beside the table when it exists;
- a sweep's output directory (the table in it: a `.parquet` file, else `sweep.csv`/`results.csv`);
- a run directory of `haptic-teleop run` (summary.json, scene.yaml, bag/, plots/);
- a bag (the rosbag2 directory, its metadata.yaml or its .mcap file): summarised here with the same
  code as `analyze` (nothing is written beside it);
- a directory of run directories or bags (e.g. a sweep's `runs/`).

A column is a scene key when its name is a key path (has a dot; in today's sweep.csv: the columns
between `run` and `seed`), a metric when every value it has is a number. Everything else (the
scene's name, the tick loop, flags) is kept as information only.
"""

from __future__ import annotations

import csv
import importlib
import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from haptic_teleop.errors import HapticTeleopError, InputError

PARQUET_EXTRA = "pip install haptic_teleop[sweep]"
TABLE_SUFFIXES = (".csv", ".parquet", ".pq")
TABLE_NAMES = ("sweep.csv", "results.csv")
SPECIAL = ("run", "seed", "run_hash", "bag_path", "run_dir")
ALLOWED = (
    "allowed: a results table (.csv, .parquet), a sweep's output directory, a run directory "
    "(summary.json), or a bag (rosbag2 directory, metadata.yaml or .mcap)"
)


@dataclass
class Run:
    """One run: its scene keys (all, or the swept ones), seed, numeric metrics and where its bag is."""

    label: str
    source: str
    params: dict[str, Any]
    seed: int | None
    metrics: dict[str, float]
    info: dict[str, Any] = field(default_factory=dict)
    bag: Path | None = None
    plots_dir: Path | None = None  # a run directory's plots/ (its PNGs), when there is no bag
    lag_s: float | None = None  # summary's force_alignment_lag_s (saves the plots' passes)


@dataclass
class Inputs:
    runs: list[Run]
    sources: list[str]  # one line per input: what it was read as
    notes: list[str] = field(default_factory=list)
    sweep_metrics: list[str] = field(default_factory=list)  # the sweeps' own metrics (sweep.json), in order


# ------------------------------------------------------------------------------------------------
# values


def parse_value(text: str) -> Any:
    """A CSV cell as what it was written from: "" -> None, int, float, True/False, else the text."""
    t = text.strip()
    if t == "":
        return None
    if t in ("True", "False", "true", "false"):
        return t in ("True", "true")
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _scalar(v: Any) -> Any:
    """A table cell or a scene value as a hashable scalar (lists and mappings as JSON text)."""
    if v is None or isinstance(v, (bool, int, float, str)):
        if isinstance(v, float) and math.isnan(v):
            return None
        return v
    if hasattr(v, "item"):  # numpy scalars from Parquet
        return _scalar(v.item())
    return json.dumps(v, sort_keys=True, default=str)


def flatten(tree: Any, prefix: str = "") -> dict[str, Any]:
    """A nested mapping as {key.path: scalar}; lists are one value (their JSON text)."""
    out: dict[str, Any] = {}
    if isinstance(tree, dict):
        for k, v in tree.items():
            path = f"{prefix}.{k}" if prefix else str(k)
            if isinstance(v, dict):
                out.update(flatten(v, path))
            else:
                out[path] = _scalar(v)
    return out


def _metrics_and_info(summary: dict[str, Any], skip: Iterable[str] = ()) -> tuple[dict[str, float], dict[str, Any]]:
    metrics: dict[str, float] = {}
    info: dict[str, Any] = {}
    skipped = set(skip)
    for k, v in summary.items():
        if k in skipped:
            continue
        if v is None:
            metrics[k] = math.nan  # summary.json writes a non-finite value as null
        elif is_number(v):
            metrics[k] = float(v)
        elif isinstance(v, (str, bool)):
            info[k] = v
    # a key null in every run is no metric: dropped in `_finish` when no run has a number for it
    return metrics, info


def _number(v: Any) -> float | None:
    return float(v) if is_number(v) else None


def _seed(v: Any) -> int | None:
    if is_number(v) and float(v) == int(v):
        return int(v)
    return None


# ------------------------------------------------------------------------------------------------
# tables


def _table_rows(path: Path) -> list[dict[str, Any]]:
    if path.suffix.lower() in (".parquet", ".pq"):
        try:
            pq: Any = importlib.import_module("pyarrow.parquet")
        except ImportError:
            raise InputError(
                f"{path}: reading Parquet needs pyarrow; install it with `{PARQUET_EXTRA}` (or give the CSV table)"
            ) from None
        try:
            rows: list[dict[str, Any]] = pq.read_table(path).to_pylist()
        except Exception as exc:  # noqa: BLE001 (pyarrow's own errors: not a Parquet file, damaged)
            raise InputError(f"{path}: not a readable Parquet table ({exc}); {ALLOWED}") from None
        return [{str(k): _scalar(v) for k, v in r.items()} for r in rows]
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            body = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"{path}: not a readable CSV table ({exc}); {ALLOWED}") from None
    if not header or len(set(header)) != len(header):
        raise InputError(f"{path}: no header row of distinct column names; {ALLOWED}")
    out = []
    for n, cells in enumerate(body, start=2):
        if not cells:
            continue
        if len(cells) != len(header):
            raise InputError(f"{path}: line {n} has {len(cells)} cells, the header {len(header)}; {ALLOWED}")
        out.append({h: parse_value(c) for h, c in zip(header, cells, strict=True)})
    return out


def _csv_header(path: Path) -> list[str]:
    if path.suffix.lower() != ".csv":
        return []
    with path.open(newline="", encoding="utf-8") as fh:
        return next(csv.reader(fh), [])


def _beside(table: Path, text: str) -> Path:
    """A path in a table: relative to the table's directory (else to the working directory)."""
    p = Path(text)
    if not p.is_absolute() and ((table.parent / p).exists() or not p.exists()):
        p = table.parent / p
    return p.resolve()


def read_table(path: Path) -> list[Run]:
    """The runs of a results table (module docstring): exit 2 (InputError) when it has no metric."""
    rows = _table_rows(path)
    header = _csv_header(path)
    names: list[str] = list(header) if header else list(dict.fromkeys(k for r in rows for k in r))
    legacy = bool(names) and names[0] == "run" and "seed" in names and "run_hash" not in names
    if legacy:  # today's sweep.csv: run, the swept keys, seed, the summary's keys
        param_cols = names[1 : names.index("seed")]
    else:
        param_cols = [c for c in names if "." in c and c != "scene.seed"]
    rest = [c for c in names if c not in param_cols and c not in SPECIAL and c != "scene.seed"]
    metric_cols = [
        c
        for c in rest
        if any(is_number(r.get(c)) for r in rows) and all(r.get(c) is None or is_number(r.get(c)) for r in rows)
    ]
    if not rows:
        raise InputError(f"{path}: a table with no rows; {ALLOWED}")
    if not metric_cols:
        raise InputError(
            f"{path}: a table with no metric columns (numbers other than scene keys, seed and run_hash); "
            f"allowed: a results table of `haptic-teleop sweep` (one column per summary.json metric)"
        )
    runs = []
    for i, r in enumerate(rows):
        seed = _seed(r.get("seed", r.get("scene.seed")))
        label = r.get("run") or (str(r["run_hash"])[:12] if r.get("run_hash") else f"row {i + 1}")
        bag: Path | None = None
        plots: Path | None = None
        run_dir: Path | None = None
        if legacy and r.get("run"):
            run_dir = path.parent / "runs" / str(r["run"])
        elif r.get("run_hash") and (path.parent / "runs" / str(r["run_hash"])).is_dir():
            run_dir = path.parent / "runs" / str(r["run_hash"])  # `sweep SWEEP.yaml`: runs/<run_hash>/
        if r.get("run_dir"):
            run_dir = _beside(path, str(r["run_dir"]))
        if r.get("bag_path"):
            bag = _beside(path, str(r["bag_path"]))
            if not bag.exists() and run_dir is not None and (run_dir / "bag").exists():
                bag = run_dir / "bag"  # a path relative to where the sweep ran, read from elsewhere
        if run_dir is not None:
            if bag is None and (run_dir / "bag" / "metadata.yaml").is_file():
                bag = run_dir / "bag"
            if (run_dir / "plots").is_dir():
                plots = run_dir / "plots"
        metrics = {c: (float(r[c]) if is_number(r.get(c)) else math.nan) for c in metric_cols}
        info = {c: r[c] for c in rest if c not in metric_cols and r.get(c) is not None}
        lag = metrics.get("force_alignment_lag_s")
        runs.append(
            Run(
                label=str(label),
                source=str(path),
                params={c: r.get(c) for c in param_cols},
                seed=seed,
                metrics=metrics,
                info=info,
                bag=bag if bag is not None and bag.exists() else None,
                plots_dir=plots,
                lag_s=lag if lag is not None and math.isfinite(lag) else None,
            )
        )
    return runs


# ------------------------------------------------------------------------------------------------
# run directories and bags


def _load_yaml(text: str) -> Any:
    import yaml

    return yaml.safe_load(text)


def read_run_dir(path: Path) -> Run:
    """A run directory of `run` (or of a sweep's runs/): its summary.json and scene.yaml."""
    try:
        summary = json.loads((path / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path / 'summary.json'}: not a readable summary ({exc}); {ALLOWED}") from None
    if not isinstance(summary, dict):
        raise InputError(f"{path / 'summary.json'}: not a summary (a JSON object); {ALLOWED}")
    scene_file = path / "scene.yaml"
    scene: Any = _load_yaml(scene_file.read_text(encoding="utf-8")) if scene_file.is_file() else None
    if scene is None:
        bag_dir = path / "bag"
        scene = _bag_scene(bag_dir) if (bag_dir / "metadata.yaml").is_file() else {}
    params = flatten(scene)
    params.pop("scene.seed", None)
    params.pop("scene.description", None)
    metrics, info = _metrics_and_info(summary, skip=("seed",))
    bag = path / "bag"
    lag = summary.get("force_alignment_lag_s")
    return Run(
        label=path.name,
        source=str(path),
        params=params,
        seed=_seed(summary.get("seed", (scene.get("scene") or {}).get("seed") if isinstance(scene, dict) else None)),
        metrics=metrics,
        info=info,
        bag=bag if (bag / "metadata.yaml").is_file() else None,
        plots_dir=path / "plots" if (path / "plots").is_dir() else None,
        lag_s=_number(lag),
    )


def _bag_scene(bag: Path) -> Any:
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag) as r:
        return _load_yaml(r.string("/haptic_teleop/scene"))


def read_bag(path: Path) -> Run:
    """A bare bag: its scene and the summary `analyze` would write (computed, not written)."""
    from haptic_teleop.errors import BagError
    from haptic_teleop.record.reader import BagReader

    bag = path.parent if path.is_file() and path.name == "metadata.yaml" else path
    try:
        with BagReader(bag) as r:
            nve = r.nve_schema is not None
            scene = _load_yaml(r.string("/haptic_teleop/scene"))
        if nve:
            from haptic_teleop.analysis.nve_summary import summarize_nve

            summary = summarize_nve(bag)
        else:
            from haptic_teleop.analysis.stream import summarize_bag

            summary = summarize_bag(bag)
    except BagError as exc:
        raise InputError(f"{path}: not a readable bag ({exc})") from None
    params = flatten(scene)
    params.pop("scene.seed", None)
    params.pop("scene.description", None)
    metrics, info = _metrics_and_info(summary, skip=("seed",))
    lag = summary.get("force_alignment_lag_s")
    label = bag.parent.name if bag.name == "bag" else bag.name
    if bag.is_file():
        label = bag.stem
    return Run(
        label=label,
        source=str(path),
        params=params,
        seed=_seed(summary.get("seed", (scene or {}).get("scene", {}).get("seed"))),
        metrics=metrics,
        info=info,
        bag=bag,
        lag_s=_number(lag),
    )


# ------------------------------------------------------------------------------------------------
# one path, many paths


def _has_pyarrow() -> bool:
    try:
        importlib.import_module("pyarrow.parquet")
    except ImportError:
        return False
    return True


def _table_in(d: Path) -> Path | None:
    parquet = sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() in (".parquet", ".pq"))
    named = [d / n for n in TABLE_NAMES if (d / n).is_file()]
    if parquet and (_has_pyarrow() or not named):
        return parquet[0]
    return named[0] if named else None


def _is_bag_dir(d: Path) -> bool:
    return (d / "metadata.yaml").is_file()


def _is_run_dir(d: Path) -> bool:
    return (d / "summary.json").is_file()


def read_path(path: Path) -> tuple[list[Run], str]:
    """The runs of one input path and a line saying what it was read as."""
    if not path.exists():
        raise InputError(f"{path}: no such file or directory; {ALLOWED}")
    if path.is_file():
        suffix = path.suffix.lower()
        if suffix in TABLE_SUFFIXES:
            runs = read_table(path)
            return runs, f"{path}: results table, {len(runs)} runs"
        if suffix == ".mcap" or path.name == "metadata.yaml":
            return [read_bag(path)], f"{path}: bag"
        if path.name == "summary.json":
            return [read_run_dir(path.parent)], f"{path.parent}: run directory"
        raise InputError(f"{path}: neither a results table nor a bag; {ALLOWED}")
    if _is_run_dir(path):
        return [read_run_dir(path)], f"{path}: run directory"
    if _is_bag_dir(path):
        if _is_run_dir(path.parent):
            return [read_run_dir(path.parent)], f"{path.parent}: run directory (of the bag {path.name}/)"
        return [read_bag(path)], f"{path}: bag"
    table = _table_in(path)
    if table is not None:
        runs = read_table(table)
        return runs, f"{table}: results table, {len(runs)} runs"
    base = path / "runs" if (path / "runs").is_dir() else path
    subdirs = sorted(d for d in base.iterdir() if d.is_dir() and (_is_run_dir(d) or _is_bag_dir(d)))
    if subdirs:
        runs = [read_run_dir(d) if _is_run_dir(d) else read_bag(d) for d in subdirs]
        return runs, f"{base}: {len(runs)} run directories or bags"
    raise InputError(f"{path}: a directory with neither a results table, a summary.json nor a bag; {ALLOWED}")


def read_inputs(paths: Sequence[str | Path]) -> Inputs:
    """Every path's runs, in the order given; InputError (exit 2) names the first bad one."""
    import yaml

    from haptic_teleop.studies.batch.store import read_meta

    runs: list[Run] = []
    sources: list[str] = []
    sweep_metrics: list[str] = []
    for p in paths:
        path = Path(p)
        table = _table_in(path) if path.is_dir() and not _is_run_dir(path) and not _is_bag_dir(path) else None
        if table is None and path.is_file() and path.suffix.lower() in TABLE_SUFFIXES:
            table = path
        if table is not None:
            sweep_metrics.extend(m for m in read_meta(table) if m not in sweep_metrics)
        try:
            got, what = read_path(path)
        except HapticTeleopError:
            raise
        except (OSError, ValueError, yaml.YAMLError) as exc:
            raise InputError(f"{p}: cannot be read ({exc}); {ALLOWED}") from None
        runs.extend(got)
        sources.append(what)
    labels = [r.label for r in runs]
    if len(set(labels)) != len(labels):  # the same name in two inputs: say which input it came from
        for r in runs:
            if labels.count(r.label) > 1:
                r.label = f"{Path(r.source).name}:{r.label}"
    _finish(runs)
    return Inputs(runs, sources, sweep_metrics=sweep_metrics)


def _finish(runs: list[Run]) -> None:
    """Metrics every run lacks a number for are dropped; the others are NaN where a run lacks them."""
    keys = [k for k in dict.fromkeys(k for r in runs for k in r.metrics)]
    keep = [k for k in keys if any(math.isfinite(r.metrics.get(k, math.nan)) for r in runs)]
    for r in runs:
        r.metrics = {k: r.metrics.get(k, math.nan) for k in keep}
