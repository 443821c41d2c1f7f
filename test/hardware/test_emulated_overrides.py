"""`--emulate`'s overrides for a side on emulated servos: the port, the device clock and, unless the
scene sets one, a read budget for an emulator that shares the machine (assembly/emulation.py)."""

from __future__ import annotations

import pytest

from haptic_teleop.assembly.emulation import EMULATED_READ_TIMEOUT_S, emulated
from haptic_teleop.scene.load import find_scene, load_scene

pytest.importorskip("dynamixel_sdk")


@pytest.mark.parametrize(
    ("sets", "timeout"), [((), EMULATED_READ_TIMEOUT_S), (("slave.hardware.read_timeout_s=0.2",), None)]
)
def test_an_emulated_bus_gets_a_read_budget_unless_the_scene_sets_one(
    sets: tuple[str, ...], timeout: float | None
) -> None:
    config = load_scene(find_scene("touch_dynamixel_wall"), ["slave.backend=dynamixel", *sets], emulate=True).config
    with emulated(config) as overrides:
        keys = dict(o.split("=", 1) for o in overrides)
        assert keys["slave.hardware.port"].startswith("/dev/pts/")
        # the scene's own budget stands; without one, the emulator's
        assert keys.get("slave.hardware.read_timeout_s") == (None if timeout is None else str(timeout))
        resolved = load_scene(find_scene("touch_dynamixel_wall"), ["slave.backend=dynamixel", *sets, *overrides])
        assert resolved.config.slave.hardware.read_timeout_s == (0.2 if timeout is None else timeout)
