"""Two hosts: the master side and the slave side in two network namespaces joined by a veth pair.

The same node set as `haptic-teleop launch`, split with `--side master|slave`, over a real
network interface. Each namespace has only its loopback and its end of the veth, so DDS
discovery (ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET, multicast routed to the veth) cannot leave that
link. Needs root and `ip netns`; skipped with the reason otherwise.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("ip") is None, reason="needs root and iproute2 (ip netns) to make two hosts"
)

SUBNET = "10.213.{n}.{host}"


def _ip(*args: str) -> None:
    r = subprocess.run(["ip", *args], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {r.stderr.strip()}")


@pytest.fixture
def two_hosts():
    tag = os.getpid() % 100_000
    master, slave = f"htm{tag}", f"hts{tag}"
    n = tag % 250 + 1
    try:
        _ip("netns", "add", master)
        _ip("netns", "add", slave)
    except RuntimeError as exc:
        for ns in (master, slave):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        pytest.skip(f"cannot create network namespaces here: {exc}")
    try:
        _ip("link", "add", f"vm{tag}", "type", "veth", "peer", "name", f"vs{tag}")
        for ns, dev, host in ((master, f"vm{tag}", 1), (slave, f"vs{tag}", 2)):
            _ip("link", "set", dev, "netns", ns)
            _ip("-n", ns, "addr", "add", SUBNET.format(n=n, host=host) + "/30", "dev", dev)
            _ip("-n", ns, "link", "set", dev, "up")
            _ip("-n", ns, "link", "set", "lo", "up")
            _ip("-n", ns, "route", "add", "224.0.0.0/4", "dev", dev)  # DDS discovery multicast: this link only
        yield master, slave
    finally:
        for ns in (master, slave):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def test_master_and_slave_sides_on_two_hosts(two_hosts, tmp_path):
    master_ns, slave_ns = two_hosts
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", PYTHONUNBUFFERED="1")
    cli = [sys.executable, "-m", "haptic_teleop.cli", "launch", "wall_contact"]
    slave = subprocess.Popen(
        ["ip", "netns", "exec", slave_ns, *cli, "--side", "slave"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        out = tmp_path / "run"
        master = subprocess.run(
            ["ip", "netns", "exec", master_ns, *cli, "--side", "master", "--duration", "4",
             "--record", str(out), "--no-plots"],
            env=env, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
    finally:
        slave.send_signal(signal.SIGINT)
        slave_out, _ = slave.communicate(timeout=120)
    assert master.returncode == 0, master.stdout[-4000:] + master.stderr[-2000:]
    assert slave.returncode == 130, slave_out[-4000:]  # stopped by SIGINT: 128 + 2, every node exited 0
    for node in ("slave_eba", "backward_relay", "forward_buffer"):
        assert f"[launcher] {node} exited 0" in slave_out
    summary = json.loads((out / "summary.json").read_text())
    # The wall force was measured by the slave in the other namespace and recorded on this side.
    assert summary["contact_force_max_n"] > 1.0
    assert summary["packets_sent_backward"] > 500
    assert summary["all_finite"] is True
