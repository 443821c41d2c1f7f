"""MuJoCo plants: the wall has the stiffness the scene asks for, the device the mass and damping."""

import pytest

from haptic_teleop.plants.mujoco_plant import MujocoDevice, MujocoWallRobot, SimSettings


@pytest.mark.parametrize("stiffness", [1e3, 1e4, 1e5, 1e6])
def test_wall_static_stiffness(stiffness):
    """Push with a known force: the penetration is F / K (MuJoCo's force, not ours)."""
    robot = MujocoWallRobot(
        SimSettings(),
        mass_kg=1.0,
        damping_n_s_per_m=20.0,
        force_limit_n=100.0,
        wall_position_m=0.01,
        wall_stiffness_n_per_m=stiffness,
        wall_damping_n_s_per_m=50.0,
    )
    for _ in range(6000):
        robot.step([10.0])
    x, v = robot.read()
    assert abs(v[0]) < 1e-6
    assert robot.contact_force()[0] == pytest.approx(-10.0, rel=1e-4)
    assert (x[0] - 0.01) == pytest.approx(10.0 / stiffness, rel=0.01)


def test_no_contact_before_the_wall():
    robot = MujocoWallRobot(
        SimSettings(),
        mass_kg=1.0,
        damping_n_s_per_m=5.0,
        force_limit_n=50.0,
        wall_position_m=0.05,
        wall_stiffness_n_per_m=1e4,
        wall_damping_n_s_per_m=0.0,
    )
    for _ in range(100):
        robot.step([1.0])
    assert robot.contact_force() == [0.0]
    assert robot.read()[0][0] < 0.05


def test_device_mass_and_damping():
    """Constant force on mass m with damping b: terminal velocity F/b, time constant m/b."""
    dev = MujocoDevice(SimSettings(), mass_kg=0.2, damping_n_s_per_m=2.0, force_limit_n=10.0, hand_mass_kg=0.3)
    for _ in range(250):  # one time constant m/b = 0.25 s
        dev.step([1.0], [0.0])
    v = dev.read()[1][0]
    assert v == pytest.approx(0.5 * (1 - 2.718281828**-1), rel=0.01)
    for _ in range(3000):
        dev.step([0.0], [1.0])  # the hand's force moves it the same way
    assert dev.read()[1][0] == pytest.approx(0.5, rel=1e-3)


def test_actuator_limit_and_nan_are_clipped():
    dev = MujocoDevice(SimSettings(), mass_kg=0.2, damping_n_s_per_m=2.0, force_limit_n=5.0)
    assert dev.step([50.0]) == [5.0]
    assert dev.step([-50.0]) == [-5.0]
    assert dev.step([float("nan")]) == [0.0]
