"""What the report computes from the runs, without plotting: the swept keys, the predicted/measured
pairs, means and spreads over seeds, and differences paired by seed.

Spread over a group of runs: the sample standard deviation (n - 1; none for one run) and the
minimum and maximum. Non-finite values (a metric a run could not compute) are left out of a group;
its count says how many were used.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from haptic_teleop.studies.document.inputs import Run, is_number

KEY_JOIN = "+"

# Unit of a name from its suffix (longest first): the project's names carry their units.
UNITS = (
    ("_n_s_per_m", "N s/m"),
    ("_n_per_m", "N/m"),
    ("_n_per_s", "N/s"),
    ("_m_per_s", "m/s"),
    ("_rad_per_s", "rad/s"),
    ("_packets", "packets"),
    ("_bps", "bit/s"),
    ("_nm", "N m"),
    ("_ms", "ms"),
    ("_mm", "mm"),
    ("_hz", "Hz"),
    ("_kg", "kg"),
    ("_rad", "rad"),
    ("_n", "N"),
    ("_s", "s"),
    ("_m", "m"),
    ("_j", "J"),
    ("_w", "W"),
)
RATE_WORDS = ("rate", "probability", "fraction", "factor")


def unit_of(name: str) -> str:
    """`force_rms_error_n` -> "N", `late_loss_rate_backward` -> "1" (a ratio), unknown -> ""."""
    last = name.split(KEY_JOIN, maxsplit=1)[0].rsplit(".", 1)[-1]
    if last.startswith("wire_bits_per_s"):
        return "bit/s"
    for suffix, unit in UNITS:
        if last.endswith(suffix):
            return unit
    if any(w in last for w in RATE_WORDS):
        return "1"
    return ""


def label_of(name: str, wrap: bool = False) -> str:
    """A name with its unit for an axis: `force_rms_error_n (N)`; `wrap`: keys swept together
    (`a+b`) one per line."""
    u = unit_of(name)
    text = name.replace(KEY_JOIN, f"{KEY_JOIN}\n") if wrap else name
    return f"{text} ({u})" if u else text


# ------------------------------------------------------------------------------------------------
# swept keys


@dataclass(frozen=True)
class Key:
    """A swept key: one scene key path, or several that always took the same values (joined by +)."""

    name: str
    paths: tuple[str, ...]
    values: tuple[Any, ...]  # distinct values, in the order the runs first have them (numbers sorted)
    numeric: bool

    def of(self, run: Run) -> Any:
        return run.params.get(self.paths[0])


def swept_keys(runs: Sequence[Run]) -> list[Key]:
    """The scene keys whose values differ between runs; keys whose columns are the same in every
    run (swept together) become one Key named `a+b`. Numeric when every value is a number."""
    paths = list(dict.fromkeys(p for r in runs for p in r.params))
    by_column: dict[tuple[Any, ...], list[str]] = {}
    for p in paths:
        column = tuple(r.params.get(p) for r in runs)
        if len({v for v in column if v is not None}) < 2:
            continue
        by_column.setdefault(column, []).append(p)
    keys = []
    for column, group in by_column.items():
        # a key swept with '+' in today's sweep.csv is already one column named a+b
        present = [v for v in column if v is not None]
        numeric = all(is_number(v) for v in present)
        values = tuple(sorted(set(present))) if numeric else tuple(dict.fromkeys(present))
        keys.append(Key(KEY_JOIN.join(group), tuple(group), values, numeric))
    return keys


def metric_names(runs: Sequence[Run]) -> list[str]:
    return list(dict.fromkeys(k for r in runs for k in r.metrics))


# ------------------------------------------------------------------------------------------------
# groups


@dataclass(frozen=True)
class Spread:
    n: int
    mean: float
    std: float  # sample standard deviation; nan for fewer than two values
    lo: float
    hi: float


def spread(values: Sequence[float]) -> Spread:
    v = [float(x) for x in values if math.isfinite(x)]
    if not v:
        return Spread(0, math.nan, math.nan, math.nan, math.nan)
    n = len(v)
    mean = math.fsum(v) / n
    std = math.sqrt(math.fsum((x - mean) ** 2 for x in v) / (n - 1)) if n > 1 else math.nan
    return Spread(n, mean, std, min(v), max(v))


def group_by(runs: Sequence[Run], keys: Sequence[Key]) -> dict[tuple[Any, ...], list[Run]]:
    """Runs by their values of `keys`, in the order of the keys' values."""
    out: dict[tuple[Any, ...], list[Run]] = {}
    for r in runs:
        out.setdefault(tuple(k.of(r) for k in keys), []).append(r)

    def order(combo: tuple[Any, ...]) -> tuple[int, ...]:
        return tuple(k.values.index(v) if v in k.values else len(k.values) for k, v in zip(keys, combo, strict=True))

    return {c: out[c] for c in sorted(out, key=order)}


# ------------------------------------------------------------------------------------------------
# predicted against measured

_PREDICTED = re.compile(r"^(?P<stem>.+)_predicted(?P<unit>_.+)?$")


@dataclass(frozen=True)
class Pair:
    stem: str
    unit: str  # the name's unit suffix without the underscore ("n_per_s"), "" when none
    predicted: str
    measured: str

    @property
    def label(self) -> str:
        u = unit_of(self.predicted)
        return f"{self.stem} ({u})" if u else self.stem


def prediction_pairs(metrics: Sequence[str]) -> list[Pair]:
    """Every `<stem>_predicted_<unit>` with its `<stem>_measured_<unit>` (both among `metrics`)."""
    have = set(metrics)
    out = []
    for m in metrics:
        got = _PREDICTED.match(m)
        if got is None:
            continue
        unit = got.group("unit") or ""
        measured = f"{got.group('stem')}_measured{unit}"
        if measured in have:
            out.append(Pair(got.group("stem"), unit.lstrip("_"), m, measured))
    return out


@dataclass(frozen=True)
class PredictionError:
    """Over the runs that have both numbers: error = measured - predicted."""

    n: int
    predicted_mean: float
    measured_mean: float
    mean_error: float
    rms_error: float
    max_abs_error: float
    mean_abs_relative_pct: float  # |error| / |predicted|, over the runs whose prediction is not 0


def prediction_error(runs: Sequence[Run], pair: Pair) -> PredictionError:
    pts = points(runs, pair)
    if not pts:
        return PredictionError(0, *([math.nan] * 6))
    p = [a for a, _ in pts]
    m = [b for _, b in pts]
    e = [b - a for a, b in pts]
    rel = [abs(b - a) / abs(a) * 100.0 for a, b in pts if a != 0.0]
    n = len(pts)
    return PredictionError(
        n,
        math.fsum(p) / n,
        math.fsum(m) / n,
        math.fsum(e) / n,
        math.sqrt(math.fsum(x * x for x in e) / n),
        max(abs(x) for x in e),
        math.fsum(rel) / len(rel) if rel else math.nan,
    )


def points(runs: Sequence[Run], pair: Pair) -> list[tuple[float, float]]:
    """(predicted, measured) of each run that has both as finite numbers."""
    out = []
    for r in runs:
        a = r.metrics.get(pair.predicted, math.nan)
        b = r.metrics.get(pair.measured, math.nan)
        if math.isfinite(a) and math.isfinite(b):
            out.append((a, b))
    return out


# ------------------------------------------------------------------------------------------------
# categories, paired by seed


@dataclass(frozen=True)
class Paired:
    """category - baseline of one metric over the pairs of runs with the same seed and the same
    values of every other swept key."""

    n: int
    mean: float
    std: float
    mean_baseline: float  # the baseline's mean over the same pairs (for a relative difference)


def paired_difference(
    runs: Sequence[Run], key: Key, others: Sequence[Key], category: Any, baseline: Any, metric: str
) -> Paired:
    def by_pair(value: Any) -> dict[tuple[Any, ...], float]:
        acc: dict[tuple[Any, ...], list[float]] = {}
        for r in runs:
            if key.of(r) != value:
                continue
            v = r.metrics.get(metric, math.nan)
            if math.isfinite(v):
                acc.setdefault((r.seed, *(o.of(r) for o in others)), []).append(v)
        return {k: math.fsum(vs) / len(vs) for k, vs in acc.items()}

    a, b = by_pair(category), by_pair(baseline)
    common = [k for k in a if k in b]
    d = spread([a[k] - b[k] for k in common])
    base = spread([b[k] for k in common])
    return Paired(d.n, d.mean, d.std, base.mean)


# ------------------------------------------------------------------------------------------------
# numbers as text


def fmt(x: float) -> str:
    return f"{x:.4g}" if math.isfinite(x) else "n/a"


def fmt_value(v: Any) -> str:
    if v is None:
        return "(unset)"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def fmt_spread(s: Spread) -> str:
    """`mean ± std [min, max]` (no ± for one run)."""
    if s.n == 0:
        return "n/a"
    if s.n == 1:
        return fmt(s.mean)
    std = 0.0 if s.std <= 1e-12 * abs(s.mean) else s.std
    return f"{fmt(s.mean)} ± {fmt(std)} [{fmt(s.lo)}, {fmt(s.hi)}]"
