"""Every command of `haptic-teleop` (`main.py` the parser and `run`, `analyze`, `scenes`, `bag`,
`compile`, `launch`, `emulate`; one module per larger command: `sweep.py`, `report.py`,
`experiment.py`, `bench.py`, `identify.py`). The top layer: it may import any other."""

import argparse


def tcp_port(text: str) -> int:
    """An argparse type: a TCP port, 0 to 65535 (0: any free port)."""
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: a TCP port, 0 to 65535 (0: any free port)")
    return port
