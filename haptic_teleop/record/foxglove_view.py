"""A live view of a run in Foxglove: a Foxglove WebSocket server (the `foxglove-sdk` package) fed the
rows a recording appends (`RunRecorder(view=...)`), as they are written (docs/foxglove.md).

One JSON channel per group of the row's columns, named by the columns' prefix: `/view/op` (the
operator), `/view/m` (master: position, velocity, force, the EBA reservoir), `/view/s` (slave, and
the wall force), `/view/fwd` and `/view/bwd` (each direction's released sample and buffer
occupancy), for an arm or NVE scene the groups its schema has; and `/view/packets`: per direction the
packets recorded so far, `sent` and by fate (the names the caller passes: core.link.FATE_NAMES). Each message is
`{"t_s": scene time, <column>: value, ...}`, logged at its scene time.

At most `rate_hz` rows a second of wall time go out (the newest row at that moment): a compiled
run at 200 times real time shows its latest state instead of flooding the viewer, a live run at
1 kHz shows every tenth tick. The view never holds up the recording: a slow or absent viewer costs
the encoding of the rows sent, nothing more (the server drops what a client cannot take).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from haptic_teleop.errors import InputError

DEFAULT_PORT = 8765  # Foxglove's default connection (ws://localhost:8765)
VIEW_PORT = "view.foxglove_port"  # the recorder node's parameter (launch --foxglove)
DEFAULT_RATE_HZ = 50.0
PREFIX = "/view"


def column_groups(columns: Sequence[str]) -> dict[str, list[int]]:
    """Column indices by channel: the text before each column's first underscore ("m_x_m" -> "m")."""
    groups: dict[str, list[int]] = {}
    for i, name in enumerate(columns):
        groups.setdefault(name.split("_", 1)[0], []).append(i)
    return groups


class FoxgloveView:
    """The server and its channels; `rows` and `packets` are called by the recording, `close` at its end."""

    def __init__(
        self,
        columns: Sequence[str],
        period_ns: int,
        fate_names: Mapping[int, str],
        port: int = DEFAULT_PORT,
        host: str = "127.0.0.1",
        rate_hz: float = DEFAULT_RATE_HZ,
        name: str = "haptic_teleop",
    ) -> None:
        try:
            import foxglove
        except ImportError:
            raise InputError(
                "--foxglove needs the Python package foxglove-sdk, which is not installed: "
                "pip install 'foxglove-sdk>=0.30' (or install haptic_teleop with its 'standalone' extra)"
            ) from None
        self.columns = tuple(columns)
        self.fate_names = dict(fate_names)
        self.period_ns = period_ns
        self.min_gap_s = 1.0 / rate_hz
        self._last = -float("inf")
        self._tick = 0  # the next row's tick
        self._counts: dict[str, dict[str, int]] = {}
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
        except Exception as exc:  # noqa: BLE001 - the SDK's own error type: a taken port, mostly
            raise InputError(
                f"--foxglove {port}: cannot serve on {host}:{port} ({exc}); allowed: a free port"
            ) from None
        self.port = int(self.server.port)
        self.groups = column_groups(self.columns)
        self.channels = {
            g: foxglove.Channel(
                f"{PREFIX}/{g}", schema=_schema(["t_s", *(self.columns[i] for i in idx)]), context=self.context
            )
            for g, idx in self.groups.items()
        }
        self.packet_channel = foxglove.Channel(f"{PREFIX}/packets", message_encoding="json", context=self.context)

    def rows(self, rows: np.ndarray) -> None:
        """The next k ticks the recording appended: the newest goes out if `min_gap_s` of wall time
        passed since the last one sent."""
        first = self._tick
        self._tick += rows.shape[0]
        now = time.monotonic()
        if rows.shape[0] == 0 or now - self._last < self.min_gap_s:
            return
        self._last = now
        tick = first + rows.shape[0] - 1
        row = rows[-1]
        log_ns = tick * self.period_ns
        for g, idx in self.groups.items():
            msg: dict[str, Any] = {"t_s": log_ns * 1e-9}
            msg.update({self.columns[i]: _json_number(row[i]) for i in idx})
            self.channels[g].log(msg, log_time=log_ns)

    def packets(self, direction: str, rows: np.ndarray) -> None:
        """Packet records of `direction` the recording appended (record.layouts PACKET_FIELDS rows):
        the running count by fate goes out."""
        from haptic_teleop.record.layouts import PACKET_FIELDS

        count = self._counts.setdefault(direction, {"sent": 0, **dict.fromkeys(self.fate_names.values(), 0)})
        rows = np.asarray(rows, dtype=float).reshape(-1, len(PACKET_FIELDS))
        fate = rows[:, PACKET_FIELDS.index("fate")].astype(int)
        count["sent"] += rows.shape[0]
        for code, name in self.fate_names.items():
            count[name] += int(np.count_nonzero(fate == code))
        log_ns = max(self._tick - 1, 0) * self.period_ns
        self.packet_channel.log({"t_s": log_ns * 1e-9, **self._counts}, log_time=log_ns)

    def close(self) -> None:
        self.server.stop()


def _json_number(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None  # JSON has no NaN: null


def _schema(names: Sequence[str]) -> dict[str, Any]:
    return {"type": "object", "properties": {n: {"type": ["number", "null"]} for n in names}}


def serve_view(
    columns: Sequence[str], period_ns: int, fate_names: Mapping[int, str], port: int, say: Any
) -> FoxgloveView:
    """A FoxgloveView on `port` (0: any free one), and `say` where it serves."""
    view = FoxgloveView(columns, period_ns, fate_names, port=port)
    say(f"Foxglove live view on ws://127.0.0.1:{view.port} (Foxglove: Open connection)")
    return view
