"""The first live arm launch of a fresh install (docs/performance.md, "Compile once"): numba's cache
is empty, so the launcher compiles the side tick before it starts the nodes.

Not in the real-time unit of the suite (test/conftest.py): most of this test is the compile, a
minute of one core that would hold up the real-time modules queued behind it; its live part is a
1 s session of which only liveness is asserted (it comes up, ends 0 and writes its summary), which
holds beside the other worker's load as the live tests hold beside two busy loops."""

from __future__ import annotations

import pytest
from launched import Launch

pytest.importorskip("rclpy")

SCENE = "touch_ur5e_wall"


def test_a_first_launch_on_an_empty_numba_cache_builds_the_side_tick_first_and_comes_up(tmp_path):
    """A fresh install's first live arm launch: the launcher compiles the side tick the arm nodes
    run before it starts them, and says so, so no node spends its start-up compiling while the
    others wait past their start timeout (before: "the node graph was not up within
    start.timeout_s=30 s"). numba's cache is a new empty directory for this launch alone."""
    out = tmp_path / "run"
    launch = Launch(SCENE, "--set", "scene.duration_s=1", "--record", str(out), "--no-plots", cwd=tmp_path,
                    env={"NUMBA_CACHE_DIR": str(tmp_path / "numba")})  # fmt: skip
    code = launch.finish(900)
    assert code == 0, launch.failure
    assert "compiling the tick loop side_kernel" in launch.text  # it really compiled, and said so
    assert (out / "summary.json").exists()
