"""`controllers.<side>.eba.law` in a scene: checked, run by the Python loop (the compiled loops
refuse it with one line), and the contact force slope each law gives in the seed's setting
(docs/eba_two_condition.md, "The published two-condition law")."""

from __future__ import annotations

import numpy as np
import pytest

from haptic_teleop.core.eba_two_condition import TwoConditionBound, contact_force_slope_n_per_s
from haptic_teleop.engine.lockstep import COL, Engine
from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.load import find_scene, load_scene

BOTH = ("controllers.master.eba.law=two_condition", "controllers.slave.eba.law=two_condition")
# The master bound binding: 2 b_m / T = 200 N/m below c1 = 500 N/m; a stiff hand keeps v_m constant.
BINDING = (
    "master.damping_n_s_per_m=0.1",
    "operator.stiffness_n_per_m=10000",
    "operator.damping_n_s_per_m=200",
    "operator.start_s=0.1",
    "scene.duration_s=2.0",
)


def test_a_bad_law_is_one_line_naming_the_allowed_ones():
    with pytest.raises(ConfigError) as e:
        load_scene(find_scene("wall_contact"), overrides=["controllers.slave.eba.law=pooled"])
    msg = str(e.value)
    assert "controllers.slave.eba.law" in msg and "reservoir" in msg and "two_condition" in msg
    assert "\n" not in msg


def test_a_slew_limit_is_refused():
    """(On arms the law runs joint by joint: test_two_condition_arm.py has what is refused there.)"""
    with pytest.raises(ConfigError, match=r"controllers\.master\.eba\.law two_condition .*slew_rate_n_per_s"):
        load_scene(
            find_scene("wall_contact"),
            overrides=["controllers.master.eba.law=two_condition", "master.effects.saturation.slew_rate_n_per_s=200"],
        )


def test_auto_runs_it_compiled_with_the_python_loops_bits():
    """The compiled one-axis loop runs the law (core/eba_two_condition.two_condition_bound1, the
    Python bound's step): the same columns, bit for bit (test_compiled_loop.py has more cases)."""
    scene = load_scene(find_scene("wall_contact"), overrides=[*BOTH, "scene.duration_s=0.5"])
    engine = Engine(scene)
    assert engine.loop_kind == "compiled"
    assert isinstance(engine.master_ctrl.bound, TwoConditionBound)
    assert isinstance(engine.slave_ctrl.bound, TwoConditionBound)
    engine.run(handle_sigint=False)
    python = Engine(scene, loop="python")
    python.run(handle_sigint=False)
    assert np.array_equal(engine.data, python.data, equal_nan=True)
    assert engine.master_ctrl.bound.energy_j == python.master_ctrl.bound.energy_j


@pytest.fixture(scope="module")
def binding_runs() -> dict[str, np.ndarray]:
    out = {}
    for law in ("reservoir", "two_condition"):
        laws = (f"controllers.master.eba.law={law}", f"controllers.slave.eba.law={law}")
        engine = Engine(load_scene(find_scene("wall_contact"), overrides=[*BINDING, *laws]), loop="python")
        engine.run(handle_sigint=False)
        out[law] = engine.data[: engine.ticks_done].copy()
    return out


def test_contact_force_slope_is_the_predicted_one_under_each_law(binding_runs):
    """The seed's setting, measured: from 0.35 s after the slave touches the wall both laws raise
    the master's force at (2 b_m / T) v_m (`contact_force_slope_n_per_s` with v_m measured); in the
    first 0.2 s after the force comes back the two-condition law already does, while the reservoir
    law, spending the energy its reservoir stored in free motion, rises faster."""
    t_s, b_m, c1 = 1e-3, 0.1, 500.0
    early = {}
    for law, data in binding_runs.items():
        f = -data[:, COL["m_force_n"]]
        v = data[:, COL["m_v_m_per_s"]]
        c0 = int(np.argmax(-data[:, COL["s_contact_n"]] > 0.01))
        t = np.arange(f.size) * t_s
        late = slice(c0 + 350, c0 + 800)
        assert late.stop < f.size
        slope = np.polyfit(t[late], f[late], 1)[0]
        predicted = contact_force_slope_n_per_s(law, c1, b_m, t_s, float(np.mean(v[late])))
        assert slope == pytest.approx(predicted, rel=0.01), law
        first = slice(c0 + 150, c0 + 350)
        early[law] = np.polyfit(t[first], f[first], 1)[0] / float(np.mean(v[first]))
    assert early["two_condition"] == pytest.approx(2 * b_m / t_s, rel=0.01)
    assert early["reservoir"] > 1.5 * 2 * b_m / t_s
