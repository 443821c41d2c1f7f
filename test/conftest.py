"""Test environment: DDS stays on this host, each test module gets its own ROS domain, and the suite
runs on two pytest-xdist workers with every real-time test on one of them (docs/development.md,
"Tests")."""

import itertools
import os
import subprocess
import sys
import tempfile
import zlib
from pathlib import Path
from typing import Any

import pytest
from shm_clean import remove_stale

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("MPLBACKEND", "Agg")
_USER_DOMAIN = os.environ.get("ROS_DOMAIN_ID")
# Domains 1 to 100: their DDS ports stay below Linux's ephemeral range (32768 and up), where a
# participant's port could be taken by another socket (ROS 2's domain-ID guidance: 0 to 101).
# Under pytest-xdist the workers share one base (from the run's id) and worker w of W takes the
# domains that are w modulo W, so two workers never share a domain (W dividing 100: -n 2 does).
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw") or 0)
_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
_RUN_ID = os.environ.get("PYTEST_XDIST_TESTRUNUID")
_BASE = (zlib.crc32(_RUN_ID.encode()) if _RUN_ID else os.getpid()) % 100


def _domain(k: int) -> int:
    """The k-th ROS domain of this worker: 1 to 100, congruent to the worker's index modulo W."""
    return 1 + (_BASE - _BASE % _WORKERS + k * _WORKERS + _WORKER) % 100


_SESSION = _domain(0)
_MODULES = itertools.count(1)
os.environ.setdefault("ROS_DOMAIN_ID", str(_SESSION))

# Modules whose tests run against a real-time clock: live ROS 2 launches (their loops ask for
# SCHED_FIFO), the UR emulator's 1 kHz session (one at a time per host: its fixed ports), clocked
# device emulators, signals timed against a running command. Under pytest-xdist they form one work
# unit, run one after another on one worker, so no two of them compete for the two cores (a live
# launch beside the UR emulator starved its 1 kHz loop once); the other worker runs the rest, a
# module at a time (its module-scoped fixtures built once).
REALTIME = {
    "test_cli_entry.py",
    "test_foxglove_view.py",
    "test_launch_files.py",
    "test_launch_lifetime.py",
    "test_node_entry.py",
    "test_two_hosts.py",
    "test_engine_sessions.py",
    "test_late_holds_emulated.py",
    # emulators in real-time mode (the bus watchdog on the wall clock): with a live launch on the
    # other worker a read right after the watchdog returned no torque once (CI, 2026-12-02)
    "test_dxl_emulator.py",
    "test_dxl_driver.py",
    "test_ur_driver.py",
    "test_ur_emulator.py",
    "test_ur_modes.py",
}


def realtime(module: Path) -> bool:
    return module.name in REALTIME or module.name.startswith("test_live")


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """The work units under `-n N` (whatever `--dist` says): the REALTIME modules are one unit,
    every other module a unit of its own. (pytest-xdist's own `loadgroup` does not group under
    pytest 9.2: it renames `item._nodeid`, which pytest 9.2 no longer reads. The unit is chosen
    by `_split_scope`, LoadScopeScheduling's hook for subclasses: pytest-xdist < 4 in setup.py.)
    Units go out largest first (by tests): the real-time one, about half the suite's time."""
    from xdist.scheduler import LoadScopeScheduling

    class RealtimeApart(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return "realtime" if realtime(Path(module)) else module

        def _assign_work_unit(self, node: Any) -> None:
            # The LATE modules go out after every other unit (while others are left).
            queue = self.workqueue
            late = [scope for scope in queue if Path(scope).name in LATE]
            if len(late) < len(queue):
                for scope in late:
                    queue.move_to_end(scope)
            super()._assign_work_unit(node)

    return RealtimeApart(config, log)


# Modules whose first test needs the kernel the background compile builds last (the compiled arm
# loop with codecs: about 2.5 min cold, 5 min into a fresh clone's suite): sent out last, so a
# worker does not sit in their setup while other modules wait (a clean-clone CI run: 238 s). A
# real-time one runs last in the real-time unit (pytest_collection_modifyitems): its arm codec
# fixture waited 112 s there once the cold-launch test no longer ran before it.
LATE = {"test_compiled_arm_codec.py", "test_stabilizers.py", "test_live_codec.py"}


def pytest_collection_modifyitems(session, config, items):
    """The LATE modules' tests after every other (a stable sort: the same order on every worker)."""
    items.sort(key=lambda item: Path(str(item.fspath)).name in LATE)


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
    if hasattr(session.config, "workerinput"):
        return  # an xdist worker: the controller cleans up and compiles once for all of them
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
    module keeps one module's kills from reaching the next. Not all of them: each participant also
    opens a port numbered from 7000 up, counted over the whole host whatever its domain (seen in
    /dev/shm during a live launch), so a module also starts by removing the stale groups of files
    the modules before it left (test/shm_clean.py: nobody holds their lock or maps them; 2 s old,
    nothing being created now). A CI run saw a live launch whose backward link never carried a
    sample before scene time 0, in a module that ran after such kills."""
    remove_stale(min_age_s=2.0)
    if _USER_DOMAIN is not None:
        yield
        return
    os.environ["ROS_DOMAIN_ID"] = str(_domain(next(_MODULES)))
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
