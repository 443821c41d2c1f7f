"""Dynamixel X-series servos spoken to through Protocol 2.0 (docs/dynamixel.md).

`tables.py` holds the facts (control tables per servo model, units, register codes, protocol
codes) as plain data, with the SI <-> register unit conversions; it imports no SDK, so both the
host-side driver (over `dynamixel_sdk`) and the bus emulator (`haptic_teleop.emulators.dynamixel`)
share one source of every address and unit.
"""
