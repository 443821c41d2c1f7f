"""argparse value types shared by several commands (`run --foxglove`, `launch --foxglove`).

Not in cli/__init__.py: the package's __init__ runs before the console script's entry module
installs its signal handler (entry.py), so it imports nothing.
"""

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
