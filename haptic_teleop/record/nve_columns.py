"""Stand-in for the NVE record schema (the full one, with its topics, replaces this module)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class NveSchema:
    """The columns of an NVE run's tick row: the server's object, then per client its HIP, the
    object it sees, its force and its link facts (docs/nve.md)."""

    clients: tuple[str, ...]
    axes: int

    @property
    def width(self) -> int:
        return 3 * self.axes + len(self.clients) * (5 * self.axes + 6)

    def facts(self) -> dict[str, Any]:
        return {"clients": list(self.clients), "axes": self.axes}
