"""The UR emulator through the unmodified ur_rtde receive interface, and its RTDE and dashboard
protocol seen from raw sockets (docs/ur_emulator.md). One emulator at a time: ur_rtde's ports are fixed."""

from __future__ import annotations

import math
import socket
import struct
import subprocess
import sys

import numpy as np
import pytest

from haptic_teleop.core.spatial import rotvec_to_matrix
from haptic_teleop.emulators.ur.config import URConfig
from haptic_teleop.emulators.ur.process import start_ur
from haptic_teleop.errors import PlantError
from haptic_teleop.plants.ur import rtde_wire as w

rtde_receive = pytest.importorskip("rtde_receive")

# Universal Robots' published UR5e DH parameters (docs/ur.md): a, d, alpha per joint.
DH = [(0.0, 0.1625, math.pi / 2), (-0.425, 0.0, 0.0), (-0.3922, 0.0, 0.0), (0.0, 0.1333, math.pi / 2),
      (0.0, 0.0997, -math.pi / 2), (0.0, 0.0996, 0.0)]  # fmt: skip
TOOL_M = 0.05  # the model's tool site: 50 mm out along the flange's z axis


def dh_tool(q: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    for qi, (a, d, al) in zip(q, DH, strict=True):
        c, s, ca, sa = math.cos(qi), math.sin(qi), math.cos(al), math.sin(al)
        t = t @ np.array([[c, -s * ca, s * sa, a * c], [s, c * ca, -c * sa, a * s], [0, sa, ca, d], [0, 0, 0, 1]])
    return t @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, TOOL_M], [0, 0, 0, 1]])


START_Q = (0.3, -1.2, 1.4, -1.7, -1.5708, 0.4)


def test_receive_reads_the_emulated_arms_joints_and_tool_pose():
    with start_ur(URConfig(start_q_rad=START_Q)) as ur:
        r = rtde_receive.RTDEReceiveInterface(ur.host, 500.0)
        try:
            assert r.isConnected()
            q = np.array(r.getActualQ())
            pose = np.array(r.getActualTCPPose())
            truth = ur.state()
            assert r.getRobotMode() == 7 and r.getSafetyMode() == 1 and r.getSafetyStatusBits() == 1
            assert r.getRuntimeState() == 1  # STOPPED: no program yet
            assert not r.isProtectiveStopped()
        finally:
            r.disconnect()
    # the arm holds still: the RTDE joints are MuJoCo's
    np.testing.assert_allclose(q, truth["q_rad"], atol=1e-6)
    np.testing.assert_allclose(q, START_Q, atol=1e-3)
    # the TCP pose is MuJoCo's tool site ...
    np.testing.assert_allclose(pose[:3], truth["tcp_position_m"], atol=1e-6)
    np.testing.assert_allclose(rotvec_to_matrix(pose[3:]), np.reshape(truth["tcp_rotation"], (3, 3)), atol=1e-6)
    # ... and the model's kinematics are UR's DH kinematics
    t = dh_tool(q)
    np.testing.assert_allclose(pose[:3], t[:3, 3], atol=1e-6)
    np.testing.assert_allclose(rotvec_to_matrix(pose[3:]), t[:3, :3], atol=1e-6)


def test_unknown_output_variables_are_not_found():
    with start_ur() as ur, pytest.raises(RuntimeError, match="no_such_variable"):
        rtde_receive.RTDEReceiveInterface(ur.host, 500.0, ["actual_q", "no_such_variable"])


def _package(s: socket.socket) -> tuple[int, bytes]:
    head = b""
    while len(head) < 3:
        head += s.recv(3 - len(head))
    size, kind = w.HEADER.unpack(head)
    body = b""
    while len(body) < size - 3:
        body += s.recv(size - 3 - len(body))
    return kind, body


def _raw_client(host: str) -> socket.socket:
    s = socket.create_connection((host, 30004), timeout=30.0)
    s.sendall(w.frame(w.REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2)))
    assert _package(s) == (w.REQUEST_PROTOCOL_VERSION, b"\x01")
    return s


def test_rtde_protocol_from_a_raw_socket():
    cfg = URConfig(controller_version=(5.0, 23.0, 0.0, 1234.0))
    with start_ur(cfg) as ur:
        a, b = _raw_client(ur.host), _raw_client(ur.host)
        try:
            a.sendall(w.frame(w.GET_URCONTROL_VERSION))
            kind, body = _package(a)
            assert struct.unpack(">IIII", body) == (5, 23, 0, 1234)
            # an input register belongs to the first client that sets it up
            a.sendall(w.frame(w.SETUP_INPUTS, b"input_int_register_5,input_double_register_5"))
            assert _package(a) == (w.SETUP_INPUTS, b"\x01INT32,DOUBLE")
            b.sendall(w.frame(w.SETUP_INPUTS, b"input_int_register_5"))
            assert _package(b) == (w.SETUP_INPUTS, b"\x00IN_USE")
            b.sendall(w.frame(w.SETUP_INPUTS, b"speed_slider_fraction,bogus"))
            assert _package(b) == (w.SETUP_INPUTS, b"\x00DOUBLE,NOT_FOUND")
            # outputs at 500 Hz: consecutive packages are one controller period apart
            b.sendall(w.frame(w.SETUP_OUTPUTS, struct.pack(">d", 500.0) + b"timestamp,input_int_register_5"))
            assert _package(b) == (w.SETUP_OUTPUTS, b"\x01DOUBLE,INT32")
            b.sendall(w.frame(w.START))
            assert _package(b) == (w.START, b"\x01")
            a.sendall(w.frame(w.DATA_PACKAGE, b"\x01" + struct.pack(">id", 42, 0.5)))
            stamps, seen = [], set()
            while len(stamps) < 200:
                kind, body = _package(b)
                if kind == w.DATA_PACKAGE:
                    t, reg = struct.unpack(">di", body[1:])
                    stamps.append(t)
                    seen.add(reg)
            np.testing.assert_allclose(np.diff(stamps), 0.002, atol=1e-9)
            assert 42 in seen  # the input written by one client is read back by another
            # a protective stop reaches RTDE clients as a text message
            ur.inject("protective_stop", reason="test")
            text = b""
            while b"protective stop" not in text:
                kind, body = _package(b)
                if kind == w.TEXT_MESSAGE:
                    text = body
            assert text[0] == len(text) - 1 - 1 - text[1 + text[0]] - 1  # u8 length, message, u8 length, source, level
            b.sendall(w.frame(w.PAUSE))
        finally:
            a.close()
            b.close()


def _subscribe(host: str, names: str) -> tuple[socket.socket, bytes]:
    """A raw RTDE client with one output recipe at 500 Hz: the socket and the setup's answer."""
    s = _raw_client(host)
    s.sendall(w.frame(w.SETUP_OUTPUTS, struct.pack(">d", 500.0) + names.encode()))
    kind, body = _package(s)
    assert kind == w.SETUP_OUTPUTS
    return s, body


def _next_values(s: socket.socket, recipe: w.Recipe) -> dict:
    while True:
        kind, body = _package(s)
        if kind == w.DATA_PACKAGE:
            return recipe.unpack(body[1:])


def test_the_applied_joint_torque_is_what_the_motors_did_and_a_joint_fault_shows_in_it():
    names = ("target_moment", "actual_current_as_torque", "joint_mode")
    # PolyScope 5.23 brought actual_current_as_torque: an older controller does not know it
    with start_ur(URConfig(controller_version=(5.0, 22.0, 0.0, 0.0))) as ur:
        s, body = _subscribe(ur.host, ",".join(names))
        s.close()
        assert body == b"\x00VECTOR6D,NOT_FOUND,VECTOR6INT32"
    with start_ur(URConfig(controller_version=(5.0, 26.0, 0.0, 0.0))) as ur:
        s, body = _subscribe(ur.host, ",".join(names))
        try:
            recipe = w.Recipe(body[0], names, tuple(body[1:].decode().split(",")))
            s.sendall(w.frame(w.START))
            assert _package(s) == (w.START, b"\x01")
            v = _next_values(s, recipe)
            # healthy: each joint's motors apply the controller's target (the hold loop's torque), to the bit
            assert v["actual_current_as_torque"] == v["target_moment"] and v["joint_mode"] == (253,) * 6
            ur.inject("joint_fault", joint=2, kind="brake")
            for _ in range(500):  # a second of packages at most
                if (v := _next_values(s, recipe))["joint_mode"][2] == 255:
                    break
            # the braked elbow's motor is off: it applies minus the gravity torque it carried; the others still apply
            # their target
            applied, target = v["actual_current_as_torque"], v["target_moment"]
            assert abs(applied[2] - target[2]) > 1.0
            assert [a == t for a, t in zip(applied, target, strict=True)] == [True, True, False, True, True, True]
            assert v["joint_mode"] == (253, 253, 255, 253, 253, 253)
            assert ur.state()["joint_faults"] == {"2": "brake"}
            ur.inject("joint_fault", joint=2, kind=None)
            assert ur.state()["joint_faults"] == {}
            with pytest.raises(PlantError, match=r"joint_fault needs joint 0\.\.5"):
                ur.inject("joint_fault", joint=6, kind="brake")
            with pytest.raises(PlantError, match="unknown command 'no_such_fault'"):
                ur.inject("no_such_fault")
        finally:
            s.close()


def _dash(host: str, *cmds: str) -> list[str]:
    with socket.create_connection((host, 29999), timeout=30.0) as s:
        f = s.makefile("rb")
        assert f.readline().startswith(b"Connected: Universal Robots Dashboard Server")
        out = []
        for c in cmds:
            s.sendall(c.encode() + b"\n")
            out.append(f.readline().decode().strip())
        return out


def test_dashboard_answers_and_clears_a_protective_stop():
    with start_ur(URConfig(controller_version=(5.0, 15.0, 2.0, 1.0))) as ur:
        assert _dash(ur.host, "PolyscopeVersion", "robotmode", "safetystatus", "programState") == [
            "URSoftware 5.15.2.1 (emulated)",
            "Robotmode: RUNNING",
            "Safetystatus: NORMAL",
            "STOPPED <unnamed>",
        ]
        ur.inject("protective_stop")
        r = rtde_receive.RTDEReceiveInterface(ur.host, 500.0)
        try:
            assert r.isProtectiveStopped() and r.getSafetyMode() == 3
            assert _dash(ur.host, "safetystatus", "unlock protective stop") == [
                "Safetystatus: PROTECTIVE_STOP",
                "Protective stop releasing",
            ]
            assert ur.state()["safety_mode"] == 1
        finally:
            r.disconnect()


def test_entry_point_refuses_a_bad_config_in_one_line(tmp_path):
    bad = tmp_path / "ur.json"
    bad.write_text('{"frequency_hz": 200}')
    p = subprocess.run([sys.executable, "-m", "haptic_teleop.emulators.ur", "--config", str(bad)],
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0 and "frequency_hz" in p.stderr and "Traceback" not in p.stderr


PARENT = """
import subprocess, sys
p = subprocess.Popen([sys.executable, "-m", "haptic_teleop.emulators.ur", "--config", sys.argv[1]],
                     stdout=subprocess.PIPE, text=True)
print(p.pid, p.stdout.readline(), flush=True)
import time
time.sleep(600)
"""


def test_the_emulator_ends_when_its_parent_dies(tmp_path):
    import contextlib
    import json
    import os
    import signal
    import time

    from haptic_teleop.emulators.ur.process import LOCK_PATH

    cfg = tmp_path / "ur.json"
    cfg.write_text(json.dumps(URConfig(rtde_port=0, dashboard_port=0, script_ports=(0.0,)).to_dict()))
    import fcntl

    with open(LOCK_PATH, "a") as lock:  # the same lock start_ur holds, though no fixed port is used here
        fcntl.flock(lock, fcntl.LOCK_EX)
        parent = subprocess.Popen([sys.executable, "-c", PARENT, str(cfg)], stdout=subprocess.PIPE, text=True)
        assert parent.stdout is not None
        pid_text, ready = parent.stdout.readline().split(" ", 1)
        assert ready.startswith("READY 127.0.0.1")
        child = int(pid_text)
        os.kill(child, 0)  # alive
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        host0 = time.monotonic()
        try:
            while True:
                try:
                    os.kill(child, 0)
                    with open(f"/proc/{child}/stat") as f:
                        if f.read().split()[2] == "Z":
                            break  # ended, waiting for its new parent to reap it
                except (ProcessLookupError, FileNotFoundError):
                    break
                assert time.monotonic() - host0 < 30.0, "safety net: the emulator outlived its parent"
                time.sleep(0.05)
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.kill(child, signal.SIGKILL)


def test_the_emulator_runs_at_the_priority_of_hardware_where_permitted():
    # a controller never waits for the host's scheduler: HARDWARE_NICE where permitted (root or
    # CAP_SYS_NICE), else the niceness it was started with
    import os
    import subprocess
    import sys

    from haptic_teleop.lifetime import HARDWARE_NICE

    mine = os.getpriority(os.PRIO_PROCESS, 0)
    with start_ur() as ur:
        nice = os.getpriority(os.PRIO_PROCESS, ur.proc.pid)
    probe = [sys.executable, "-c", f"import os; os.setpriority(os.PRIO_PROCESS, 0, {HARDWARE_NICE})"]
    permitted = subprocess.run(probe, capture_output=True).returncode == 0
    assert nice == (min(HARDWARE_NICE, mine) if permitted else mine)
