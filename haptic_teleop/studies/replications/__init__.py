"""The seeds' experiments, each a module with its arguments, its runs and its outputs
(`haptic-teleop experiment NAME`, cli/experiment.py)."""
