"""One direction of a link in a scene: its network effects and the playout buffer at its end."""

from __future__ import annotations

from dataclasses import dataclass, field

from haptic_teleop.core.netconfig import NetworkEffectsConfig
from haptic_teleop.core.playout import BufferConfig


@dataclass(frozen=True)
class DirectionConfig:
    effects: NetworkEffectsConfig = field(default_factory=NetworkEffectsConfig)
    buffer: BufferConfig = field(default_factory=BufferConfig)
