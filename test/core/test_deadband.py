"""Perceptual deadband codec (core/deadband.py): the deadzone geometry of seed 001, the first
sample, the zero-vector and floor conventions, hold and extrapolation, the velocity-adaptive
threshold, the rate reduction on a synthetic signal and config validation."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop import typedconfig
from haptic_teleop.core.deadband import (
    DeadbandConfig,
    DeadbandDecoder,
    DeadbandEncoder,
    GroupedDeadbandEncoder,
    build_deadband,
    effective_deadband,
    reduction_on,
    synthetic_contact_signal,
    violates,
)
from haptic_teleop.core.link import Packet
from haptic_teleop.errors import ConfigError
from haptic_teleop.record.layouts import joint_state_size

T = 1_000_000  # 1 ms period in ns
P_VALUES = (0.025, 0.05, 0.1, 0.2, 0.4)


def _sends(cfg: DeadbandConfig, first: tuple[float, ...], second: tuple[float, ...], **kw: object) -> bool:
    enc = DeadbandEncoder(cfg, len(first), 0)
    assert len(enc.send(0, 0, first)) == 1
    return len(enc.send(1, T, second, **kw)) == 1  # type: ignore[arg-type]


def _rotate_xy(v: tuple[float, float, float], angle: float, scale: float = 1.0) -> tuple[float, float, float]:
    c, s = math.cos(angle), math.sin(angle)
    return (scale * (c * v[0] - s * v[1]), scale * (s * v[0] + c * v[1]), scale * v[2])


# ------------------------------------------------------------------------------------------
# Geometry


@pytest.mark.parametrize("p", P_VALUES)
def test_constant_magnitude_direction_change_threshold(p: float) -> None:
    """At constant magnitude the chord 2|v| sin(a/2) reaches p|v| at a = 2 arcsin(p/2)."""
    cfg = DeadbandConfig(deadband=p)
    vi = (3.0, 0.0, 0.0)
    a_star = 2.0 * math.asin(p / 2.0)
    assert _sends(cfg, vi, _rotate_xy(vi, a_star * (1 + 1e-6)))
    assert not _sends(cfg, vi, _rotate_xy(vi, a_star * (1 - 1e-6)))
    # The seed's arcsin(p) itself, at constant magnitude, is past the threshold: it sends.
    assert a_star < math.asin(p)
    assert _sends(cfg, vi, _rotate_xy(vi, math.asin(p)))


@pytest.mark.parametrize("p", P_VALUES)
def test_arcsin_p_is_the_largest_undetected_direction_change(p: float) -> None:
    """Just under arcsin(p) there is a magnitude (the tangent point |v_i| cos a) that stays in
    the deadzone; just over arcsin(p) no magnitude does."""
    cfg = DeadbandConfig(deadband=p)
    vi = (0.0, 2.0, 0.0)
    under = math.asin(p) * (1 - 1e-6)
    assert not _sends(cfg, vi, _rotate_xy(vi, under, math.cos(under)))
    over = math.asin(p) * (1 + 1e-6)
    for scale in np.linspace(0.0, 2.0, 401):
        assert _sends(cfg, vi, _rotate_xy(vi, over, float(scale))), scale


@pytest.mark.parametrize("p", P_VALUES)
def test_magnitude_change_threshold(p: float) -> None:
    cfg = DeadbandConfig(deadband=p)
    vi = (1.0, -2.0, 2.0)  # |v_i| = 3
    for sign in (1.0, -1.0):
        assert _sends(cfg, vi, tuple(x * (1 + sign * p * (1 + 1e-6)) for x in vi))
        assert not _sends(cfg, vi, tuple(x * (1 + sign * p * (1 - 1e-6)) for x in vi))


@pytest.mark.parametrize("p", (0.05, 0.2))
def test_one_dimensional_stream(p: float) -> None:
    cfg = DeadbandConfig(deadband=p)
    assert _sends(cfg, (-1.0,), (-1.0 - p * 1.001,))
    assert not _sends(cfg, (-1.0,), (-1.0 + p * 0.999,))


_coord = st.floats(-10.0, 10.0, allow_nan=False)
_vec = st.tuples(_coord, _coord, _coord).filter(lambda v: math.sqrt(sum(x * x for x in v)) > 1e-3)
_unit = _vec.map(lambda v: tuple(x / math.sqrt(sum(y * y for y in v)) for x in v))


@settings(max_examples=300, deadline=None)
@given(vi=_vec, u=_unit, p=st.floats(0.01, 0.9), frac=st.floats(0.0, 0.999))
def test_inside_sphere_never_sends(vi: tuple[float, ...], u: tuple[float, ...], p: float, frac: float) -> None:
    r = frac * p * math.sqrt(sum(x * x for x in vi))
    assert not _sends(DeadbandConfig(deadband=p), vi, tuple(a + r * b for a, b in zip(vi, u, strict=True)))


@settings(max_examples=300, deadline=None)
@given(vi=_vec, u=_unit, p=st.floats(0.01, 0.9), factor=st.floats(1.001, 50.0))
def test_outside_sphere_always_sends(vi: tuple[float, ...], u: tuple[float, ...], p: float, factor: float) -> None:
    r = factor * p * math.sqrt(sum(x * x for x in vi))
    assert _sends(DeadbandConfig(deadband=p), vi, tuple(a + r * b for a, b in zip(vi, u, strict=True)))


@settings(max_examples=300, deadline=None)
@given(vi=_vec, w=_vec, p=st.floats(0.01, 0.9), extra=st.floats(1e-3, 1.0), scale=st.floats(0.0, 5.0))
def test_any_direction_change_beyond_arcsin_p_sends(
    vi: tuple[float, ...], w: tuple[float, ...], p: float, extra: float, scale: float
) -> None:
    """3-D: a vector at angle a > arcsin(p) from v_i, of any magnitude, leaves the deadzone."""
    a = min(math.asin(p) + extra, math.pi)
    n_vi = math.sqrt(sum(x * x for x in vi))
    e1 = tuple(x / n_vi for x in vi)
    dot = sum(x * y for x, y in zip(w, e1, strict=True))
    perp = tuple(x - dot * y for x, y in zip(w, e1, strict=True))
    n_perp = math.sqrt(sum(x * x for x in perp))
    if n_perp < 1e-6:
        perp = (-e1[1], e1[0], 0.0) if abs(e1[2]) < 0.9 else (0.0, -e1[2], e1[1])
        n_perp = math.sqrt(sum(x * x for x in perp))
    e2 = tuple(x / n_perp for x in perp)
    mag = scale * n_vi
    vc = tuple(mag * (math.cos(a) * x + math.sin(a) * y) for x, y in zip(e1, e2, strict=True))
    if mag < 1e-9:
        vc = (0.0, 0.0, 0.0)
    assert _sends(DeadbandConfig(deadband=p), vi, vc)


# ------------------------------------------------------------------------------------------
# First sample, zero vector, floor, counters, payload


def test_first_sample_always_sent() -> None:
    for first in ((0.0, 0.0, 0.0), (1.0, 2.0, 3.0)):
        enc = DeadbandEncoder(DeadbandConfig(deadband=1.0, min_threshold=1e6), 3, 0)
        out = enc.send(7, 7 * T, first)
        assert len(out) == 1 and out[0].payload == first and out[0].seq == 7
        assert enc.send(8, 8 * T, first) == []


def test_zero_vector_any_change_sends_and_floor_suppresses_it() -> None:
    zero = (0.0, 0.0, 0.0)
    tiny = (0.0, 1e-12, 0.0)
    assert _sends(DeadbandConfig(deadband=0.4), zero, tiny)
    assert not _sends(DeadbandConfig(deadband=0.4), zero, zero)
    floored = DeadbandConfig(deadband=0.4, min_threshold=0.01)
    assert not _sends(floored, zero, (0.0, 0.0099, 0.0))
    assert _sends(floored, zero, (0.0, 0.0101, 0.0))
    # Above the floor, p |v_i| rules: 0.4 * 1 = 0.4 > 0.01.
    assert not _sends(floored, (1.0, 0.0, 0.0), (1.39, 0.0, 0.0))


def test_floor_stops_near_zero_noise_from_sending_every_tick() -> None:
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 1e-3, size=(2000, 3))
    assert reduction_on(noise, DeadbandConfig(deadband=0.1)) < 0.5
    assert reduction_on(noise, DeadbandConfig(deadband=0.1, min_threshold=0.02)) > 0.99


def test_counters_payload_and_size() -> None:
    cfg = DeadbandConfig(deadband=0.1, reconstruction="extrapolate")
    size = joint_state_size(cfg.floats_per_axis, 3)
    enc, _ = build_deadband(cfg, 3, T, size)
    samples = [(1.0, 0.0, 0.0), (1.05, 0.0, 0.0), (1.2, 0.0, 0.0), (1.2, 0.0, 0.0)]
    sent = [enc.send(n, n * T, s, rate=(float(n), 0.0, 0.5)) for n, s in enumerate(samples)]
    assert [len(x) for x in sent] == [1, 0, 1, 0]
    pkt = sent[2][0]
    assert pkt.seq == 2 and pkt.send_time_ns == 2 * T and pkt.size_bytes == size
    assert pkt.payload == (1.2, 0.0, 0.0, 2.0, 0.0, 0.5)  # sample, then its rate
    assert enc.counters == {"offered": 4, "sent": 2, "filtered": 2}
    assert enc.reduction == pytest.approx(0.5)
    assert joint_state_size(1, 3) < size  # hold sends the sample only: a smaller message
    assert DeadbandConfig(reconstruction="hold").floats_per_axis == 1
    assert DeadbandConfig(reconstruction="extrapolate", extrapolate_from="last_two").floats_per_axis == 1


# ------------------------------------------------------------------------------------------
# Reconstruction


def _run(
    cfg: DeadbandConfig, signal: list[tuple[float, ...]], rate: list[tuple[float, ...]] | None = None
) -> tuple[list[tuple[float, ...] | None], list[int]]:
    dim = len(signal[0])
    enc, dec = build_deadband(cfg, dim, T, 0)
    out, sent = [], []
    for n, s in enumerate(signal):
        for pkt in enc.send(n, n * T, s, rate=None if rate is None else rate[n]):
            sent.append(n)
            assert dec.receive(pkt, n * T) == []
        out.append(dec.sample(n, n * T))
    return out, sent


def _ramp(n_ticks: int, x0: tuple[float, ...], v: tuple[float, ...]) -> list[tuple[float, ...]]:
    return [tuple(a + b * n * T * 1e-9 for a, b in zip(x0, v, strict=True)) for n in range(n_ticks)]


def test_hold_reproduces_the_last_sent_sample_on_a_ramp() -> None:
    ramp = _ramp(500, (0.1, -0.2, 0.3), (0.05, 0.1, -0.02))
    out, sent = _run(DeadbandConfig(deadband=0.05), ramp)
    assert 2 < len(sent) < 100
    for n, got in enumerate(out):
        last = max(k for k in sent if k <= n)
        assert got == ramp[last]


@pytest.mark.parametrize("given_rate", [True, False])
def test_extrapolation_reproduces_constant_velocity_position_exactly(given_rate: bool) -> None:
    v = (0.05, 0.1, -0.02)
    ramp = _ramp(500, (0.1, -0.2, 0.3), v)
    cfg = DeadbandConfig(deadband=0.05, reconstruction="extrapolate", max_extrapolation_s=None)
    out, sent = _run(cfg, ramp, [v] * len(ramp) if given_rate else None)
    assert 2 < len(sent) < 100
    start = 0 if given_rate else sent[1]  # the backward difference needs one earlier sample
    for n in range(start, len(ramp)):
        assert out[n] == pytest.approx(ramp[n], rel=1e-9, abs=1e-12), n


def test_extrapolation_from_the_last_two_received_samples_on_a_force_ramp() -> None:
    ramp = _ramp(400, (2.0, -1.0), (3.0, 1.5))
    cfg = DeadbandConfig(deadband=0.05, reconstruction="extrapolate", extrapolate_from="last_two")
    out, sent = _run(cfg, ramp)
    assert len(sent) > 3
    for n in range(sent[0], sent[1] + 1):  # one sample received: hold
        assert out[n] == ramp[sent[0] if n < sent[1] else sent[1]]
    for n in range(sent[1], len(ramp)):
        assert out[n] == pytest.approx(ramp[n], rel=1e-9, abs=1e-12), n


def test_extrapolation_cap_then_hold() -> None:
    cfg = DeadbandConfig(reconstruction="extrapolate", max_extrapolation_s=0.005)
    dec = DeadbandDecoder(cfg, 1, T)
    dec.receive(Packet(seq=10, send_time_ns=10 * T, payload=(1.0, 2.0)), 0)  # x = 1, rate 2 /s
    assert dec.sample(10, 0) == (1.0,)
    assert dec.sample(13, 0) == pytest.approx((1.006,))
    for n in (15, 16, 100):
        assert dec.sample(n, 0) == pytest.approx((1.010,))
    assert dec.counters["extrapolated"] == 2  # ticks 13 and 15; 16 and 100 hold


def test_decoder_ignores_stale_and_duplicate_packets() -> None:
    dec = DeadbandDecoder(DeadbandConfig(), 1, T)
    assert dec.sample(0, 0) is None
    dec.receive(Packet(seq=5, send_time_ns=0, payload=(5.0,)), 0)
    dec.receive(Packet(seq=3, send_time_ns=0, payload=(3.0,)), 0)
    dec.receive(Packet(seq=5, send_time_ns=0, payload=(9.0,)), 0)
    assert dec.sample(6, 0) == (5.0,)
    assert dec.counters == {"received": 1, "stale": 2, "extrapolated": 0}


# ------------------------------------------------------------------------------------------
# Velocity-adaptive deadband


@pytest.mark.parametrize(("p0", "alpha", "p_max"), [(0.05, 10.0, 0.3), (0.1, 2.0, 0.15), (0.02, 0.5, 1.0)])
def test_velocity_adaptive_threshold_follows_its_formula(p0: float, alpha: float, p_max: float) -> None:
    cfg = DeadbandConfig(deadband=p0, adaptive_gain=alpha, max_deadband=p_max)
    for speed in (0.0, 0.01, 0.1, 0.5, 2.0, 50.0):
        expected = min(p0 * (1.0 + alpha * speed), p_max)
        assert effective_deadband(cfg, speed) == pytest.approx(expected, rel=1e-12)
        vel = (0.0, speed * 0.6, -speed * 0.8)  # |vel| = speed
        vi = (2.0, 0.0, 0.0)
        assert _sends(cfg, vi, (2.0 * (1 + expected * (1 + 1e-6)), 0.0, 0.0), velocity=vel)
        assert not _sends(cfg, vi, (2.0 * (1 + expected * (1 - 1e-6)), 0.0, 0.0), velocity=vel)
    assert effective_deadband(DeadbandConfig(deadband=p0), 100.0) == p0  # gain 0: off


def test_velocity_adaptive_uses_the_streams_own_rate_without_a_velocity() -> None:
    cfg = DeadbandConfig(deadband=0.05, adaptive_gain=10.0, max_deadband=0.5)
    enc = DeadbandEncoder(cfg, 1, 0)
    enc.send(0, 0, (1.0,))
    assert enc.send(1, T, (1.01,), rate=(0.4,)) == []  # p = 0.05 * (1 + 4) = 0.25
    assert enc.last_deadband == pytest.approx(0.25)
    enc.send(2, 2 * T, (1.011,))  # backward difference: 0.001 / 1 ms = 1 unit/s: p = 0.5
    assert enc.last_deadband == pytest.approx(0.5)


# ------------------------------------------------------------------------------------------
# Rate reduction on a synthetic signal


def test_reduction_is_monotone_in_p_on_a_synthetic_haptic_signal() -> None:
    _, vel, force = synthetic_contact_signal(np.random.default_rng(2026), 8000)
    ps = (0.0, 0.025, 0.05, 0.075, 0.1, 0.125, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4)
    for signal in (force, vel):
        red = [reduction_on(signal, DeadbandConfig(deadband=p)) for p in ps]
        assert all(b >= a for a, b in itertools.pairwise(red)), red
        assert red[-1] > red[0] + 0.2, red
    fixed = reduction_on(force, DeadbandConfig(deadband=0.05))
    adaptive = reduction_on(force, DeadbandConfig(deadband=0.05, adaptive_gain=5.0, max_deadband=0.4), vel)
    assert adaptive > fixed


# ------------------------------------------------------------------------------------------
# Bad configuration and arguments


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"deadband": -0.1}, "deadband must be in [0.0, 1.0]"),
        ({"deadband": 1.5}, "deadband must be in [0.0, 1.0]"),
        ({"deadband": math.nan}, "deadband must be finite"),
        ({"min_threshold": -1.0}, "min_threshold must be in"),
        ({"adaptive_gain": -2.0}, "adaptive_gain must be in"),
        ({"reconstruction": "interpolate"}, "reconstruction must be one of hold, extrapolate"),
        ({"extrapolate_from": "guess"}, "extrapolate_from must be one of sent_rate, last_two"),
        ({"max_extrapolation_s": 0.0}, "max_extrapolation_s must be > 0"),
        ({"deadband": 0.3, "adaptive_gain": 1.0, "max_deadband": 0.2}, "max_deadband (0.2) must be >= deadband"),
        ({"deadband": "0.1"}, "deadband must be a number"),
    ],
)
def test_bad_config_raises_a_clear_value_error(kwargs: dict[str, object], words: str) -> None:
    with pytest.raises(ValueError) as err:
        DeadbandConfig(**kwargs)  # type: ignore[arg-type]
    assert words in str(err.value)


def test_bad_arguments_raise_value_error() -> None:
    cfg = DeadbandConfig()
    with pytest.raises(ValueError, match="dim must be >= 1"):
        build_deadband(cfg, 0, T, 0)
    with pytest.raises(ValueError, match="period_ns must be > 0"):
        build_deadband(cfg, 3, 0, 0)
    with pytest.raises(ValueError, match="size_bytes must be >= 0"):
        build_deadband(cfg, 3, T, -1)
    enc, dec = build_deadband(cfg, 3, T, 0)
    with pytest.raises(ValueError, match="sample has 2 values, the stream has 3"):
        enc.send(0, 0, (1.0, 2.0))
    with pytest.raises(ValueError, match="payload has 6 values, expected 3"):
        dec.receive(Packet(seq=0, send_time_ns=0, payload=(0.0,) * 6), 0)


def test_config_builds_from_scene_data() -> None:
    cfg = typedconfig.build(
        DeadbandConfig, {"deadband": 0.05, "reconstruction": "extrapolate", "max_extrapolation_s": None}
    )
    assert cfg.deadband == 0.05 and cfg.sends_rate and cfg.max_extrapolation_s is None
    with pytest.raises(ConfigError, match="deadband"):
        typedconfig.build(DeadbandConfig, {"deadband": 2})
    with pytest.raises(ConfigError, match="contradiction"):
        typedconfig.build(DeadbandConfig, {"deadband": 0.3, "adaptive_gain": 1.0, "max_deadband": 0.1})
    keys = {row[0] for row in typedconfig.describe(DeadbandConfig)}
    assert keys == {f"{k}" for k in DeadbandConfig.__dataclass_fields__}


# ------------------------------------------------------------------------------------------
# The grouped encoder (the engine's and the nodes'): one definition over state arrays


def _grouped(cfg: DeadbandConfig, group: int) -> GroupedDeadbandEncoder:
    # two quantities of `group` values: x (rides along) and v (the trigger and the velocity)
    v = slice(group, 2 * group)
    return GroupedDeadbandEncoder(cfg, 2 * group, 0, (v,), v)


@pytest.mark.parametrize("group", [1, 3])
def test_grouped_encoder_sends_when_its_trigger_group_leaves_the_sphere(group: int) -> None:
    enc = _grouped(DeadbandConfig(deadband=0.1), group)
    x0, v0 = (1.0,) * group, (2.0,) * group
    assert len(enc.send(0, 0, x0 + v0)) == 1  # the first sample always goes
    assert enc.send(1, T, (5.0,) * group + v0) == []  # x is no trigger
    inside = tuple(2.0 * 1.09 for _ in range(group))  # |dv| = 0.09 |v| < p |v|
    assert enc.send(2, 2 * T, x0 + inside) == []
    outside_ = (2.0 * 1.11,) + (2.0,) * (group - 1)  # |dv| = 0.22: past p |v| = 0.2 for one value, not 0.35 for three
    sent = enc.send(3, 3 * T, x0 + outside_)
    assert len(sent) == (1 if 0.22 > 0.1 * 2.0 * math.sqrt(group) else 0)
    assert enc.counters == {"offered": 4, "sent": 1 + len(sent), "filtered": 3 - len(sent)}


def test_grouped_encoder_sends_the_backward_difference_rate() -> None:
    cfg = DeadbandConfig(deadband=0.0, reconstruction="extrapolate", extrapolate_from="sent_rate")
    enc = _grouped(cfg, 1)
    assert enc.send(0, 0, (1.0, 2.0))[0].payload == (1.0, 2.0, 0.0, 0.0)
    assert enc.send(1, 2 * T, (1.5, 2.0 + 1e-6))[0].payload == pytest.approx((1.5, 2.0 + 1e-6, 250.0, 5e-4))


@given(st.lists(st.floats(-5.0, 5.0), min_size=6, max_size=6), st.lists(st.floats(-5.0, 5.0), min_size=6, max_size=6))
@settings(max_examples=200, deadline=None)
def test_grouped_trigger_is_violates_on_each_group(a: list[float], b: list[float]) -> None:
    cfg = DeadbandConfig(deadband=0.1, min_threshold=0.01)
    for group in (1, 3):
        enc = GroupedDeadbandEncoder(cfg, 6, 0, tuple(slice(g, g + group) for g in range(0, 6, group)), slice(0, group))
        enc.send(0, 0, tuple(a))
        expect = any(violates(a[g : g + group], b[g : g + group], 0.1, 0.01) for g in range(0, 6, group))
        assert (len(enc.send(1, T, tuple(b))) == 1) is expect


def test_grouped_encoder_refuses_groups_of_other_sizes() -> None:
    with pytest.raises(ValueError, match="3-value groups"):
        GroupedDeadbandEncoder(DeadbandConfig(), 6, 0, (slice(0, 2),), slice(3, 6))


def test_the_compiled_loops_run_cores_deadband_definition() -> None:
    # the kernels compose core's functions: no copy of the encoder's or decoder's steps
    from haptic_teleop.core import deadband as db
    from haptic_teleop.engine.compiled import codec_deadband as k

    for name in ("encoder_send", "decoder_receive", "decoder_sample"):
        assert getattr(k, name).py_func.__code__ is getattr(db, name).__code__, name
