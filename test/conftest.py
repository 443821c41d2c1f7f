"""Test environment: DDS stays on this host, each test module gets its own ROS domain."""

import itertools
import os

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


def pytest_sessionstart(session):
    """Stale Fast DDS shared-memory files of killed processes go before the session (shm_clean.py)."""
    remove_stale()


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
