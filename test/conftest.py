"""Test environment: DDS stays on this host, each test module gets its own ROS domain."""

import itertools
import os

import pytest

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("MPLBACKEND", "Agg")
_USER_DOMAIN = os.environ.get("ROS_DOMAIN_ID")
_SESSION = 100 + os.getpid() % 100
_MODULES = itertools.count()
os.environ.setdefault("ROS_DOMAIN_ID", str(_SESSION))


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
    os.environ["ROS_DOMAIN_ID"] = str(100 + (_SESSION + next(_MODULES)) % 100)
    yield
    os.environ["ROS_DOMAIN_ID"] = str(_SESSION)
