"""Start the bus emulator in its own process from Python (tests, bench, the integrator).

    with start_bus(BusConfig.from_dict({...})) as bus:
        port = PortHandler(bus.port) ...
        bus.inject(servo_id=1, kind="hardware_error", bits=32)
    counters = bus.stop()   # also what `with` calls; idempotent

The child is `sys.executable -m haptic_teleop.emulators.dynamixel`; it dies with this process
(PR_SET_PDEATHSIG, and end of file on its stdin). The pty master stays in the child only.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Any

from haptic_teleop.emulators.dynamixel.config import BusConfig
from haptic_teleop.errors import HapticTeleopError

PACKAGE_ROOT = Path(__file__).resolve().parents[3]


class EmulatorError(HapticTeleopError):
    """The emulator did not start, or its control socket refused a command; the message says why."""


class DynamixelBus:
    """A running emulator: `.port` (the pty path for PortHandler), `.alive()`, `.stop()`."""

    def __init__(self, proc: subprocess.Popen[bytes], port: str, control: str | None, tmpdir: str) -> None:
        self.proc = proc
        self.port = port
        self.control_path = control
        self._tmpdir = tmpdir
        self._counters: dict[str, Any] | None = None
        self.stderr_text = ""

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def command(self, **msg: Any) -> dict[str, Any]:
        """Send one control command (see __main__.py) and return its answer."""
        if self.control_path is None:
            raise EmulatorError("this bus has no control socket (start_bus(..., control=True))")
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(10.0)
            s.connect(self.control_path)
            s.sendall((json.dumps(msg) + "\n").encode())
            buf = b""
            while not buf.endswith(b"\n"):
                chunk = s.recv(65536)
                if not chunk:
                    break
                buf += chunk
        answer: dict[str, Any] = json.loads(buf)
        if not answer.get("ok"):
            raise EmulatorError(f"emulator refused {msg}: {answer.get('error')}")
        return answer

    def inject(self, **fault: Any) -> None:
        """A fault now: servo_id, kind (config.FAULT_KINDS) and its bits/count/extra_delay_s."""
        self.command(cmd="fault", **fault)

    def counters(self) -> dict[str, Any]:
        result: dict[str, Any] = self.command(cmd="counters")["counters"]
        return result

    def state(self) -> dict[str, Any]:
        return self.command(cmd="state")

    def stop(self, timeout_s: float = 10.0) -> dict[str, Any]:
        """SIGTERM, wait, and the counters it wrote at exit ({} if it wrote none)."""
        if self._counters is not None:
            return self._counters
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            _, err = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        self.stderr_text = err.decode(errors="replace")
        self._counters = {}
        for line in reversed(self.stderr_text.splitlines()):
            with contextlib.suppress(ValueError):
                obj = json.loads(line)
                if isinstance(obj, dict) and "counters" in obj:
                    self._counters = obj["counters"]
                    break
        shutil.rmtree(self._tmpdir, ignore_errors=True)
        return self._counters

    def __enter__(self) -> DynamixelBus:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()


def start_bus(config: BusConfig, timeout_s: float = 90.0, control: bool = True) -> DynamixelBus:
    """Start an emulator for `config` and wait for its port; EmulatorError naming why not. The wait
    is long: a MuJoCo-physics emulator imports MuJoCo and loads its model, which on a busy 2-core
    machine (a test run beside a fresh clone's compiling) once took more than 30 s."""
    tmpdir = tempfile.mkdtemp(prefix="dxl-emu-")
    control_path = config.control_socket
    if control and control_path is None:
        control_path = os.path.join(tmpdir, "control.sock")
        config = dataclasses.replace(config, control_socket=control_path)
    cfg_path = os.path.join(tmpdir, "bus.json")
    with open(cfg_path, "w") as fh:
        fh.write(config.to_json())
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(PACKAGE_ROOT), env.get("PYTHONPATH", "")) if p)
    proc = subprocess.Popen(
        [sys.executable, "-m", "haptic_teleop.emulators.dynamixel", "--config", cfg_path, "--die-with-stdin"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout_s
    line = b""
    while not line.endswith(b"\n"):
        left = deadline - time.monotonic()
        ready, _, _ = select.select([proc.stdout], [], [], max(0.0, left))
        if not ready:
            proc.kill()
            _, err = proc.communicate()
            shutil.rmtree(tmpdir, ignore_errors=True)
            raise EmulatorError(
                f"the Dynamixel emulator printed no PORT line within {timeout_s} s: {err.decode()[-500:]}"
            )
        ch = os.read(proc.stdout.fileno(), 1)
        if not ch:
            _, err = proc.communicate()
            shutil.rmtree(tmpdir, ignore_errors=True)
            raise EmulatorError(
                f"the Dynamixel emulator exited with {proc.returncode} before its port: {err.decode().strip()[-800:]}"
            )
        line += ch
    text = line.decode().strip()
    if not text.startswith("PORT "):
        proc.kill()
        raise EmulatorError(f"the Dynamixel emulator printed {text!r}, not 'PORT /dev/pts/N'")
    bus = DynamixelBus(proc, text[5:], control_path, tmpdir)
    if control_path is not None:
        while not os.path.exists(control_path) and time.monotonic() < deadline:
            time.sleep(0.01)
    return bus
