"""The backend registry (plants/base.py): one line per backend names its pieces, each beside the
backend (its hardware section's config class, its arm driver, its SDK, its emulator), and the scene
reads a side's `hardware` section with the class of the side's backend."""

from __future__ import annotations

import dataclasses
import importlib.util

import pytest

from haptic_teleop.errors import ConfigError
from haptic_teleop.plants.base import BACKENDS, backend, hardware_classes
from haptic_teleop.plants.hardware import SDKS, HardwareConfig
from haptic_teleop.scene import schema
from haptic_teleop.scene.load import find_scene, load_scene


def test_every_backend_names_pieces_that_exist():
    for name, b in BACKENDS.items():
        assert b.help
        for module in b.sdk:
            assert module in SDKS, (name, module)  # what to pip install when it is missing
        if b.emulator is not None:
            assert importlib.util.find_spec(b.emulator) is not None, (name, b.emulator)
        if b.real:
            cls = b.config_class()
            assert issubclass(cls, HardwareConfig) and dataclasses.is_dataclass(cls), name
            assert b.arm_driver is not None and callable(
                getattr(importlib.import_module(b.arm_driver.partition(":")[0]), b.arm_driver.partition(":")[2])
            ), name
        else:
            assert b.config is None and b.arm_driver is None and not b.sdk
    assert set(hardware_classes()) == {n for n, b in BACKENDS.items() if b.real} == {"dynamixel", "ur"}
    with pytest.raises(ValueError, match="unknown plant backend 'kuka'; allowed: mujoco, dynamixel, ur"):
        backend("kuka")


def test_the_scene_offers_exactly_the_registrys_backends():
    for side in (schema.MasterConfig, schema.SlaveConfig):
        f = next(f for f in dataclasses.fields(side) if f.name == "backend")
        assert tuple(f.metadata["choices"]) == tuple(BACKENDS)
    keys = {path for path, _, _ in __import__("haptic_teleop.typedconfig").typedconfig.describe(schema.Scene)}
    # every backend's keys are scene keys (docs, `--set` completion, node parameters)
    for name, cls in hardware_classes().items():
        for f in dataclasses.fields(cls):
            assert f"slave.hardware.{f.name}" in keys, (name, f.name)


@pytest.mark.parametrize(
    ("overrides", "cls"),
    [
        ([], "DynamixelConfig"),  # a simulated side's section: read by the backend whose keys it has
        (["slave.backend=dynamixel", "slave.hardware.port=/dev/ttyUSB0"], "DynamixelConfig"),
    ],
)
def test_a_sides_hardware_section_is_read_by_its_backends_class(overrides, cls):
    scene = load_scene(find_scene("touch_dynamixel_wall"), overrides=overrides)
    assert type(scene.config.slave.hardware).__name__ == cls


@pytest.mark.parametrize(
    ("overrides", "words"),
    [
        (
            ["slave.backend=ur"],
            "slave.hardware.baud_bps = 4000000: a key of backend dynamixel, and slave.backend is ur",
        ),
        (
            ["slave.backend=dynamixel", "slave.hardware.host=robot"],
            "a key of backend ur, and slave.backend is dynamixel",
        ),
        (["slave.hardware.nonsense=1"], "keys of no one backend's hardware section"),
        (["slave.backend=dynamixel"], "slave.hardware.port = None: required: the serial port"),
        (["slave.backend=kuka"], "slave.backend = 'kuka': allowed: one of mujoco, dynamixel, ur"),
    ],
)
def test_a_section_of_another_backend_is_one_line_naming_it(overrides, words):
    with pytest.raises(ConfigError) as err:
        load_scene(find_scene("touch_dynamixel_wall"), overrides=overrides)
    assert words in str(err.value) and "\n" not in str(err.value)
