"""Every command of `haptic-teleop` (`main.py` the parser and `run`, `analyze`, `scenes`, `bag`,
`compile`, `launch`, `emulate`; one module per larger command: `sweep.py`, `report.py`,
`experiment.py`, `bench.py`, `identify.py`). The top layer: it may import any other."""

# Nothing is imported here: this runs before entry.py installs the console script's signal handler
# (test_cli_entry checks it).
