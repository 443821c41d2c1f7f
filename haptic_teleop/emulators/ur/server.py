"""The emulator's sockets and its 500 Hz controller loop (docs/ur_emulator.md, "The emulator").

Threads: one controller loop (absolute deadlines at the configured frequency: read the inputs,
run the emulated script, step the robot, check the safety limits, send a data package to every
started RTDE client at its recipe's rate), one accept thread per listening port, one reader
thread per connection. One lock guards the controller's state.
"""

from __future__ import annotations

import contextlib
import json
import math
import select
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from haptic_teleop.emulators.ur.config import URConfig
from haptic_teleop.emulators.ur.robot import SimulatedUR
from haptic_teleop.emulators.ur.script import ControlScript, Registers, ScriptError, parse_script
from haptic_teleop.plants.arm import WallSpec
from haptic_teleop.plants.ur import rtde_wire as w

# UR codes (RTDE guide, "robot_mode", "safety_mode", "safety_status_bits", "runtime_state",
# "robot_status_bits"; docs/ur_protocols.md)
ROBOT_MODE_NAMES = {
    -1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
    4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE",
}  # fmt: skip
SAFETY_MODE_NAMES = {
    1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
    10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
    13: "SYSTEM_THREE_POSITION_ENABLING_STOP",
}  # fmt: skip
SAFETY_BIT = {1: 0, 2: 1, 3: 2, 4: 3, 5: 4, 6: 5, 7: 6, 8: 8, 9: 9}  # safety mode -> its status bit
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
_ZERO: dict[str, Any] = {
    "BOOL": False, "UINT8": 0, "UINT32": 0, "UINT64": 0, "INT32": 0, "DOUBLE": 0.0,
    "VECTOR3D": (0.0,) * 3, "VECTOR6D": (0.0,) * 6, "VECTOR6INT32": (0,) * 6, "VECTOR6UINT32": (0,) * 6,
}  # fmt: skip
ROBOT_RUNNING = 7
# RTDE joint_mode codes [RTDE guide]: a joint's mode follows the robot's unless a joint fault sets its own.
JOINT_RUNNING, JOINT_IDLE, JOINT_BACKDRIVE, JOINT_POWER_OFF = 253, 255, 238, 239
APPLIED_TORQUE_OUTPUT = "actual_current_as_torque"  # PolyScope 5.23 / 10.11 on [RTDE guide; docs/ur.md]
JOINT_FAULTS = ("no_torque", "brake")


@dataclass
class Client:
    sock: socket.socket
    kind: str
    send_lock: threading.Lock = field(default_factory=threading.Lock)
    protocol: int = 0
    outputs: w.Recipe | None = None
    decimation: int = 1
    started: bool = False
    inputs: dict[int, w.Recipe] = field(default_factory=dict)
    alive: bool = True

    def send(self, data: bytes) -> None:
        with self.send_lock:
            self.sock.sendall(data)


class Controller:
    def __init__(self, cfg: URConfig) -> None:
        self.cfg = cfg
        self.period_s = 1.0 / cfg.frequency_hz
        wall = None
        if cfg.wall is not None:
            wall = WallSpec(
                point_m=(cfg.wall.point_m[0], cfg.wall.point_m[1], cfg.wall.point_m[2]),
                normal=(cfg.wall.normal[0], cfg.wall.normal[1], cfg.wall.normal[2]),
                stiffness_n_per_m=cfg.wall.stiffness_n_per_m,
                damping_n_s_per_m=cfg.wall.damping_n_s_per_m,
            )
        self.robot = SimulatedUR(
            cfg.model, cfg.start_q_rad, self.period_s, cfg.substeps, wall,
            cfg.force_mode_damping_n_s_per_m, cfg.force_mode_damping_nm_s_per_rad,
        )  # fmt: skip
        self.lock = threading.RLock()
        self.regs = Registers()
        self.script: ControlScript | None = None
        self.scripts_received = 0
        self.script_errors: list[str] = []
        self.robot_mode = cfg.robot_mode
        self.safety_mode = cfg.safety_mode
        self.cycles = 0
        self.t_s = 0.0
        self.input_stamp: dict[str, float] = {}
        self.input_owner: dict[str, int] = {}
        self.frozen = False
        self.refusing_until = 0.0
        self.clients: list[Client] = []
        self.messages: list[tuple[str, int]] = []
        self.speed_slider = 1.0
        self.stop_reason = ""

    # ------------------------------------------------------------------ state
    @property
    def program_running(self) -> bool:
        return self.script is not None and self.script.running

    def safety_status_bits(self) -> int:
        bit = SAFETY_BIT.get(self.safety_mode)
        bits = 0 if bit is None else 1 << bit
        if self.safety_mode != 1:
            bits |= 1 << 10  # stopped due to safety
        return bits

    def robot_status_bits(self) -> int:
        power = 1 if self.robot_mode in (4, 5, 6, 7) else 0
        return power | (2 if self.program_running else 0)

    def values(self) -> dict[str, Any]:
        """Every output variable's value this cycle."""
        r = self.robot
        q, qd = r.arm.read()
        pose, speed, force = r.tcp_pose(), r.tcp_speed(), r.tcp_force()
        z6 = (0.0,) * 6
        v: dict[str, Any] = {name: _ZERO[t] for name, t in w.OUTPUT_TYPES.items()}  # unmodelled values read 0
        tau = r.joint_torques()
        q_t = r.q_hold if r.mode == "hold" else r.q_ref
        if self.robot_mode == ROBOT_RUNNING:
            joint_mode = tuple(r.joint_modes())
        else:
            joint_mode = ({5: JOINT_IDLE, 6: JOINT_BACKDRIVE}.get(self.robot_mode, JOINT_POWER_OFF),) * 6
        v.update(
            timestamp=self.t_s,
            actual_q=tuple(q), actual_qd=tuple(qd), target_q=tuple(q_t), target_qd=z6,
            actual_TCP_pose=tuple(pose), actual_TCP_speed=tuple(speed), actual_TCP_force=tuple(force),
            target_TCP_pose=tuple(pose), target_TCP_speed=tuple(speed), ft_raw_wrench=tuple(force),
            # the controller's target beyond gravity, and what the motors applied (they differ under a joint fault)
            target_moment=tuple(r.tau_target), actual_current_as_torque=tuple(tau), joint_control_output=tuple(tau),
            robot_mode=self.robot_mode, safety_mode=self.safety_mode, safety_status=self.safety_mode,
            joint_mode=joint_mode,
            runtime_state=RUNTIME_PLAYING if self.program_running else RUNTIME_STOPPED,
            robot_status_bits=self.robot_status_bits(), safety_status_bits=self.safety_status_bits(),
            speed_scaling=1.0, target_speed_fraction=self.speed_slider,
            tcp_force_scalar=float(np.linalg.norm(force[:3])),
            actual_main_voltage=48.0, actual_robot_voltage=48.0, actual_joint_voltage=(48.0,) * 6,
            joint_temperatures=(30.0,) * 6, tool_temperature=30.0, actual_execution_time=0.1,
        )  # fmt: skip
        for i in range(48):
            v[f"output_int_register_{i}"] = self.regs.out_int[i]
            v[f"output_double_register_{i}"] = self.regs.out_double[i]
            v[f"input_int_register_{i}"] = self.regs.in_int[i]
            v[f"input_double_register_{i}"] = self.regs.in_double[i]
        return v

    # ------------------------------------------------------------------ events
    def message(self, text: str, level: int = w.WARNING_MESSAGE) -> None:
        self.messages.append((text, level))

    def load_script(self, text: str) -> None:
        with self.lock:
            self.scripts_received += 1
            try:
                parsed = parse_script(text)
            except ScriptError as exc:
                self.script_errors.append(str(exc))
                self.message(f"program refused: {exc}", w.ERROR_MESSAGE)
                return
            if self.robot_mode != ROBOT_RUNNING or self.safety_mode != 1:
                self.script_errors.append("robot not ready: program not started")
                self.message("program not started: the robot is not running in normal safety mode", w.ERROR_MESSAGE)
                return
            self.regs.out_int = [0] * 48
            self.script = ControlScript(parsed, self.regs)
            self.stop_reason = ""

    def stop_program(self, reason: str) -> None:
        with self.lock:
            if self.script is not None and self.script.running:
                self.script.running = False
                self.stop_reason = reason
            self.robot.hold()

    def protective_stop(self, reason: str) -> None:
        with self.lock:
            if self.safety_mode == 3:
                return
            self.safety_mode = 3
            self.stop_program(f"protective stop: {reason}")
            self.message(f"C153A0 protective stop: {reason}", w.ERROR_MESSAGE)

    def safety_stop(self, mode: int, reason: str) -> None:
        """Another safety stop than a protective one: the safety mode (5 safeguard stop, 6 / 7 system
        / robot emergency stop, 8 violation, 9 fault ...), the program stopped, the arm holding; an
        emergency stop also removes the arm's power (robot mode POWER_OFF), as its stop category 1 does."""
        with self.lock:
            self.safety_mode = mode
            self.stop_program(f"{SAFETY_MODE_NAMES.get(mode, str(mode))}: {reason}")
            if mode in (6, 7):
                self.robot_mode = 3
            self.message(f"{SAFETY_MODE_NAMES.get(mode, str(mode))}: {reason}", w.ERROR_MESSAGE)

    def unlock_protective_stop(self) -> bool:
        with self.lock:
            if self.safety_mode != 3:
                return False
            self.safety_mode = 1
            self.robot.hold()
            return True

    # ------------------------------------------------------------------ the cycle
    def input_waiting(self) -> bool:
        """Whether an RTDE client's socket holds bytes this process has not read yet: the host sent
        them while the emulator was not running. The emulator is no real-time controller; a stall
        of its own process must not count against the host as a silence."""
        socks = [c.sock for c in self.clients if c.kind == "rtde" and c.alive and c.inputs]
        if not socks:
            return False
        try:
            readable, _, _ = select.select(socks, [], [], 0.0)
        except (OSError, ValueError):  # a socket closed meanwhile
            return False
        return bool(readable)

    def cycle(self, late: bool = False) -> None:
        """One controller cycle. `late`: the emulator's own loop runs behind its clock (its process
        stalled and is catching up): the RTDE watchdog is not judged until it is on time again."""
        with self.lock:
            s = self.script
            if s is not None and s.running:
                s.step(self.robot)
                if s.protective_stop_requested:
                    s.protective_stop_requested = False
                    self.protective_stop("requested by the program")
                if s.running and s.watchdog_hz > 0.0:
                    name = f"input_int_register_{s.script.reg_offset}"
                    last = self.input_stamp.get(name, 0.0)
                    if self.t_s - last > 1.0 / s.watchdog_hz and not late and not self.input_waiting():
                        self.stop_program(f"RTDE watchdog: no update of {name} for {self.t_s - last:.3f} s")
                        self.message(f"RTDE input watchdog expired on {name}: program stopped", w.ERROR_MESSAGE)
            self.robot.cycle()
            self.cycles += 1
            self.t_s = self.cycles * self.period_s
            f, _ = self.robot.arm.contact_wrench()  # the real force, whatever zeroFtSensor subtracted
            if float(np.linalg.norm(f)) > self.cfg.protective_stop_force_n:
                self.protective_stop(f"TCP force {np.linalg.norm(f):.1f} N over {self.cfg.protective_stop_force_n} N")
            tau = np.abs(self.robot.joint_torques())
            if float(tau.max()) > self.cfg.protective_stop_torque_nm:
                self.protective_stop(f"joint torque {tau.max():.1f} N m over {self.cfg.protective_stop_torque_nm} N m")


class Server:
    def __init__(self, cfg: URConfig) -> None:
        self.cfg = cfg
        self.ctl = Controller(cfg)
        self._stop = threading.Event()
        self._listeners: dict[str, socket.socket] = {}
        self._threads: list[threading.Thread] = []
        self._next_id = 1
        self.ports: dict[str, int] = {}

    # ------------------------------------------------------------------ lifecycle
    def _listen(self, name: str, port: int) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((self.cfg.host, port))
        s.listen(8)
        self._listeners[name] = s
        self.ports[name] = s.getsockname()[1]
        return s

    def open(self) -> None:
        self._listen("rtde", self.cfg.rtde_port)
        self._listen("dashboard", self.cfg.dashboard_port)
        for k, p in enumerate(self.cfg.script_ports):
            self._listen(f"script{k}", int(p))
        self._listen("control", self.cfg.control_port)
        for name in list(self._listeners):
            self._spawn(self._accept_loop, name)
        self._spawn(self._loop)

    def _spawn(self, fn: Any, *args: Any) -> None:
        t = threading.Thread(target=fn, args=args, daemon=True)
        t.start()
        self._threads.append(t)

    def close(self) -> None:
        self._stop.set()
        for s in self._listeners.values():
            with contextlib.suppress(OSError):
                s.close()
        self._drop_clients()
        self.ctl.robot.close()

    def request_stop(self) -> None:
        self._stop.set()

    def wait(self) -> None:
        self._stop.wait()

    def _drop_clients(self) -> None:
        with self.ctl.lock:
            clients, self.ctl.clients = self.ctl.clients, []
        for c in clients:
            c.alive = False
            with contextlib.suppress(OSError):
                c.sock.shutdown(socket.SHUT_RDWR)
            with contextlib.suppress(OSError):
                c.sock.close()

    def _accept_loop(self, name: str) -> None:
        lst = self._listeners[name]
        while not self._stop.is_set():
            try:
                sock, _ = lst.accept()
            except OSError:
                return
            if time.monotonic() < self.ctl.refusing_until:
                sock.close()
                continue
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            kind = "script" if name.startswith("script") else name
            c = Client(sock, kind)
            with self.ctl.lock:
                self.ctl.clients.append(c)
            handler = {
                "rtde": self._rtde,
                "dashboard": self._dashboard,
                "script": self._script,
                "control": self._control,
            }
            self._spawn(self._serve, handler[kind], c)

    def _serve(self, handler: Any, c: Client) -> None:
        try:
            handler(c)
        except (OSError, ConnectionError, struct.error, ValueError):
            pass
        finally:
            c.alive = False
            with self.ctl.lock:
                if c in self.ctl.clients:
                    self.ctl.clients.remove(c)
                for name, owner in list(self.ctl.input_owner.items()):
                    if owner == id(c):
                        del self.ctl.input_owner[name]
            with contextlib.suppress(OSError):
                c.sock.close()

    # ------------------------------------------------------------------ the loop
    def _loop(self) -> None:
        period = self.ctl.period_s
        t_next = time.monotonic()
        late = False
        while not self._stop.is_set():
            self.ctl.cycle(late)
            self._publish()
            t_next += period
            delay = t_next - time.monotonic()
            late = delay < -period  # the next cycle starts more than a period behind the clock
            if delay > 0:
                time.sleep(delay)
            elif delay < -20 * period:
                t_next = time.monotonic()  # far behind (the machine stalled): skip, as the controller skips packages

    def _publish(self) -> None:
        ctl = self.ctl
        with ctl.lock:
            if ctl.frozen:
                return
            clients = [c for c in ctl.clients if c.kind == "rtde" and c.started and c.outputs is not None]
            msgs, ctl.messages = ctl.messages, []
            if not clients and not msgs:
                return
            values = ctl.values() if clients else {}
            cycles = ctl.cycles
            talkers = [c for c in ctl.clients if c.kind == "rtde" and c.protocol == 2] if msgs else []
        for c in talkers:
            for text, level in msgs:
                with contextlib.suppress(OSError):
                    c.send(w.text_message(text, "Controller", level))
        for c in clients:
            if cycles % c.decimation:
                continue
            assert c.outputs is not None
            try:
                c.send(c.outputs.pack(values))
            except OSError:
                c.alive = False
                with contextlib.suppress(OSError):
                    c.sock.shutdown(socket.SHUT_RDWR)

    # ------------------------------------------------------------------ RTDE
    def _rtde(self, c: Client) -> None:
        ctl = self.ctl
        while not self._stop.is_set() and c.alive:
            kind, body = w.read_package(c.sock)
            if ctl.frozen:
                continue  # the network is down: nothing arrives
            if kind == w.REQUEST_PROTOCOL_VERSION:
                (version,) = struct.unpack(">H", body[:2])
                ok = version == 2
                if ok:
                    c.protocol = 2
                c.send(w.frame(kind, bytes([1 if ok else 0])))
            elif kind == w.GET_URCONTROL_VERSION:
                c.send(w.frame(kind, struct.pack(">IIII", *self.cfg.version)))
            elif kind == w.SETUP_OUTPUTS:
                (freq,) = struct.unpack(">d", body[:8])
                names = [n for n in body[8:].decode().split(",") if n]  # ur_rtde ends the list with a comma
                types = w.resolve_names(names, w.OUTPUT_TYPES)
                if not self._has_applied_torque_output():
                    types = [
                        w.NOT_FOUND if n == APPLIED_TORQUE_OUTPUT else t for n, t in zip(names, types, strict=True)
                    ]
                bad = not (0.0 < freq <= self.cfg.frequency_hz) or w.NOT_FOUND in types
                with ctl.lock:
                    c.started = False
                    if bad:
                        c.outputs = None
                        rid = 0
                    else:
                        rid = 1
                        c.outputs = w.Recipe(rid, tuple(names), tuple(types))
                        c.decimation = max(1, round(self.cfg.frequency_hz / freq))
                c.send(w.frame(kind, bytes([rid]) + ",".join(types).encode()))
            elif kind == w.SETUP_INPUTS:
                names = [n for n in body.decode().split(",") if n]
                types = w.resolve_names(names, w.INPUT_TYPES)
                with ctl.lock:
                    for k, n in enumerate(names):
                        owner = ctl.input_owner.get(n)
                        if types[k] != w.NOT_FOUND and owner is not None and owner != id(c):
                            types[k] = w.IN_USE
                    if w.NOT_FOUND in types or w.IN_USE in types:
                        rid = 0
                    else:
                        rid = len(c.inputs) + 1
                        if rid > 255:
                            rid = 0
                        else:
                            c.inputs[rid] = w.Recipe(rid, tuple(names), tuple(types))
                            for n in names:
                                ctl.input_owner[n] = id(c)
                c.send(w.frame(kind, bytes([rid]) + ",".join(types).encode()))
            elif kind == w.START:
                ok = c.outputs is not None or bool(c.inputs)
                c.started = ok and c.outputs is not None
                c.send(w.frame(kind, bytes([1 if ok else 0])))
            elif kind == w.PAUSE:
                c.started = False
                c.send(w.frame(kind, b"\x01"))
            elif kind == w.DATA_PACKAGE:
                recipe = c.inputs.get(body[0])
                if recipe is None:
                    continue
                vals = recipe.unpack(body[1:])
                with ctl.lock:
                    for n, v in vals.items():
                        self._set_input(n, v)
                        ctl.input_stamp[n] = ctl.t_s
            elif kind == w.TEXT_MESSAGE:
                pass

    def _has_applied_torque_output(self) -> bool:
        v = self.cfg.version
        return (v[0], v[1]) >= ((10, 11) if v[0] >= 10 else (5, 23))

    def _set_input(self, name: str, value: object) -> None:
        regs = self.ctl.regs
        if name.startswith("input_int_register_"):
            regs.in_int[int(name.rsplit("_", 1)[1])] = int(value)  # type: ignore[call-overload]
        elif name.startswith("input_double_register_"):
            regs.in_double[int(name.rsplit("_", 1)[1])] = float(value)  # type: ignore[arg-type]
        elif name == "speed_slider_fraction":
            self.ctl.speed_slider = float(value)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ dashboard
    def _dashboard(self, c: Client) -> None:
        c.send(b"Connected: Universal Robots Dashboard Server\n")
        f = c.sock.makefile("rb")
        for raw in f:
            if self.ctl.frozen:
                continue
            line = raw.decode(errors="replace").strip()
            reply = self._dash_reply(line)
            c.send((reply + "\n").encode())
            if line == "quit":
                return

    def _dash_reply(self, cmd: str) -> str:
        ctl = self.ctl
        v = self.cfg.version
        with ctl.lock:
            if cmd == "PolyscopeVersion":
                return f"URSoftware {v[0]}.{v[1]}.{v[2]}.{v[3]} (emulated)"
            if cmd == "get serial number":
                return self.cfg.serial_number
            if cmd == "get robot model":
                return "UR5"
            if cmd == "is in remote control":
                return "true"
            if cmd == "robotmode":
                return f"Robotmode: {ROBOT_MODE_NAMES.get(ctl.robot_mode, 'UNKNOWN')}"
            if cmd == "safetystatus":
                return f"Safetystatus: {SAFETY_MODE_NAMES.get(ctl.safety_mode, 'UNKNOWN')}"
            if cmd == "safetymode":
                return f"Safetymode: {SAFETY_MODE_NAMES.get(ctl.safety_mode, 'UNKNOWN')}"
            if cmd == "programState":
                return "PLAYING rtde_control" if ctl.program_running else "STOPPED <unnamed>"
            if cmd == "running":
                return f"Program running: {'true' if ctl.program_running else 'false'}"
            if cmd == "stop":
                ctl.stop_program("stopped from the dashboard")
                return "Stopped"
            if cmd == "pause":
                return "Pausing program"
            if cmd == "play":
                return "Failed to execute: play"
            if cmd == "unlock protective stop":
                ok = ctl.unlock_protective_stop()
                return (
                    "Protective stop releasing"
                    if ok
                    else "Cannot unlock protective stop until 5s after occurrence. "
                    "Always inspect cause of protective stop before unlocking"
                )
            if cmd == "close safety popup":
                return "closing safety popup"
            if cmd == "close popup":
                return "closing popup"
            if cmd == "power on":
                if ctl.robot_mode in (3, 4):
                    ctl.robot_mode = 5
                return "Powering on"
            if cmd == "brake release":
                if ctl.robot_mode in (5, 7):
                    ctl.robot_mode = 7
                return "Brake releasing"
            if cmd == "power off":
                ctl.stop_program("powered off")
                ctl.robot_mode = 3
                return "Powering off"
            if cmd == "quit":
                return "Disconnected"
            if cmd.startswith("popup ") or cmd == "close popup" or cmd.startswith("addToLog "):
                return "showing popup" if cmd.startswith("popup") else "Added log message"
            return f"could not understand: '{cmd}'"

    # ------------------------------------------------------------------ script ports
    def _script(self, c: Client) -> None:
        buf = ""
        while not self._stop.is_set():
            data = c.sock.recv(65536)
            if not data:
                return
            if self.ctl.frozen:
                continue
            buf += data.decode(errors="replace")
            while True:
                start = buf.find("def ")
                end_at = self._program_end(buf, start)
                if start < 0 or end_at < 0:
                    break
                self.ctl.load_script(buf[start:end_at])
                buf = buf[end_at:]

    @staticmethod
    def _program_end(buf: str, start: int) -> int:
        if start < 0:
            return -1
        pos = start
        while True:
            nl = buf.find("\nend", pos)
            if nl < 0:
                return -1
            after = nl + 4
            if after >= len(buf):
                return -1
            if buf[after] == "\n":
                return after + 1
            pos = after

    # ------------------------------------------------------------------ test channel
    def _control(self, c: Client) -> None:
        f = c.sock.makefile("rb")
        for raw in f:
            req = json.loads(raw)
            reply = self._control_reply(req)
            c.send((json.dumps(reply) + "\n").encode())

    def _control_reply(self, req: dict[str, Any]) -> dict[str, Any]:
        ctl = self.ctl
        cmd = req.get("cmd")
        with ctl.lock:
            if cmd == "state":
                r = ctl.robot
                q, qd = r.arm.read()
                f, t = r.arm.contact_wrench()
                s = ctl.script
                return {
                    "q_rad": list(map(float, q)), "qd_rad_per_s": list(map(float, qd)),
                    "tcp_position_m": list(map(float, r.arm.data.site_xpos[r.arm.constants().site_id])),
                    "tcp_rotation": list(map(float, r.arm.data.site_xmat[r.arm.constants().site_id])),
                    "contact_force_n": list(map(float, f)), "contact_torque_nm": list(map(float, t)),
                    "mode": r.mode, "robot_mode": ctl.robot_mode, "safety_mode": ctl.safety_mode,
                    "program_running": ctl.program_running, "scripts_received": ctl.scripts_received,
                    "script_errors": list(ctl.script_errors), "reg_offset": None if s is None else s.script.reg_offset,
                    "has_direct_torque": None if s is None else s.script.has_direct_torque,
                    "watchdog_hz": 0.0 if s is None else s.watchdog_hz, "stop_reason": ctl.stop_reason,
                    "t_s": ctl.t_s, "cycles": ctl.cycles, "tau_nm": list(map(float, r.joint_torques())),
                    "script_log": [] if s is None else list(s.log),
                    "force_mode_damping": None if s is None else s.force_mode_damping,
                    "motor_work_j": r.motor_work_j, "dissipated_j": r.dissipated_j, "env_work_j": r.env_work_j,
                    "max_net_motor_work_j": r.max_net_motor_work_j, "max_env_work_j": r.max_env_work_j,
                    "tau_target_nm": list(map(float, r.tau_target)),
                    "joint_faults": {str(k): v for k, v in r.joint_faults.items()},
                }  # fmt: skip
            if cmd == "protective_stop":
                ctl.protective_stop(str(req.get("reason", "injected")))
                return {"ok": True}
            if cmd == "safety_stop":
                mode = req.get("mode", 7)
                if not isinstance(mode, int) or not 4 <= mode <= 13:
                    return {"error": "safety_stop needs a safety mode 4..13 (protective_stop for 3)"}
                ctl.safety_stop(mode, str(req.get("reason", "injected")))
                return {"ok": True}
            if cmd == "joint_fault":
                joint, kind = req.get("joint"), req.get("kind", "no_torque")
                if not isinstance(joint, int) or not 0 <= joint < ctl.robot.n or kind not in (*JOINT_FAULTS, None):
                    return {"error": f"joint_fault needs joint 0..{ctl.robot.n - 1} and kind in {JOINT_FAULTS} or null"}
                ctl.robot.set_joint_fault(joint, kind)
                return {"ok": True}
            if cmd == "stop_program":
                ctl.stop_program(str(req.get("reason", "injected")))
                return {"ok": True}
            if cmd == "freeze":
                ctl.frozen = bool(req.get("on", True))
                return {"ok": True}
        if cmd == "drop_connections":
            refuse = float(req.get("refuse_s", math.inf))
            ctl.refusing_until = time.monotonic() + refuse
            with ctl.lock:
                others = [x for x in ctl.clients if x.kind != "control"]
                ctl.clients = [x for x in ctl.clients if x.kind == "control"]
            for x in others:
                x.alive = False
                with contextlib.suppress(OSError):
                    x.sock.shutdown(socket.SHUT_RDWR)
                with contextlib.suppress(OSError):
                    x.sock.close()
            return {"ok": True}
        return {"error": f"unknown command {cmd!r}"}
