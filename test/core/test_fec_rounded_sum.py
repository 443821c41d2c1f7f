"""`fec.rounded_sum` (the compiled loop's parity sums) gives `math.fsum`'s value, bit for bit."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.core.fec import rounded_sum

FINITE = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e300, max_value=1e300)
# sums that cancel and tie: small dyadic values at far-apart scales, and their negatives
DYADIC = st.builds(lambda m, e: m * 2.0**e, st.integers(-16, 16), st.integers(-1074, 900))


def _same(xs: list[float]) -> None:
    arr = np.array([7.0, *xs])  # from index 1: the start offset is used
    partials = np.zeros(len(xs) + 1)
    got = rounded_sum(arr, 1, len(xs), partials)
    want = math.fsum(xs)
    assert got == want and math.copysign(1.0, got) == math.copysign(1.0, want), (xs, got, want)


@settings(max_examples=2000, deadline=None)
@given(st.lists(st.one_of(FINITE, DYADIC), max_size=12))
def test_rounded_sum_is_fsum(xs: list[float]) -> None:
    _same(xs)
    _same([*xs, *(-x for x in xs[::2])])


def test_rounded_sum_rounds_half_way_cases_as_one_rounding() -> None:
    # 1 + 2**-53 is half way between 1 and its successor: a tie to even, unless a smaller term
    # breaks it (the case the plain top-down sum of the partials gets wrong).
    for xs in ([1.0, 2.0**-53], [1.0, 2.0**-53, 2.0**-100], [1.0, 2.0**-53, -(2.0**-100)], [1e16, 1.0, 1e-16]):
        _same(xs)
    assert rounded_sum(np.array([1.0, 2.0**-53, 2.0**-100]), 0, 3, np.zeros(3)) == 1.0 + 2.0**-52
