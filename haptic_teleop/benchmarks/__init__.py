"""`haptic-teleop bench NAME`: benchmarks that print figures (never asserted in tests).

Each module in this package is one benchmark with `add_arguments(parser)` and `main(args) -> int`.
The table below is the only place that lists them, so the CLI needs no change when one is added.
"""

BENCHMARKS = {
    "speed": "haptic_teleop.benchmarks.speed",
    "live": "haptic_teleop.benchmarks.live",
    "effects": "haptic_teleop.benchmarks.effects",
    "network": "haptic_teleop.benchmarks.network",
    "accuracy": "haptic_teleop.benchmarks.accuracy",
    "memory": "haptic_teleop.benchmarks.memory",
    "recording": "haptic_teleop.benchmarks.recording",
}
