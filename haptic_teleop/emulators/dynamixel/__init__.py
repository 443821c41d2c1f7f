"""A Dynamixel Protocol 2.0 bus of X-series servos on a pseudo-terminal (docs/dynamixel.md).

`protocol.py` frames packets (CRC, byte stuffing, the incremental parser, status composers);
`config.py` the bus configuration (`BusConfig`); `servo.py` one servo's control table and its
rules; `physics.py` the joints the servos drive; `bus.py` the instructions, wire timing and faults;
`__main__.py` the process (`python -m haptic_teleop.emulators.dynamixel --config FILE.json`);
`process.py` starts it from Python (`start_bus`).
"""
