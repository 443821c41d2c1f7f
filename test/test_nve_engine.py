"""The NVE scene end to end in the engine (engine/nve_loop.py): the force against the model's
exact delay property and the continuous solution, the measured round trip, the compensation as
applied, the number of clients, reproducibility, and scene errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from haptic_teleop.core.nve_transparency import NveModel, mass_based_spring_n_per_m
from haptic_teleop.engine.nve_loop import NveEngine
from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.load import find_scene, load_scene

NONE = "nve.clients.0.compensation={scheme: none}"


def _run(scene: str = "nve_push", *overrides: str, seconds: float = 6.0) -> tuple[NveEngine, np.ndarray]:
    s = load_scene(find_scene(scene), overrides=[f"scene.duration_s={seconds}", *overrides])
    e = NveEngine(s)
    e.run(handle_sigint=False)
    assert e.data is not None
    return e, e.data


def _cols(e: NveEngine, k: int = 0) -> dict[str, int]:
    """The first column of client k's groups (the run's NveSchema)."""
    name = e.schema.clients[k]
    groups = {
        "hip_x": "hip_x_m",
        "obj_x": "obj_x_m",
        "force": "force_n",
        "spring": "spring_n_per_m",
        "rtt": "rtt_s",
        "up_rx": "up_rx_seq",
        "down_rx": "down_rx_seq",
    }
    return {key: e.schema.client_group(name, g).start for key, g in groups.items()}


def _delays(one_way_s: float, k: int = 0) -> list[str]:
    return [f"nve.clients.{k}.{d}.effects.delay.delay_s={one_way_s}" for d in ("up", "down")]


def test_delay_adds_kh_v_r_and_shifts_the_undelayed_force_by_r() -> None:
    """While pushing at v, the model gives F_R(t) = k_h v R + F_0(t - R) exactly (docs/nve_scenes.md):
    the delayed run against the undelayed one, tick by tick."""
    _, d0 = _run("nve_push", NONE, *_delays(0.0))
    e3, d3 = _run("nve_push", NONE, *_delays(0.15))
    c = _cols(e3)
    f0, f3 = d0[:, c["force"]], d3[:, c["force"]]
    lag = 300  # ticks of R
    t = np.arange(len(f3)) * e3.period_s
    push = (t > 0.5 + 0.3 + 0.01) & (t < 6.0)
    pred = 0.5 * 0.1 * 0.3 + f0[np.nonzero(push)[0] - lag]
    assert np.max(np.abs(f3[push] - pred)) < 1e-12
    assert np.max(np.abs(f3[push] - f0[push])) > 1e-3  # the delay does change the force


def test_undelayed_force_matches_the_continuous_solution() -> None:
    """No network delay: the force is k_h times the continuous spring stretch of a pushed
    mass-damper, up to the loop's own one period (k_h v T)."""
    e, d = _run("nve_push", NONE, *_delays(0.0))
    c = _cols(e)
    m, b, ke, kh, v = 0.25, 0.0025, 0.5, 0.5, 0.1
    t = np.arange(len(d)) * e.period_s
    tau = t - 0.5
    wn = math.sqrt(ke / m)
    z = b / (2 * math.sqrt(ke * m))
    wd = wn * math.sqrt(1 - z * z)
    ess = b * v / ke
    a0, b0 = -ess, (v - z * wn * ess) / wd
    stretch = np.where(tau > 0, ess + np.exp(-z * wn * tau) * (a0 * np.cos(wd * tau) + b0 * np.sin(wd * tau)), 0.0)
    err = np.abs(d[:, c["force"]] - kh * stretch)
    assert np.max(err) <= kh * v * e.period_s * 1.05
    assert np.max(np.abs(kh * stretch)) > 100 * kh * v * e.period_s  # the force is not tiny


@pytest.mark.parametrize(("up", "down"), [(0.0, 0.0), (0.05, 0.1), (0.15, 0.15)])
def test_the_measured_round_trip_is_the_two_delays_plus_one_period(up: float, down: float) -> None:
    e, d = _run(
        "nve_push",
        NONE,
        f"nve.clients.0.up.effects.delay.delay_s={up}",
        f"nve.clients.0.down.effects.delay.delay_s={down}",
        seconds=1.0,
    )
    rtt = d[:, _cols(e)["rtt"]]
    got = rtt[~np.isnan(rtt)]
    assert got.size and np.allclose(got, up + down + e.period_s, atol=1e-9)
    first = int(np.argmax(~np.isnan(rtt)))
    assert first * e.period_s == pytest.approx(up + down + e.period_s, abs=1.5e-3)


def test_jitter_round_trip_is_the_age_of_the_hip_the_client_sees() -> None:
    """With jitter the measured R is t minus the send time of the HIP sample the seen object state
    reflects: read back from the recorded tick columns of the released samples."""
    e, d = _run(
        "nve_push",
        NONE,
        "nve.clients.0.up.effects.delay={delay_s: 0.05, jitter_s: 0.01}",
        "nve.clients.0.down.effects.delay={delay_s: 0.05, jitter_s: 0.01}",
        seconds=2.0,
    )
    c = _cols(e)
    rtt = d[:, c["rtt"]]
    released = d[:, c["down_rx"]]
    ok = released >= 0
    assert np.any(ok)
    # the released object sample was sent at tick s; it reflects the HIP the server had released at
    # tick s - 1, which was sent at the up-rx tick recorded for s - 1
    s = released[ok].astype(int)
    hip_sent = d[s - 1, c["up_rx"]]
    good = hip_sent >= 0
    n = np.nonzero(ok)[0][good]
    assert np.allclose(rtt[n], (n - hip_sent[good]) * e.period_s, atol=1e-9)
    assert np.std(rtt[n]) > 1e-3  # the jitter shows


def test_the_transparency_scheme_sets_the_spring_the_formula_gives() -> None:
    e, d = _run("nve_push", seconds=1.0)
    c = _cols(e)
    rtt, spring = d[:, c["rtt"]], d[:, c["spring"]]
    model = NveModel(0.25, 0.0025, 0.5, 0.5)
    r = rtt[-1]
    assert spring[-1] == pytest.approx(0.5 - (mass_based_spring_n_per_m(model, r) - 0.5))
    assert np.all(spring[np.isnan(rtt)] == 0.5)  # before the first measurement: k_h
    # within the allowable delay (0.195 s for m_allowable 0.26) nothing changes
    e2, d2 = _run("nve_push", *_delays(0.05), seconds=1.0)
    assert np.all(d2[:, _cols(e2)["spring"]] == 0.5)


def test_an_observer_client_changes_nothing_for_the_pushing_one(tmp_path: Path) -> None:
    """The number of clients does not change a client's transparency: an added observer (k_e = 0)
    over any link leaves the first client's every column bit for bit."""
    base = find_scene("nve_push").read_text()
    added = base + (
        "    - name: watcher\n"
        "      operator: {profile: sinusoid, amplitude_m: 0.2, frequency_hz: 1.0}\n"
        "      coupling: {server_stiffness_n_per_m: 0.0}\n"
        "      up: {effects: {delay: {delay_s: 0.4}, loss: {probability: 0.3}}}\n"
    )
    p = tmp_path / "two.yaml"
    p.write_text(added)
    e1, d1 = _run("nve_push", seconds=3.0)
    e2, d2 = _run(str(p), seconds=3.0)
    w = 5 * 1 + 6
    assert e2.schema.width == e1.schema.width + w
    assert np.array_equal(d1, d2[:, : e1.schema.width], equal_nan=True)


def test_a_holding_partners_delay_does_not_change_the_pushers_force() -> None:
    """A partner holding its HIP still is a spring to ground for the object; once its first sample
    is in, its round trip changes nothing the pusher feels."""
    _, d1 = _run("nve_two_clients", "nve.clients.1.up.effects.delay.delay_s=0.15", seconds=3.0)
    e2, d2 = _run("nve_two_clients", "nve.clients.1.up.effects.delay.delay_s=0.35", seconds=3.0)
    c = _cols(e2, 0)
    a = e2.parts.axes
    t = np.arange(len(d1)) * e2.period_s
    after = t > 0.4  # the partner's first sample has reached the server in both runs
    f1 = d1[after, c["force"] : c["force"] + a]
    f2 = d2[after, c["force"] : c["force"] + a]
    assert np.array_equal(f1, f2)
    far = _cols(e2, 1)
    assert not np.array_equal(d1[:, far["rtt"]], d2[:, far["rtt"]], equal_nan=True)


def test_same_scene_and_seed_same_rows_another_seed_other_losses() -> None:
    _, a = _run("nve_two_clients", seconds=2.0)
    _, b = _run("nve_two_clients", seconds=2.0)
    _, c = _run("nve_two_clients", "scene.seed=2", seconds=2.0)
    assert np.array_equal(a, b, equal_nan=True)
    assert not np.array_equal(a, c, equal_nan=True)


def test_three_axes_push_along_a_direction() -> None:
    e, d = _run("nve_two_clients", seconds=4.0)
    c = _cols(e, 0)
    hip = d[:, c["hip_x"] : c["hip_x"] + 3]
    assert hip[-1, 0] > 0.1 and np.all(hip[:, 1:] == 0.0)
    assert np.all(np.isfinite(d[:, :9]))
    assert d[-1, 0] > 0.01  # the object moved along +x


@pytest.mark.parametrize(
    ("override", "needle"),
    [
        ("nve.axes=2", "nve.axes"),
        ("nve.object.mass_kg=0", "mass_kg"),
        ("nve.clients.0.name=1bad", "name"),
        ("nve.clients.3.name=x", "index 0..0"),
        ("nve.clients.0.compensation={scheme: fujimoto04}", "reduction_n_per_m_per_s"),
        ("nve.clients.0.compensation={scheme: none, allowable_mass_kg: 1}", "not used by scheme"),
        ("nve.object.start_position_m=[0, 0]", "start_position_m"),
        ("nve.clients.0.compensation={scheme: transparency, rule: damping, allowable_damping_n_s_per_m: 1}"
         " ", "transparency"),
    ],
)  # fmt: skip
def test_bad_nve_keys_name_what_is_wrong(override: str, needle: str) -> None:
    if "rule: damping" in override:
        override = override.strip()
        overrides = [override, "nve.object.damping_n_s_per_m=0"]
        needle = "damping"
    else:
        overrides = [override]
    with pytest.raises(ConfigError) as exc:
        load_scene(find_scene("nve_push"), overrides=overrides)
    assert needle in str(exc.value)


def test_an_nve_scene_names_no_teleoperation_section(tmp_path: Path) -> None:
    p = tmp_path / "mixed.yaml"
    p.write_text(find_scene("nve_push").read_text() + "master: {mass_kg: 1.0}\n")
    with pytest.raises(ConfigError, match="an NVE scene"):
        load_scene(p)
