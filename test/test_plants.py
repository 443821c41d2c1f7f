"""MuJoCo plants: the wall has the stiffness the scene asks for, the device the mass and damping."""

import math

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


def _trajectory(plant, forces, ext=None):
    out = []
    for f in forces:
        plant.step([f], ext) if ext is not None else plant.step([f])
        x, v = plant.read()
        out.append((x[0], v[0], plant.contact_force()[0]))
    return out


def test_skipped_stages_change_nothing():
    """The plants turn off MuJoCo stages that cannot matter (collision on the master, which has
    nothing to collide; islands with one dof). The same pushes with every stage on give the same
    bits: position, velocity and wall force (contact included)."""
    import mujoco

    flags = mujoco.mjtDisableBit
    forces = [8.0 * math.sin(i / 200.0) + 6.0 for i in range(1500)]  # reaches the wall and leaves it
    kw = dict(
        mass_kg=1.0,
        damping_n_s_per_m=5.0,
        force_limit_n=50.0,
        wall_position_m=0.01,
        wall_stiffness_n_per_m=1e4,
        wall_damping_n_s_per_m=10.0,
    )
    fast, full = MujocoWallRobot(SimSettings(), **kw), MujocoWallRobot(SimSettings(), **kw)
    assert fast.model.opt.disableflags & int(flags.mjDSBL_ISLAND)
    assert not fast.model.opt.disableflags & int(flags.mjDSBL_CONTACT)  # the wall must stay
    full.model.opt.disableflags = 0
    a, b = _trajectory(fast, forces), _trajectory(full, forces)
    assert a == b
    assert min(f for _, _, f in a) < -1.0  # contact happened: the comparison covers it

    dev_fast = MujocoDevice(SimSettings(), mass_kg=0.2, damping_n_s_per_m=2.0, force_limit_n=10.0)
    dev_full = MujocoDevice(SimSettings(), mass_kg=0.2, damping_n_s_per_m=2.0, force_limit_n=10.0)
    assert dev_fast.model.opt.disableflags & int(flags.mjDSBL_CONTACT)
    dev_full.model.opt.disableflags = 0
    assert _trajectory(dev_fast, forces, [0.5]) == _trajectory(dev_full, forces, [0.5])


def test_collision_stays_on_where_geoms_can_collide(tmp_path):
    """Only a model where nothing can collide loses its collision stage."""
    import mujoco

    from haptic_teleop.plants.mujoco_plant import models_dir

    xml = (models_dir() / "master_device.xml").read_text().replace('contype="0" conaffinity="0"', "")
    path = tmp_path / "collidable_device.xml"
    path.write_text(xml)
    dev = MujocoDevice(SimSettings(), mass_kg=0.2, damping_n_s_per_m=2.0, force_limit_n=10.0, model=str(path))
    assert not dev.model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CONTACT)


def test_plant_reads_follow_mujoco_state():
    """read() goes through memoryviews on MjData: it must see what MuJoCo holds, also after the
    state is set from outside (options and state stay public on `plant.model` / `plant.data`)."""
    dev = MujocoDevice(SimSettings(), mass_kg=0.2, damping_n_s_per_m=2.0, force_limit_n=10.0)
    dev.data.qpos[0] = 0.123
    dev.data.qvel[0] = -0.5
    x, v = dev.read()
    assert (x, v) == ([0.123], [-0.5])
    assert type(x[0]) is float
    dev.step([1.0], [2.0])
    assert list(dev.data.ctrl) == [2.0, 1.0]
    assert dev.read() == ([float(dev.data.qpos[0])], [float(dev.data.qvel[0])])


def test_backend_registry_names_the_classes_and_refuses_unknown_names():
    from haptic_teleop.plants.base import BACKENDS, backend_class
    from haptic_teleop.plants.mujoco_plant import MujocoDevice, MujocoWallRobot

    assert list(BACKENDS) == ["mujoco", "dynamixel", "ur"]
    assert backend_class("mujoco", "master") is MujocoDevice
    assert backend_class("mujoco", "slave") is MujocoWallRobot
    with pytest.raises(ValueError, match=r"unknown plant backend 'ur_rtde'; allowed: mujoco, dynamixel, ur"):
        backend_class("ur_rtde", "slave")
    with pytest.raises(ValueError, match=r"plant backend 'ur' has no one-axis plants; allowed: mujoco"):
        backend_class("ur", "slave")
    with pytest.raises(ValueError, match=r"unknown plant role 'operator'; allowed: master, slave"):
        backend_class("mujoco", "operator")
