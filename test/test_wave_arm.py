"""Wave variables on the arm scenes, one port per task axis (core/wave_coupled.py,
docs/stabilizers_arms.md, "Wave variables on arms"): each axis runs the one-axis port of
core/wave.py (the same forces, waves and reference, bit for bit); the waves sent never carry more
than the port's energy allows when the motors' limits cut the force; the samples carry the waves
where the velocities were; what cannot run is refused; and the arm hard cases of
test_hard_cases_arm.py, run with wave variables on both sides (plain, and the slave matched with
the wave filter and drift compensation) and recorded to real bags, keep the two-port passive,
judged from the plant signals (both sides' joints, the damping the simulator really has).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.core.eba_coupled import CoupledEnergyBoundParams
from haptic_teleop.core.wave import WaveParams, wave1
from haptic_teleop.core.wave_coupled import W_ENERGY, W_GOT, CoupledWaveBound
from haptic_teleop.engine.run import record_run
from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.load import find_scene, load_scene

sys.path.insert(0, str(Path(__file__).parent))
import test_hard_cases_arm as ha
from test_stabilizers_arm import Runs, assert_passive, recorded_cases

T = 0.001
B = 20.0
WAVE = ("controllers.master.eba.law=wave", "controllers.slave.eba.law=wave")
MATCHED = (
    *WAVE,
    "controllers.slave.eba.wave_matched=true",
    *(f"controllers.{s}.eba.wave_filter_hz=50" for s in ("master", "slave")),
    "controllers.slave.eba.wave_drift_gain_per_s=5",
)
VARIANTS = {"wave": WAVE, "wave_matched_filtered": MATCHED}
K, C = np.array([300.0, 500.0, 800.0]), np.array([5.0, 10.0, 20.0])

# One tick: the point's position and velocity on each task axis, and (or not) a received wave per axis.
axis_tick = st.tuples(st.floats(-0.05, 0.05), st.floats(-0.5, 0.5), st.one_of(st.none(), st.floats(-5.0, 5.0)))
ticks = st.lists(st.lists(axis_tick, min_size=3, max_size=3), min_size=1, max_size=40)


def _bound(master: bool, wave: WaveParams, e0: float = 0.0) -> CoupledWaveBound:
    params = CoupledEnergyBoundParams(period_s=T, damping_nm_s_per_rad=(0.5, 1.0, 2.0), initial_energy_j=e0)
    return CoupledWaveBound(params, wave, master, K, C)


@settings(max_examples=80, deadline=None)
@given(
    steps=ticks,
    master=st.booleans(),
    matched=st.booleans(),
    filtered=st.booleans(),
    drift=st.floats(0.0, 20.0),
)
def test_each_task_axis_runs_the_one_axis_port_bit_for_bit(
    steps: Any, master: bool, matched: bool, filtered: bool, drift: float
) -> None:
    """With nothing cut (ratio 1), axis k of the arm's ports is `core.wave.wave1` on that axis's
    position, velocity and waves: the same port force, wave sent and reference, bit for bit; the
    ledger is E0 plus the axes' ledgers' changes (summed in another order: to rounding)."""
    wave = WaveParams(B, 50.0 if filtered else None, drift, matched)
    arm = _bound(master, wave, e0=0.3)
    axes = [dict(energy=0.0, held=0.0, last_x=0.0, started=False, xd=0.0, wf=0.0) for _ in range(3)]
    for row in steps:
        got = [w for _, _, w in row]
        if any(w is not None for w in got):
            arm.receive((0.01, -0.02, 0.03, *(0.0 if w is None else w for w in got)))
        x = np.array([p for p, _, _ in row])
        v = np.array([q for _, q, _ in row])
        force = arm.begin(x, v).copy()
        arm.end(1.0)
        fresh = any(w is not None for w in got)
        for i, a in enumerate(axes):
            w_in = (0.0 if got[i] is None else got[i]) if fresh else 0.0
            e, xd, wf, f, fa, sent = wave1(
                master, a["energy"], a["held"], a["last_x"], a["started"], a["xd"], a["wf"], w_in, fresh,
                (0.01, -0.02, 0.03)[i], x[i], v[i], math.inf, T, arm.s, B, K[i], C[i], arm.pole, arm.drift_gain,
                arm.matched,
            )  # fmt: skip
            a.update(energy=e, held=fa, last_x=x[i], started=True, xd=xd, wf=wf)
            assert force[i] == f and arm.sent[i] == sent, i
            if not master:
                assert arm.ws[12 + i] == xd
        assert arm.energy_j == pytest.approx(0.3 + sum(a["energy"] for a in axes), abs=1e-12)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3),
    st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3),
    st.floats(0.0, 1.0),
    st.booleans(),
)
def test_a_cut_force_sends_no_more_wave_energy_than_the_port_received_less_what_it_gave(
    v: list[float], w: list[float], ratio: float, master: bool
) -> None:
    """The motors' limits apply r F on every axis: each axis's wave sent satisfies
    u^2 / 2 <= w^2 / 2 - (power the port gave its device), the channel's consistency (core.wave.consistent1)."""
    arm = _bound(master, WaveParams(B))
    arm.begin(np.zeros(3), np.zeros(3))
    arm.end(1.0)
    arm.receive((0.0, 0.0, 0.0, *w))
    vel = np.array(v)
    force = arm.begin(vel * T, vel).copy()
    arm.end(ratio)
    for i in range(3):
        got = arm.ws[W_GOT + i]
        xd_dot = vel[i] if master else arm.ws[27 + i]
        power = ratio * force[i] * xd_dot
        assert 0.5 * arm.sent[i] ** 2 <= 0.5 * got * got - power + 1e-12 * (1.0 + got * got) or arm.sent[i] == 0.0


def test_each_received_wave_is_used_once() -> None:
    """A tick without a new sample uses no wave (a held wave would release its energy again)."""
    arm = _bound(False, WaveParams(B), e0=0.0)
    arm.begin(np.zeros(3), np.zeros(3))
    arm.end(1.0)
    arm.receive((0.0, 0.0, 0.0, 1.0, 0.0, 0.0))
    arm.begin(np.zeros(3), np.zeros(3))
    arm.end(1.0)
    once = arm.ws[W_ENERGY]
    assert once > 0.0
    arm.begin(np.zeros(3), np.zeros(3))
    assert arm.ws[W_GOT] == 0.0 and arm.ws[W_ENERGY] == once  # no wave in, nothing moved


# --------------------------------------------------------------------------------------------
# The scene: the samples, what cannot run.


def test_the_arm_samples_carry_the_waves_where_the_velocities_were(tmp_path: Path, monkeypatch: Any) -> None:
    from haptic_teleop.assembly.stages import ArmSideStage

    sent: dict[bool, list[tuple[float, ...]]] = {True: [], False: []}
    tick = ArmSideStage.tick

    def spy(self: ArmSideStage, n: int) -> Any:
        p = tick(self, n)
        assert p[:3] == tuple(self.x.tolist()) and p[3:6] == tuple(self.side_tick.bound.sent.tolist())
        sent[self.master].append(p)
        return p

    monkeypatch.setattr(ArmSideStage, "tick", spy)
    scene = load_scene(find_scene("touch_ur5e_wall"), ["scene.duration_s=0.5", *ha.GEOMETRY, *WAVE])
    record_run(scene, tmp_path / "bag", parallel=False, handle_sigint=False, loop="python")
    assert {len(p) for p in sent[True]} == {6} and {len(p) for p in sent[False]} == {9}
    assert max(abs(p[3]) for p in sent[True]) > 0.0  # the master's waves: its motion


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        (("slave.slew_nm_per_s=[100, 100, 100]", *WAVE), "slave.slew_nm_per_s"),
        (
            (
                "slave.backend=dynamixel",
                "slave.hardware.port=/dev/ttyUSB0",
                "slave.start_q_rad=[0, 0, 0]",
                "slave.damping_nm_s_per_rad=[0.1, 0.1, 0.1]",
                *WAVE,
            ),
            "controllers.slave.eba.law",
        ),
        ((*WAVE, "network.forward.codec.kind=deadband"), "network.forward.codec"),
    ],
)
def test_what_wave_variables_on_arms_cannot_run_is_refused_naming_the_key(overrides: tuple[str, ...], key: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_scene(find_scene("touch_dynamixel_wall"), list(overrides))
    assert key in str(err.value) and "allowed" in str(err.value)


# --------------------------------------------------------------------------------------------
# The arm hard cases, from bags.


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Runs:
    return recorded_cases(tmp_path_factory, VARIANTS)


@pytest.mark.parametrize("variant", sorted(VARIANTS))
@pytest.mark.parametrize("name", [c.name for c in ha.CASES])
def test_wave_variables_keep_the_arms_two_port_passive(runs: Any, name: str, variant: str) -> None:
    summary, engine = runs(name, variant)
    assert_passive(summary, engine)
    assert engine.loop_kind == "compiled"
