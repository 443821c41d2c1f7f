"""A node stopped while it is still starting: the signal is noted from the entry module's first line
(nodes/entry.py) and the node exits 0 with one line, as a node stopped after its start does, not -2
with a KeyboardInterrupt traceback from inside an import (seen when a launch stopped every node
because one failed at start)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

# SIGINT at a chosen moment: when the node process first imports rclpy (its heaviest import),
# after the entry module has been imported.
SIGNAL_AT_RCLPY = """
import os, signal as _s, sys
class _Finder:
    def find_spec(self, name, path=None, target=None):
        if name == "rclpy" and "haptic_teleop.nodes.entry" in sys.modules:
            sys.meta_path.remove(self)
            os.kill(os.getpid(), _s.SIGINT)
        return None
sys.meta_path.insert(0, _Finder())
"""


def _env(tmp_path: Path) -> dict[str, str]:
    (tmp_path / "sitecustomize.py").write_text(SIGNAL_AT_RCLPY)
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))


def test_a_node_console_script_signalled_while_importing_exits_0_with_one_line(tmp_path):
    script = Path(sys.executable).parent / "sync_buffer"
    if not script.is_file():
        pytest.skip("no console script beside this interpreter")
    r = subprocess.run([str(script), "--ros-args", "-p", "direction:=forward"], env=_env(tmp_path),
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "sync_buffer: SIGINT before start; exiting" in r.stderr, r.stderr


def test_the_launchers_node_process_signalled_while_importing_exits_0(tmp_path):
    """The launcher's command line for a node (launcher.node_command: `-m haptic_teleop.nodes.entry`)."""
    from haptic_teleop.live.launcher import NodeSpec, node_command

    params = tmp_path / "p.yaml"
    params.write_text("recorder:\n  ros__parameters: {}\n")
    cmd = node_command(NodeSpec("recorder", "recorder", {}), params)
    r = subprocess.run(cmd, env=_env(tmp_path), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "recorder: SIGINT before start; exiting" in r.stderr, r.stderr


def test_the_entry_module_names_what_it_runs(tmp_path):
    r = subprocess.run([sys.executable, "-m", "haptic_teleop.nodes.entry", "no_such_node"],
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 2 and "EXECUTABLE one of master_eba" in r.stderr, r.stderr
