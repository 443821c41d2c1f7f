"""When scene time starts live (docs/live_network.md, "Network effects run in scene time"): the operator
source announces scene time 0 only once the slave's loop runs, shown by a sample of its state, not
as soon as a publisher of /slave/joint_states exists (a node declares its publisher seconds before
its loop runs when a busy machine is still building its plant and codec).

One real operator_source process over real DDS; this test's own node plays the master (its state,
published) and a slave that has declared its publisher but not yet ticked. Nothing is timed: the
operator's loop is seen running by its own diagnostics.
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

rclpy = pytest.importorskip("rclpy")

TIMEOUT_S = 60.0


def _operator(**override: str) -> subprocess.Popen[str]:
    params = {
        "start.wait_for_publishers": "['/slave/joint_states']",
        "start.min_subscribers": "0",
        "start.delay_s": "0.0",
        "start.timeout_s": "600.0",
        "stop_at_end": "false",
        **override,
    }
    args = [a for k, v in params.items() for a in ("-p", f"{k}:={v}")]
    return subprocess.Popen(
        [sys.executable, "-m", "haptic_teleop.nodes.operator_source", "--ros-args", *args],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip


def test_scene_time_starts_only_once_the_slave_has_sent_a_sample():
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Header

    from haptic_teleop.nodes.topics import MASTER_STATE, SCENE_START_TOPIC, SLAVE_STATE, latched_qos

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("test_start_graph", context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    started: list[Header] = []
    diagnostics: list[DiagnosticArray] = []
    node.create_subscription(Header, SCENE_START_TOPIC, started.append, latched_qos())
    node.create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda m: diagnostics.extend([m] if any(s.hardware_id == "operator_source" for s in m.status) else []), 10,
    )  # fmt: skip
    master = node.create_publisher(JointState, MASTER_STATE, 10)
    slave = node.create_publisher(JointState, SLAVE_STATE, 10)  # declared, silent: the slave not ticking yet
    proc = _operator()

    def state(name: str) -> JointState:
        m = JointState(name=[name], position=[0.0], velocity=[0.0], effort=[0.0])
        m.header.stamp = node.get_clock().now().to_msg()
        return m

    def spin_until(done, publish_slave: bool) -> bool:
        end = time.monotonic() + TIMEOUT_S
        while time.monotonic() < end and proc.poll() is None:
            master.publish(state("master_x"))
            if publish_slave:
                slave.publish(state("slave_x"))
            executor.spin_once(timeout_sec=0.01)
            if done():
                return True
        return False

    try:
        # The operator's loop runs and hears the master (two diagnostics reports, a second apart),
        # and the slave's publisher is there: with the publisher alone the graph is not up.
        seen = spin_until(lambda: len(diagnostics) >= 3 and node.count_subscribers(MASTER_STATE) > 0, False)
        assert seen, "the operator source never reported its loop"
        assert slave.get_subscription_count() > 0  # the operator listens for the slave's state
        assert not started, "scene time announced before the slave sent a sample"
        # The slave's first sample: now the graph is up and scene time 0 is announced (latched).
        announced = spin_until(lambda: bool(started), True)
    finally:
        proc.terminate()
        out = proc.communicate(timeout=30)[0]
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert announced, f"no scene start after the slave's sample; the operator source printed:\n{out}"
    assert "Traceback" not in out, out
    assert "graph is up" in out, out


def test_a_graph_that_never_comes_up_is_named_part_by_part():
    """Alone, with its default wait list and a 1 s start timeout (its own clock), the operator source
    exits 1 with one line (no traceback) that names each part of the graph still missing: the master's and the
    slave's samples, its subscriber, the publishers it waits for (a CI run once ended with a bare
    "not up within 30 s" and nothing saying which link was down)."""
    from haptic_teleop.nodes.topics import MASTER_STATE, OPERATOR_STATE, SLAVE_STATE, received_topic

    proc = _operator(**{"start.wait_for_publishers": "['/slave/joint_states', '/forward/received']",
                        "start.min_subscribers": "1", "start.timeout_s": "1.0"})  # fmt: skip
    out = proc.communicate(timeout=TIMEOUT_S)[0]
    assert proc.returncode == 1, out
    line = next(ln for ln in out.splitlines() if "was not up within start.timeout_s=1 s" in ln)
    missing = line.split("still missing: ")[1]
    assert f"a sample of {MASTER_STATE}" in missing
    assert f"a sample of {SLAVE_STATE}" in missing
    assert f"1 subscribers of {OPERATOR_STATE} (has 0)" in missing
    assert f"a publisher of {received_topic('forward')}" in missing
    assert f"a publisher of {SLAVE_STATE}" in missing
    assert "Traceback" not in out, out


def test_an_nve_graph_that_never_comes_up_is_named_part_by_part():
    """The NVE server alone, one client, a 1 s start timeout: exit 1, one line naming each missing
    node end of the client's links (its node, relays and buffers), no traceback."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "haptic_teleop.nodes.nve_server", "--ros-args",
         "-p", "start.timeout_s:=1.0", "-p", "nve.client_names:=['c1']"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    out = proc.communicate(timeout=TIMEOUT_S)[0]
    assert proc.returncode == 1, out
    line = next(ln for ln in out.splitlines() if "NVE node graph was not up within start.timeout_s=1 s" in ln)
    missing = set(line.split("still missing: ")[1].split("; "))
    assert missing == {
        "a publisher of /c1/up/sent", "a subscriber of /c1/up/sent", "a publisher of /c1/up/received",
        "a subscriber of /c1/down/sent", "a publisher of /c1/down/received", "a subscriber of /c1/down/received",
    }  # fmt: skip
    assert "Traceback" not in out, out
