"""Shared by the compiled loops' identity tests (test_compiled_loop.py, test_compiled_arm.py,
test_compiled_codec.py, test_compiled_arm_codec.py): the sink that notes every call a loop makes
on it, and the codec and loss configurations the codec cases combine."""

from __future__ import annotations

import numpy as np

BERNOULLI = "{probability: 0.2}"
GILBERT = "{model: gilbert_elliott, p: 0.05, r: 0.2, one_minus_h: 0.9, one_minus_k: 0.02}"

HOLD = "{kind: deadband, deadband: 0.1}"
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
