"""Test environment: DDS stays on this host, each test module gets its own ROS domain."""

import itertools
import os
import subprocess
import sys
import tempfile

import pytest
from shm_clean import remove_stale

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("MPLBACKEND", "Agg")
_USER_DOMAIN = os.environ.get("ROS_DOMAIN_ID")
# Domains 1 to 100: their DDS ports stay below Linux's ephemeral range (32768 and up), where a
# participant's port could be taken by another socket (ROS 2's domain-ID guidance: 0 to 101).
_SESSION = 1 + os.getpid() % 100
_MODULES = itertools.count()
os.environ.setdefault("ROS_DOMAIN_ID", str(_SESSION))


_COMPILE: list[subprocess.Popen] = []


def pytest_sessionstart(session):
    """Stale Fast DDS shared-memory files of killed processes go before the session (shm_clean.py).

    Then the compiled tick loops are built in a background process (`haptic-teleop compile`), on
    the core the tests leave idle, instead of inside the first tests that need them: on a fresh
    clone that is about two minutes of numba compiling. A test that reaches a kernel first compiles
    it itself and the background process waits for it and loads it (compiling.first_compile),
    so nothing is compiled twice. HAPTIC_TELEOP_TEST_COMPILE=0 turns it off.

    First of all, SIGINT gets its default back if the session inherited it ignored: a suite started
    in the background of a non-interactive shell (`bash .ci/run &`, nohup) runs with SIGINT ignored,
    every child inherits that, and the tests that send Ctrl-C to a command would see it do nothing
    (seen: four such failures in a run started that way, none when started in the foreground)."""
    import signal

    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    remove_stale()
    if os.environ.get("HAPTIC_TELEOP_TEST_COMPILE", "1") == "0":
        return
    log = open(os.path.join(tempfile.gettempdir(), f"haptic-teleop-test-compile-{os.getuid()}.log"), "w")
    _COMPILE.append(
        subprocess.Popen(
            [sys.executable, "-m", "haptic_teleop.cli", "compile", "--only", "arm,side,codec,arm_codec,axis"],
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    )
    log.close()


def pytest_sessionfinish(session):
    for proc in _COMPILE:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


@pytest.fixture(autouse=True, scope="module")
def _own_ros_domain():
    """A fresh ROS domain for every test module (unless the user set ROS_DOMAIN_ID).

    Several modules kill node processes on purpose; Fast DDS leaves their shared-memory port
    segments behind, and a later participant of the same domain that reopens one can crash in
    Fast DDS (a segfault at start, seen once in CI). Ports are per domain: a new domain per
    module keeps one module's kills from reaching the next."""
    if _USER_DOMAIN is not None:
        yield
        return
    os.environ["ROS_DOMAIN_ID"] = str(1 + (_SESSION + next(_MODULES)) % 100)
    yield
    os.environ["ROS_DOMAIN_ID"] = str(_SESSION)


@pytest.fixture
def context():
    """An rclpy context of its own, shut down after the test: for tests that build nodes in this
    process and call their handlers directly."""
    rclpy = pytest.importorskip("rclpy")
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)
