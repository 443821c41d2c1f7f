"""The compiled tick is one driver (engine/compiled/driver.py) composed four ways: each kernel's
entry point calls a composition of `driver.drive`'s own code with that kernel's stages, and no
kernel has a tick loop of its own. That the compositions run each scene's ticks bit for bit as
the Python loop does is test_compiled_loop, _codec, _arm and _arm_codec's business."""

from __future__ import annotations

import pytest

pytest.importorskip("numba")
pytest.importorskip("mujoco")

from haptic_teleop.engine.compiled import driver

ENTRIES = (
    ("axis_kernel", "run_ticks", "drive_axis"),
    ("codec_kernel", "run_ticks_codec", "drive_axis_codec"),
    ("arm_kernel", "run_ticks", "drive_arm"),
    ("arm_codec_kernel", "run_ticks_codec", "drive_arm_codec"),
)


def _module(name: str):
    import importlib

    return importlib.import_module(f"haptic_teleop.engine.compiled.{name}")


@pytest.mark.parametrize(("module", "entry", "composed"), ENTRIES)
def test_each_kernel_runs_the_one_driver_with_its_stages(module, entry, composed):
    m = _module(module)
    drive = getattr(m, composed)
    assert drive.py_func.__code__ is driver.drive.__code__  # the driver's own code, not a copy
    assert drive.targetoptions.get("inline") == "always"  # inlined into the entry point (numba IR)
    code = getattr(m, entry).py_func.__code__
    assert composed in code.co_names
    # the entry point has no loop of its own: the ticks are the driver's
    assert "range" not in code.co_names
    glob = drive.py_func.__globals__
    for stage in driver.STAGES:  # every stage is bound to a compiled function, none is the stub
        bound = glob[stage]
        assert hasattr(bound, "py_func") and bound.py_func is not driver._stage, stage


def test_one_axis_and_arm_kernels_share_their_sides_and_differ_in_their_channels():
    plain, codec = _module("axis_kernel").drive_axis, _module("codec_kernel").drive_axis_codec
    arm, arm_codec = _module("arm_kernel").drive_arm, _module("arm_codec_kernel").drive_arm_codec
    for a, b in ((plain, codec), (arm, arm_codec)):
        ga, gb = a.py_func.__globals__, b.py_func.__globals__
        for stage in ("begin", "sense", "master", "slave", "finish", "end"):
            assert ga[stage] is gb[stage], stage
        for stage in ("open_forward", "forward", "backward"):
            assert ga[stage] is not gb[stage], stage


def test_compose_names_the_stages_it_misses_and_an_uncomposed_stage_refuses_to_run():
    with pytest.raises(TypeError, match=r"missing \['backward'.*unknown \['backwards'\]"):
        stages = dict.fromkeys(driver.STAGES, driver._stage)
        del stages["backward"], stages["end"]
        driver.compose(backwards=None, **stages)
    with pytest.raises(NotImplementedError, match="compose"):
        driver.drive(0, 1, None, None, None)
