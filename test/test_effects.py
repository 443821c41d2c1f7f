"""Plant effects: a scene builds only the effects it names; physical effects act inside MuJoCo."""

import math

import numpy as np
import pytest

from haptic_teleop.assembly.plants import build_master_plant, build_slave_plant
from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.errors import ConfigError
from haptic_teleop.plants.effects import EffectsPlant
from haptic_teleop.plants.mujoco_plant import MujocoDevice, MujocoWallRobot
from haptic_teleop.scene.load import find_scene, load_scene

SCENE = find_scene("wall_contact")


def scene(*overrides):
    return load_scene(SCENE, list(overrides))


def config(*overrides):
    return scene(*overrides).config


def physics(plant):
    m = plant.model
    return (tuple(m.opt.gravity), tuple(m.dof_frictionloss), tuple(m.dof_damping))


def untouched_physics(plant):
    """The MuJoCo model has the MJCF's zero gravity and no dry friction."""
    m = plant.model
    return not np.any(m.opt.gravity) and not np.any(m.dof_frictionloss)


def test_no_effects_named_gives_the_bare_mujoco_plants():
    engine = Engine(scene())
    assert type(engine.master) is MujocoDevice
    assert type(engine.slave) is MujocoWallRobot
    assert untouched_physics(engine.master) and untouched_physics(engine.slave)


# (override naming one effect, side it is on, names the composed plant must hold exactly;
#  None = the bare MuJoCo plant with that physical effect written into its model)
ONE_EFFECT = [
    ("master.effects.noise.position_std_m=1e-5", "master", ("position_noise",)),
    ("master.effects.noise.velocity_std_m_per_s=1e-3", "master", ("velocity_noise",)),
    ("slave.effects.noise.force_std_n=0.1", "slave", ("force_noise",)),
    ("slave.effects.encoder.resolution_m=1e-5", "slave", ("encoder",)),
    ("slave.effects.force_filter.cutoff_hz=30", "slave", ("lowpass",)),
    ("slave.effects.force_filter={type: moving_average, window_samples: 5}", "slave", ("moving_average",)),
    ("master.effects.saturation.slew_rate_n_per_s=500", "master", ("saturation",)),
    ("slave.effects.friction.coulomb_n=1.0", "slave", ("friction",)),  # wall force without friction
    ("master.effects.friction.coulomb_n=1.0", "master", None),
    ("slave.effects.friction.viscous_n_s_per_m=2.0", "slave", None),
    ("master.effects.gravity.incline_deg=10", "master", None),
]


@pytest.mark.parametrize(("override", "side", "names"), ONE_EFFECT)
def test_a_scene_with_one_effect_builds_exactly_that_effect(override, side, names):
    engine = Engine(scene(override))
    named = engine.master if side == "master" else engine.slave
    other = engine.slave if side == "master" else engine.master
    assert type(other) in (MujocoDevice, MujocoWallRobot)  # the other side: bare
    assert untouched_physics(other)
    if names is None:
        assert type(named) in (MujocoDevice, MujocoWallRobot)  # no per-tick wrapper
        bare = Engine(scene())
        bare_side = bare.master if side == "master" else bare.slave
        assert physics(named) != physics(bare_side)  # written into the model instead
    else:
        assert isinstance(named, EffectsPlant)
        assert named.effects == names
        chains = (named.position_effects, named.velocity_effects, named.force_effects, named.actuator_effects)
        assert sum(len(c) for c in chains) == len([n for n in names if n not in ("friction", "gravity")])
        if "friction" not in names:
            assert untouched_physics(named)


def test_viscous_friction_adds_to_the_device_damping_only():
    plant = build_slave_plant(config("slave.effects.friction.viscous_n_s_per_m=2.0"))
    assert type(plant) is MujocoWallRobot
    assert plant.model.dof_damping[0] == pytest.approx(5.0 + 2.0)
    assert untouched_physics(plant)


def master_after(plant, force_n, ticks):
    for _ in range(ticks):
        plant.step([force_n], [0.0])
    return plant.read()


def test_a_push_below_the_coulomb_level_does_not_move_the_device():
    coulomb = 1.0
    for force in (0.5, -0.9):
        plant = build_master_plant(config(f"master.effects.friction.coulomb_n={coulomb}"))
        (x,), (v,) = master_after(plant, force, 1000)
        assert abs(x) < 1e-6 and abs(v) < 1e-6
        # The unprotected variant: the same push without friction moves it by centimetres.
        bare = build_master_plant(config())
        (xb,), _ = master_after(bare, force, 1000)
        assert abs(xb) > 0.1


def test_a_push_above_the_coulomb_level_slides_with_the_excess_force():
    """m a = F - F_c - b v: x(t) = (F - F_c)/b (t - m/b (1 - exp(-b t / m))), within the 1 ms
    integration error (2 T / t relative)."""
    coulomb, force, t = 1.0, 1.5, 1.0
    plant = build_master_plant(config(f"master.effects.friction.coulomb_n={coulomb}"))
    (x,), _ = master_after(plant, force, round(t / 0.001))
    m = 0.2 + 0.5  # device + hand mass (default scene)
    b = 1.0
    expected = (force - coulomb) / b * (t - m / b * (1 - math.exp(-b * t / m)))
    assert x == pytest.approx(expected, rel=2 * 0.001 / t)


def test_slave_wall_force_leaves_out_the_joint_friction():
    """Below the Coulomb level in free space MuJoCo's constraint force on the joint is the
    friction force (-F); the wall force the slave reports must stay zero."""
    plant = build_slave_plant(config("slave.effects.friction.coulomb_n=2.0"))
    for _ in range(200):
        plant.step([1.0])
    assert plant.contact_force() == [0.0]
    assert plant.plant.contact_force()[0] == pytest.approx(-1.0, abs=1e-5)  # what the bare plant reports


@pytest.mark.parametrize("incline_deg", [30.0, -45.0, 90.0])
def test_gravity_accelerates_the_free_device_at_g_sin_incline(incline_deg):
    g = 9.81
    plant = build_master_plant(config(f"master.effects.gravity.incline_deg={incline_deg}"))
    a = -g * math.sin(math.radians(incline_deg))
    assert plant.data.qacc[0] == pytest.approx(a, rel=1e-9)  # at rest: no damping force yet
    # Then the damped motion, against the analytic solution (within the 1 ms integration error).
    t = 0.2
    (x,), _ = master_after(plant, 0.0, round(t / 0.001))
    m, b = 0.7, 1.0
    expected = a * m / b * (t - m / b * (1 - math.exp(-b * t / m)))
    assert x == pytest.approx(expected, rel=1.5 * 0.001 / t)


def test_gravity_pushes_the_slave_onto_its_wall_with_m_g_sin_incline():
    """Tilted so the wall is downhill: at rest the wall force (from MuJoCo's contact) carries the weight."""
    plant = build_slave_plant(config("slave.effects.gravity.incline_deg=-30"))
    for _ in range(5000):
        plant.step([0.0])
    assert plant.contact_force()[0] == pytest.approx(-1.0 * 9.81 * 0.5, rel=1e-6)


def test_same_seed_same_noise_other_seed_other_noise_and_streams_are_per_effect():
    base = "master.effects.noise.position_std_m=1e-4"

    def positions(*overrides, seed=1):
        plant = build_master_plant(config(base, f"scene.seed={seed}", *overrides))
        return [plant.read()[0][0] for _ in range(300)]

    a = positions()
    assert a == positions()
    assert a != positions(seed=2)
    # Naming more effects (on other signals and the other side) leaves these draws alone.
    assert a == positions("master.effects.noise.velocity_std_m_per_s=1e-3", "master.effects.saturation.force_limit_n=5")


def test_engine_runs_are_reproducible_with_effects():
    overrides = (
        "scene.duration_s=1.0",
        "slave.effects.noise.force_std_n=0.2",
        "master.effects.encoder.resolution_m=1e-5",
    )
    r1 = Engine(scene(*overrides)).run(handle_sigint=False)
    r2 = Engine(scene(*overrides)).run(handle_sigint=False)
    r3 = Engine(scene(*overrides, "scene.seed=5")).run(handle_sigint=False)
    assert np.array_equal(r1.data, r2.data)
    assert not np.array_equal(r1.data, r3.data)


def test_saturation_limits_the_recorded_applied_force():
    overrides = ("scene.duration_s=3.0",)
    free = Engine(scene(*overrides)).run(handle_sigint=False)
    limited = Engine(scene(*overrides, "master.effects.saturation.force_limit_n=1.0")).run(handle_sigint=False)
    assert np.max(np.abs(free.column("m_force_n"))) > 1.5  # the limit matters in this run
    assert np.max(np.abs(limited.column("m_force_n"))) <= 1.0


class TrueState:
    """Records the true position (inside MuJoCo) and the applied force of a plant each period."""

    def __init__(self, plant):
        self.plant = plant
        self.axes = plant.axes
        self._data = getattr(plant, "plant", plant).data
        self.x = [float(self._data.qpos[0])]
        self.f = []

    def read(self):
        return self.plant.read()

    def contact_force(self):
        return self.plant.contact_force()

    def step(self, force, external=None):
        applied = self.plant.step(force, external)
        self.f.append(applied[0])
        self.x.append(float(self._data.qpos[0]))
        return applied

    def close(self):
        self.plant.close()


def true_energy_margins(*overrides):
    """Minimum over the run of E0 + sum((b/T) dx^2 - F dx) at each side, from the true motion,
    and the largest applied force magnitude at each side."""
    sc = scene("scene.duration_s=4.0", *overrides)
    c = sc.config
    engine = Engine(sc)
    engine.master, engine.slave = TrueState(engine.master), TrueState(engine.slave)
    engine.run(handle_sigint=False)
    out, peaks = [], []
    for rec, b, e0 in (
        (engine.master, c.master.damping_n_s_per_m, c.controllers.master.eba.initial_energy_j),
        (engine.slave, c.slave.damping_n_s_per_m, c.controllers.slave.eba.initial_energy_j),
    ):
        dx = np.diff(rec.x)
        out.append(float(np.min(e0 + np.cumsum(b / c.scene.period_s * dx * dx - np.array(rec.f) * dx))))
        peaks.append(float(np.max(np.abs(rec.f))))
    return out, peaks


STIFF = ("controllers.master.stiffness_n_per_m=5000", "controllers.slave.stiffness_n_per_m=5000")
EFFECTS_ON = (
    "master.effects.saturation.force_limit_n=5.0",
    "slave.effects.saturation.force_limit_n=8.0",
    "master.effects.noise.velocity_std_m_per_s=1e-3",
    "slave.effects.noise.force_std_n=0.2",
    "slave.effects.force_filter.cutoff_hz=50",
    "master.effects.friction.coulomb_n=0.2",
)


def test_eba_energy_margins_stay_non_negative_with_saturation_and_noise():
    (master, slave), peaks = true_energy_margins(*STIFF, *EFFECTS_ON)
    assert master >= -1e-12 and slave >= -1e-12
    assert peaks == [5.0, 8.0]  # the saturation did clip
    # The unprotected variant of the same scene loses passivity: the check can fail.
    (master_off, slave_off), _ = true_energy_margins(
        *STIFF, *EFFECTS_ON, "controllers.master.eba.enabled=false", "controllers.slave.eba.enabled=false"
    )
    assert min(master_off, slave_off) < -0.1


@pytest.mark.parametrize(
    ("override", "match"),
    [
        ("master.effects.force_filter.cutoff_hz=10", "no force sensor"),
        ("master.effects.noise.force_std_n=0.1", "no force sensor"),
        ("slave.effects.saturation.force_limit_n=60", "must be below slave.force_limit_n"),
        ("slave.effects.saturation={}", "needs force_limit_n, slew_rate_n_per_s or both"),
        ("slave.effects.force_filter.window_samples=4", "'lowpass' needs cutoff_hz and no window_samples"),
        ("slave.effects.force_filter.cutoff_hz=600", "Nyquist"),
        ("slave.effects.noise={}", "at least one of"),
        ("master.effects.friction={}", "coulomb_n > 0 or viscous"),
        ("master.effects.gravity={}", "required key is missing"),
        ("master.effects.gravity.incline_deg=120", "<= 90.0"),
        ("slave.effects.encoder.resolution_m=0", "> 0.0"),
        ("slave.effects.wind.speed=1", "unknown key"),
    ],
)
def test_bad_effects_are_rejected_naming_the_key(override, match):
    with pytest.raises(ConfigError, match=match):
        scene(override)


def test_slave_coulomb_friction_needs_one_substep():
    with pytest.raises(ConfigError, match="substeps: 1"):
        scene("slave.effects.friction.coulomb_n=1", "simulation.substeps=2")
    scene("slave.effects.friction.viscous_n_s_per_m=1", "simulation.substeps=2")  # viscous is fine


def test_live_nodes_build_the_same_effects_from_their_parameters(tmp_path):
    """The launcher writes each node's scene sections as parameters; master_eba and slave_eba
    build their plants through the same factory, so they hold the effects the scene names."""
    rclpy = pytest.importorskip("rclpy")
    from haptic_teleop.live.launcher import node_plan, write_params_files
    from haptic_teleop.nodes.master_eba import MasterEba
    from haptic_teleop.nodes.slave_eba import SlaveEba

    sc = scene(
        "slave.effects.force_filter.cutoff_hz=40",
        "master.effects.noise.position_std_m=1e-5",
        "master.effects.gravity.incline_deg=5",
    )
    files = write_params_files(node_plan(sc), tmp_path)
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        built = {}
        for cls, name in ((MasterEba, "master_eba"), (SlaveEba, "slave_eba")):
            node = cls(
                node_name=name,
                cli_args=["--ros-args", "--params-file", str(files[name])],
                use_global_arguments=False,
                context=context,
            )
            built[name] = (node.plant.effects, tuple(node.plant.model.opt.gravity))
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    engine = Engine(sc)
    assert built["master_eba"] == (engine.master.effects, tuple(engine.master.model.opt.gravity))
    assert built["slave_eba"] == (engine.slave.effects, tuple(engine.slave.model.opt.gravity))
    assert built["master_eba"][0] == ("gravity", "position_noise")
    assert built["slave_eba"][0] == ("lowpass",)


def test_per_tick_calls_grow_only_with_the_effects_named():
    """`bench effects`' exact column: physical effects add no call per tick (they are inside
    MuJoCo's step; they change the motion, and with it which branches the controllers take, so
    the count may move by one), a sensor effect adds a few, and the bench is registered."""
    from haptic_teleop.cli.bench import BENCHMARKS
    from haptic_teleop.studies.benchmarks.effects import NO_NETWORK, calls_per_tick

    assert BENCHMARKS["effects"] == "haptic_teleop.studies.benchmarks.effects"
    bare = calls_per_tick(str(SCENE), NO_NETWORK, ticks=200)
    for physical in ("master.effects.gravity.incline_deg=10", "master.effects.friction.coulomb_n=0.2"):
        # Not exactly 0: a different motion takes other branches in the controllers (about one
        # call a tick); a wrapper around the plant would add at least 2 (the noise case below).
        assert abs(calls_per_tick(str(SCENE), (*NO_NETWORK, physical), ticks=200) - bare) < 1.5
    noisy = calls_per_tick(str(SCENE), (*NO_NETWORK, "slave.effects.noise.force_std_n=0.1"), ticks=200)
    assert bare + 2 <= noisy <= bare + 5
