"""Errors raised by haptic_teleop; each names what was wrong and what is allowed.

`exit_code` is what the command line exits with: 2 for input the user can fix (a scene, a flag,
a path, a bag given to read), 1 for a failure while working (a plant, writing a bag).
"""


class HapticTeleopError(Exception):
    """Base class of every error this package raises on purpose."""

    exit_code = 1


class ConfigError(HapticTeleopError):
    """A scene file or override is invalid (unknown key, wrong type, out of range, contradiction)."""

    exit_code = 2

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


class InputError(HapticTeleopError):
    """A path given on the command line cannot be used (an --out that is a file, not writable, not empty)."""

    exit_code = 2


class BagError(HapticTeleopError):
    """A bag is missing, unreadable or lacks the topics an analysis needs."""

    exit_code = 2


class PlantError(HapticTeleopError):
    """A plant backend failed or replied with something outside its protocol."""
