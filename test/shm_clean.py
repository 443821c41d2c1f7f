"""Stale Fast DDS shared-memory files: found and removed before a test session.

Fast DDS (the `ros-kilted-*` wheels' RMW) keeps each participant's shared-memory ports and
segments in /dev/shm: `fastdds_<name>`, its lock files `fastdds_<name>_el` (and `_sl`), and a
port's named semaphore `sem.fastdds_<name>_mutex`. A process killed with SIGKILL leaves them
behind. A later participant of the same ROS domain that reopens a stale port can crash at start
or write into a port no reader drains (docs/live_launch.md, "Native crashes at start"). The tests kill
nodes on purpose and this machine keeps /dev/shm between sessions, so a session starts by removing
the groups of files that are stale, and only those:
- the owner of a live segment or port holds an flock on its lock file (checked here: a lock we
  can take is nobody's), and
- no process we can read has any file of the group mapped or open, and
- every file of the group is older than `min_age_s` (nothing being created right now).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import time
from pathlib import Path

PREFIX = "fastdds_"
_SUFFIXES = ("_el", "_sl", "_mutex")


def group_of(name: str) -> str | None:
    """The segment or port a Fast DDS file belongs to (`fastdds_port7413` for all of
    `fastdds_port7413`, `fastdds_port7413_el`, `sem.fastdds_port7413_mutex`); None for another file."""
    if name.startswith("sem."):
        name = name[4:]
    if not name.startswith(PREFIX):
        return None
    for s in _SUFFIXES:
        if name.endswith(s):
            return name[: -len(s)]
    return name


def files_in_use(shm: Path, proc: Path = Path("/proc")) -> set[str]:
    """Names of files under `shm` that a process (of those this user can read) has mapped or open."""
    mark = f"{shm}/"
    used: set[str] = set()
    for p in proc.iterdir():
        if not p.name.isdigit():
            continue
        with contextlib.suppress(FileNotFoundError, PermissionError, ProcessLookupError):
            for line in (p / "maps").read_text().splitlines():
                i = line.find(mark)
                if i >= 0:
                    used.add(line[i + len(mark) :].split(" (deleted)")[0].strip())
            for fd in (p / "fd").iterdir():
                with contextlib.suppress(OSError):
                    target = os.readlink(fd)
                    if target.startswith(mark):
                        used.add(target[len(mark) :])
    return used


def _locked(path: Path) -> bool:
    """Whether some process holds an flock on `path` (its owner does while it lives)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    finally:
        os.close(fd)


def stale_files(shm: Path = Path("/dev/shm"), min_age_s: float = 30.0, proc: Path = Path("/proc")) -> list[Path]:
    """The files of the stale Fast DDS groups under `shm` (module docstring)."""
    if not shm.is_dir():
        return []
    groups: dict[str, list[Path]] = {}
    for f in shm.iterdir():
        g = group_of(f.name)
        if g is not None:
            groups.setdefault(g, []).append(f)
    used = files_in_use(shm, proc)
    now = time.time()
    out: list[Path] = []
    for g, files in groups.items():
        if any(f.name in used for f in files) or any(_locked(shm / f"{g}{s}") for s in ("_el", "_sl")):
            continue
        try:
            if any(now - f.stat().st_mtime <= min_age_s for f in files):
                continue
        except FileNotFoundError:
            continue
        out.extend(files)
    return sorted(out)


def remove_stale(shm: Path = Path("/dev/shm"), min_age_s: float = 30.0) -> int:
    """Remove `stale_files`; returns how many went."""
    n = 0
    for f in stale_files(shm, min_age_s):
        with contextlib.suppress(OSError):
            f.unlink()
            n += 1
    return n
