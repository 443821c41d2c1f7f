"""Binary search over the sorted head of a list or an array, as plain loops that numba compiles (the
core rules that search sorted values: core/delay.py's piecewise profile, core/playout_rules.py's
window), with `bisect`'s results."""

from __future__ import annotations

from typing import Any


def bisect_right_in(a: Any, n: int, x: Any) -> int:
    """`bisect.bisect_right` over the first `n` values of the sorted `a` (a list or an array,
    compiled or not): the index after the last value <= x."""
    lo = 0
    hi = n
    while lo < hi:
        mid = (lo + hi) // 2
        if x < a[mid]:
            hi = mid
        else:
            lo = mid + 1
    return lo


def bisect_left_in(a: Any, n: int, x: Any) -> int:
    """`bisect.bisect_left` over the first `n` values of the sorted `a`: the index of the first
    value >= x."""
    lo = 0
    hi = n
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] < x:
            lo = mid + 1
        else:
            hi = mid
    return lo
