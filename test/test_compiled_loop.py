"""The compiled loop (haptic_teleop/fastloop.py) gives the Python loop's run, bit for bit.

Each case runs a scene in both loops and compares every recorded column, every packet record,
the guards' rejection counts and the controllers' final state. The cases cover what the compiled
loop takes: both laws, EBA on and off, the three operator profiles, saturating controllers, substeps, gravity, zero
delay, the vectorized network (constant delay, uncorrelated loss, blackouts, policy `none`) and
the network ticked through the Python objects (bursty loss, jitter with reordering, every
scheduled buffer policy).
"""

import numpy as np
import pytest

from haptic_teleop import fastloop
from haptic_teleop.bag import _packet_rows
from haptic_teleop.engine import Engine
from haptic_teleop.errors import HapticTeleopError
from haptic_teleop.scene import find_scene, load_scene

SHORT = "scene.duration_s=2.0"
FWD = "network.forward"
BWD = "network.backward"

CASES = {
    "default": ("wall_contact", []),
    "sinusoid": ("wall_contact", ["operator.profile=sinusoid", "operator.amplitude_m=0.03", "operator.frequency_hz=2"]),
    "hold": ("wall_contact", ["operator.profile=hold"]),
    "force_law_loss": ("wall_contact", ["controllers.master.law=force", f"{FWD}.effects.loss.probability=0.2"]),
    "eba_off_stiff": ("stiff_wall", ["controllers.master.eba.enabled=false", "controllers.slave.eba.enabled=false"]),
    "substeps": ("wall_contact", ["simulation.substeps=3"]),
    "saturation": ("wall_contact", ["controllers.master.force_limit_n=0.5", "controllers.slave.force_limit_n=2.0"]),
    "gravity": ("wall_contact", ["master.effects.gravity.incline_deg=10", "slave.effects.gravity.incline_deg=-5"]),
    "zero_delay": ("wall_contact", [f"{FWD}.effects.delay.delay_s=0", f"{BWD}.effects.delay.delay_s=0.0005"]),
    "blackout": ("blackout", ["scene.duration_s=4.0"]),
    "bursty_loss": ("bursty_loss", []),
    "jitter_reorder": (
        "wall_contact",
        [
            f"{FWD}.effects.delay.jitter_s=0.01",
            f"{FWD}.effects.reorder.probability=0.1",
            f"{BWD}.effects.duplicate.probability=0.05",
        ],
    ),
    "fixed": ("jitter", [f"{FWD}.buffer.policy=fixed", f"{BWD}.buffer.policy=fixed"]),
    "adaptive": ("jitter", [f"{FWD}.buffer.policy=adaptive", f"{BWD}.buffer.policy=adaptive"]),
    "percentile": ("jitter", [f"{FWD}.buffer.policy=percentile", f"{BWD}.buffer.policy=percentile"]),
    "transparency": ("varying_delay", []),
}


def _scene(name, overrides):
    extra = [] if any(o.startswith("scene.duration_s") for o in overrides) else [SHORT]
    return load_scene(find_scene(name), overrides=[*extra, *overrides])


def _rows(log):
    return log if isinstance(log, np.ndarray) else _packet_rows(log)


def _both(scene, stop_at=None):
    out = []
    for loop in ("compiled", "python"):
        e = Engine(scene, loop=loop)
        assert e.loop_kind == loop

        def progress(n, e=e):
            if stop_at is not None and n >= stop_at:
                e.request_stop()

        out.append((e, e.run(handle_sigint=False, progress=progress)))
    return out


def _assert_same_run(compiled, python):
    (ec, rc), (ep, rp) = compiled, python
    assert rc.ticks == rp.ticks
    assert np.array_equal(rc.data[: rc.ticks], rp.data[: rp.ticks])
    for c, p in zip(ec.packet_logs(), ep.packet_logs(), strict=True):
        assert np.array_equal(_rows(c), _rows(p), equal_nan=True)
    for side in ("master_ctrl", "slave_ctrl"):
        a, b = getattr(ec, side), getattr(ep, side)
        assert a.rejected_samples == b.rejected_samples
        assert a.bound.energy_j == b.bound.energy_j
        assert a._remote == b._remote
    assert ec.slave.contact_force() == ep.slave.contact_force()


@pytest.mark.parametrize("case", sorted(CASES))
def test_compiled_loop_equals_python_loop(case):
    name, overrides = CASES[case]
    compiled, python = _both(_scene(name, overrides))
    _assert_same_run(compiled, python)
    assert np.ptp(compiled[1].column("s_x_m")) > 1e-3 or case == "hold"  # not a vacuous comparison


@pytest.mark.parametrize("case", ["default", "jitter_reorder"])
def test_stopped_compiled_run_leaves_the_python_loops_records(case):
    """Stopped at the same tick, both loops leave the same columns and packet records (a ticked
    schedule ran ahead of the loop and is ticked again for the ticks that ran)."""
    name, overrides = CASES[case]
    compiled, python = _both(_scene(name, overrides), stop_at=700)
    assert compiled[1].interrupted and compiled[1].ticks == 700
    _assert_same_run(compiled, python)


def test_guard_rejections_are_the_same_in_both_loops():
    """Limits below what the scene produces make the guards reject real samples: the compiled
    loop rejects the same ones, keeps the previous sample, and counts them."""
    runs = []
    for loop in ("compiled", "python"):
        e = Engine(_scene("wall_contact", []), loop=loop)
        e.slave_ctrl.guard.limits = (0.01, 1.0)  # x beyond 1 cm is "absurd"
        e.master_ctrl.guard.limits = (50.0, 0.005, 1.0)  # (f_env, x, v): x beyond 5 mm
        runs.append((e, e.run(handle_sigint=False)))
    _assert_same_run(*runs)
    e = runs[0][0]
    assert e.slave_ctrl.rejected_samples > 100 and e.master_ctrl.rejected_samples > 100


@pytest.mark.parametrize(
    ("overrides", "reason"),
    [
        (["slave.effects.noise.force_std_n=0.1"], "plant effects"),
        ([f"{FWD}.effects.corrupt.probability=0.01"], "corrupts payloads"),
        ([f"{BWD}.buffer.gap=extrapolate"], "extrapolates"),
    ],
)
def test_scenes_the_compiled_loop_cannot_run_fall_back_and_say_why(overrides, reason):
    scene = _scene("wall_contact", overrides)
    e = Engine(scene)
    assert e.loop_kind == "python" and reason in e.compiled_reason
    with pytest.raises(HapticTeleopError, match=reason):
        Engine(scene, loop="compiled")
    with pytest.raises(ValueError, match="loop must be one of"):
        Engine(scene, loop="fast")


def test_vectorized_network_only_where_it_is_exact():
    """The default network is decided in one go; bursty (Markov) loss is ticked."""
    e = Engine(_scene("wall_contact", [f"{FWD}.effects.loss.probability=0.3"]))
    s = fastloop.schedule(e.forward, e.forward_buffer, 100, e.period_ns, 72)
    assert s.vectorized and isinstance(s.packets, np.ndarray)
    assert np.count_nonzero(s.released_seq >= 0) == np.count_nonzero(s.packets[:50, 3] == 0)  # 50 ms delay
    b = Engine(_scene("bursty_loss", []))
    assert not fastloop.schedule(b.forward, b.forward_buffer, 100, b.period_ns, 72).vectorized
