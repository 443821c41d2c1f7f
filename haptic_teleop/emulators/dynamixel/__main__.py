"""The bus emulator's process: `python -m haptic_teleop.emulators.dynamixel --config FILE.json`.

Opens a pseudo-terminal, prints `PORT /dev/pts/N` on stdout, then serves the bus on it until
SIGTERM or SIGINT (or, with --die-with-stdin, until its stdin closes; or when its parent dies).
Exits 0 and writes its counters as one JSON line on stderr. A bad configuration: one line on
stderr, exit 2.

Run-time control (optional, `control_socket` in the config): a UNIX stream socket taking one JSON
object per line, answered by one JSON line:
  {"cmd": "fault", "servo_id": 1, "kind": "hardware_error", "bits": 32}   (FaultConfig keys, no at_*)
  {"cmd": "counters"}   the counters so far
  {"cmd": "state"}      emulator time, joint names, q (rad), qd (rad/s), and per servo its torque
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import select
import signal
import socket
import sys
import termios
import time
import tty
from typing import Any

from haptic_teleop.emulators.dynamixel import protocol as p
from haptic_teleop.emulators.dynamixel.bus import Bus, Reply
from haptic_teleop.emulators.dynamixel.config import BusConfig, FaultConfig
from haptic_teleop.errors import ConfigError, HapticTeleopError
from haptic_teleop.lifetime import as_hardware, die_with_parent
from haptic_teleop.plants.dynamixel import tables as t
from haptic_teleop.typedconfig import build

SPIN_S = 200e-6
"""The last part of each wait is a busy loop on time.perf_counter (sleep is too coarse at 4 Mbps)."""
IDLE_POLL_S = 0.002
"""How often an idle bus advances its realtime physics and checks its watchdogs."""


def wait_until(clock0: float, target_s: float) -> float:
    """Sleep, then spin, until the bus clock reads `target_s`; returns how late it was (s)."""
    while True:
        now = time.perf_counter() - clock0
        left = target_s - now
        if left <= 0.0:
            return -left
        if left > SPIN_S:
            time.sleep(left - SPIN_S)


class Server:
    def __init__(self, bus: Bus, die_with_stdin: bool) -> None:
        self.bus = bus
        self.die_with_stdin = die_with_stdin
        self.stop = False
        self.parser = p.Parser()
        self.clock0 = time.perf_counter()
        self.late_max_s = 0.0
        self.late_sum_s = 0.0
        self.late_n = 0
        self.master_fd, self.slave_fd = os.openpty()
        tty.setraw(self.slave_fd, termios.TCSANOW)
        os.set_blocking(self.master_fd, False)
        self.port = os.ttyname(self.slave_fd)
        self.listener: socket.socket | None = None
        self.clients: dict[int, tuple[socket.socket, bytearray]] = {}
        path = bus.cfg.control_socket
        if path:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(path)
            self.listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self.listener.bind(path)
            self.listener.listen(4)
            self.listener.setblocking(False)
        self.pending_since: float | None = None

    def now(self) -> float:
        return time.perf_counter() - self.clock0

    def serve(self) -> None:
        realtime = self.bus.cfg.time.mode == "realtime"
        while not self.stop:
            fds: list[Any] = [self.master_fd]
            if self.die_with_stdin:
                fds.append(sys.stdin.fileno())
            if self.listener is not None:
                fds.append(self.listener)
                fds.extend(c for c, _ in self.clients.values())
            try:
                ready, _, _ = select.select(fds, [], [], IDLE_POLL_S)
            except InterruptedError:
                continue
            if self.stop:
                break
            now = self.now()
            if realtime:  # (in lockstep the watchdog runs on the emulator's time: Bus.handle checks it)
                self.bus.advance_to(now)
                self.bus.check_watchdogs(now)
            for fd in ready:
                if fd == self.master_fd:
                    self._line(now)
                elif self.die_with_stdin and fd == sys.stdin.fileno():
                    if not os.read(fd, 4096):
                        self.stop = True
                elif fd is self.listener:
                    self._accept()
                else:
                    self._client(fd)

    # ------------------------------------------------------------------------ the line

    def _line(self, t_read: float) -> None:
        try:
            chunk = os.read(self.master_fd, 65536)
        except BlockingIOError:
            return
        except OSError:
            return
        if not chunk:
            return
        start = self.pending_since if self.parser.pending and self.pending_since is not None else t_read
        baud = self.bus.baud_bps
        replies: list[Reply] = []
        for item in self.parser.feed(chunk):
            wire = t.wire_time_s(item.wire_bytes, baud)
            end = max(t_read, start + wire)
            if isinstance(item, p.FramingError):
                self.bus.framing_error(item)
            else:
                if self.bus.cfg.time.mode == "realtime":
                    self.bus.advance_to(end)
                replies.extend(self.bus.handle(item, end))
            start = end
        self.pending_since = start if self.parser.pending else None
        for r in replies:
            late = wait_until(self.clock0, r.deliver_s)
            self.late_max_s = max(self.late_max_s, late)
            self.late_sum_s += late
            self.late_n += 1
            self._write(r.data)

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.master_fd, view)
            except BlockingIOError:
                select.select([], [self.master_fd], [], 0.01)
                continue
            view = view[n:]

    # ------------------------------------------------------------------------ control socket

    def _accept(self) -> None:
        assert self.listener is not None
        with contextlib.suppress(BlockingIOError):
            conn, _ = self.listener.accept()
            conn.setblocking(False)
            self.clients[conn.fileno()] = (conn, bytearray())

    def _client(self, fd: Any) -> None:
        key = fd.fileno() if isinstance(fd, socket.socket) else fd
        conn, buf = self.clients[key]
        try:
            data = conn.recv(65536)
        except BlockingIOError:
            return
        if not data:
            del self.clients[key]
            conn.close()
            return
        buf += data
        while b"\n" in buf:
            line, _, rest = bytes(buf).partition(b"\n")
            buf[:] = rest
            answer = self._command(line)
            with contextlib.suppress(OSError):
                conn.setblocking(True)
                conn.sendall((json.dumps(answer) + "\n").encode())
                conn.setblocking(False)

    def _command(self, line: bytes) -> dict[str, Any]:
        try:
            msg = json.loads(line)
            if not isinstance(msg, dict):
                raise ValueError("a JSON object per line")
            cmd = msg.pop("cmd", None)
            if cmd == "fault":
                f = build(FaultConfig, {**msg, "at_transaction": 0}, "fault", "control socket")
                self.bus.apply_fault(f)
                return {"ok": True}
            if cmd == "counters":
                return {"ok": True, "counters": self.counters()}
            if cmd == "state":
                q, qd = self.bus.physics.state()
                return {
                    "ok": True,
                    "time_s": self.bus.time_s,
                    "joints": list(self.bus.physics.joints),
                    "q_rad": [float(v) for v in q],
                    "qd_rad_per_s": [float(v) for v in qd],
                    "torque_nm": [float(v) for v in self.bus.torques_nm()],
                }
            raise ValueError(f"unknown cmd {cmd!r}; allowed: fault, counters, state")
        except (ValueError, HapticTeleopError) as exc:
            return {"ok": False, "error": str(exc)}

    def counters(self) -> dict[str, Any]:
        out: dict[str, Any] = dict(self.bus.counters)
        out["late_max_s"] = self.late_max_s
        out["late_mean_s"] = self.late_sum_s / self.late_n if self.late_n else 0.0
        out["time_s"] = self.bus.time_s
        out["baud_bps"] = self.bus.baud_bps
        return out

    def close(self) -> None:
        for conn, _ in self.clients.values():
            conn.close()
        if self.listener is not None:
            self.listener.close()
            with contextlib.suppress(OSError):
                os.unlink(self.bus.cfg.control_socket or "")
        os.close(self.master_fd)
        os.close(self.slave_fd)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m haptic_teleop.emulators.dynamixel", description=__doc__.split("\n")[0])
    ap.add_argument("--config", required=True, help="a JSON file of BusConfig, or - to read it from stdin")
    ap.add_argument("--die-with-stdin", action="store_true", help="also stop when stdin is closed")
    args = ap.parse_args(argv)
    die_with_parent(signal.SIGTERM)
    as_hardware()  # a servo never waits for the host's scheduler (lifetime.HARDWARE_NICE)
    try:
        if args.config == "-":
            text, source = sys.stdin.read(), "stdin"
        else:
            with open(args.config) as fh:
                text, source = fh.read(), args.config
        cfg = BusConfig.from_json(text, source)
        bus = Bus(cfg, notes=lambda line: print(f"dynamixel emulator: {line}", file=sys.stderr, flush=True))
    except (ConfigError, OSError) as exc:
        print(f"dynamixel emulator: {exc}", file=sys.stderr)
        return 2
    except (ValueError, HapticTeleopError) as exc:
        print(f"dynamixel emulator: {args.config}: {exc}", file=sys.stderr)
        return 2
    server = Server(bus, args.die_with_stdin and args.config != "-")

    def stop(_sig: int, _frame: object) -> None:
        server.stop = True

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    print(f"PORT {server.port}", flush=True)
    try:
        server.serve()
    finally:
        counters = server.counters()
        server.close()
        print(json.dumps({"counters": counters}), file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
