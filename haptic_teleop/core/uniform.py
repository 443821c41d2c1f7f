"""Seeded random streams of the network effects: one generator per effect, uniform numbers
drawn in blocks (optionally correlated), and the jitter quantile tables of netem's shapes.

Each effect draws from its own `numpy.random.Generator`, derived from the scene seed, the
direction and the effect's name (`effect_rng`), so adding one effect never changes another's
draws (docs/network_effects.md, "Correlation" and "Jitter").
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable
from functools import cache
from statistics import NormalDist
from typing import Any

import numpy as np

DISTRIBUTIONS = ("uniform", "normal", "pareto", "paretonormal")
CORRELATION_MODELS = ("netem", "gaussian_copula")

_BLOCK = 4096  # random numbers drawn per numpy call
_TABLE_SIZE = 4096  # entries of a jitter quantile table, as netem's tables
_TABLE_MIN = -32768 / 8192  # netem stores table values as int16 scaled by NETEM_DIST_SCALE=8192
_TABLE_MAX = 32767 / 8192


def effect_rng(seed: int, direction: str, effect: str) -> np.random.Generator:
    """An independent random stream for one effect of one direction of one run."""
    key = (zlib.crc32(direction.encode()), zlib.crc32(effect.encode()))
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


# --------------------------------------------------------------------------------------------
# Random sources: numbers are drawn from numpy in blocks and handed out one at a time, because a
# numpy call per packet costs about a microsecond.


class UniformSource:
    """Uniform numbers in [0, 1) from `rng`, drawn in blocks. Call `next()` for one."""

    __slots__ = ("_it", "_rng")

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._it: Callable[[], float] = iter(()).__next__

    def next(self) -> float:
        try:
            return self._it()
        except StopIteration:
            self._it = iter(self._rng.random(_BLOCK).tolist()).__next__
            return self._it()

    def take_rest(self) -> list[float]:
        """The numbers left of the block drawn last, taken (so the next ones come from the
        Generator): for a reader that goes on drawing the stream from `rng` itself (the compiled
        codec links' jitter and correlated loss)."""
        rest: list[float] = list(iter(self._it, None))  # (the bound __next__ raises StopIteration at the end)
        self._it = iter(()).__next__
        return rest

    def take(self, n: int) -> np.ndarray:
        """The next `n` numbers, exactly as `n` calls of `next()` would give them: the rest of the
        block drawn last, then from the Generator (`rng.random(k)` continues one stream whatever
        the block sizes). A later `next()` goes on after them (a window's draws at once:
        `Delay.apply_all`)."""
        rest = self.take_rest()
        if n <= len(rest):
            self._it = iter(rest[n:]).__next__
            return np.array(rest[:n], dtype=np.float64)
        return np.concatenate((np.array(rest, dtype=np.float64), self._rng.random(n - len(rest))))


def netem_next(fresh: float, rho: float, last: float) -> float:
    """netem's correlated random number from a fresh uniform and the last one it gave:
    (1 - rho) fresh + rho last. One definition: `NetemCorrelatedUniform` and the compiled links
    (engine/compiled/codec_link.py: jitter, Bernoulli loss)."""
    return (1.0 - rho) * fresh + rho * last


def unit_jitter(u: float, table: Any, n: int) -> float:
    """A unit jitter value from a uniform u in [0, 1): 2 u - 1 without a table (n = 0: netem's
    uniform), else the table's cell int(u n) (`jitter_table`). One definition: `jitter_quantile`
    and the compiled links."""
    return 2.0 * u - 1.0 if n == 0 else table[int(u * n)]  # type: ignore[no-any-return]


class NetemCorrelatedUniform:
    """netem's correlated random: u_n = (1 - rho) v_n + rho u_(n-1), v_n fresh uniform.

    The mean stays 1/2 but the variance shrinks to (1 - rho) / (1 + rho) of a uniform's, so the
    marginal is no longer uniform (docs/network_effects.md, "Correlation")."""

    __slots__ = ("_fresh", "_last", "_rho")

    def __init__(self, rng: np.random.Generator, rho: float) -> None:
        self._fresh = UniformSource(rng).next
        self._rho = rho
        self._last = self._fresh()  # netem seeds `last` with a fresh random number

    def next(self) -> float:
        u = netem_next(self._fresh(), self._rho, self._last)
        self._last = u
        return u


class GaussianCopulaUniform:
    """Correlated uniforms with an exactly uniform marginal: u_n = Phi(z_n) for a stationary
    Gaussian AR(1) z_n = rho z_(n-1) + sqrt(1 - rho^2) e_n."""

    __slots__ = ("_it", "_rho", "_rng", "_s", "_z")

    def __init__(self, rng: np.random.Generator, rho: float) -> None:
        self._rng = rng
        self._it = iter(()).__next__
        self._rho = rho
        self._s = math.sqrt(1.0 - rho * rho)
        self._z = self._normal()

    def _normal(self) -> float:
        try:
            return self._it()
        except StopIteration:
            self._it = iter(self._rng.standard_normal(_BLOCK).tolist()).__next__
            return self._it()

    def next(self) -> float:
        z = self._rho * self._z + self._s * self._normal()
        self._z = z
        u = 0.5 * math.erfc(-z * 0.7071067811865476)
        return u if u < 1.0 else 0.9999999999999999


def uniform_source(rng: np.random.Generator, correlation: float = 0.0, model: str = "netem") -> Callable[[], float]:
    """A function returning the next uniform number of an (optionally correlated) stream."""
    if not 0.0 <= correlation < 1.0:
        raise ValueError(f"correlation must be in [0, 1), got {correlation}")
    if model not in CORRELATION_MODELS:
        raise ValueError(f"correlation model must be one of {', '.join(CORRELATION_MODELS)}, got {model!r}")
    if correlation == 0.0:
        return UniformSource(rng).next
    if model == "netem":
        return NetemCorrelatedUniform(rng, correlation).next
    return GaussianCopulaUniform(rng, correlation).next


# --------------------------------------------------------------------------------------------
# Jitter distributions: quantile tables of netem's shapes (docs/network_effects.md, "Jitter").


def _pareto_quantile(q: float) -> float:
    # netem's pareto table: Pareto(shape 3, scale 1) X = (1 - q)^(-1/3), mean 1.5, shifted to
    # mean 0 and scaled by 4/3.
    x: float = (1.0 - q) ** (-1.0 / 3.0)
    return (x - 1.5) * (4.0 / 3.0)


@cache
def jitter_table(distribution: str) -> tuple[float, ...]:
    """The 4096 quantiles (at cell midpoints) of a unit jitter distribution, clipped to netem's
    int16 table range [-4, 32767/8192]. Delay = base + jitter_s * table[int(u * 4096)]."""
    if distribution not in ("normal", "pareto", "paretonormal"):
        raise ValueError(f"no table for distribution {distribution!r}")
    inv = NormalDist().inv_cdf
    out = []
    for j in range(_TABLE_SIZE):
        q = (j + 0.5) / _TABLE_SIZE
        if distribution == "normal":
            v = inv(q)
        elif distribution == "pareto":
            v = _pareto_quantile(q)
        else:
            # netem pairs the normal and pareto quantiles of the same q (a comonotone mix).
            v = (inv(q) + 3.0 * _pareto_quantile(q)) / 4.0
        out.append(min(max(v, _TABLE_MIN), _TABLE_MAX))
    return tuple(out)


def jitter_quantile(distribution: str) -> Callable[[float], float]:
    """Map a uniform u in [0, 1) to a unit jitter value of `distribution`."""
    if distribution == "uniform":  # netem without a table: uniform on [-jitter, +jitter)
        return lambda u: unit_jitter(u, (), 0)
    table = jitter_table(distribution)
    n = len(table)
    return lambda u: unit_jitter(u, table, n)
