"""Experiment runs as bags: each run recorded to `bags/NNN_<key>` and what the tables use read back
from its bag, so every figure of an experiment can be checked from data.

`BagRuns` names the bags in run order, keeps `bags/index.csv` (each bag's run, settings and scene
overrides; rewritten after every run, so a Ctrl-C leaves it naming every bag written) and
deletes each bag once read with `discard`; without a folder the bags go to a
temporary directory. `record_ticks` runs a teleoperation scene into a bag and returns its tick rows
and packet records as the bag holds them (`BagReader.read_ticks`, `packets`).
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.replications.tables import write_csv

INDEX_HEADER = ["bag", "run", "settings", "overrides"]


def compression(discard: bool) -> str:
    """The scene override for an experiment's bags: zstd (a fifth of the size, about no time here)
    for bags kept, none for bags measured and deleted (compressing them would cost time for nothing)."""
    return f"recording.compression={'none' if discard else 'zstd'}"


def bags_line(out: Path, discard: bool) -> str:
    """What an experiment prints last about its bags."""
    return "bags:  measured, then deleted (--discard-bags)" if discard else f"bags:  {out / 'bags'}"


@dataclass
class BagRuns:
    """Where an experiment's runs are recorded, and the index of them."""

    bags: Path | None = None
    discard: bool = False
    index: list[list[str]] = field(default_factory=list, init=False)

    @contextmanager
    def bag(self, key: str, label: str = "", settings: str = "", overrides: Sequence[str] = ()) -> Iterator[Path]:
        """The path of the next run's bag (`NNN_<key>`): record into it and read it inside the block;
        indexed after it, also when a Ctrl-C stopped it (its bag is closed and readable)."""
        with tempfile.TemporaryDirectory() as tmp:
            path = self._next(key, Path(tmp))
            try:
                yield path
            finally:
                self._add(path, label, settings, overrides)
            self.drop(path)

    def reserve(self, key: str, label: str = "", settings: str = "", overrides: Sequence[str] = ()) -> Path:
        """The next run's bag path, for runs recorded elsewhere (worker processes), indexed now; the
        caller records into it and calls `drop` once it is read."""
        if self.bags is None:
            raise ValueError("reserve needs a bag folder")
        path = self._next(key, self.bags)
        self._add(path, label, settings, overrides)
        return path

    def drop(self, path: Path) -> None:
        """With `discard`, delete a bag once read (and the bag folder once empty)."""
        if not self.discard:
            return
        if path.exists():
            shutil.rmtree(path)
        if path.parent.is_dir() and not any(path.parent.iterdir()):
            path.parent.rmdir()

    def _next(self, key: str, temporary: Path) -> Path:
        return (self.bags if self.bags is not None else temporary) / f"{len(self.index) + 1:03d}_{key}"

    def _add(self, path: Path, label: str, settings: str, overrides: Sequence[str]) -> None:
        self.index.append([path.name, label, settings, " ".join(overrides)])
        self.write_index()

    def write_index(self) -> None:
        """`bags/index.csv`, when the bags are kept."""
        if self.bags is not None and self.index and not self.discard:
            self.bags.mkdir(parents=True, exist_ok=True)  # reserved paths come before their bags
            write_csv(self.bags / "index.csv", INDEX_HEADER, self.index)


@dataclass(frozen=True)
class Ticks:
    """One recorded run as its bag holds it: the tick rows (`BagReader.read_ticks`) and the packet
    records of both directions (record.layouts.PACKET_FIELDS rows, by seq)."""

    rows: np.ndarray
    schema: Any
    forward_log: np.ndarray
    backward_log: np.ndarray

    def column(self, name: str) -> np.ndarray:
        out: np.ndarray = self.rows[:, self.schema.index(name)]
        return out


def record_ticks(scene: Any, bag: Path) -> Ticks:
    """Run the teleoperation `scene` recorded to `bag` (the engine's own loop choice) and read it back."""
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.record.reader import BagReader

    record_run(scene, bag, parallel=False, handle_sigint=False)
    with BagReader(bag) as reader:
        none = np.zeros((0, 6))
        return Ticks(
            reader.read_ticks(),
            reader.schema,
            reader.packets("/forward/packets") if reader.has("/forward/packets") else none,
            reader.packets("/backward/packets") if reader.has("/backward/packets") else none,
        )
