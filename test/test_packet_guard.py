"""Bad values in packets: NaN, Inf and absurd magnitudes are rejected, counted, never propagated."""

import math

import numpy as np
import pytest

from haptic_teleop.analysis.metrics import analyze_bag
from haptic_teleop.assembly import parts as assembly_module
from haptic_teleop.core.controller import ControllerParams, RemoteLimits, SampleGuard, TeleopController
from haptic_teleop.core.eba_state import EnergyBoundParams
from haptic_teleop.engine.lockstep import COL, COLUMNS, Engine, remote_limits
from haptic_teleop.engine.run import record_run
from haptic_teleop.scene.load import find_scene, load_scene

T = 0.001
BAD = (math.nan, math.inf, -math.inf, 1e300)
SCENE = load_scene(find_scene("wall_contact"), overrides=["scene.duration_s=2.0"])


def test_guard_rejects_non_finite_and_absurd_values_and_counts_them():
    g = SampleGuard((1.0, 2.0))
    assert g.accept((1.0, -2.0))  # the limits themselves are allowed
    assert g.accept((0.0, 0.0))
    for bad in BAD:
        assert not g.accept((bad, 0.0))
        assert not g.accept((0.0, bad))
    assert not g.accept((1.0000001, 0.0))
    assert not g.accept((0.0,))  # wrong length: a malformed sample
    assert g.rejected == 2 * len(BAD) + 2
    for n in (1, 3, 4):  # the spelled-out 3-value path and the general loop
        g = SampleGuard((1.0,) * n)
        assert g.accept((1.0,) * n)
        for i in range(n):
            for bad in (*BAD, -1.5):
                assert not g.accept(tuple(bad if j == i else 0.0 for j in range(n)))
        assert g.rejected == n * (len(BAD) + 1)
    with pytest.raises(ValueError):
        SampleGuard((1.0, math.inf))
    with pytest.raises(ValueError):
        RemoteLimits(position_m=0.0, velocity_m_per_s=1.0, force_n=1.0)


def test_controller_keeps_its_previous_sample():
    lim = RemoteLimits(position_m=1.0, velocity_m_per_s=1.0, force_n=100.0)
    params = ControllerParams(role="master", stiffness_n_per_m=100.0, damping_n_s_per_m=0.0, remote_limits=lim)
    c = TeleopController(params, EnergyBoundParams(T, (1.0,), enabled=False))
    c.set_remote((-5.0, 0.01, 0.0))  # slave: f_env, x, v
    good = c.desired_force([0.0], [0.0])
    for bad in BAD:
        c.set_remote((bad, 0.01, 0.0))  # a bad force: the whole sample goes
        c.set_remote((-5.0, bad, 0.0))
        c.set_remote((-5.0, 0.01, bad))
    c.set_remote((500.0, 0.01, 0.0))  # beyond the force sensor's range
    assert c.desired_force([0.0], [0.0]) == good
    assert c.rejected_samples == 3 * len(BAD) + 1
    # Per-axis layout: a slave controller of 2 axes checks (x1, x2, v1, v2).
    two = TeleopController(
        ControllerParams(role="slave", remote_limits=lim), EnergyBoundParams(T, (1.0, 1.0), enabled=False)
    )
    assert two.guard is not None and two.guard.limits == (1.0, 1.0, 1.0, 1.0)
    no_guard = TeleopController(ControllerParams(role="slave"), EnergyBoundParams(T, (1.0,)))
    no_guard.set_remote((math.nan, 0.0))
    assert no_guard.rejected_samples == 0


def test_default_limits_come_from_the_scene():
    c = SCENE.config
    lim = remote_limits(c)
    # wall_contact: wall at 0.02 m, the push reaches 0.05 m: workspace floor 0.1 m; speed 0.02 m/s
    # below the 0.1 m/s floor; strongest force limit 50 N (the slave actuator); margin 10.
    assert lim == RemoteLimits(position_m=1.0, velocity_m_per_s=1.0, force_n=500.0)
    fast = load_scene(find_scene("wall_contact"), overrides=["operator.speed_m_per_s=0.5"]).config
    assert remote_limits(fast).velocity_m_per_s == pytest.approx(5.0)


class _Corruptor:
    """Wraps a link's `deliver`: every `every`-th delivered packet gets a bad value in its payload."""

    def __init__(self, link, every: int, offset: int) -> None:
        self._deliver = link.deliver
        self.every = every
        self.offset = offset
        self.corrupted: set[int] = set()
        self._k = 0
        link.deliver = self

    def __call__(self, now_ns: int):
        out = self._deliver(now_ns)
        for p in out:
            self._k += 1
            if self._k % self.every == 0:
                bad = BAD[(self._k // self.every) % len(BAD)]
                i = (self._k // self.every + self.offset) % len(p.payload)
                p.payload = (*p.payload[:i], bad, *p.payload[i + 1 :])
                self.corrupted.add(p.seq)
        return out


def _corrupted_run(guard: bool):
    e = Engine(SCENE, loop="python")  # the injection wraps the Python loop's link objects
    fwd = _Corruptor(e.forward, every=37, offset=0)
    bwd = _Corruptor(e.backward, every=29, offset=1)
    if not guard:
        e.master_ctrl.guard = None
        e.slave_ctrl.guard = None
    r = e.run(handle_sigint=False)
    return e, r.data[: r.ticks], fwd, bwd


def _played(data, column: str, corrupted: set[int]) -> int:
    seqs = data[:, COL[column]]
    return len(corrupted & {int(s) for s in seqs if s >= 0})


def test_injected_bad_values_are_rejected_counted_and_never_reach_the_loop():
    e, d, fwd, bwd = _corrupted_run(guard=True)
    assert len(fwd.corrupted) > 40 and len(bwd.corrupted) > 40  # the test is not vacuous
    # Each corrupted sample the buffer released was rejected once, on the receiving side.
    assert e.slave_ctrl.rejected_samples == _played(d, "fwd_rx_seq", fwd.corrupted) > 0
    assert e.master_ctrl.rejected_samples == _played(d, "bwd_rx_seq", bwd.corrupted) > 0
    assert np.all(np.isfinite(d))  # every column: states, forces, desired forces, reservoirs
    # The absurd samples did not drive the actuators: the forces stay where the clean run has them.
    clean = Engine(SCENE).run(handle_sigint=False)
    for col in ("m_force_n", "s_force_n"):
        assert np.max(np.abs(d[:, COL[col]])) <= 1.5 * np.max(np.abs(clean.column(col))) + 1e-9


def test_without_the_guard_nan_propagates():
    """The same injection with the guard off: NaN reaches the controllers' state (the plants
    still clip a NaN force to 0, so the recorded positions may stay finite)."""
    e, d, _, _ = _corrupted_run(guard=False)
    assert e.slave_ctrl.rejected_samples == e.master_ctrl.rejected_samples == 0
    ctrl_cols = [COL[c] for c in ("m_force_desired_n", "m_energy_j", "s_force_desired_n", "s_energy_j")]
    assert not np.all(np.isfinite(d[:, ctrl_cols]))
    assert len(COLUMNS) == d.shape[1]


def test_rejections_reach_the_bag_and_the_summary(tmp_path, monkeypatch):
    made = {}
    real_build_link = assembly_module.build_scene_link

    def corrupting_build_link(cfg, seed, direction, **kw):
        link = real_build_link(cfg, seed, direction, **kw)
        made[direction] = _Corruptor(link, every=37 if direction == "forward" else 29, offset=0)
        return link

    monkeypatch.setattr(assembly_module, "build_scene_link", corrupting_build_link)  # reaches the Python loop
    engine, _ = record_run(SCENE, tmp_path / "bag", parallel=False, handle_sigint=False, loop="python", keep=True)
    summary, _ = analyze_bag(tmp_path / "bag")
    d = engine.data[: engine.ticks_done]
    assert summary["rejected_samples_forward"] == _played(d, "fwd_rx_seq", made["forward"].corrupted) > 0
    assert summary["rejected_samples_backward"] == _played(d, "bwd_rx_seq", made["backward"].corrupted) > 0
    assert summary["all_finite"]


def test_live_nodes_guard_their_remote_samples_with_the_engines_limits(tmp_path):
    """master_eba and slave_eba build their controllers with the same packet guard as the engine,
    from the parameters the launcher writes; a NaN sample is rejected and counted."""
    rclpy = pytest.importorskip("rclpy")
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.live.launcher import node_plan, write_params_files
    from haptic_teleop.nodes.master_eba import MasterEba
    from haptic_teleop.nodes.slave_eba import SlaveEba
    from haptic_teleop.scene.load import find_scene, load_scene

    sc = load_scene(find_scene("wall_contact"))
    files = write_params_files(node_plan(sc), tmp_path)
    engine = Engine(sc)
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        for cls, name, ref, bad in (
            (MasterEba, "master_eba", engine.master_ctrl, (float("nan"), 0.0, 0.0)),
            (SlaveEba, "slave_eba", engine.slave_ctrl, (0.0, float("inf"))),
        ):
            node = cls(node_name=name, cli_args=["--ros-args", "--params-file", str(files[name])],
                       use_global_arguments=False, context=context)  # fmt: skip
            ctrl = node.side.ctrl
            assert ctrl.guard is not None and ctrl.guard.limits == ref.guard.limits
            ctrl.set_remote(bad)
            assert ctrl.rejected_samples == 1
            assert node.side.diagnostic_values()["rejected_samples"] == 1
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
