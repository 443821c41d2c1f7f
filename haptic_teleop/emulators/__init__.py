"""Protocol-level device emulators (docs/dynamixel.md, "The emulator").

Each emulator runs in its own process and speaks a device's real wire protocol on a
pseudo-terminal or a 127.0.0.1 socket, so the unmodified vendor SDKs are tested against it. This
layer sits above `plants/` (an emulator's physics is the project's own plants) and below `scene/`.
"""
