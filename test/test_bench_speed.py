"""`bench speed`'s pairing of the compiled tick with a bare MuJoCo step: which ticks it times and
how many bare steps it takes (the figures themselves are timings, printed by the bench, not tested)."""

from __future__ import annotations

import math

import pytest

from haptic_teleop.scene.load import find_scene, load_scene
from haptic_teleop.studies.benchmarks import speed


@pytest.mark.parametrize("stride", [1, 5])
def test_the_tick_is_timed_apart_from_the_chunks_a_sample_disturbed(stride: int) -> None:
    # 2 s at 1 kHz: progress calls at ticks 100, 200, ..., 2000; the steady state timed is the
    # chunks from tick 400 (20 %) to 1900 (95 %), 1500 ticks
    scene = load_scene(find_scene("wall_contact"), overrides=["scene.duration_s=2"])
    spent = speed.cost_run(scene, every=10, stride=stride)
    calls = range(100, 2001, 100)
    sampled = [n for n in calls if (n // 100) % stride == 0]
    assert spent["samples"] == 10 * len(sampled)  # `every` bare steps at each sampled call
    assert spent["loop_ticks"] + spent["after_ticks"] == 1500
    # the chunk after each sample inside the window is timed apart (none when every call samples)
    after = [n for n in sampled if 400 <= n < 1900] if stride > 1 else []
    assert spent["after_ticks"] == 100 * len(after)
    loop, bare, mujoco_calls, after_us = speed.per_tick_us(spent)
    assert loop > 0.0 and bare > 0.0
    assert math.isnan(mujoco_calls)  # a 1-DoF scene: no arm calls to time
    assert math.isnan(after_us) == (stride == 1)
