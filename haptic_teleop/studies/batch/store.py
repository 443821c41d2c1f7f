"""A sweep's results on disk: the ledger of finished points, and the table (Parquet and a CSV twin).

- `points.jsonl`: one JSON line per finished point, appended (flushed and fsynced) the moment the
  point's result comes back; a rerun into the same directory skips every run hash it holds. A kill
  loses at most the points still running (a torn last line is ignored and that point runs again).
- `sweep.parquet` (pyarrow) and `sweep.csv`: every point of the ledger, one row each, rewritten
  whole (through a rename) from the ledger. Columns, in order: the swept scene keys (one column per
  key, named by its key path, in sweep order), `seed`, `run_hash`, every scalar of the run's
  summary.json by its name (sorted), `bag_path` (empty unless the bag was kept).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from haptic_teleop.errors import InputError

LEDGER = "points.jsonl"
META = "sweep.json"  # beside the tables: the metrics the sweep was asked for (`haptic-teleop report` reads it)
PARQUET = "sweep.parquet"
CSV = "sweep.csv"
FIXED = ("seed", "run_hash")
LAST = "bag_path"
EXTRA = "sweep"  # the setup.py extra with dask[distributed] and pyarrow
FORMATS = ("auto", "parquet", "csv")


def have_pyarrow() -> bool:
    try:
        import pyarrow
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        return False
    return True


def check_format(fmt: str) -> bool:
    """Whether to write Parquet; `parquet` without pyarrow is one line, exit 2 (before anything runs)."""
    if fmt == "csv":
        return False
    if have_pyarrow():
        return True
    if fmt == "parquet":
        raise InputError(
            f"--format parquet: pyarrow is not installed; allowed: pip install 'haptic_teleop[{EXTRA}]', "
            "or --format csv"
        )
    return False


def is_sweep_dir(out: Path) -> bool:
    return (out / LEDGER).is_file()


def scalar(v: Any) -> bool:
    return v is None or isinstance(v, (int, float, str, bool))


def flat_scalars(summary: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """A summary's scalars by name, sections flattened into dotted names (an NVE run's
    `clients.<name>.force_rms_n`, `clients.<name>.round_trip_s.median`); lists left out. A
    teleoperation summary has no sections: its scalars keep their names."""
    out: dict[str, Any] = {}
    for k, v in summary.items():
        if isinstance(v, Mapping):
            out.update(flat_scalars(v, f"{prefix}{k}."))
        elif scalar(v):
            out[f"{prefix}{k}"] = v
    return out


class Store:
    """The ledger of one output directory and the tables written from it."""

    def __init__(self, out: Path, parquet: bool) -> None:
        self.out = out
        self.parquet = parquet
        self.records: dict[str, dict[str, Any]] = {}
        self._fh: io.TextIOWrapper | None = None

    def load(self) -> dict[str, dict[str, Any]]:
        """The finished points of earlier invocations, by run hash (a torn last line is skipped)."""
        path = self.out / LEDGER
        if path.is_file():
            for line in path.read_text(encoding="utf-8").splitlines():
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:
                    continue  # a line cut by a kill: that point runs again
                if isinstance(rec, dict) and isinstance(rec.get("run_hash"), str):
                    self.records[rec["run_hash"]] = rec
        return self.records

    def append(self, record: Mapping[str, Any]) -> None:
        """One finished point: on disk (fsynced) before this returns."""
        if self._fh is None:
            path = self.out / LEDGER
            # A torn last line (a kill while writing) must not swallow the next record.
            if path.is_file() and path.stat().st_size and not path.read_bytes().endswith(b"\n"):
                with path.open("a", encoding="utf-8") as fh:
                    fh.write("\n")
            self._fh = path.open("a", encoding="utf-8")
        self._fh.write(json.dumps(record, sort_keys=True, allow_nan=True) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self.records[str(record["run_hash"])] = dict(record)

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def write_tables(self, order: Sequence[str] = ()) -> list[Path]:
        """sweep.csv (and sweep.parquet) of every point of the ledger, the run hashes in `order`
        first (the sweep's plan order), then the others; the paths written."""
        first = [self.records[h] for h in order if h in self.records]
        rest = [r for h, r in self.records.items() if h not in set(order)]
        columns, rows = table([*first, *rest])
        written = [self.out / CSV]
        _replace(self.out / CSV, lambda tmp: write_csv(tmp, columns, rows))
        if self.parquet:
            written.append(self.out / PARQUET)
            _replace(self.out / PARQUET, lambda tmp: write_parquet(tmp, columns, rows))
        return written


def record(
    run_hash: str, seed: int, keys: Mapping[str, Any], summary: Mapping[str, Any], bag: str | None
) -> dict[str, Any]:
    """A ledger line: the point's swept keys, seed, hash, the summary's scalars, the kept bag."""
    return {
        "run_hash": run_hash,
        "seed": seed,
        "keys": dict(keys),
        "summary": flat_scalars(summary),
        "bag_path": bag,
    }


def table(records: Iterable[Mapping[str, Any]]) -> tuple[list[str], list[dict[str, Any]]]:
    """The columns (key paths, seed, run_hash, metrics sorted, bag_path) and one row per record."""
    recs = list(records)
    key_cols: dict[str, None] = {}
    metric_cols: set[str] = set()
    for r in recs:
        key_cols.update(dict.fromkeys(r["keys"]))
        metric_cols.update(r["summary"])
    taken = {*key_cols, *FIXED, LAST}
    metrics = sorted(metric_cols - taken)  # summary.json's `seed` is the seed column's value
    columns = [*key_cols, *FIXED, *metrics, LAST]
    rows = []
    for r in recs:
        row = {k: r["keys"].get(k) for k in key_cols}
        row.update(seed=r["seed"], run_hash=r["run_hash"])
        row.update({m: r["summary"].get(m) for m in metrics})
        row[LAST] = r.get("bag_path")
        rows.append(row)
    return columns, rows


def column_type(values: Sequence[Any]) -> str:
    """bool, int64, float64 or string: the narrowest type every non-null value fits."""
    present = [v for v in values if v is not None]
    if present and all(isinstance(v, bool) for v in present):
        return "bool"
    if all(isinstance(v, int) and not isinstance(v, bool) for v in present):
        return "int64" if present else "string"
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
        return "float64"
    return "string"


def _cell(v: Any, kind: str) -> Any:
    if v is None:
        return None
    if kind == "float64":
        return float(v)
    if kind == "string":
        return v if isinstance(v, str) else json.dumps(v)
    return v


def write_csv(path: Path, columns: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> None:
    """Empty cells for None and NaN; floats as repr (they read back bit for bit)."""
    kinds = {c: column_type([r[c] for r in rows]) for c in columns}
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            cells = []
            for c in columns:
                v = _cell(r[c], kinds[c])
                cells.append("" if v is None or (isinstance(v, float) and math.isnan(v)) else v)
            w.writerow(cells)


def write_parquet(path: Path, columns: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays, fields = [], []
    for c in columns:
        kind = column_type([r[c] for r in rows])
        typ = {"bool": pa.bool_(), "int64": pa.int64(), "float64": pa.float64(), "string": pa.string()}[kind]
        arrays.append(pa.array([_cell(r[c], kind) for r in rows], type=typ))
        fields.append(pa.field(c, typ))
    pq.write_table(pa.Table.from_arrays(arrays, schema=pa.schema(fields)), path)


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _replace(path: Path, write: Any) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def write_meta(out: Path, metrics: Sequence[str]) -> None:
    """`out`/sweep.json: {"metrics": [...]}, the metrics of the sweep file's `metrics:` (or
    --metrics, or the defaults), in their order, for a report on the sweep's table."""
    _replace(out / META, lambda tmp: tmp.write_text(json.dumps({"metrics": list(metrics)}, indent=2) + "\n"))


def read_meta(table: Path) -> list[str]:
    """The metrics a sweep's sweep.json beside `table` names ([] when there is none, or it is not
    such a file: the report then chooses as it would without it)."""
    try:
        data = json.loads((table.parent / META).read_text())
    except (OSError, ValueError):
        return []
    metrics = data.get("metrics") if isinstance(data, dict) else None
    return [m for m in metrics if isinstance(m, str)] if isinstance(metrics, list) else []
