"""Sensor and actuator effects against their analytic behaviour (docs/effects.md)."""

import math

import numpy as np
import pytest

from haptic_teleop.core.sensing import (
    ActuatorLimit,
    GaussianNoise,
    LowPassFilter,
    MovingAverage,
    Quantizer,
    sensing_rng,
)


@pytest.mark.parametrize("std", [1e-6, 0.01, 2.5])
def test_noise_mean_and_std_match_the_asked_gaussian(std):
    """Sample mean within 4 standard errors of the true value (and of zero); the sample variance
    within 4 of its own standard errors (sqrt(2/(n-1)) sigma^2 for a Gaussian)."""
    n = 40000
    noise = GaussianNoise(std, sensing_rng(3, "master", "position_noise"))
    true = 0.125
    samples = np.array([noise.apply([true, -true]) for _ in range(n)])
    err = samples - np.array([true, -true])
    for axis in range(2):
        e = err[:, axis]
        assert abs(e.mean()) < 4 * std / math.sqrt(n)
        assert abs(e.var(ddof=1) - std**2) < 4 * std**2 * math.sqrt(2 / (n - 1))
    # The two axes draw different numbers (not one draw copied to both).
    assert abs(np.corrcoef(err[:, 0], err[:, 1])[0, 1]) < 4 / math.sqrt(n)
    # The one-axis path draws the same stream, number for number.
    one = GaussianNoise(std, sensing_rng(3, "master", "position_noise"))
    two = GaussianNoise(std, sensing_rng(3, "master", "position_noise"))
    flat = [one.apply([0.0])[0] for _ in range(2 * 5000)]
    pairs = [v for _ in range(5000) for v in two.apply([0.0, 0.0])]
    assert flat == pairs


def test_noise_is_reproducible_per_seed_and_independent_per_effect():
    def draws(seed, side, name):
        g = GaussianNoise(1.0, sensing_rng(seed, side, name))
        return [g.apply([0.0])[0] for _ in range(5000)]  # crosses a block boundary (4096)

    a = draws(7, "slave", "force_noise")
    assert a == draws(7, "slave", "force_noise")
    assert a != draws(8, "slave", "force_noise")
    assert a != draws(7, "master", "force_noise")
    assert a != draws(7, "slave", "position_noise")


def test_noise_rejects_a_non_positive_std():
    with pytest.raises(ValueError, match="std"):
        GaussianNoise(0.0, sensing_rng(0, "master", "x"))


def test_quantizer_reports_whole_counts_within_half_a_count():
    r = 1e-5
    q = Quantizer(r)
    xs = np.linspace(-3e-4, 3e-4, 10007)
    out = np.array([q.apply([float(x)])[0] for x in xs])
    counts = out / r
    assert np.allclose(counts, np.round(counts), atol=1e-9)
    assert np.max(np.abs(out - xs)) <= r / 2 + 1e-15
    # A staircase: 61 levels over +-30 counts, and monotonic.
    assert len(np.unique(np.round(counts))) == 61
    assert np.all(np.diff(out) >= 0)


def test_lowpass_step_response_is_the_sampled_exponential():
    fc, period = 20.0, 0.001
    filt = LowPassFilter(fc, period)
    tau = 1.0 / (2 * math.pi * fc)
    assert filt.time_constant_s == pytest.approx(tau)
    assert filt.apply([0.0, 3.0]) == [0.0, 3.0]  # starts at the first input: no transient
    one_axis = LowPassFilter(fc, period)
    one_axis.apply([0.0])
    for n in range(200):
        y = filt.apply([1.0, 3.0])
        assert y[0] == pytest.approx(1.0 - math.exp(-(n + 1) * period / tau), abs=1e-12)
        assert y[1] == pytest.approx(3.0, abs=1e-12)
        assert one_axis.apply([1.0]) == [y[0]]


def test_lowpass_gain_at_its_cutoff_is_one_over_sqrt2():
    """Steady-state amplitude of a sinusoid at the cutoff (f_c far below Nyquist): 1/sqrt(2)."""
    fc, period = 5.0, 0.0005
    filt = LowPassFilter(fc, period)
    ys = [filt.apply([math.sin(2 * math.pi * fc * n * period)])[0] for n in range(20000)]
    amplitude = max(abs(y) for y in ys[-2000:])  # the last 2000 samples hold 5 whole periods
    assert amplitude == pytest.approx(1 / math.sqrt(2), rel=0.01)


def test_moving_average_delays_a_ramp_by_half_its_window():
    w = 9
    ma = MovingAverage(w)
    out = [ma.apply([float(n)])[0] for n in range(50)]
    assert out[0] == 0.0 and out[1] == 0.5  # fewer samples while filling
    for n in range(w - 1, 50):
        assert out[n] == pytest.approx(n - (w - 1) / 2)


def test_slew_limit_ramps_at_the_rate_and_clip_holds():
    period = 0.001
    act = ActuatorLimit(period, 1, force_limit_n=5.0, slew_rate_n_per_s=1000.0)
    applied = [act.apply([100.0])[0] for _ in range(10)]
    assert applied == pytest.approx([1.0, 2.0, 3.0, 4.0, 5.0, 5.0, 5.0, 5.0, 5.0, 5.0])
    down = [act.apply([-100.0])[0] for _ in range(12)]
    assert down[0] == pytest.approx(4.0) and down[-1] == pytest.approx(-5.0)
    assert max(abs(d) for d in down) <= 5.0


def test_force_limit_alone_clips_and_nan_never_reaches_the_plant():
    act = ActuatorLimit(0.001, 2, force_limit_n=3.0)
    assert act.apply([10.0, -2.0]) == [3.0, -2.0]
    assert act.apply([-10.0, 2.5]) == [-3.0, 2.5]
    out = act.apply([float("nan"), 1.0])
    assert out == [0.0, 1.0]
    one = ActuatorLimit(0.001, 1, force_limit_n=3.0)
    assert [one.apply([f])[0] for f in (10.0, -10.0, 2.5, float("nan"))] == [3.0, -3.0, 2.5, 0.0]


def test_actuator_limit_needs_a_limit():
    with pytest.raises(ValueError, match="force_limit_n, slew_rate_n_per_s"):
        ActuatorLimit(0.001, 1)
