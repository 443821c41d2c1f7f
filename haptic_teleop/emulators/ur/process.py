"""Start the UR emulator in its own process (its timing is its own) and talk to its test channel.

    with start_ur(URConfig(...)) as ur:
        ... rtde_receive.RTDEReceiveInterface(ur.host, 500.0) ...
        ur.state()["q_rad"]; ur.inject("protective_stop"); ur.inject("joint_fault", joint=5, kind="brake")

ur_rtde 1.6.5 connects to fixed ports (RTDE 30004, dashboard 29999, scripts 30003), so only one
emulator on those ports can run on a host at a time: `start_ur` holds an exclusive file lock
(LOCK_PATH) while one runs, and a second caller waits for it (tests serialise there).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from haptic_teleop.emulators.ur.config import URConfig
from haptic_teleop.errors import PlantError

LOCK_PATH = Path(tempfile.gettempdir()) / "haptic_teleop_ur_emulator.lock"
START_TIMEOUT_S = 60.0


class URProcess:
    """A running emulator: `host`, `ports` (name -> port: rtde, dashboard, script0.., control)."""

    def __init__(self, proc: subprocess.Popen[str], host: str, ports: dict[str, int], lock: IO[str], tmp: Path) -> None:
        self.proc = proc
        self.host = host
        self.ports = ports
        self._lock = lock
        self._tmp = tmp
        self._sock: socket.socket | None = None
        self._file: IO[bytes] | None = None

    def request(self, cmd: str, **args: Any) -> dict[str, Any]:
        """One request on the emulator's test channel (state, protective_stop, safety_stop, stop_program,
        joint_fault, freeze, drop_connections)."""
        if self._sock is None:
            self._sock = socket.create_connection((self.host, self.ports["control"]), timeout=30.0)
            self._file = self._sock.makefile("rb")
        assert self._file is not None
        self._sock.sendall((json.dumps({"cmd": cmd, **args}) + "\n").encode())
        reply: dict[str, Any] = json.loads(self._file.readline())
        return reply

    def state(self) -> dict[str, Any]:
        return self.request("state")

    def inject(self, fault: str, **args: Any) -> None:
        """An injected fault (docs/ur_emulator.md, "The emulator"); one the emulator does not know is an error here,
        not a test that waits in vain for its effect."""
        reply = self.request(fault, **args)
        if "error" in reply:
            raise PlantError(f"the UR emulator refused the fault {fault!r}: {reply['error']}")

    def stop(self) -> None:
        """End the emulator (SIGTERM, then SIGKILL after 10 s) and release the port lock; idempotent."""
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
            self._sock = None
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if not self._lock.closed:
            fcntl.flock(self._lock, fcntl.LOCK_UN)
            self._lock.close()
        with contextlib.suppress(OSError):
            self._tmp.unlink()

    def __enter__(self) -> URProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def start_ur(config: URConfig | None = None) -> URProcess:
    """Start an emulator with `config` and wait until it listens (READY)."""
    cfg = config or URConfig()
    lock = open(LOCK_PATH, "a")  # noqa: SIM115 (held for the emulator's life)
    fcntl.flock(lock, fcntl.LOCK_EX)
    fd, name = tempfile.mkstemp(prefix="ur_emulator_", suffix=".json")
    tmp = Path(name)
    with os.fdopen(fd, "w") as f:
        json.dump(cfg.to_dict(), f)
    err = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 (the child writes into it)
    proc = subprocess.Popen(
        [sys.executable, "-m", "haptic_teleop.emulators.ur", "--config", str(tmp)],
        stdout=subprocess.PIPE,
        stderr=err,
        text=True,
    )
    assert proc.stdout is not None
    deadline = time.monotonic() + START_TIMEOUT_S
    line = ""
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if line.startswith("READY") or not line:
            break
    if not line.startswith("READY"):
        proc.kill()
        proc.wait()
        err.seek(0)
        fcntl.flock(lock, fcntl.LOCK_UN)
        lock.close()
        raise PlantError(f"the UR emulator did not start: {err.read().strip() or line.strip() or 'no output'}")
    parts = line.split()
    ports = {k: int(v) for k, v in (p.split("=") for p in parts[2:])}
    return URProcess(proc, parts[1], ports, lock, tmp)


@contextlib.contextmanager
def running_ur(config: URConfig | None = None) -> Iterator[URProcess]:
    ur = start_ur(config)
    try:
        yield ur
    finally:
        ur.stop()
