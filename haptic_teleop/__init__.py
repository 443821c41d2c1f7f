"""Bilateral haptic teleoperation over imperfect networks."""

__version__ = "0.1.0"
