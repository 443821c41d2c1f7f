"""Sweeps over scene keys and seeds: the plan (plan.py), where points run (runner.py), the results
on disk (store.py). The command is haptic_teleop/cli/sweep.py (`haptic-teleop sweep`); docs/sweep.md."""
