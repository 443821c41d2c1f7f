"""Errors raised by haptic_teleop; each names what was wrong and what is allowed."""


class HapticTeleopError(Exception):
    """Base class of every error this package raises on purpose."""


class ConfigError(HapticTeleopError):
    """A scene file or override is invalid (unknown key, wrong type, out of range, contradiction)."""

    def __init__(self, source: str, key_path: str, value: object, allowed: str) -> None:
        self.source = source
        self.key_path = key_path
        self.value = value
        self.allowed = allowed
        where = key_path or "<top level>"
        if isinstance(value, dict):  # a whole section (a contradiction between its keys): the message names them
            super().__init__(f"{source}: {where}: {allowed}")
            return
        shown = repr(value)
        if len(shown) > 80:
            shown = shown[:77] + "..."
        super().__init__(f"{source}: {where} = {shown}: {allowed}")


class BagError(HapticTeleopError):
    """A bag is missing, unreadable or lacks the topics an analysis needs."""


class PlantError(HapticTeleopError):
    """A plant backend failed or replied with something outside its protocol."""
