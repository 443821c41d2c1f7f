"""The compiled loop (haptic_teleop/axis_host.py) gives the Python loop's run, bit for bit.

Each case runs a scene in both loops and compares what each hands its sink, call by call (every
block of columns, every batch of packet records, at the same points of the run), the guards'
rejection counts and the controllers' final state. The cases cover what the compiled
loop takes: both laws, EBA on and off, TDPA (both controllers, reflection) and wave variables
(filter, drift correction), the operator profiles (hands and the imposed trajectory;
free and in-contact starts), saturating controllers, substeps, gravity, zero
delay, the vectorized network (constant delay, uncorrelated and bursty loss, blackouts, policy
`none`) and
the network ticked through the Python objects (jitter with reordering, every
scheduled buffer policy).
"""

import numpy as np
import pytest
from compiled_identity import Calls, assert_same_calls

from haptic_teleop.engine.compiled import axis_host
from haptic_teleop.engine.compiled.buffer_schedule import BufferedSchedule
from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.errors import HapticTeleopError
from haptic_teleop.scene.load import find_scene, load_scene

SHORT = "scene.duration_s=2.0"
FWD = "network.forward"
BWD = "network.backward"
TDPA = ("controllers.master.eba.law=tdpa", "controllers.slave.eba.law=tdpa")
WAVE = ("controllers.master.eba.law=wave", "controllers.slave.eba.law=wave")

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
    # The seed scenario: an in-contact start and the imposed (position source) profile.
    "seed_contact": ("seed_contact", []),
    "seed_contact_force_law": ("seed_contact", ["controllers.master.law=force", "controllers.master.force_gain=1"]),
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
    "bandwidth": ("bandwidth", []),
    "varying_delay_fixed": ("varying_delay", [f"{FWD}.buffer.policy=fixed", f"{BWD}.buffer.policy=fixed"]),
    "none_jitter": ("jitter", [f"{FWD}.buffer.policy=none", f"{BWD}.buffer.policy=none"]),
    "percentile": ("jitter", [f"{FWD}.buffer.policy=percentile", f"{BWD}.buffer.policy=percentile"]),
    "transparency": ("varying_delay", []),
    # Seed 000's network-adaptive buffer: D_a, L_a and d0 passed by the engine (assembly.build_network).
    "network_adaptive": (
        "seed_contact",
        [
            f"{FWD}.effects.delay.jitter_s=0.004",
            f"{BWD}.effects.delay.jitter_s=0.004",
            f"{FWD}.buffer.policy=network_adaptive",
            f"{BWD}.buffer.policy=network_adaptive",
        ],
    ),
    # The other stabilizers (core/tdpa.py, core/wave.py), with loss (vectorized) and jitter (ticked).
    "tdpa_velocity_loss": ("wall_contact", [*TDPA, f"{FWD}.effects.loss.probability=0.2"]),
    "tdpa_zoh_reflect_jitter": (
        "wall_contact",
        [
            *TDPA,
            *(
                f"controllers.{s}.eba.{k}"
                for s in ("master", "slave")
                for k in ("tdpa_controller=zoh", "tdpa_reflection=0.5")
            ),
            f"{BWD}.effects.delay.jitter_s=0.004",
            f"{BWD}.buffer.policy=fixed",
        ],
    ),
    # TDPA's admittance placement on both sides, where the controllers act (stiff coupling), with loss.
    "tdpa_zoh_admittance_stiff_loss": (
        "wall_contact",
        [
            *TDPA,
            *(
                f"controllers.{s}.{k}"
                for s in ("master", "slave")
                for k in (
                    "eba.tdpa_controller=zoh",
                    "eba.tdpa_placement=admittance",
                    "eba.tdpa_drift_gain_per_s=2",
                    "stiffness_n_per_m=1e6",
                    "damping_n_s_per_m=1e4",
                )
            ),
            f"{FWD}.effects.loss.probability=0.2",
        ],
    ),
    "wave_loss": ("wall_contact", [*WAVE, f"{BWD}.effects.loss.probability=0.2"]),
    # EBA's published two conditions (core/eba_two_condition.two_condition_bound1), with the
    # controllers' force limits and loss; the slave alone on it at a stiff wall
    "two_condition_limit_loss": (
        "wall_contact",
        [
            *(f"controllers.{s}.eba.law=two_condition" for s in ("master", "slave")),
            "controllers.master.force_limit_n=0.5",
            f"{FWD}.effects.loss.probability=0.2",
        ],
    ),
    "two_condition_slave_stiff": ("stiff_wall", ["controllers.slave.eba.law=two_condition"]),
    "wave_matched_loss": (
        "wall_contact",
        [*WAVE, "controllers.slave.eba.wave_matched=true", f"{FWD}.effects.loss.probability=0.2"],
    ),
    "wave_filtered_drift_jitter": (
        "wall_contact",
        [
            *WAVE,
            "controllers.master.eba.wave_filter_hz=50",
            "controllers.slave.eba.wave_filter_hz=50",
            "controllers.slave.eba.wave_drift_gain_per_s=5",
            f"{FWD}.effects.delay.jitter_s=0.004",
            f"{FWD}.effects.reorder.probability=0.1",
        ],
    ),
    # Delays longer than the compiled loop's first history ring (1024 ticks) and than a block:
    # the ring grows, records wait several blocks for their fates.
    "long_delay": ("wall_contact", ["scene.duration_s=4.0", f"{FWD}.effects.delay.delay_s=1.5"]),
    "long_jitter": (
        "wall_contact",
        [
            "scene.duration_s=4.0",
            f"{BWD}.effects.delay.delay_s=1.3",
            f"{BWD}.effects.delay.jitter_s=0.005",
            f"{BWD}.buffer.policy=fixed",
        ],
    ),
}


def _scene(name, overrides):
    extra = [] if any(o.startswith("scene.duration_s") for o in overrides) else [SHORT]
    return load_scene(find_scene(name), overrides=[*extra, *overrides])


def _both(scene, stop_at=None):
    out = []
    for loop in ("compiled", "python"):
        e = Engine(scene, loop=loop)
        assert e.loop_kind == loop

        def progress(n, e=e):
            if stop_at is not None and n >= stop_at:
                e.request_stop()

        out.append((e, _run(e, progress)))
    return out


def _run(e, progress=None):
    sink = Calls()
    r = e.run(handle_sigint=False, progress=progress, sink=sink)
    r.data = sink.data()  # for the checks below
    r.calls = sink.calls
    return r


def _assert_same_run(compiled, python):
    (ec, rc), (ep, rp) = compiled, python
    assert rc.ticks == rp.ticks
    assert_same_calls(rc.calls, rp.calls)
    for side in ("master_ctrl", "slave_ctrl"):
        a, b = getattr(ec, side), getattr(ep, side)
        assert a.rejected_samples == b.rejected_samples
        assert a.bound.energy_j == b.bound.energy_j
        assert a.bound.axis_state() == b.bound.axis_state()  # energy, held force, last position
        assert a.remote == b.remote
    assert ec.slave.contact_force() == ep.slave.contact_force()


@pytest.mark.parametrize("case", sorted(CASES))
def test_compiled_loop_equals_python_loop(case):
    name, overrides = CASES[case]
    compiled, python = _both(_scene(name, overrides))
    _assert_same_run(compiled, python)
    assert np.ptp(compiled[1].column("s_x_m")) > 1e-3 or case == "hold"  # not a vacuous comparison
    # Blocks and packet records were handed over while the run went on, not only at its end.
    kinds = [k for k, _ in compiled[1].calls]
    assert kinds[0] == "rows" and {"forward", "backward"} & set(kinds[: kinds.index("rows", 1)])


@pytest.mark.parametrize("case", ["default", "jitter_reorder", "adaptive"])
def test_stopped_compiled_run_leaves_the_python_loops_records(case):
    """Stopped at the same tick, both loops leave the same columns and packet records (a ticked
    schedule is decided one chunk of the loop at a time, so it never runs ahead of a stop; a
    buffered one is decided a window ahead and records what had happened by the stop)."""
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
        runs.append((e, _run(e)))
    _assert_same_run(*runs)
    e = runs[0][0]
    assert e.slave_ctrl.rejected_samples > 100 and e.master_ctrl.rejected_samples > 100


def test_bound_with_actuator_limits_is_the_same_in_both_loops():
    """The bound that models an actuator's clip and slew limit (`ramp_limit1`, `actuator_bounded1`)
    runs compiled too, with the same bits. Scenes with actuator effects run in the Python loop, so
    the limits are given to the bounds of an effect-free scene: 3 N / 10 N/s on the master,
    8 N / 20 N/s on the slave (the bare plants then apply what the bound lets through)."""
    import dataclasses

    from haptic_teleop.core.eba import EnergyBound

    runs = []
    for loop in ("compiled", "python"):
        e = Engine(_scene("wall_contact", []), loop=loop)
        for ctrl, clip, slew in ((e.master_ctrl, 3.0, 10.0), (e.slave_ctrl, 8.0, 20.0)):
            p = dataclasses.replace(ctrl.bound.params, force_limit_n=clip, slew_rate_n_per_s=slew)
            ctrl.bound = EnergyBound(p)
        runs.append((e, _run(e)))
    _assert_same_run(*runs)
    r = runs[0][1]
    # Not vacuous: both forces ramp at their full slew rate on some ticks, and never faster.
    for column, step in (("m_force_n", 0.01), ("s_force_n", 0.02)):
        ramp = np.abs(np.diff(r.column(column)))
        assert np.count_nonzero(ramp >= step * (1 - 1e-12)) > 10 and np.max(ramp) <= step * (1 + 1e-12)


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
    """The default network is decided in numpy, window by window, and bursty (Markov) loss too (its
    chain run compiled over the window); jitter with an adaptive buffer too, its buffer's rules
    compiled (buffer_schedule.py), and a time-varying delay into the transparency buffer; a link
    that copies packets is ticked."""
    e = Engine(_scene("wall_contact", [f"{FWD}.effects.loss.probability=0.3"]))
    s = axis_host.schedule(e.forward, e.forward_buffer, e.period_ns, 72)
    assert s.vectorized
    released = np.concatenate([s.window(0, 30)[0], s.window(30, 100)[0]])  # two windows, one stream
    rows = s.settled(100, final=True)
    assert np.count_nonzero(released >= 0) == np.count_nonzero(rows[:50, 3] == 0)  # 50 ms delay
    assert np.array_equal(released[50:], np.where(rows[:50, 3] == 0, np.arange(50), -1))
    b = Engine(_scene("bursty_loss", []))
    assert axis_host.schedule(b.forward, b.forward_buffer, b.period_ns, 72).vectorized
    j = Engine(_scene("jitter", []))
    assert type(axis_host.schedule(j.forward, j.forward_buffer, j.period_ns, 72)) is BufferedSchedule
    v = Engine(_scene("varying_delay", []))  # a sinusoidal delay and the transparency buffer
    assert type(axis_host.schedule(v.forward, v.forward_buffer, v.period_ns, 72)) is BufferedSchedule
    d = Engine(_scene("wall_contact", [f"{BWD}.effects.duplicate.probability=0.05"]))  # copies: packet by packet
    assert not axis_host.schedule(d.backward, d.backward_buffer, d.period_ns, 72).vectorized


def test_settled_records_wait_for_packets_in_flight():
    """A record is handed over once its fate is final: not while the packet is on its way."""
    e = Engine(_scene("wall_contact", [f"{FWD}.effects.delay.delay_s=0.2"]), loop="python")
    sink = Calls()
    e.run(handle_sigint=False, sink=sink)
    fwd = [rows for kind, rows in sink.calls if kind == "forward"]
    assert [len(r) for r in fwd[:2]] == [800, 1000]  # at 1 s: sent 1000, 200 on their way
    assert len(np.concatenate(fwd)) == 2000 and np.array_equal(np.concatenate(fwd)[:, 0], np.arange(2000))
