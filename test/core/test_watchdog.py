"""Remote-data watchdog: force fades to zero within the documented bound and comes back."""

import math

import pytest

from haptic_teleop.core.controller import ControllerParams, TeleopController
from haptic_teleop.core.eba_state import EnergyBoundParams
from haptic_teleop.core.watchdog import ForceFade, Watchdog

PERIOD_NS = 1_000_000
TIMEOUT_NS = 100_000_000
FADE_NS = 50_000_000


def _run(wd: Watchdog, feed_until_ns: int, end_ns: int, resume_ns: int | None = None) -> list[tuple[int, float]]:
    out = []
    for k in range(end_ns // PERIOD_NS):
        t = k * PERIOD_NS
        if t <= feed_until_ns or (resume_ns is not None and t >= resume_ns):
            wd.feed(t)
        out.append((t, wd.update(t)))
    return out


def test_gain_is_zero_within_timeout_plus_fade_plus_one_period_of_the_last_arrival():
    wd = Watchdog(TIMEOUT_NS, FADE_NS, PERIOD_NS)
    last = 500_000_000
    gains = _run(wd, last, 1_000_000_000)
    bound_ns = wd.bound_s(PERIOD_NS * 1e-9) * 1e9
    assert bound_ns == pytest.approx(TIMEOUT_NS + FADE_NS + PERIOD_NS)
    after = [g for t, g in gains if t >= last + bound_ns]
    assert after and all(g == 0.0 for g in after)
    # ... and not earlier than the timeout: fresh data keeps full force.
    assert all(g == 1.0 for t, g in gains if FADE_NS + PERIOD_NS <= t <= last + TIMEOUT_NS)
    # The fade is gradual (no step from full force to none).
    fading = [g for t, g in gains if last + TIMEOUT_NS < t < last + TIMEOUT_NS + FADE_NS]
    assert len(fading) > 10 and all(0.0 < g < 1.0 for g in fading)
    assert wd.trips == 1


def test_gain_recovers_over_the_fade_when_data_returns():
    wd = Watchdog(TIMEOUT_NS, FADE_NS, PERIOD_NS)
    gains = _run(wd, 200_000_000, 1_000_000_000, resume_ns=600_000_000)
    assert dict(gains)[590_000_000] == 0.0
    back = [t for t, g in gains if t >= 600_000_000 and g == 1.0]
    assert back and back[0] <= 600_000_000 + FADE_NS + PERIOD_NS


def test_no_force_before_the_first_arrival():
    wd = Watchdog(TIMEOUT_NS, FADE_NS, PERIOD_NS)
    assert wd.update(0) == 0.0 and wd.update(5 * PERIOD_NS) == 0.0


@pytest.mark.parametrize("args", [(0, FADE_NS, PERIOD_NS), (TIMEOUT_NS, -1, PERIOD_NS), (TIMEOUT_NS, FADE_NS, 0)])
def test_bad_settings_are_rejected(args):
    with pytest.raises(ValueError):
        Watchdog(*args)


def test_faded_controller_commands_zero_force_and_keeps_its_reservoir_non_negative():
    """The slave side: remote master samples stop; the robot's commanded force goes to zero within
    the bound, the energy bound still accounts for it, and force returns with the data."""
    period_s = PERIOD_NS * 1e-9
    ctrl = TeleopController(
        ControllerParams(role="slave", stiffness_n_per_m=500.0, damping_n_s_per_m=20.0, force_limit_n=40.0),
        EnergyBoundParams(period_s=period_s, damping_n_s_per_m=(5.0,), initial_energy_j=0.5),
    )
    fade = ForceFade(ctrl)
    wd = Watchdog(TIMEOUT_NS, FADE_NS, PERIOD_NS)
    x, v = 0.0, 0.0
    forces = []
    for k in range(1500):
        t = k * PERIOD_NS
        if k < 300 or k >= 900:  # samples arrive, then a 600 ms outage
            ctrl.set_remote((0.01 if k < 300 else 0.03, 0.0))  # the master moved during the outage
            wd.feed(t)
        fade.set_gain(wd.update(t))
        f = ctrl.step([x], [v])[0]
        forces.append(f)
        assert ctrl.bound.energy_j[0] >= -1e-12
        # a damped 1 kg robot moving under the force (semi-implicit Euler)
        v += period_s * (f - 5.0 * v) / 1.0
        x += period_s * v
    bound_ticks = math.ceil((TIMEOUT_NS + FADE_NS + PERIOD_NS) / PERIOD_NS)
    assert max(abs(f) for f in forces[299 + bound_ticks : 900]) <= math.ulp(0.0)
    assert max(abs(f) for f in forces[100:300]) > 0.1  # it was pushing before the outage
    assert max(abs(f) for f in forces[960:1500]) > 0.1  # and pushes again after it
    assert fade._ctrl.params.force_limit_n == 40.0  # full limit restored
