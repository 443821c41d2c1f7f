"""The arm tick with the numba-compiled kernels of core.taskspace and core.eba (assembly.arm_kernels)
gives the torques of the interpreted functions."""

from __future__ import annotations

import numpy as np
import pytest

from haptic_teleop.assembly.parts import arm_kernels, build_arm_parts
from haptic_teleop.assembly.side import _SideTick
from haptic_teleop.scene.load import find_scene, load_scene

pytest.importorskip("numba")


@pytest.mark.parametrize("side", ["master", "slave"])
def test_compiled_kernels_give_the_interpreted_torques(side: str) -> None:
    assert arm_kernels() is not None
    config = load_scene(find_scene("touch_ur5e_wall"), ["controllers.master.eba.initial_energy_j=1.0"]).config
    rng = np.random.default_rng(3)
    ticks = []
    for compiled in (True, False):
        parts = build_arm_parts(config, compiled=compiled)
        arm_side = getattr(parts, side)
        scale = parts.mapping.force_scale * parts.mapping.matrix if side == "master" else None
        ticks.append(_SideTick(arm_side, scale))
    assert ticks[0].side.kernels is not None and ticks[1].side.kernels is None
    for _ in range(5):
        qd = rng.normal(0.0, 0.3, ticks[0].plant.n)
        remote = tuple(rng.normal(0.0, 0.2, 6) + np.r_[ticks[0].plant.point()[0], 0, 0, 0])
        x = ticks[0].plant.point()[0] + rng.normal(0.0, 0.01, 3)
        v = rng.normal(0.0, 0.1, 3)
        out = []
        for t in ticks:
            t.plant.data.qvel[:] = qd
            t.plant._fresh = False  # the new velocities: read them again
            out.append(t.torque(x, v, remote).copy())
        np.testing.assert_allclose(out[0], out[1], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(ticks[0].force, ticks[1].force, rtol=1e-12, atol=1e-12)
        assert ticks[0].bound.energy_j == pytest.approx(ticks[1].bound.energy_j, rel=1e-12, abs=1e-15)
        assert np.abs(out[0]).max() > 0.0
