"""Offline analysis: reads bags only, never the engine."""
