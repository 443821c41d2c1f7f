"""The two-condition energy bound (docs/eba_two_condition.md, "The published two-condition law"): a passive port
for any motion and any desired force, judged from the port's signals (positions, applied forces,
the damping); how its allowed forces compare with the reservoir law's; the contact force slope."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.analysis.metrics import port_energy
from haptic_teleop.core.eba import EnergyBound, reservoir1
from haptic_teleop.core.eba_state import EnergyBoundParams
from haptic_teleop.core.eba_two_condition import (
    TwoConditionBound,
    contact_force_slope_n_per_s,
    two_condition_interval1,
)

T = 0.001

# One tick of a drive: a displacement (or None: the worst one for the force just held,
# dx* = F T / (2 b), which drains the port most) and a desired force.
tick = st.tuples(st.one_of(st.none(), st.floats(-1e-2, 1e-2)), st.floats(-500.0, 500.0))


def _drive(bound: TwoConditionBound, damping: float, steps: list[tuple[float | None, float]]) -> tuple:
    """Run the bound over `steps`; returns (positions, applied forces, controller energies)."""
    xs, fs, es = [], [], []
    x, held = 0.0, 0.0
    for dx, fd in steps:
        if xs:
            x += held * T / (2.0 * damping) if dx is None else dx
        held = bound.step1(x, fd)
        xs.append(x)
        fs.append(held)
        es.append(bound.energy_j[0])
    return np.array(xs), np.array(fs), np.array(es)


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(tick, min_size=2, max_size=120),
    damping=st.floats(0.01, 50.0),
    e0=st.floats(0.0, 1.0),
    clip=st.one_of(st.none(), st.floats(0.5, 100.0)),
)
def test_port_never_delivers_more_than_e0(steps, damping, e0, clip):
    """Any displacements (worst-case ones among them), any desired forces, with or without an
    actuator clip: the energy the port delivered, from its positions and applied forces with the
    damping it has, never exceeds E0; the controller energy keeps its reserve T F^2 / (4 b); and
    the port's true margin is at least the controller energy (the ZOH steps only add to it)."""
    p = EnergyBoundParams(
        period_s=T, damping_n_s_per_m=(damping,), initial_energy_j=e0, force_limit_n=clip, law="two_condition"
    )
    xs, fs, es = _drive(TwoConditionBound(p), damping, steps)
    margin = e0 + port_energy(xs, fs, damping, T)
    tol = 1e-9 * max(1.0, e0)
    assert margin.min() >= -tol
    assert np.all(es >= T * fs * fs / (4.0 * damping) - tol)
    assert np.all(margin >= es - tol)
    if clip is not None:
        assert np.max(np.abs(fs)) <= clip


def test_without_the_bound_the_same_drive_delivers_energy():
    """The check above can fail: the law switched off (its ledger still kept) pushes along the motion."""
    p = EnergyBoundParams(period_s=T, damping_n_s_per_m=(1.0,), enabled=False, law="two_condition")
    steps = [(1e-4, 5.0)] * 100
    xs, fs, _ = _drive(TwoConditionBound(p), 1.0, steps)
    assert port_energy(xs, fs, 1.0, T).min() < -0.04
    on = TwoConditionBound(EnergyBoundParams(period_s=T, damping_n_s_per_m=(1.0,), law="two_condition"))
    xs, fs, _ = _drive(on, 1.0, steps)
    assert port_energy(xs, fs, 1.0, T).min() >= 0.0


def _reservoir_energy(xs: np.ndarray, fs: np.ndarray, damping: float, e0: float) -> float:
    """The reservoir law's E after the history (xs, fs), from `reservoir1`."""
    e = e0
    for k in range(1, xs.size):
        e = reservoir1(e, damping / T, fs[k - 1], xs[k] - xs[k - 1])
    return e


@settings(max_examples=40, deadline=None)
@given(steps=st.lists(tick, min_size=2, max_size=60), damping=st.floats(0.05, 20.0), e0=st.floats(0.0, 0.5))
def test_two_condition_forces_are_within_the_reservoir_bound_of_the_same_history(steps, damping, e0):
    """docs/eba_two_condition.md: after any history, every force the two-condition law allows is one the
    reservoir law allows after the same history (the reservoir is the controller energy plus the
    ZOH steps' unused damping credit, and the reservoir's bound is the largest passive one)."""
    p = EnergyBoundParams(period_s=T, damping_n_s_per_m=(damping,), initial_energy_j=e0, law="two_condition")
    bound = TwoConditionBound(p)
    xs, fs, _ = _drive(bound, damping, steps[:-1])
    # The next tick: its displacement, then the ends of what the law allows (what it returns for
    # a desired force far beyond either end; rounding can leave the interval empty by a few ulps,
    # and then the law returns the ZOH edge).
    dx = steps[-1][0]
    if dx is None:
        dx = fs[-1] * T / (2.0 * damping)
    ends = []
    for far in (-1e12, 1e12):
        trial = copy.deepcopy(bound)
        ends.append(trial.step1(xs[-1] + dx, far))
    energy = _reservoir_energy(np.append(xs, xs[-1] + dx), np.append(fs, 0.0), damping, e0)
    assert ends[0] <= ends[1]
    # Within the reservoir's bound, T F^2 / (4 b) <= E, up to the rounding of the two ledgers' sums.
    for f in ends:
        assert T * f * f / (4.0 * damping) <= energy + 1e-11


# The state of the counterexamples (docs/eba_two_condition.md): b = 1 N s/m, T = 1 ms, E0 = 2 mJ; at tick 0 both
# laws hold f = 2 N; the device then moves dx = 0.5 mm along that force.
B, E0, F0, DX = 1.0, 2e-3, 2.0, 5e-4


def _both_after_one_step(desired: float) -> tuple[float, float]:
    """The force each law holds at tick 1 for `desired`: (reservoir, two_condition)."""
    out = []
    for law in ("reservoir", "two_condition"):
        p = EnergyBoundParams(period_s=T, damping_n_s_per_m=(B,), initial_energy_j=E0, law=law)
        bound = EnergyBound(p) if law == "reservoir" else TwoConditionBound(p)
        assert bound.step1(0.0, F0) == F0
        out.append(bound.step1(DX, desired))
    return out[0], out[1]


def test_the_reservoir_law_allows_a_force_the_two_condition_law_refuses():
    """Releasing the force: the reservoir law lets it drop to 0; the ZOH condition refuses any
    drop beyond (2b/T) dx = 1 N in one step along the motion, so the two-condition law holds 1 N."""
    reservoir, two = _both_after_one_step(0.0)
    assert reservoir == 0.0
    assert two == pytest.approx(F0 - 2.0 * B / T * DX)  # 1 N: the ZOH condition's edge
    # Their allowed sets: the reservoir's is +-sqrt(4 b E / T) with E = E0 + (b/T) dx^2 - f dx.
    e = E0 + B / T * DX * DX - F0 * DX
    lo, hi = two_condition_interval1(E0, B / T, 4 * B / T, F0, DX, math.inf)  # E_c(0) = E0: no motion yet
    assert lo == pytest.approx(1.0) and hi == pytest.approx(2.0)
    assert -math.sqrt(4 * B * e / T) < lo


def test_the_published_conditions_without_the_reserve_allow_a_force_the_reservoir_refuses():
    """The two conditions as usually stated (E_c >= 0, no reserve) allow, with no motion yet, any
    force: 3 N here, above the reservoir law's sqrt(4 b E0 / T) = 2.83 N. Held, one step of the
    worst motion dx = F T / (2 b) makes the port deliver F^2 T / (4 b) = 2.25 mJ > E0 (from the
    port's signals), and on that step the two conditions have no common solution."""
    lo, hi = two_condition_interval1(E0, B / T, 4 * B / T, 0.0, 0.0, math.inf, reserve=False)
    assert lo <= 3.0 <= hi
    assert 3.0 > math.sqrt(4 * B * E0 / T)  # the reservoir law refuses it
    reserved = two_condition_interval1(E0, B / T, 4 * B / T, 0.0, 0.0, math.inf)
    assert not reserved[0] <= 3.0 <= reserved[1]  # so does the law as implemented (the reserve)
    dx = 3.0 * T / (2 * B)
    delivered = -port_energy(np.array([0.0, dx]), np.array([3.0, 0.0]), B, T)[-1]
    assert delivered == pytest.approx(2.25e-3) and delivered > E0
    # The next tick: E_c(0) = E0; no force meets both conditions any more.
    lo, hi = two_condition_interval1(E0, B / T, 4 * B / T, 3.0, dx, math.inf, reserve=False)
    assert lo > hi


def test_a_search_finds_both_counterexamples():
    """Random states (seeded): the search finds states where the reservoir law allows a force
    the two-condition law refuses, and where the conditions without the reserve allow a force
    the reservoir law refuses; it finds none where the law as implemented allows one the
    reservoir law refuses (the containment above)."""
    rng = np.random.default_rng(14)
    found_reservoir_only = found_unreserved_only = found_reserved_only = 0
    for _ in range(2000):
        b = 10 ** rng.uniform(-1, 1)
        k = 4 * b / T
        e_c = rng.uniform(0, 0.01)
        f = rng.uniform(-1, 1) * math.sqrt(k * e_c)  # a held force within the reserve
        dx = rng.uniform(-3, 3) * abs(f) * T / (2 * b) + rng.normal(0, 1e-5)
        # Same history for both: the reservoir holds E_c plus a ZOH credit of 0 or more.
        e_r = reservoir1(e_c + rng.uniform(0, 1e-3) * rng.integers(0, 2), b / T, f, dx)
        lim = math.sqrt(k * max(e_r, 0.0))
        lo, hi = two_condition_interval1(e_c, b / T, k, f, dx, math.inf)
        ulo, uhi = two_condition_interval1(e_c, b / T, k, f, dx, math.inf, reserve=False)
        probe = rng.uniform(-2, 2) * max(lim, abs(f), 1e-6)
        in_res = abs(probe) <= lim
        if in_res and not lo <= probe <= hi:
            found_reservoir_only += 1
        if ulo <= probe <= uhi and not in_res:
            found_unreserved_only += 1
        if lo <= probe <= hi and abs(probe) > lim * (1 + 1e-9) + 1e-12:
            found_reserved_only += 1
    assert found_reservoir_only > 0
    assert found_unreserved_only > 0
    assert found_reserved_only == 0


@pytest.mark.parametrize("c1", [1000.0, 8000.0])
def test_contact_force_slope_matches_each_law(c1):
    """A device pushed at v into a spring c1 (the far end fixed), b = 2, T = 1 ms (2b/T = 4000 N/m):
    the two-condition law's force rises at min(c1, 2b/T) v from the first tick; the reservoir law's
    at c1 v while its stored energy lasts, then at min(c1, 2b/T) v once the bound binds."""
    b, v = 2.0, 0.01
    xs = [v * T * i for i in range(3000)]
    slopes = {}
    for law, e0 in (("two_condition", 1.0), ("reservoir", 0.2)):
        p = EnergyBoundParams(period_s=T, damping_n_s_per_m=(b,), initial_energy_j=e0, law=law)
        bound = EnergyBound(p) if law == "reservoir" else TwoConditionBound(p)
        f = np.array([bound.step1(x, -c1 * x) for x in xs])
        slopes[law] = (-(f[300] - f[100]) / (200 * T), -(f[2900] - f[2700]) / (200 * T))
    two = contact_force_slope_n_per_s("two_condition", c1, b, T, v)
    assert slopes["two_condition"][0] == pytest.approx(two, rel=1e-6)
    assert slopes["two_condition"][1] == pytest.approx(two, rel=1e-6)
    early = contact_force_slope_n_per_s("reservoir", c1, b, T, v, bound_binding=False)
    late = contact_force_slope_n_per_s("reservoir", c1, b, T, v)
    assert slopes["reservoir"][0] == pytest.approx(early, rel=1e-6)
    assert slopes["reservoir"][1] == pytest.approx(late, rel=1e-6)
    assert late == two == pytest.approx(min(c1, 2 * b / T) * v)


def test_params_refuse_an_unknown_law_and_a_slew_limit():
    with pytest.raises(ValueError, match="reservoir, two_condition"):
        EnergyBoundParams(period_s=T, damping_n_s_per_m=(1.0,), law="pooled")
    with pytest.raises(ValueError, match="slew"):
        EnergyBoundParams(period_s=T, damping_n_s_per_m=(1.0,), slew_rate_n_per_s=100.0, law="two_condition")
    with pytest.raises(ValueError, match="reservoir, two_condition"):
        contact_force_slope_n_per_s("pooled", 1.0, 1.0, T, 1.0)
