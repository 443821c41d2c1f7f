"""No node outlives the launcher: SIGKILL of `haptic-teleop launch` stops every node it started
(Linux parent-death signal, haptic_teleop/lifetime.py), and the recorder still closes its bag."""

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from launched import wait_for_bag_messages

pytest.importorskip("rclpy")

CLI = [sys.executable, "-m", "haptic_teleop.cli"]


def _alive(pid: int) -> bool:
    """Running (a zombie waiting for its new parent to reap it counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return not re.search(r"^State:\s+Z", state, re.M)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="parent-death signal is Linux's")
def test_sigkill_of_the_launcher_stops_every_node_and_the_bag_is_closed(tmp_path):
    out = tmp_path / "run"
    p = subprocess.Popen(
        [*CLI, "launch", "wall_contact", "--duration", "60", "--record", str(out), "--no-plots"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,
        start_new_session=True,
    )
    pids: dict[str, int] = {}
    lines: list[str] = []
    assert p.stdout is not None
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = p.stdout.readline()
        if not line:
            break
        lines.append(line)
        m = re.search(r"started (\w+) \(.*\) pid (\d+)", line)
        if m:
            pids[m.group(1)] = int(m.group(2))
        if "scene time 0 at stamp" in line:
            break
    else:
        p.kill()
    assert "recorder" in pids and len(pids) >= 8, "".join(lines[-40:])
    # wait until the recorder has flushed recorded ticks (on this shared machine DDS discovery can
    # take seconds), then kill the launcher (not its nodes)
    wait_for_bag_messages(out / "bag", 120)
    os.kill(p.pid, signal.SIGKILL)
    p.wait(timeout=30)
    end = time.monotonic() + 60
    while time.monotonic() < end and any(_alive(pid) for pid in pids.values()):
        time.sleep(0.1)
    left = {name: pid for name, pid in pids.items() if _alive(pid)}
    for pid in left.values():
        os.kill(pid, signal.SIGKILL)
    assert not left, f"nodes outlived the launcher: {left}"
    # The recorder stopped on SIGTERM like on Ctrl-C: its bag is closed and reads.
    from haptic_teleop.record.reader import BagReader

    assert (out / "bag" / "metadata.yaml").is_file()
    with BagReader(out / "bag") as reader:
        assert reader.read("/operator/joint_states").stamp_ns.size > 0


def test_a_node_that_does_not_stop_prints_its_stacks_before_it_is_killed(tmp_path, monkeypatch):
    """A node that ignores SIGINT past the stop timeout: the launcher sends SIGABRT first, so the
    node's fault handler prints where every thread is into the launcher's output, then kills it."""
    import io
    import threading

    from haptic_teleop.live import launcher as L

    monkeypatch.setattr(L, "ABORT_WAIT_S", 20.0)
    hang = (
        "import signal, sys, time\n"
        "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
        "def stuck_here():\n"
        "    while True:\n"
        "        time.sleep(0.05)\n"
        "print('up', flush=True)\n"
        "stuck_here()\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", hang], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env={**os.environ, "PYTHONFAULTHANDLER": "1"})  # fmt: skip
    out = io.StringIO()
    launcher = L.Launcher([], tmp_path, out=out)
    spec = L.NodeSpec(name="hung", executable="operator_source", params={})
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == b"up"
    pump = threading.Thread(target=launcher._pump, args=("hung", proc.stdout), daemon=True)
    pump.start()
    child = L.Child(spec, proc, pump)
    launcher._stop_group([child], 0.5)
    pump.join(10)
    text = out.getvalue()
    assert child.returncode == -signal.SIGABRT, text
    assert "did not stop within" in text and "its stacks follow" in text
    assert "stuck_here" in text  # the hung thread's Python stack, from its fault handler
