"""One direction of a link in a scene: its network effects and the playout buffer at its end, and
(teleoperation's channels only: `ChannelDirectionConfig`) the codec stage in front of the link."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from haptic_teleop.core.arq import KIND as ARQ_KIND
from haptic_teleop.core.arq import ArqConfig
from haptic_teleop.core.deadband import KIND as DEADBAND_KIND
from haptic_teleop.core.deadband import DeadbandConfig
from haptic_teleop.core.fec import KIND as FEC_KIND
from haptic_teleop.core.fec import FecConfig
from haptic_teleop.core.hli_codec import KIND as HLI_KIND
from haptic_teleop.core.hli_codec import HliConfig
from haptic_teleop.core.netconfig import NetworkEffectsConfig
from haptic_teleop.core.playout_config import BufferConfig
from haptic_teleop.core.prediction import KIND as PREDICTION_KIND
from haptic_teleop.core.prediction import PredictionConfig


@dataclass(frozen=True)
class DirectionConfig:
    effects: NetworkEffectsConfig = field(default_factory=NetworkEffectsConfig)
    buffer: BufferConfig = field(default_factory=BufferConfig)


# Each codec's config class by its scene name (`codec: {kind: ...}`; docs/codec.md).
CODEC_CONFIGS: dict[str, type] = {
    DEADBAND_KIND: DeadbandConfig,
    HLI_KIND: HliConfig,
    PREDICTION_KIND: PredictionConfig,
    FEC_KIND: FecConfig,
    ARQ_KIND: ArqConfig,
}
CODEC_KINDS = tuple(CODEC_CONFIGS)
# The HLI codec's Gilbert parameters come from the direction's `effects.loss`, never from the codec.
_HLI_FROM_LOSS = ("p", "r", "one_minus_h", "one_minus_k")


def codec_keys(kind: str) -> tuple[str, ...]:
    """The scene keys of codec `kind` besides `kind`."""
    return tuple(f.name for f in dataclasses.fields(CODEC_CONFIGS[kind]) if f.name not in _HLI_FROM_LOSS)


_N = {"help": "see the codec's section of docs/codec.md"}


@dataclass(frozen=True)
class CodecConfig:
    """`network.<direction>.codec`: `kind` and that codec's own keys (the union of every codec's
    keys is declared here so a scene's YAML can be read field by field; a key of another codec is
    refused, and the values are checked by the codec's own config class, `settings()`)."""

    kind: str = field(metadata={"choices": CODEC_KINDS, "help": "which codec (docs/codec.md)"})
    # deadband
    deadband: float | None = field(default=None, metadata=_N)
    min_threshold: float | None = field(default=None, metadata=_N)
    adaptive_gain: float | None = field(default=None, metadata=_N)
    max_deadband: float | None = field(default=None, metadata=_N)
    reconstruction: str | None = field(default=None, metadata=_N)
    extrapolate_from: str | None = field(default=None, metadata=_N)
    # deadband, prediction, fec, arq
    max_extrapolation_s: float | None = field(default=None, metadata=_N)
    # prediction, fec, arq
    gap: str | None = field(default=None, metadata=_N)
    # fec
    scheme: str | None = field(default=None, metadata=_N)
    k: int | None = field(default=None, metadata=_N)
    # fec, arq
    wait_ticks: int | None = field(default=None, metadata=_N)
    # arq
    timeout_s: float | None = field(default=None, metadata=_N)
    max_retransmissions: int | None = field(default=None, metadata=_N)
    ack_every_ticks: int | None = field(default=None, metadata=_N)
    # hli
    threshold_m: float | None = field(default=None, metadata=_N)
    predictor: str | None = field(default=None, metadata=_N)
    alpha: float | None = field(default=None, metadata=_N)
    clock: str | None = field(default=None, metadata=_N)
    filtering: str | None = field(default=None, metadata=_N)
    allowed_bandwidth_bps: float | None = field(default=None, metadata=_N)
    p_allowable: float | None = field(default=None, metadata=_N)
    rate_window_s: float | None = field(default=None, metadata=_N)
    max_n_hli1: int | None = field(default=None, metadata=_N)

    def __post_init__(self) -> None:
        if self.kind not in CODEC_CONFIGS:
            raise ValueError(f"codec kind must be one of {', '.join(CODEC_KINDS)}, got {self.kind!r}")
        own = codec_keys(self.kind)
        stray = [f.name for f in dataclasses.fields(self) if f.name != "kind" and f.name not in own]
        stray = [k for k in stray if getattr(self, k) is not None]
        if stray:
            raise ValueError(f"codec {self.kind!r} has no key {', '.join(stray)} (its keys: {', '.join(own)})")
        self.settings()  # the codec's own checks (ranges, choices, contradictions), as one line

    def given(self) -> dict[str, Any]:
        """The keys the scene gave (besides kind)."""
        return {k: getattr(self, k) for k in codec_keys(self.kind) if getattr(self, k) is not None}

    def settings(self, **extra: Any) -> Any:
        """The codec's own config object (`extra`: the HLI codec's Gilbert parameters)."""
        try:
            return CODEC_CONFIGS[self.kind](**self.given(), **extra)
        except TypeError as exc:  # a value of the wrong type reaching a codec's own checks
            raise ValueError(f"codec {self.kind}: {exc}") from None


@dataclass(frozen=True)
class ChannelDirectionConfig(DirectionConfig):
    """A teleoperation channel's direction: `DirectionConfig` and the optional codec stage
    (absent: no codec, the channel as before; docs/codec_channels.md)."""

    codec: CodecConfig | None = None

    def __post_init__(self) -> None:
        c = self.codec
        if c is None:
            return
        b = self.buffer
        if b.policy != "none" or b.gap != "hold":
            raise ValueError(
                f"codec {c.kind} needs buffer.policy none with gap hold (the decoder takes the link's "
                f"arrivals itself and does its own reconstruction), got policy {b.policy} with gap {b.gap}"
            )
        if c.kind == HLI_KIND:
            loss = self.effects.loss
            if loss is None or loss.model not in ("gilbert", "gilbert_elliott"):
                got = "none" if loss is None else loss.model
                raise ValueError(
                    f"codec hli needs this direction's effects.loss to be a gilbert or gilbert_elliott model "
                    f"(N_HLI1 comes from its p and r), got loss model {got}"
                )
            c.settings(**hli_gilbert(self))


def hli_gilbert(d: ChannelDirectionConfig) -> dict[str, float]:
    """The HLI codec's Gilbert parameters from the direction's loss model."""
    loss = d.effects.loss
    assert loss is not None
    p, r, h, k = loss.gilbert_elliott_parameters()
    return {"p": p, "r": r, "one_minus_h": h, "one_minus_k": k}
