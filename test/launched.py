"""`haptic-teleop launch ...` (or any command: `Child`) as a child process for the live tests
(test_live.py, test_live_arm.py, test_live_hardware.py, test_live_device_record.py,
test_launch_files.py): its output lines collected as they come, waits on them, exit codes."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

CLI = [sys.executable, "-m", "haptic_teleop.cli"]


def wait_for_bag_messages(bag: Path, timeout_s: float) -> None:
    """Until the bag's MCAP file, still being written, holds a complete chunk of messages (the
    recorder has ticks on disk): a condition, not a sleep, since DDS discovery on this shared
    machine can take seconds."""
    from haptic_teleop.errors import BagError
    from haptic_teleop.record.mcapread import scan

    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        for mcap in bag.glob("*.mcap"):
            try:
                if scan(mcap).messages > 0:
                    return
            except (OSError, BagError):  # a file still being started: look again
                pass
        time.sleep(0.1)
    raise AssertionError(f"no recorded messages in {bag} within {timeout_s} s")


def failure_text(text: str) -> str:
    """The output's last 4000 characters, after the start of the first native crash report (`Fatal
    Python error`, its first 3000 characters) when the tail does not hold it: the frames that say
    where a process aborted come first, and the tail alone cuts them."""
    tail = text[-4000:]
    at = text.find("Fatal Python error")
    if at < 0 or at >= len(text) - 4000:
        return tail
    return text[at : at + 3000] + "\n[...]\n" + tail


class Child:
    """A command as a child process (stdin closed); its output lines are collected as they come."""

    def __init__(self, cmd: list[str], cwd: Path | None = None, env: dict[str, str] | None = None) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1", **(env or {}))
        self.proc = subprocess.Popen(
            cmd,
            cwd=cwd,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    @property
    def text(self) -> str:
        return "\n".join(self.lines)

    @property
    def failure(self) -> str:
        """What an assertion shows (`failure_text` of the output)."""
        return failure_text(self.text)

    def wait_for(self, pattern: str, timeout_s: float) -> re.Match[str]:
        end = time.monotonic() + timeout_s
        rx = re.compile(pattern)
        while time.monotonic() < end:
            for line in list(self.lines):
                m = rx.search(line)
                if m:
                    return m
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        raise AssertionError(f"no line matching {pattern!r} within {timeout_s} s; output:\n{self.failure}")

    def finish(self, timeout_s: float) -> int:
        try:
            code = self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(f"still running after {timeout_s} s:\n{self.failure}") from None
        self._reader.join(5)
        return code


class Launch(Child):
    """`haptic-teleop launch ...` as a child process: its launcher's lines, exit codes, loop table."""

    def __init__(self, *args: str, cwd: Path, env: dict[str, str] | None = None) -> None:
        super().__init__([*CLI, "launch", *args], cwd=cwd, env=env)

    def pid_of(self, node: str) -> int:
        return int(self.wait_for(rf"started {node} \(\w+\) pid (\d+)", 30).group(1))

    def exit_codes(self) -> dict[str, int]:
        return {m.group(1): int(m.group(2)) for m in re.finditer(r"\[launcher\] (\w+) exited (-?\d+)", self.text)}

    def loop_table(self) -> str:
        """The launcher's table of each node's loop over the run."""
        i = self.text.find("loops (whole run):")
        return self.text[i : i + 2400] if i >= 0 else "(no loop table)"

    def loop_row(self, node: str) -> tuple[int, int, int]:
        """`node`'s row of the loop table: (ticks run, late ticks, skipped ticks). Counts, not rates:
        a test may use them to allow for what a busy machine's loops skipped."""
        table = self.loop_table()
        m = re.search(rf"^\s+{node}\s+(\d+)\s+[\d.]+\s+(\d+)\s+(\d+)", table, re.MULTILINE)
        assert m, table
        return int(m.group(1)), int(m.group(2)), int(m.group(3))

    def end_late_s(self, node: str) -> float:
        """`node`'s "latest end" in the loop table (s): the most a tick's work ended after its deadline,
        so whatever the tick took (inputs, samples) it took no later than that after its deadline."""
        table = self.loop_table()
        m = re.search(rf"^\s+{node}\s+\d+\s+[\d.]+\s+\d+\s+\d+\s+([\d.]+)", table, re.MULTILINE)
        assert m, table
        return float(m.group(1)) * 1e-3
