"""A direction's playout buffer from the scene: its keys (`BufferConfig`, every policy's, checked
together) and `build_buffer`, which makes the policy it names (core/playout.py,
core/playout_seed.py).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from haptic_teleop.core.playout import (
    GAP_MODES,
    POLICIES,
    RAMJEE_SMOOTHING,
    AdaptiveBuffer,
    FixedBuffer,
    PercentileBuffer,
    PlayOnArrival,
    PlayoutBuffer,
)
from haptic_teleop.core.playout_seed import NetworkAdaptiveBuffer, TransparencyBuffer


@dataclass(frozen=True)
class BufferConfig:
    """One receiving side's sync buffer. Parameters a policy does not use are ignored."""

    policy: str = field(default="none", metadata={"choices": POLICIES, "help": "sync buffer policy"})
    gap: str = field(
        default="hold",
        metadata={
            "choices": GAP_MODES,
            "help": "empty slot: hold the last sample or extrapolate the last two",
        },
    )
    max_extrapolation_s: float = field(
        default=0.05, metadata={"min": 0.0, "max": 10.0, "help": "extrapolate at most this far, then hold"}
    )
    buffering_time_s: float = field(
        default=0.01,
        metadata={"min": 0.0, "max": 10.0, "help": "fixed: buffering above the minimum relative delay"},
    )
    smoothing: float = field(
        default=RAMJEE_SMOOTHING,
        metadata={"gt": 0.0, "lt": 1.0, "help": "adaptive: alpha of the delay estimates"},
    )
    variation_factor: float = field(
        default=4.0, metadata={"min": 0.0, "max": 100.0, "help": "adaptive: beta in D = d + beta v"}
    )
    quantile: float = field(
        default=0.95, metadata={"gt": 0.0, "lt": 1.0, "help": "percentile: fraction of packets in time"}
    )
    window_packets: int = field(
        default=1000,
        metadata={"min": 1, "max": 100_000, "help": "percentile, transparency, network_adaptive: delay window"},
    )
    allowed_force_error_n: float = field(
        default=0.1, metadata={"gt": 0.0, "max": 1e4, "help": "transparency: allowed felt-force distortion"}
    )
    force_slope_n_per_s: float | None = field(
        default=None,
        metadata={
            "min": 0.0,
            "max": 1e9,
            "help": "transparency: contact force slope c*vm (unset: engine passes it)",
        },
    )
    min_one_way_delay_s: float | None = field(
        default=None,
        metadata={
            "min": 0.0,
            "max": 100.0,
            "help": "transparency, network_adaptive: smallest one-way delay d0 (unset: 0 for transparency, "
            "the link's minimum for network_adaptive)",
        },
    )
    allowable_delay_s: float | None = field(
        default=None,
        metadata={
            "min": 0.0,
            "max": 3600.0,
            "help": "network_adaptive: allowable one-way delay D_a (unset: from the scene's transparency analysis)",
        },
    )
    allowable_loss_time_s: float | None = field(
        default=None,
        metadata={
            "min": 0.0,
            "max": 3600.0,
            "help": "network_adaptive: allowable loss time L_a (unset: from the scene's transparency analysis)",
        },
    )
    contact_horizon_s: float = field(
        default=1.0,
        metadata={"gt": 0.0, "max": 3600.0, "help": "transparency: contact length the error builds over"},
    )
    max_slew_rate: float = field(
        default=0.05,
        metadata={"gt": 0.0, "max": 1.0, "help": "adaptive policies: playout delay change, s per s"},
    )
    hysteresis_s: float = field(
        default=0.002,
        metadata={"min": 0.0, "max": 10.0, "help": "adaptive policies: ignore target changes this small"},
    )

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            _check_field(f.name, getattr(self, f.name), f.metadata)
        if self.gap == "extrapolate" and self.max_extrapolation_s == 0.0:
            raise ValueError("gap 'extrapolate' with max_extrapolation_s 0 never extrapolates: use gap 'hold'")
        if self.policy == "percentile" and self.window_packets * (1.0 - self.quantile) < 1.0 - 1e-9:
            need = math.ceil(1.0 / (1.0 - self.quantile) - 1e-9)
            raise ValueError(
                f"window_packets {self.window_packets} cannot resolve quantile {self.quantile} "
                f"(it would be the window maximum): use at least {need} packets"
            )


def _check_field(name: str, value: object, meta: Mapping[str, Any]) -> None:
    """The schema's metadata checks, for configs built in code rather than from YAML."""
    if value is None:
        return
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value}")
        lo, hi, gt, lt = meta.get("min"), meta.get("max"), meta.get("gt"), meta.get("lt")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise ValueError(f"{name} must be in [{lo}, {hi}], got {value}")
        if (gt is not None and not value > gt) or (lt is not None and not value < lt):
            raise ValueError(f"{name} must be > {gt} and < {lt}, got {value}")


def _ns(seconds: float) -> int:
    return round(seconds * 1e9)


def build_buffer(cfg: BufferConfig, period_ns: int) -> PlayoutBuffer:
    """The buffer `cfg` names, for a stream with one sample every `period_ns` (seq = send / period)."""
    if not period_ns > 0:
        raise ValueError(f"period_ns must be > 0, got {period_ns}")
    gap, extra_ns = cfg.gap, _ns(cfg.max_extrapolation_s)
    slew, hyst_ns = cfg.max_slew_rate, _ns(cfg.hysteresis_s)
    if cfg.policy == "none":
        return PlayOnArrival(period_ns, gap, extra_ns)
    if cfg.policy == "fixed":
        return FixedBuffer(period_ns, _ns(cfg.buffering_time_s), gap, extra_ns)
    if cfg.policy == "adaptive":
        return AdaptiveBuffer(
            period_ns,
            smoothing=cfg.smoothing,
            variation_factor=cfg.variation_factor,
            gap=gap,
            max_extrapolation_ns=extra_ns,
            max_slew_rate=slew,
            hysteresis_ns=hyst_ns,
        )
    if cfg.policy == "percentile":
        return PercentileBuffer(
            period_ns,
            quantile=cfg.quantile,
            window_packets=cfg.window_packets,
            gap=gap,
            max_extrapolation_ns=extra_ns,
            max_slew_rate=slew,
            hysteresis_ns=hyst_ns,
        )
    if cfg.policy == "transparency":
        return TransparencyBuffer(
            period_ns,
            allowed_force_error_n=cfg.allowed_force_error_n,
            force_slope_n_per_s=cfg.force_slope_n_per_s,
            min_one_way_delay_ns=_ns(cfg.min_one_way_delay_s or 0.0),
            contact_horizon_ns=_ns(cfg.contact_horizon_s),
            window_packets=cfg.window_packets,
            gap=gap,
            max_extrapolation_ns=extra_ns,
            max_slew_rate=slew,
            hysteresis_ns=hyst_ns,
        )
    if cfg.policy == "network_adaptive":
        return NetworkAdaptiveBuffer(
            period_ns,
            allowable_delay_ns=None if cfg.allowable_delay_s is None else _ns(cfg.allowable_delay_s),
            allowable_loss_time_ns=_ns(cfg.allowable_loss_time_s or 0.0),
            min_one_way_delay_ns=_ns(cfg.min_one_way_delay_s or 0.0),
            window_packets=cfg.window_packets,
            gap=gap,
            max_extrapolation_ns=extra_ns,
            max_slew_rate=slew,
            hysteresis_ns=hyst_ns,
        )
    raise ValueError(f"unknown policy {cfg.policy!r}; allowed: {', '.join(POLICIES)}")
