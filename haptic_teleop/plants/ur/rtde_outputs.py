"""A read-only RTDE client for controller outputs that ur_rtde 1.6.5's Python receive interface has
no getter for (docs/ur.md, "Applied, not commanded"): the driver reads `actual_current_as_torque`
through it. ur_rtde's C++ receive interface subscribes that output on PolyScope 5.23 and later
and has `getActualCurrentAsTorque()`, but the 1.6.5 Python binding does not expose it.

One TCP connection to the controller's RTDE port, protocol version 2, one output recipe at the
controller's rate and no inputs, so it takes no input register from ur_rtde's control session
(the controller serves several RTDE clients at once [RTDE guide]). A daemon thread keeps the
newest data package; `latest()` hands it out with a sequence number that tells a fresh package
from one already seen. The package framing is the RTDE guide's, `plants/ur/rtde_wire.py` (pure:
no sockets), which the emulator speaks too.
"""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from haptic_teleop.plants.ur import rtde_wire as w


class RTDEOutputError(Exception):
    """The controller refused the connection or the recipe; the text says what it answered."""


@dataclass(frozen=True)
class OutputPackage:
    """The newest data package: its sequence number (1, 2, ... for each batch of packages taken in;
    a new number is a fresh package) and its values by name."""

    seq: int
    values: dict[str, Any]


class RTDEOutputReader:
    """Subscribe `names` at `frequency_hz` on host:port; `start()` connects (raises RTDEOutputError
    or OSError), `latest()` is the newest package (None before the first), `close()` ends it
    (idempotent). `closed_reason` says why the stream ended, None while it runs."""

    def __init__(
        self, host: str, names: Sequence[str], frequency_hz: float = 500.0, port: int = 30004, timeout_s: float = 2.0
    ) -> None:
        self.host, self.port = host, port
        self.names = tuple(names)
        self.frequency_hz = frequency_hz
        self.timeout_s = timeout_s
        self.closed_reason: str | None = None
        self._sock: socket.socket | None = None
        self._recipe: w.Recipe | None = None
        self._lock = threading.Lock()
        self._latest: OutputPackage | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ the handshake
    def _answer(self, sock: socket.socket, kind: int) -> bytes:
        """The body of the controller's answer of `kind` (text messages in between are skipped)."""
        while True:
            got, body = w.read_package(sock)
            if got == kind:
                return body

    def start(self) -> None:
        sock = self._sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            sock.sendall(w.frame(w.REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2)))
            if self._answer(sock, w.REQUEST_PROTOCOL_VERSION)[:1] != b"\x01":
                raise RTDEOutputError("the controller refused RTDE protocol version 2")
            payload = struct.pack(">d", self.frequency_hz) + ",".join(self.names).encode()
            sock.sendall(w.frame(w.SETUP_OUTPUTS, payload))
            body = self._answer(sock, w.SETUP_OUTPUTS)
            types = body[1:].decode(errors="replace").split(",")
            missing = [n for n, t in zip(self.names, types, strict=False) if t == w.NOT_FOUND]
            if missing or body[:1] == b"\x00" or len(types) != len(self.names):
                raise RTDEOutputError(f"the controller has no RTDE output {', '.join(missing) or body[1:]!r}")
            self._recipe = w.Recipe(body[0], self.names, tuple(types))
            sock.sendall(w.frame(w.START))
            if self._answer(sock, w.START)[:1] != b"\x01":
                raise RTDEOutputError("the controller refused to start the output recipe")
        except BaseException:
            self.close()
            raise
        sock.settimeout(None)
        self._thread = threading.Thread(target=self._run, args=(sock,), name=f"rtde-outputs-{self.host}", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ the stream
    def _run(self, sock: socket.socket) -> None:
        """Take in whatever has arrived and keep only its newest data package: a thread that falls
        behind (a busy host) skips to the present instead of working through old packages."""
        recipe = self._recipe
        assert recipe is not None
        seq = 0
        buf = b""
        try:
            while not self._stop.is_set():
                chunk = sock.recv(65536)
                if not chunk:
                    raise ConnectionError("the controller closed the RTDE connection")
                buf += chunk
                newest = None
                while len(buf) >= w.HEADER.size:
                    size, kind = w.HEADER.unpack_from(buf)
                    if size < w.HEADER.size:
                        raise ValueError(f"an RTDE package of size {size}")
                    if len(buf) < size:
                        break
                    body, buf = buf[w.HEADER.size : size], buf[size:]
                    if kind == w.DATA_PACKAGE and body[:1] == bytes([recipe.recipe_id]):
                        newest = body  # text messages and anything else are not ours
                if newest is not None:
                    seq += 1
                    package = OutputPackage(seq, recipe.unpack(newest[1:]))
                    with self._lock:
                        self._latest = package
        except (OSError, struct.error, ValueError) as exc:  # ConnectionError is an OSError
            if not self._stop.is_set():
                self.closed_reason = str(exc) or type(exc).__name__

    def latest(self) -> OutputPackage | None:
        with self._lock:
            return self._latest

    def close(self) -> None:
        self._stop.set()
        if self.closed_reason is None:
            self.closed_reason = "closed by the driver"
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)  # wakes the reader thread's recv
            with contextlib.suppress(OSError):
                sock.close()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
