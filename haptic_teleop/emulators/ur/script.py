"""The emulated ur_rtde control script (docs/ur_protocols.md, "How RTDEControlInterface runs the arm").

ur_rtde 1.6.5 uploads a URScript program ("def rtde_control(): ... end") that talks to its client
through RTDE registers, offset by `reg_offset_int`/`reg_offset_float` (0, or 24 with the upper
register range). This class does not interpret URScript: it checks that the uploaded program is
that script, reads the offset and which version-gated lines ur_rtde kept, and then follows the
script's main loop every controller cycle:

- signal_ready: output_int_register_0 = 1; signal_done_with_cmd: output_int_register_0 = 2;
- cmd = input_int_register_0; the real-time commands (SERVOL 24, SERVOJ 11, SPEEDJ 9, SPEEDL 10,
  FORCE_MODE 6, TOOL_CONTACT 25, GET_STEPTIME 26, GET_ACTUAL_JOINT_POSITIONS_HISTORY 27,
  GET_JOINT_TORQUES 38, SET_EXTERNAL_FORCE_TORQUE 58, DIRECT_TORQUE 66, 67-71) are processed every
  cycle they are present, then signal_ready;
- cmd 0 clears "executing" and signals ready; any other command runs once (until the client
  clears the register) and signals done, except STOP_SCRIPT 255, which ends the program.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

REALTIME = frozenset({24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})
FORCE_MODE, FORCE_MODE_STOP, ZERO_FT_SENSOR = 6, 7, 8
SPEEDL, SERVOL = 10, 24
SPEED_STOP, SERVO_STOP = 15, 16
PROTECTIVE_STOP, STOPL, STOPJ = 31, 33, 34
SET_WATCHDOG, GET_JOINT_TORQUES = 35, 38
FORCE_MODE_SET_DAMPING = 20
DIRECT_TORQUE = 66
STOP_SCRIPT = 255

# ur_rtde injects the offset right after the comment "# int register offset\n", so the value
# starts the next line: "global reg_offset_int = # int register offset\n0    global ...".
_OFFSET = re.compile(r"global reg_offset_int = # int register offset\n(\d+)")


class ScriptError(ValueError):
    """The uploaded program is not ur_rtde's control script."""


class Robot(Protocol):
    def hold(self) -> None: ...
    def servo_l(self, pose: np.ndarray, gain: float) -> None: ...
    def speed_l(self, twist: np.ndarray, accel: float) -> None: ...
    def speed_stop(self, decel: float) -> None: ...
    def force_mode(self, frame: np.ndarray, selection: np.ndarray, wrench: np.ndarray, limits: np.ndarray) -> None: ...
    def direct_torque(self, tau: np.ndarray) -> None: ...
    def force_mode_set_damping(self, damping: float) -> None: ...
    def zero_ft(self) -> None: ...
    def joint_torques(self) -> np.ndarray: ...


@dataclass(frozen=True)
class UploadedScript:
    """What the emulator learnt from the program ur_rtde sent."""

    text: str
    reg_offset: int
    has_direct_torque: bool  # ur_rtde keeps the direct_torque() line only on new enough controllers


def parse_script(text: str) -> UploadedScript:
    if "def rtde_control():" not in text or "RTDE Control Script Loaded" not in text:
        raise ScriptError("not ur_rtde's control script (no 'def rtde_control():' / 'RTDE Control Script Loaded')")
    if not re.search(r"^end\s*$", text, re.MULTILINE):
        raise ScriptError("the program has no closing 'end'")
    m = _OFFSET.search(text)
    if m is None:
        raise ScriptError("no register offset after 'global reg_offset_int = # int register offset'")
    offset = int(m.group(1))
    if offset not in (0, 24):
        raise ScriptError(f"register offset {offset}; ur_rtde uses 0 or 24")
    return UploadedScript(text=text, reg_offset=offset, has_direct_torque="direct_torque(torque" in text)


@dataclass
class Registers:
    """The controller's 48 + 48 input and output registers of each kind."""

    in_int: list[int] = field(default_factory=lambda: [0] * 48)
    in_double: list[float] = field(default_factory=lambda: [0.0] * 48)
    out_int: list[int] = field(default_factory=lambda: [0] * 48)
    out_double: list[float] = field(default_factory=lambda: [0.0] * 48)


@dataclass
class ControlScript:
    """One run of the uploaded control script; `step()` once per controller cycle."""

    script: UploadedScript
    regs: Registers
    running: bool = True
    executing: bool = False
    watchdog_hz: float = 0.0
    force_mode_damping: float | None = None  # the last force_mode_set_damping
    protective_stop_requested: bool = False
    log: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._signal(1)  # signal_ready() before the main loop

    def _i(self, k: int) -> int:
        return self.regs.in_int[k + self.script.reg_offset]

    def _d(self, k: int, n: int = 1) -> np.ndarray:
        o = k + self.script.reg_offset
        return np.array(self.regs.in_double[o : o + n], dtype=float)

    def _signal(self, value: int) -> None:
        self.regs.out_int[self.script.reg_offset] = value

    def step(self, robot: Robot) -> None:
        if not self.running:
            return
        cmd = self._i(0)
        if cmd in REALTIME:
            self._realtime(cmd, robot)
            self._signal(1)
        elif cmd == 0:
            self.executing = False
            self._signal(1)
        elif not self.executing:
            keep = self._process(cmd, robot)
            self.executing = True
            if keep:
                self._signal(2)
            else:
                self.running = False

    def _realtime(self, cmd: int, robot: Robot) -> None:
        if cmd == SERVOL:
            robot.servo_l(self._d(0, 6), float(self._d(10)[0]))
        elif cmd == SPEEDL:
            robot.speed_l(self._d(0, 6), float(self._d(6)[0]))
        elif cmd == FORCE_MODE:
            sel = np.array([self._i(k) for k in range(2, 8)], dtype=float)
            robot.force_mode(self._d(0, 6), sel, self._d(6, 6), self._d(12, 6))
        elif cmd == DIRECT_TORQUE:
            if self.script.has_direct_torque:
                robot.direct_torque(self._d(0, 6))
        elif cmd == GET_JOINT_TORQUES:
            o = self.script.reg_offset
            self.regs.out_double[o : o + 6] = [float(t) for t in robot.joint_torques()]
        # SERVOJ, SPEEDJ, tool contact, step time, history, external F/T, 67-71: not emulated

    def _process(self, cmd: int, robot: Robot) -> bool:
        if cmd == STOP_SCRIPT:
            self.log.append("Received stop script!")
            robot.hold()
            return False
        if cmd in (FORCE_MODE_STOP, SERVO_STOP, STOPL, STOPJ):
            robot.hold()
        elif cmd == SPEED_STOP:
            robot.speed_stop(float(self._d(0)[0]))
        elif cmd == ZERO_FT_SENSOR:
            robot.zero_ft()
        elif cmd == FORCE_MODE_SET_DAMPING:
            self.force_mode_damping = float(self._d(0)[0])
            robot.force_mode_set_damping(self.force_mode_damping)
        elif cmd == SET_WATCHDOG:
            self.watchdog_hz = float(self._d(0)[0])
        elif cmd == PROTECTIVE_STOP:
            self.protective_stop_requested = True
        # everything else (payload, tcp, damping, moves...) is acknowledged without effect
        return True
