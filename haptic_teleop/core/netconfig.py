"""The network effects of one direction as config (YAML sections, see haptic_teleop/typedconfig.py for
the conventions), and `build_link`: a `Link` with exactly the effects a config names.

Core reads no files: a trace's rows come in `LinkTraces`, read by the scene layer
(`haptic_teleop/scene/traces.py`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from haptic_teleop.core.delay import ConstantDelay, Delay, PiecewiseDelay, SinusoidDelay, TokenBucket
from haptic_teleop.core.link import CANONICAL_ORDER, DEFAULT_OVERHEAD_BYTES, Duplicate, Effect, Link
from haptic_teleop.core.loss import BernoulliLoss, Blackout, Corrupt, FourStateLoss, GilbertElliottLoss, TraceLoss
from haptic_teleop.core.uniform import CORRELATION_MODELS, DISTRIBUTIONS, effect_rng, jitter_table

_P = {"min": 0.0, "max": 1.0}
_CORR = {"min": 0.0, "lt": 1.0, "help": "netem correlation with the previous draw, as a fraction (25% = 0.25)"}


@dataclass(frozen=True)
class BlackoutConfig:
    starts_s: tuple[float, ...] = field(metadata={"min": 0.0, "help": "start of each link-down window"})
    ends_s: tuple[float, ...] = field(metadata={"min": 0.0, "help": "end of each window (exclusive)"})

    def __post_init__(self) -> None:
        if not self.starts_s or len(self.starts_s) != len(self.ends_s):
            raise ValueError(
                f"starts_s and ends_s need the same number of entries (at least one), "
                f"got {len(self.starts_s)} and {len(self.ends_s)}"
            )
        prev_end = None
        for a, b in zip(self.starts_s, self.ends_s, strict=True):
            if b <= a:
                raise ValueError(f"window [{a}, {b}) s ends before it starts")
            if prev_end is not None and a < prev_end:
                raise ValueError(f"windows must be in time order without overlap: {a} s starts before {prev_end} s")
            prev_end = b


@dataclass(frozen=True)
class RateLimitConfig:
    rate_bps: float = field(metadata={"min": 1.0, "max": 1e12, "help": "token rate in bits per second, wire bytes"})
    burst_bytes: int = field(
        default=1500, metadata={"min": 1, "max": 1 << 30, "help": "bucket depth; must hold the largest packet"}
    )
    queue_limit_packets: int = field(
        default=1000,
        metadata={"min": 0, "max": 1 << 24, "help": "packets that may wait for tokens; more are dropped; 0 polices"},
    )
    overhead_bytes: int = field(
        default=DEFAULT_OVERHEAD_BYTES,
        metadata={
            "min": 0,
            "max": 65535,
            "help": "bytes per packet besides the message: IPv4 20+UDP 8+RTPS 20+DATA 24",
        },
    )

    def __post_init__(self) -> None:
        if self.burst_bytes < self.overhead_bytes + 1:
            raise ValueError(
                f"burst_bytes ({self.burst_bytes}) must exceed overhead_bytes ({self.overhead_bytes}): "
                "no packet would ever fit in the bucket"
            )


def _ge_stats(p: float, r: float, loss_bad: float, loss_good: float) -> tuple[float, float]:
    """(stationary loss rate, mean loss-burst length) of netem's Gilbert-Elliott chain."""
    if p == 0.0:
        return loss_good, (1.0 / (1.0 - loss_good) if loss_good < 1.0 else math.inf)  # stays good
    pi_bad = p / (p + r)
    pi_good = r / (p + r)
    rate = pi_good * loss_good + pi_bad * loss_bad
    # A burst starts at packet n when packet n-1 was delivered and packet n is lost.
    starts = pi_good * (1 - loss_good) * ((1 - p) * loss_good + p * loss_bad) + pi_bad * (1 - loss_bad) * (
        r * loss_good + (1 - r) * loss_bad
    )
    return rate, (rate / starts if starts > 0.0 else math.inf)


def _four_state_stats(p13: float, p31: float, p32: float, p23: float, p14: float) -> tuple[float, float]:
    """(stationary loss rate, mean loss-burst length) of netem's 4-state chain."""
    if p13 == 0.0:
        w = (1.0, 0.0, 0.0, p14)
    else:
        w = (1.0, p13 * p32 / (p31 * p23) if p32 > 0.0 else 0.0, p13 / p31, p14)
    total = sum(w)
    pi1, pi2, pi3, pi4 = (x / total for x in w)
    starts = pi1 * (p13 + p14) + pi2 * p23
    rate = pi3 + pi4
    return rate, (rate / starts if starts > 0.0 else math.inf)


LOSS_MODELS = ("bernoulli", "gilbert", "gilbert_elliott", "four_state", "trace")
# Which keys each model uses (besides `model`); a key of another model is a contradiction.
_LOSS_KEYS = {
    "bernoulli": ("probability", "correlation"),
    "gilbert": ("p", "r", "one_minus_h"),
    "gilbert_elliott": ("p", "r", "one_minus_h", "one_minus_k"),
    "four_state": ("p13", "p31", "p32", "p23", "p14"),
    "trace": ("file", "repeat"),
}
_LOSS_REQUIRED = {
    "bernoulli": ("probability",),
    "gilbert": ("p", "r"),
    "gilbert_elliott": ("p", "r"),
    "four_state": ("p13",),
    "trace": ("file",),
}


@dataclass(frozen=True)
class LossConfig:
    """One loss model, with netem's parameters (`loss random`, `gemodel`, `state`) or a trace."""

    model: str = field(default="bernoulli", metadata={"choices": LOSS_MODELS, "help": "which loss model"})
    probability: float | None = field(default=None, metadata={**_P, "help": "bernoulli: loss probability"})
    correlation: float | None = field(default=None, metadata={**_CORR, "help": "bernoulli: netem correlation"})
    p: float | None = field(default=None, metadata={**_P, "help": "gilbert(_elliott): P(good -> bad) per packet"})
    r: float | None = field(default=None, metadata={**_P, "help": "gilbert(_elliott): P(bad -> good) per packet"})
    one_minus_h: float | None = field(
        default=None, metadata={**_P, "help": "gilbert(_elliott): loss probability in bad state (netem 1-h, default 1)"}
    )
    one_minus_k: float | None = field(
        default=None, metadata={**_P, "help": "gilbert_elliott: loss probability in good state (netem 1-k, default 0)"}
    )
    p13: float | None = field(default=None, metadata={**_P, "help": "four_state: gap -> burst loss"})
    p31: float | None = field(default=None, metadata={**_P, "help": "four_state: burst loss -> gap (default 1-p13)"})
    p32: float | None = field(default=None, metadata={**_P, "help": "four_state: burst loss -> burst rx (default 0)"})
    p23: float | None = field(default=None, metadata={**_P, "help": "four_state: burst rx -> burst loss (default 1)"})
    p14: float | None = field(default=None, metadata={**_P, "help": "four_state: gap -> isolated loss (default 0)"})
    file: str | None = field(default=None, metadata={"help": "trace: CSV of 0/1 per packet (1 = lost)"})
    repeat: bool | None = field(default=None, metadata={"help": "trace: start over at the end (default true)"})

    def __post_init__(self) -> None:
        m = self.model
        if m not in _LOSS_KEYS:  # build() checks choices; direct construction too
            raise ValueError(f"model must be one of {', '.join(LOSS_MODELS)}, got {m!r}")
        stray = [k for ks in _LOSS_KEYS.values() for k in ks if k not in _LOSS_KEYS[m] and getattr(self, k) is not None]
        if stray:
            raise ValueError(
                f"{', '.join(dict.fromkeys(stray))} not used by loss model {m!r} (uses {', '.join(_LOSS_KEYS[m])})"
            )
        missing = [k for k in _LOSS_REQUIRED[m] if getattr(self, k) is None]
        if missing:
            raise ValueError(f"loss model {m!r} needs {', '.join(missing)}")
        if m in ("gilbert", "gilbert_elliott"):
            assert self.p is not None and self.r is not None
            if self.p > 0.0 and self.r == 0.0:
                raise ValueError(
                    "r = 0 with p > 0 makes the bad state absorbing: every packet after the first burst is lost"
                )
        if m == "four_state":
            if self.p31 is None and any(getattr(self, k) is not None for k in ("p32", "p23", "p14")):
                raise ValueError("give p31 too: its default 1 - p13 (netem's) only applies when p13 is given alone")
            p13, p31, p32, p23, p14 = self.four_state_parameters()
            if p13 + p14 > 1.0:
                raise ValueError(f"p13 + p14 = {p13 + p14} exceeds 1 (both leave state 1)")
            if p31 + p32 > 1.0:
                raise ValueError(f"p31 + p32 = {p31 + p32} exceeds 1 (both leave state 3)")
            if p13 > 0.0 and p31 == 0.0:
                raise ValueError("p31 = 0 with p13 > 0 never ends a burst: every packet after the first burst is lost")
            if p13 > 0.0 and p32 > 0.0 and p23 == 0.0:
                raise ValueError("p23 = 0 with p32 > 0 makes state 2 absorbing: losses stop after the first burst")

    def gilbert_elliott_parameters(self) -> tuple[float, float, float, float]:
        """(p, r, 1-h, 1-k) with netem's defaults filled in (gilbert: 1-k = 0)."""
        assert self.p is not None and self.r is not None
        h = 1.0 if self.one_minus_h is None else self.one_minus_h
        k = 0.0 if self.one_minus_k is None else self.one_minus_k
        return self.p, self.r, h, k

    def four_state_parameters(self) -> tuple[float, float, float, float, float]:
        """(p13, p31, p32, p23, p14) with netem's defaults (p13 alone is Bernoulli)."""
        assert self.p13 is not None
        p13 = self.p13
        p31 = 1.0 - p13 if self.p31 is None else self.p31
        p32 = 0.0 if self.p32 is None else self.p32
        p23 = 1.0 if self.p23 is None else self.p23
        p14 = 0.0 if self.p14 is None else self.p14
        return p13, p31, p32, p23, p14

    def expected_loss_rate(self) -> float:
        """Long-run fraction of packets lost (NaN for a trace; for correlated bernoulli exact only
        with the gaussian_copula correlation model). See docs/network_effects.md for the derivations."""
        m = self.model
        if m == "bernoulli":
            assert self.probability is not None
            return self.probability
        if m in ("gilbert", "gilbert_elliott"):
            return _ge_stats(*self.gilbert_elliott_parameters())[0]
        if m == "four_state":
            return _four_state_stats(*self.four_state_parameters())[0]
        return math.nan

    def expected_mean_burst_packets(self) -> float:
        """Mean length of a run of consecutive lost packets (1/r for simple Gilbert)."""
        m = self.model
        if m == "bernoulli":
            assert self.probability is not None
            return 1.0 / (1.0 - self.probability) if self.probability < 1.0 else math.inf
        if m in ("gilbert", "gilbert_elliott"):
            return _ge_stats(*self.gilbert_elliott_parameters())[1]
        if m == "four_state":
            return _four_state_stats(*self.four_state_parameters())[1]
        return math.nan


@dataclass(frozen=True)
class DuplicateConfig:
    probability: float = field(metadata={**_P, "help": "probability a delivered packet gets a copy"})
    correlation: float = field(default=0.0, metadata=_CORR)


@dataclass(frozen=True)
class CorruptConfig:
    probability: float = field(metadata={**_P, "help": "probability of a bit error (the receiver discards it)"})
    correlation: float = field(default=0.0, metadata=_CORR)


@dataclass(frozen=True)
class DelayScheduleConfig:
    times_s: tuple[float, ...] = field(metadata={"min": 0.0, "help": "points in time, strictly increasing"})
    delays_s: tuple[float, ...] = field(metadata={"min": 0.0, "max": 3600.0, "help": "extra delay at each point"})
    interpolation: str = field(default="linear", metadata={"choices": ("linear", "step"), "help": "ramps or steps"})

    def __post_init__(self) -> None:
        if not self.times_s or len(self.times_s) != len(self.delays_s):
            raise ValueError(
                f"times_s and delays_s need the same number of entries (at least one), "
                f"got {len(self.times_s)} and {len(self.delays_s)}"
            )
        for a, b in itertools.pairwise(self.times_s):
            if b <= a:
                raise ValueError(f"times_s must increase strictly: {b} after {a}")


@dataclass(frozen=True)
class DelaySinusoidConfig:
    min_delay_s: float = field(metadata={"min": 0.0, "max": 3600.0, "help": "lowest extra delay (at t = -phase_s)"})
    max_delay_s: float = field(metadata={"min": 0.0, "max": 3600.0, "help": "highest extra delay"})
    period_s: float = field(metadata={"gt": 0.0, "max": 1e6, "help": "one full cycle, min -> max -> min"})
    phase_s: float = field(default=0.0, metadata={"min": 0.0, "max": 1e6, "help": "time shift of the cycle"})

    def __post_init__(self) -> None:
        if self.max_delay_s < self.min_delay_s:
            raise ValueError(f"max_delay_s ({self.max_delay_s}) is below min_delay_s ({self.min_delay_s})")


@dataclass(frozen=True)
class DelayTraceConfig:
    file: str = field(metadata={"help": "CSV time_s,delay_s (extra delay); relative to the scene folder"})
    interpolation: str = field(
        default="linear", metadata={"choices": ("linear", "step"), "help": "between rows: ramps or steps"}
    )


@dataclass(frozen=True)
class DelayConfig:
    delay_s: float = field(default=0.0, metadata={"min": 0.0, "max": 3600.0, "help": "constant one-way delay"})
    jitter_s: float = field(
        default=0.0, metadata={"min": 0.0, "max": 3600.0, "help": "netem jitter (sigma for normal, half-width uniform)"}
    )
    distribution: str = field(default="normal", metadata={"choices": DISTRIBUTIONS, "help": "jitter shape"})
    correlation: float = field(default=0.0, metadata=_CORR)
    schedule: DelayScheduleConfig | None = None
    sinusoid: DelaySinusoidConfig | None = None
    trace: DelayTraceConfig | None = None
    keep_order: bool = field(default=False, metadata={"help": "no overtaking (netem with rate or a pfifo child)"})

    def __post_init__(self) -> None:
        named = [k for k in ("schedule", "sinusoid", "trace") if getattr(self, k) is not None]
        if len(named) > 1:
            raise ValueError(f"name at most one time-varying delay (schedule, sinusoid, trace), got {', '.join(named)}")

    @property
    def is_zero(self) -> bool:
        """True when every packet gets no delay at all."""
        if self.delay_s > 0.0 or self.jitter_s > 0.0 or self.trace is not None:
            return False
        if self.schedule is not None:
            return not any(d > 0.0 for d in self.schedule.delays_s)
        if self.sinusoid is not None:
            return self.sinusoid.max_delay_s == 0.0
        return True


@dataclass(frozen=True)
class ReorderConfig:
    probability: float = field(metadata={**_P, "help": "fraction of eligible packets sent at once, skipping the delay"})
    correlation: float = field(default=0.0, metadata=_CORR)
    gap_packets: int = field(
        default=1,
        metadata={"min": 1, "max": 1 << 20, "help": "netem gap: packets delayed after each reordered one + 1"},
    )


@dataclass(frozen=True)
class NetworkEffectsConfig:
    """Effects of one direction; absent (None) effects are not built. Applied in CANONICAL_ORDER."""

    blackout: BlackoutConfig | None = None
    rate_limit: RateLimitConfig | None = None
    loss: LossConfig | None = None
    duplicate: DuplicateConfig | None = None
    corrupt: CorruptConfig | None = None
    delay: DelayConfig | None = None
    reorder: ReorderConfig | None = None
    correlation_model: str = field(
        default="netem",
        metadata={
            "choices": CORRELATION_MODELS,
            "help": "netem: (1-rho) fresh + rho last (shrinks the spread); gaussian_copula keeps the marginal",
        },
    )

    def __post_init__(self) -> None:
        if self.reorder is not None and (self.delay is None or self.delay.is_zero):
            raise ValueError(
                "reorder needs a delay: it sends some packets at once while the others keep the delay "
                "(netem refuses reorder without a delay too)"
            )


def min_one_way_delay_s(cfg: NetworkEffectsConfig | None) -> float:
    """The smallest one-way delay the link `cfg` can give a packet, s: what the engine knows about
    the link and a playout buffer cannot observe without synchronized clocks (a live node estimates
    it as half the minimum round trip). The constant delay plus the time-varying part's minimum plus
    the jitter distribution's lowest value (netem's tables are finite: normal -3.67 sigma, pareto
    -0.67, paretonormal -1.42; uniform -jitter_s), clamped at 0; 0 with `reorder` (reordered packets
    skip the delay) and for a trace (its rows are not known here). Queues (rate_limit, keep_order)
    only add delay."""
    if cfg is None or cfg.delay is None:
        return 0.0
    if cfg.reorder is not None:
        return 0.0
    d = cfg.delay
    lo = d.delay_s
    if d.schedule is not None:
        lo += min(d.schedule.delays_s)
    elif d.sinusoid is not None:
        lo += d.sinusoid.min_delay_s
    elif d.trace is not None:
        return 0.0
    if d.jitter_s > 0.0:
        lo += d.jitter_s * (-1.0 if d.distribution == "uniform" else min(jitter_table(d.distribution)))
    return max(0.0, lo)


def canonical_order(cfg: NetworkEffectsConfig | None = None) -> tuple[str, ...]:
    """Names of the effects `cfg` configures, in the order a packet meets them (all if None)."""
    if cfg is None:
        return CANONICAL_ORDER
    return tuple(name for name in CANONICAL_ORDER if getattr(cfg, name) is not None)


@dataclass(frozen=True)
class LinkTraces:
    """The rows of the trace files a link's config names, read by the scene layer
    (`haptic_teleop.scene.traces.link_traces`): `delay` = (time_s, delay_s) arrays, `loss` = one bool
    per packet (True = lost)."""

    delay: tuple[np.ndarray, np.ndarray] | None = None
    loss: np.ndarray | None = None


def _build_loss(cfg: LossConfig, rng: np.random.Generator, model: str, pattern: np.ndarray | None) -> Effect:
    m = cfg.model
    if m == "bernoulli":
        assert cfg.probability is not None
        return BernoulliLoss(cfg.probability, rng, cfg.correlation or 0.0, model)
    if m in ("gilbert", "gilbert_elliott"):
        return GilbertElliottLoss(*cfg.gilbert_elliott_parameters(), rng)
    if m == "four_state":
        return FourStateLoss(*cfg.four_state_parameters(), rng=rng)
    if pattern is None:
        raise ValueError(f"loss trace {cfg.file}: its rows were not given (LinkTraces.loss); core reads no files")
    return TraceLoss(pattern, cfg.repeat is not False)


def build_link(
    cfg: NetworkEffectsConfig,
    seed: int,
    direction: str,
    *,
    traces: LinkTraces | None = None,
) -> Link:
    """A `Link` with exactly the effects `cfg` names, in CANONICAL_ORDER, each on its own stream.

    A trace the config names (`delay.trace`, loss model `trace`) comes as its rows in `traces`;
    `haptic_teleop.scene.traces.build_scene_link` reads the files and calls this."""
    traces = traces if traces is not None else LinkTraces()

    def rng(name: str) -> np.random.Generator:
        return effect_rng(seed, direction, name)

    model = cfg.correlation_model
    effects: list[Effect] = []
    if cfg.blackout is not None:
        b = cfg.blackout
        effects.append(Blackout([(round(a * 1e9), round(e * 1e9)) for a, e in zip(b.starts_s, b.ends_s, strict=True)]))
    if cfg.rate_limit is not None:
        r = cfg.rate_limit
        effects.append(TokenBucket(r.rate_bps, r.burst_bytes, r.queue_limit_packets, r.overhead_bytes))
    if cfg.loss is not None:
        effects.append(_build_loss(cfg.loss, rng("loss"), model, traces.loss))
    if cfg.duplicate is not None:
        d = cfg.duplicate
        effects.append(Duplicate(d.probability, rng("duplicate"), d.correlation, model))
    if cfg.corrupt is not None:
        c = cfg.corrupt
        effects.append(Corrupt(c.probability, rng("corrupt"), c.correlation, model, copy_rng=rng("corrupt:copy")))
    if cfg.delay is not None:
        effects.append(_build_delay(cfg.delay, cfg.reorder, rng, model, traces.delay))
    return Link(effects)


def _build_delay(
    cfg: DelayConfig,
    reorder: ReorderConfig | None,
    rng: Callable[[str], np.random.Generator],
    model: str,
    trace: tuple[np.ndarray, np.ndarray] | None,
) -> Effect:
    profile: Callable[[int], float] | None = None
    if cfg.schedule is not None:
        s = cfg.schedule
        profile = PiecewiseDelay(s.times_s, s.delays_s, s.interpolation)
    elif cfg.sinusoid is not None:
        w = cfg.sinusoid
        profile = SinusoidDelay(w.min_delay_s, w.max_delay_s, w.period_s, w.phase_s)
    elif cfg.trace is not None:
        if trace is None:
            raise ValueError(
                f"delay trace {cfg.trace.file}: its rows were not given (LinkTraces.delay); core reads no files"
            )
        ts, ds = trace
        profile = PiecewiseDelay(ts.tolist(), ds.tolist(), cfg.trace.interpolation)
    if profile is None and cfg.jitter_s == 0.0 and reorder is None:
        return ConstantDelay(cfg.delay_s)  # order is kept by construction
    return Delay(
        cfg.delay_s,
        jitter_s=cfg.jitter_s,
        distribution=cfg.distribution,
        rng=rng("delay"),
        correlation=cfg.correlation,
        correlation_model=model,
        profile=profile,
        keep_order=cfg.keep_order,
        reorder_probability=reorder.probability if reorder else 0.0,
        reorder_correlation=reorder.correlation if reorder else 0.0,
        reorder_gap_packets=reorder.gap_packets if reorder else 1,
        reorder_rng=rng("reorder") if reorder else None,
        copy_rng=rng("delay:copy"),
    )
