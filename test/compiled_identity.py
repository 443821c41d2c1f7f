"""Shared by the compiled loops' identity tests (test_compiled_loop.py, test_compiled_arm.py,
test_compiled_codec.py, test_compiled_arm_codec.py): the sink that notes every call a loop makes
on it, the codec and loss configurations the codec cases combine, and the comparisons of two
runs."""

from __future__ import annotations

from typing import Any

import numpy as np

from haptic_teleop.record.streams import BLOCK_TICKS

BERNOULLI = "{probability: 0.2}"
GILBERT = "{model: gilbert_elliott, p: 0.05, r: 0.2, one_minus_h: 0.9, one_minus_k: 0.02}"
CORRELATED = "{probability: 0.3, correlation: 0.3}"  # netem-correlated Bernoulli loss (the default model): 17 %
FOUR_STATE = "{model: four_state, p13: 0.05, p31: 0.5, p32: 0.3, p23: 0.4, p14: 0.02}"  # netem's GI model
# loss correlated by a Gaussian copula, which a compiled codec link refuses (netem's it runs)
COPULA_LOSS = ("loss={probability: 0.1, correlation: 0.5}", "correlation_model=gaussian_copula")

HOLD = "{kind: deadband, deadband: 0.1}"
# jitter correlated by a Gaussian copula, which a deadband's compiled link refuses (netem's it runs)
COPULA_JITTER = ("delay={delay_s: 0.05, jitter_s: 0.002, correlation: 0.5}", "correlation_model=gaussian_copula")
SENT_RATE = "{kind: deadband, deadband: 0.1, reconstruction: extrapolate, max_extrapolation_s: 0.08}"
LAST_TWO = "{kind: deadband, deadband: 0.05, reconstruction: extrapolate, extrapolate_from: last_two}"
ADAPTIVE = "{kind: deadband, deadband: 0.05, adaptive_gain: 20, max_deadband: 0.3}"
FLOOR = "{kind: deadband, deadband: 0.1, min_threshold: 0.01}"
PREDICTION = "{kind: prediction, max_extrapolation_s: 0.02}"
PREDICTION_HOLD = "{kind: prediction, gap: hold}"


class Calls:
    """A sink that notes every call the engine makes on it, with a copy of its array."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, np.ndarray]] = []

    def append(self, rows: np.ndarray) -> None:
        self.calls.append(("rows", np.array(rows)))

    def append_packets(self, direction: str, rows: np.ndarray) -> None:
        self.calls.append((direction, np.array(rows)))

    def packets(self, direction: str) -> np.ndarray:
        """Every packet record of `direction`, in the order handed over."""
        return np.concatenate([a for kind, a in self.calls if kind == direction])

    def data(self) -> np.ndarray:
        """Every row of columns, in the order handed over."""
        return np.concatenate([a for kind, a in self.calls if kind == "rows"])


def assert_same_calls(compiled: list[tuple[str, np.ndarray]], python: list[tuple[str, np.ndarray]]) -> None:
    """Both loops made the same calls on their sinks (`Calls.calls`), with the same arrays (NaN
    equal to NaN; a difference names the call's kind and the columns that differ), and no block
    of rows is longer than BLOCK_TICKS."""
    assert [k for k, _ in compiled] == [k for k, _ in python]
    for (kind, c), (_, p) in zip(compiled, python, strict=True):
        assert np.array_equal(c, p, equal_nan=True), (kind, np.flatnonzero(np.any(c != p, axis=0)))
    assert all(len(a) <= BLOCK_TICKS for k, a in compiled if k == "rows")


def assert_same_arm_sides(compiled: Any, python: Any) -> None:
    """Both arm loops left both sides in the same state: motor-limit and guard counts, the energy
    bound's reservoir, held torques, last q and scale (with TDPA its ledger too), the plants' MuJoCo
    state and wall wrench."""
    assert compiled.joint_limit_ticks == python.joint_limit_ticks
    for role in ("master", "slave"):
        a, b = getattr(compiled.arm, role), getattr(python.arm, role)
        assert a.rejected_samples == b.rejected_samples
        assert a.bound.energy_j == b.bound.energy_j
        assert np.array_equal(a.bound.held, b.bound.held)
        sa, sb = a.bound.state(), b.bound.state()
        assert np.array_equal(sa.last_q_rad, sb.last_q_rad)
        assert (sa.has_last, sa.scale) == (sb.has_last, sb.scale)
        assert sa.extra == sb.extra  # TDPA's ledger (core/tdpa_coupled.TDPA_EXTRA); () for EBA
        assert np.array_equal(a.plant.data.qpos, b.plant.data.qpos)
        assert np.array_equal(a.plant.data.qvel, b.plant.data.qvel)
        assert np.array_equal(np.concatenate(a.plant.contact_wrench()), np.concatenate(b.plant.contact_wrench()))
