"""Trace files, read at the scene layer: core objects get their rows, never a path.

Network traces (a delay trace `time_s,delay_s`, a loss trace of 0/1 per packet) and the
operator's position trace (`time_s,position_m`). A scene's relative paths are taken from its folder
and every trace is read once when the scene loads (`resolve_scene_traces`, `read_operator_trace`),
so a bad file stops the run before anything is written; `build_scene_link` reads a link's traces
again where the link is built (engine, relay node) and hands their rows to the core
`build_link`.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from haptic_teleop.core.link import Link
from haptic_teleop.core.netconfig import LinkTraces, NetworkEffectsConfig, build_link
from haptic_teleop.errors import ConfigError

if TYPE_CHECKING:
    from haptic_teleop.scene.schema import Scene


def _trace_rows(path: str | os.PathLike[str], columns: int, header: tuple[str, ...]) -> list[tuple[int, list[str]]]:
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ValueError(f"{p}: cannot read trace file ({exc.strerror or exc})") from None
    rows: list[tuple[int, list[str]]] = []
    first = True
    for lineno, row in enumerate(csv.reader(text.splitlines()), start=1):
        cells = [c.strip() for c in row]
        if not cells or all(not c for c in cells) or cells[0].startswith("#"):
            continue
        if first:
            first = False
            if tuple(c.lower() for c in cells) == header:
                continue
        if len(cells) != columns:
            raise ValueError(f"{p}: row {lineno}: expected {columns} column(s) {','.join(header)}, got {len(cells)}")
        rows.append((lineno, cells))
    if not rows:
        raise ValueError(f"{p}: no data rows (expected {','.join(header)})")
    return rows


def load_delay_trace(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Read a delay trace CSV `time_s,delay_s` (optional header, `#` comments) into two arrays.

    Raises ValueError naming the file, the row and the problem: wrong column count, a value
    that is not a finite number, time not strictly increasing or negative, negative delay."""
    times: list[float] = []
    delays: list[float] = []
    for lineno, (ts, ds) in _trace_rows(path, 2, ("time_s", "delay_s")):
        try:
            t, d = float(ts), float(ds)
        except ValueError:
            raise ValueError(f"{path}: row {lineno}: {ts!r}, {ds!r} are not two numbers time_s,delay_s") from None
        if not (math.isfinite(t) and math.isfinite(d)):
            raise ValueError(f"{path}: row {lineno}: values must be finite, got {ts}, {ds}")
        if t < 0.0:
            raise ValueError(f"{path}: row {lineno}: time_s must be >= 0, got {t}")
        if times and t <= times[-1]:
            raise ValueError(f"{path}: row {lineno}: time_s must increase strictly, got {t} after {times[-1]}")
        if d < 0.0:
            raise ValueError(f"{path}: row {lineno}: delay_s must be >= 0, got {d}")
        times.append(t)
        delays.append(d)
    return np.asarray(times), np.asarray(delays)


def load_loss_trace(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a loss trace: one `lost` value per row, 0 (delivered) or 1 (lost), optional header
    and `#` comments. Returns a bool array; raises ValueError naming file, row and problem."""
    out: list[bool] = []
    for lineno, (v,) in _trace_rows(path, 1, ("lost",)):
        if v not in ("0", "1"):
            raise ValueError(f"{path}: row {lineno}: expected 0 or 1, got {v!r}")
        out.append(v == "1")
    return np.asarray(out, dtype=bool)


def _resolve(path: str, base_dir: str | os.PathLike[str] | None) -> Path:
    p = Path(path)
    if not p.is_absolute() and base_dir is not None:
        p = Path(base_dir) / p
    return p


def resolve_trace_paths(cfg: NetworkEffectsConfig, base_dir: str | os.PathLike[str]) -> NetworkEffectsConfig:
    """Make trace paths absolute (relative to `base_dir`, the scene's folder) and check that each
    trace reads cleanly, so a bad trace is reported before anything runs. Returns the new config."""
    delay, loss = cfg.delay, cfg.loss
    if delay is not None and delay.trace is not None:
        p = _resolve(delay.trace.file, base_dir).resolve()
        load_delay_trace(p)
        delay = replace(delay, trace=replace(delay.trace, file=str(p)))
    if loss is not None and loss.model == "trace" and loss.file is not None:
        p = _resolve(loss.file, base_dir).resolve()
        load_loss_trace(p)
        loss = replace(loss, file=str(p))
    return replace(cfg, delay=delay, loss=loss)


def read_operator_trace(path: Path, source: str, key: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The operator's position trace `path` (CSV time_s,position_m): (times, positions).

    Raises ConfigError naming `source` (or the file and row) and `key`."""
    if not path.is_file():
        raise ConfigError(source, key, str(path), "allowed: an existing CSV file with columns time_s,position_m")
    ts: list[float] = []
    xs: list[float] = []
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise ConfigError(source, key, str(path), f"cannot be read ({exc.strerror}); allowed: a readable CSV") from None
    except UnicodeDecodeError:
        raise ConfigError(source, key, str(path), "not UTF-8 text; allowed: a CSV file time_s,position_m") from None
    try:
        rows = list(csv.reader(text.splitlines()))
    except csv.Error as exc:
        raise ConfigError(source, key, str(path), f"not a CSV ({exc}); allowed: rows time_s,position_m") from None
    for lineno, row in enumerate(rows, start=1):
        if not row or row[0].lstrip().startswith("#"):
            continue
        try:
            t, x = float(row[0]), float(row[1])
        except (ValueError, IndexError):
            if lineno == 1:
                continue  # header
            raise ConfigError(f"{path}:{lineno}", key, row, "allowed: two numbers time_s,position_m") from None
        if not (math.isfinite(t) and math.isfinite(x)):
            raise ConfigError(f"{path}:{lineno}", key, row, "allowed: finite numbers time_s,position_m")
        if ts and t <= ts[-1]:
            raise ConfigError(f"{path}:{lineno}", key, row, "allowed: strictly increasing time_s")
        ts.append(t)
        xs.append(x)
    if len(ts) < 2:
        raise ConfigError(source, key, str(path), "allowed: a CSV with at least two rows time_s,position_m")
    return tuple(ts), tuple(xs)


def resolve_scene_traces(config: Scene, base: Path, source: str) -> Scene:
    """Network trace files: relative to the scene's folder, read once now so a bad file stops the run.

    Raises ConfigError naming the scene file and the effects section."""
    net = config.network
    dirs = {}
    for name in ("forward", "backward"):
        d = getattr(net, name)
        try:
            effects = resolve_trace_paths(d.effects, base)
        except (OSError, ValueError) as exc:
            raise ConfigError(
                source, f"network.{name}.effects", "trace", f"allowed: a readable trace file ({exc})"
            ) from None
        dirs[name] = dataclasses.replace(d, effects=effects)
    return dataclasses.replace(config, network=dataclasses.replace(net, **dirs))


def link_traces(cfg: NetworkEffectsConfig, base_dir: str | os.PathLike[str] | None = None) -> LinkTraces:
    """The rows of the trace files `cfg` names (relative paths from `base_dir`, or the working
    directory), for `build_link`."""
    delay = cfg.delay
    loss = cfg.loss
    return LinkTraces(
        delay=load_delay_trace(_resolve(delay.trace.file, base_dir))
        if delay is not None and delay.trace is not None
        else None,
        loss=load_loss_trace(_resolve(loss.file, base_dir))
        if loss is not None and loss.model == "trace" and loss.file is not None
        else None,
    )


def build_scene_link(
    cfg: NetworkEffectsConfig, seed: int, direction: str, *, base_dir: str | os.PathLike[str] | None = None
) -> Link:
    """`build_link` with the rows of the trace files `cfg` names (relative paths from `base_dir`,
    or the working directory; a loaded scene's are absolute already)."""
    return build_link(cfg, seed, direction, traces=link_traces(cfg, base_dir))
