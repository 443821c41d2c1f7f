"""The link's rules (loss verdicts, blackout windows, the delay and the arrival's order) and ARQ's
sender rules have one definition in core/: the Python effects call them, and the compiled links
are composed of the same functions, compiled (no kernel spells a rule again)."""

from __future__ import annotations

import types

import numpy as np
import pytest

from haptic_teleop.core import arq, delay, loss
from haptic_teleop.core.link import DELIVERED, LOST_NETWORK, Packet

# (core module, rule, the Python code that calls it)
PYTHON_USES = [
    (loss, "first_fate", loss.Blackout.apply),
    (loss, "blackout_at", loss.Blackout.apply),
    (loss, "bernoulli_lost", loss.BernoulliLoss.apply),
    (loss, "bernoulli_lost", loss.Corrupt.apply),
    (loss, "first_fate", loss.GilbertElliottLoss.apply),
    (loss, "four_state_step", loss.FourStateLoss.apply),
    (loss, "trace_lost", loss.TraceLoss.apply),
    (delay, "delay_value_ns", delay.Delay.apply),
    (delay, "arrival_ns", delay.Delay.apply),
    (arq, "retry_verdict", arq.ArqEncoder.send),
    (arq, "named_mask", arq.cumulative_seqs),
]

# (kernel module's name, rule, the kernel function that calls it)
KERNEL_USES = [
    ("codec_link", "first_fate", "fate_of"),
    ("codec_link", "blackout_at", "fate_of"),
    ("codec_link", "bernoulli_lost", "loss_fate"),
    ("codec_link", "gilbert_step", "loss_fate"),
    ("codec_link", "four_state_step", "chain_or_trace_fate"),
    ("codec_link", "trace_lost", "chain_or_trace_fate"),
    ("codec_link", "delay_value_ns", "jitter_arrival"),
    ("codec_link", "arrival_ns", "jitter_arrival"),
    ("codec_arq", "retry_verdict", "arq_block"),
    ("codec_arq", "named_mask", "arq_feedback"),
]

CORE_OF = {name: module for module, name, _ in PYTHON_USES} | {"gilbert_step": loss}


def _names(f: types.FunctionType) -> tuple[str, ...]:
    return f.__code__.co_names


@pytest.mark.parametrize(
    ("module", "rule", "user"), PYTHON_USES, ids=[f"{r}-{u.__qualname__}" for _, r, u in PYTHON_USES]
)
def test_the_python_effects_call_cores_rule(module: types.ModuleType, rule: str, user: types.FunctionType) -> None:
    assert callable(getattr(module, rule))
    assert rule in _names(user), f"{user.__qualname__} does not call {module.__name__}.{rule}"


@pytest.mark.parametrize(("kernel", "rule", "user"), KERNEL_USES)
def test_the_compiled_links_are_composed_of_cores_rule(kernel: str, rule: str, user: str) -> None:
    import importlib

    m = importlib.import_module(f"haptic_teleop.engine.compiled.{kernel}")
    compiled = getattr(m, rule)
    # the kernel's function is core's own code compiled, not a copy
    assert compiled.py_func.__code__ is getattr(CORE_OF[rule], rule).__code__
    assert rule in getattr(m, user).py_func.__code__.co_names, f"{kernel}.{user} does not call {rule}"


def test_blackout_at_counts_the_windows_begun_and_says_whether_inside() -> None:
    w = np.array([[10, 20], [30, 35]], dtype=np.int64)
    got = []
    i = 0
    for t in (0, 10, 19, 20, 29, 30, 34, 35, 100):
        i, hit = loss.blackout_at(w, i, t)
        got.append((i, bool(hit)))
    assert got == [
        (0, False),
        (1, True),
        (1, True),
        (1, False),
        (1, False),
        (2, True),
        (2, True),
        (2, False),
        (2, False),
    ]


def test_a_blackout_answers_right_when_packet_times_go_back() -> None:
    # the effect keeps `blackout_at`'s row for the last time; a time before it searches again
    b = loss.Blackout([(10, 20), (30, 35)])
    fates = []
    for t in (31, 12, 25, 32, 5):
        p = Packet(0, t, ())
        b.apply(p)
        fates.append(p.fate)
    assert fates == [LOST_NETWORK, LOST_NETWORK, DELIVERED, LOST_NETWORK, DELIVERED]
    assert b.dropped == 3


def test_first_fate_keeps_the_first_effects_verdict() -> None:
    assert loss.first_fate(DELIVERED, True, 3) == 3
    assert loss.first_fate(DELIVERED, False, 3) == DELIVERED
    assert loss.first_fate(2, True, 3) == 2


def test_trace_lost_repeats_or_lets_everything_pass_after_its_end() -> None:
    pattern = [True, False, False]
    assert [loss.trace_lost(pattern, n, True) for n in range(7)] == [True, False, False, True, False, False, True]
    assert [loss.trace_lost(pattern, n, False) for n in range(5)] == [True, False, False, False, False]


def test_arrival_ns_keeps_order_only_for_delivered_packets() -> None:
    assert delay.arrival_ns(100, 50.4, True, True, 200) == (200, 200)  # held behind the last
    assert delay.arrival_ns(100, 50.6, True, False, 200) == (151, 200)  # lost: moves nothing
    assert delay.arrival_ns(100, 50.6, False, True, 200) == (151, 200)
    assert delay.arrival_ns(100, -3.0, True, True, 0) == (100, 100)  # not positive: no delay


def test_retry_verdict_waits_for_mu_then_retries_nu_times() -> None:
    mu, nu = 25, 2
    assert arq.retry_verdict(0, 0, 24, mu, nu) == arq.WAIT
    assert arq.retry_verdict(0, 0, 25, mu, nu) == arq.RETRANSMIT
    assert arq.retry_verdict(2, 0, 25, mu, nu) == arq.GIVE_UP
    assert arq.cumulative_seqs((10.0, float(0b101), 3.0)) == [10, 9, 7, 3]
