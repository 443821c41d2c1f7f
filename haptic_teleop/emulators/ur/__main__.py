"""`python -m haptic_teleop.emulators.ur --config FILE.json`: run the UR emulator until SIGTERM,
SIGINT or the parent's death; prints one line `READY host rtde=P dashboard=P script0=P ...`."""

from __future__ import annotations

import argparse
import signal
import sys

from haptic_teleop.errors import ConfigError
from haptic_teleop.lifetime import as_hardware, die_with_parent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m haptic_teleop.emulators.ur")
    parser.add_argument("--config", help="JSON file with the emulator's settings (docs/ur.md)")
    args = parser.parse_args(argv)
    die_with_parent(signal.SIGTERM)
    as_hardware()  # a controller never waits for the host's scheduler (lifetime.HARDWARE_NICE)
    from haptic_teleop.emulators.ur.config import URConfig

    try:
        cfg = URConfig.from_file(args.config) if args.config else URConfig()
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from haptic_teleop.emulators.ur.server import Server

    server = Server(cfg)
    try:
        server.open()
    except OSError as exc:
        print(
            f"error: cannot listen on {cfg.host}: {exc.strerror} (another emulator or robot service?)", file=sys.stderr
        )
        return 1

    def on_signal(signum: int, frame: object) -> None:
        server.request_stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    ports = " ".join(f"{k}={v}" for k, v in server.ports.items())
    print(f"READY {cfg.host} {ports}", flush=True)
    server.wait()
    server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
