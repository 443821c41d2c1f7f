"""The ROS 2 launch files and the launcher build one node plan from one scene file.

ROS 2's `launch` cannot be installed here, so the launch files themselves are checked for what
they consume (their arguments) and `ros2_launch.plan_from_arguments`, which they call, is
checked against the plan `haptic-teleop launch` starts.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from launched import Child, wait_for_bag_messages

from haptic_teleop.errors import ConfigError
from haptic_teleop.live.launcher import format_double, node_plan, params_yaml
from haptic_teleop.live.ros2_launch import ARGUMENTS, DEVICE_ARGUMENTS, NVE_ARGUMENTS, plan_from_arguments
from haptic_teleop.nodes import EXECUTABLES
from haptic_teleop.scene.load import find_scene, load_scene

ROOT = Path(__file__).resolve().parents[1]
LAUNCH_FILES = sorted((ROOT / "launch").glob("*_launch.py"))


def test_launch_files_exist_and_build_their_variant():
    assert [p.name for p in LAUNCH_FILES] == ["nve_launch.py", "teleop_hardware_launch.py", "teleop_launch.py"]
    variants = ('device="plant", scene_type="nve"', 'device="topic"', 'device="plant"')
    for path, variant in zip(LAUNCH_FILES, variants, strict=True):
        text = path.read_text()
        compile(text, str(path), "exec")
        assert "def generate_launch_description" in text
        assert f"launch_description({variant})" in text


def test_every_launch_argument_is_read_by_the_plan():
    src = (ROOT / "haptic_teleop" / "live/ros2_launch.py").read_text()
    body = src[src.index("def plan_from_arguments") :]
    for name, _, _ in ARGUMENTS + DEVICE_ARGUMENTS + NVE_ARGUMENTS:
        read = (f'arg("{name}")', f'switch_argument(values, "{name}")')
        assert any(r in body for r in read), f"launch argument {name} is declared but not read"


def test_nve_launch_file_plan_is_the_launcher_plan(tmp_path):
    """nve_launch.py's defaults and `set` overrides give `haptic-teleop launch`'s NVE plan: the
    server, one node per client, a relay and a buffer per direction of each client's links."""
    sets = "nve.clients.1.up.effects.delay.delay_s=0.05; nve.clients.1.down.effects.delay.delay_s=0.06"
    defaults = {name: default for name, default, _ in NVE_ARGUMENTS}
    pairs = plan_from_arguments({**defaults, "scene": "nve_two_clients", "set": sets, "seed": "3"}, "plant", tmp_path)
    overrides = [s.strip() for s in sets.split(";")]
    want = node_plan(load_scene(find_scene("nve_two_clients"), overrides=overrides, seed=3))
    assert [s for s, _ in pairs] == want
    assert [s.executable for s in want].count("nve_server") == 1
    assert [s.params.get("client") for s in want if s.executable == "nve_client"] == ["near", "far"]
    relays = {s.params["direction"]: s for s in want if s.executable == "network_relay"}
    assert sorted(relays) == ["far/down", "far/up", "near/down", "near/up"]
    far_down = relays["far/down"].params
    assert far_down["nve"]["clients"]["far"]["down"]["effects"]["delay"]["delay_s"] == 0.06
    assert far_down["nve"]["client_names"] == ["far"] and far_down["task_axes"] == 3
    for spec, path in pairs:
        assert spec.executable in EXECUTABLES
        assert path.read_text() == params_yaml(spec)
    server = yaml.safe_load((tmp_path / "nve_server.yaml").read_text())["nve_server"]["ros__parameters"]
    assert server["nve"]["client_names"] == ["near", "far"] and server["scene"]["seed"] == 3
    assert server["nve"]["clients"]["near"]["coupling"]["server_stiffness_n_per_m"] == 0.5
    assert plan_from_arguments({**defaults}, "plant", tmp_path)[0][0].name == "nve_server"  # default: nve_push


def test_nve_plan_records_with_a_recorder_the_server_waits_for(tmp_path):
    scene = load_scene(find_scene("nve_two_clients"))
    plan = node_plan(scene, record_dir=tmp_path / "rec")
    rec = plan[-1]
    assert rec.executable == "recorder" and rec.params["output_dir"] == str((tmp_path / "rec").resolve())
    assert rec.params["nve"]["client_names"] == ["near", "far"] and "far" in rec.params["nve"]["clients"]
    assert plan[0].params["start"]["min_subscribers"] == 1
    assert node_plan(scene)[0].params["start"]["min_subscribers"] == 0


def test_nve_plan_refuses_what_it_does_not_run_yet():
    scene = load_scene(find_scene("nve_push"))
    with pytest.raises(ConfigError, match="--side"):
        node_plan(scene, side="master")


def test_launch_file_plan_is_the_launcher_plan(tmp_path):
    pairs = plan_from_arguments(
        {"scene": "wall_contact", "record": str(tmp_path / "rec"), "seed": "7"}, "plant", tmp_path
    )
    scene = load_scene(find_scene("wall_contact"), seed=7)
    want = node_plan(scene, record_dir=tmp_path / "rec")
    assert [s for s, _ in pairs] == want
    for spec, path in pairs:
        assert spec.executable in EXECUTABLES
        assert path.read_text() == params_yaml(spec)
        data = yaml.safe_load(path.read_text())
        assert list(data) == [spec.name] and "ros__parameters" in data[spec.name]
    master = next(s for s, _ in pairs if s.name == "master_eba")
    assert master.params["scene"]["seed"] == 7


def test_hardware_variant_has_no_simulated_operator_and_uses_the_driver_topics(tmp_path):
    args = {"scene": "wall_contact", "state_topic": "/dev/js", "command_topic": "/dev/cmd"}
    pairs = plan_from_arguments(args, "topic", tmp_path)
    names = [s.name for s, _ in pairs]
    assert "operator_source" not in names and "master_eba" in names
    master = next(s for s, _ in pairs if s.name == "master_eba")
    assert master.params["device"] == {"source": "topic", "state_topic": "/dev/js", "command_topic": "/dev/cmd"}
    # No operator source: master_eba publishes the scene start, which the relays wait for as usual.
    relays = [s for s, _ in pairs if s.executable == "network_relay"]
    assert len(relays) == 2 and not any("scene_start" in s.params for s in relays)
    # Recorded: scene time 0 waits for the recorder to take every stream of its grid
    recorded = plan_from_arguments({**args, "record": str(tmp_path / "run")}, "topic", tmp_path / "rec")
    master = next(s for s, _ in recorded if s.name == "master_eba")
    assert master.params["device"]["wait_for_recorder"] is True and master.params["device"]["min_subscribers"] == 1


def test_hardware_variant_takes_the_force_command_qos_from_launch_arguments(tmp_path):
    args = {"scene": "wall_contact", "command_reliability": "best_effort", "command_depth": "5"}
    master = next(s for s, _ in plan_from_arguments(args, "topic", tmp_path) if s.name == "master_eba")
    assert master.params["device"]["command_reliability"] == "best_effort"
    assert master.params["device"]["command_depth"] == 5
    yaml_text = params_yaml(master)
    assert 'command_reliability: "best_effort"' in yaml_text and "command_depth: 5" in yaml_text
    for key, value in (("command_reliability", "sometimes"), ("command_depth", "0"), ("command_depth", "x")):
        with pytest.raises(ConfigError) as exc:
            plan_from_arguments({"scene": "wall_contact", key: value}, "topic", tmp_path)
        assert key in str(exc.value)


def test_sim_time_adds_a_clock_and_sets_use_sim_time(tmp_path):
    pairs = plan_from_arguments({"scene": "wall_contact", "sim_time": "true"}, "plant", tmp_path)
    assert pairs[0][0].executable == "clock_source"
    assert all(s.params.get("use_sim_time") is True for s, _ in pairs[1:])
    assert "use_sim_time" not in pairs[0][0].params


@pytest.mark.parametrize(
    ("args", "key"),
    [
        ({"side": "both"}, "side"),
        ({"seed": "x"}, "seed"),
        ({"duration": "long"}, "duration"),
        ({"sim_time": "yes"}, "sim_time"),
        ({"scene": "no_such_scene"}, ""),
    ],
)
def test_bad_launch_arguments_name_what_is_wrong(tmp_path, args, key):
    with pytest.raises(ConfigError) as exc:
        plan_from_arguments({"scene": "wall_contact", **args}, "plant", tmp_path)
    if key:
        assert key in str(exc.value)


def test_parameter_files_write_doubles_as_ros_reads_them():
    assert format_double(1.0) == "1.0"
    assert format_double(1e-8) == "1e-08".replace("1e", "1.0e")
    assert format_double(10000.0) == "10000.0"
    assert format_double(1e20) == "1.0e+20"
    with pytest.raises(ValueError):
        format_double(float("nan"))


def test_hardware_variant_runs_an_arm_scene_on_its_backends_with_set_overrides(tmp_path):
    sets = "slave.backend=dynamixel; slave.hardware.port=/dev/ttyUSB7"
    pairs = plan_from_arguments({"scene": "touch_dynamixel_wall", "set": sets}, "topic", tmp_path)
    slave = next(s for s, _ in pairs if s.name == "slave_eba")
    assert slave.params["slave"]["backend"] == "dynamixel"
    assert slave.params["slave"]["hardware"]["port"] == "/dev/ttyUSB7"
    master = next(s for s, _ in pairs if s.name == "master_eba")
    assert master.params["device"] == {"source": "plant"}  # the arms are the nodes' plants, no device topic
    with pytest.raises(ConfigError) as exc:
        plan_from_arguments({"scene": "touch_dynamixel_wall", "set": "slave.backend=dynamixel"}, "topic", tmp_path)
    assert "slave.hardware.port" in str(exc.value)


def test_a_codec_scene_plans_the_same_processes_in_the_launch_file_and_the_launcher(tmp_path):
    """ARQ on the forward direction (docs/live_network.md, "Codecs live"): the codec direction's relay
    carries codec packets, an ack relay over the backward effects is added (only for ARQ), on the
    slave's side of a two-host setup; the launch file's plan is the launcher's."""
    sets = ["network.forward.codec.kind=arq", "network.backward.codec.kind=deadband"]
    pairs = plan_from_arguments({"scene": "wall_contact", "set": ";".join(sets)}, "plant", tmp_path)
    scene = load_scene(find_scene("wall_contact"), overrides=sets)
    want = node_plan(scene)
    assert [s for s, _ in pairs] == want
    by_name = {s.name: s for s in want}
    assert "forward_ack_relay" in by_name and "backward_ack_relay" not in by_name
    ack = by_name["forward_ack_relay"].params
    assert ack["carries"] == "ack" and ack["direction"] == "forward"
    assert list(ack["network"]) == ["backward"]  # the reverse direction's effects
    assert by_name["forward_relay"].params["carries"] == "codec"
    assert by_name["backward_relay"].params["carries"] == "codec"
    assert by_name["master_eba"].params["network"]["forward"]["codec"]["kind"] == "arq"
    assert by_name["backward_buffer"].params["network"]["backward"]["codec"]["kind"] == "deadband"
    slave = node_plan(scene, side="slave")
    assert "forward_ack_relay" in {s.name for s in slave}
    plain = node_plan(load_scene(find_scene("wall_contact")))
    assert all("carries" not in s.params and "_ack_" not in s.name for s in plain)


def test_nve_launch_file_declares_record_and_its_plan_records(tmp_path):
    """`record:=DIR` is one of nve_launch.py's declared arguments (`ros2 launch -s` lists it) and
    its plan then ends with the recorder, as `haptic-teleop launch nve_push --record DIR`'s."""
    defaults = {name: default for name, default, _ in NVE_ARGUMENTS}
    assert "record" in defaults and defaults["record"] == ""
    pairs = plan_from_arguments({**defaults, "record": str(tmp_path / "rec")}, "plant", tmp_path / "params")
    assert [s for s, _ in pairs] == node_plan(load_scene(find_scene("nve_push")), record_dir=tmp_path / "rec")
    assert pairs[-1][0].executable == "recorder"
    assert plan_from_arguments(defaults, "plant", tmp_path / "p2")[-1][0].executable != "recorder"


def test_a_node_failure_fails_the_launch_and_a_finished_scene_ends_it_cleanly():
    """The launch files' exit rule (ros2_launch.exit_verdict, which their exit handler follows:
    "failed" raises NodeFailed, whose exception makes ROS 2's launch stop every node and return 1):
    a finishing node's exit 0 ends the scene; any node's non-zero exit fails the launch, a node the
    launch's own shutdown killed (SIGINT, SIGTERM) does not, a non-zero exit during shutdown does."""
    from haptic_teleop.live.ros2_launch import FINISHING_NODES, exit_verdict

    assert exit_verdict("operator_source", 0, False) == "finished"
    assert exit_verdict("nve_server", 0, False) == "finished"
    assert set(FINISHING_NODES) == {"operator_source", "nve_server", "composed"}
    for name in ("operator_source", "recorder", "slave_eba", "forward_relay"):
        assert exit_verdict(name, 1, False) == "failed"
        assert exit_verdict(name, 1, True) == "failed"  # the recorder failing to close its bag, say
        assert exit_verdict(name, -9, True) == "failed"
        assert exit_verdict(name, -2, False) == "failed"  # killed by someone else's SIGINT mid-run
        assert exit_verdict(name, -2, True) is None  # stopped by the launch itself
        assert exit_verdict(name, -15, True) is None
    assert exit_verdict("recorder", 0, False) is None and exit_verdict("slave_eba", 0, True) is None
    src = (ROOT / "haptic_teleop" / "live/ros2_launch.py").read_text()
    handler = src[src.index("def on_exit") :]
    assert "exit_verdict(" in handler and "raise NodeFailed(" in handler


def test_the_parameter_folder_is_removed_when_the_launch_process_exits(tmp_path):
    """The launch files' and `haptic-teleop launch`'s parameter folder (launcher.temporary_params_dir)."""
    import subprocess
    import sys

    code = "from haptic_teleop.live.launcher import temporary_params_dir; p = temporary_params_dir(); "
    code += "(p / 'x.yaml').write_text('a: 1'); print(p)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    folder = Path(r.stdout.strip())
    assert folder.name.startswith("haptic_teleop_params_") and not folder.exists()


# ---------------------------------------------------------------------------------------------
# single_process:=true: the whole plan composed in one process (live/composed.py).


def _launch_file_variant(path: Path) -> dict[str, str]:
    """The keyword arguments a launch file passes to `launch_description` (read, not run)."""
    import ast

    call = next(
        n
        for n in ast.walk(ast.parse(path.read_text()))
        if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "launch_description"
    )
    return {k.arg: ast.literal_eval(k.value) for k in call.keywords if k.arg}


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_every_launch_file_declares_single_process_false_by_default(path):
    """`ros2 launch -s` lists it: it is in the table `launch_description` declares for that file."""
    from haptic_teleop.live.ros2_launch import argument_table

    table = {name: (default, text) for name, default, text in argument_table(**_launch_file_variant(path))}
    assert "single_process" in table, sorted(table)
    default, text = table["single_process"]
    assert default == "false" and "one process" in text


@pytest.mark.parametrize("value", ["yes", "1", "composed", "truee"])
def test_a_bad_single_process_value_is_one_config_error_line_before_anything_is_written(tmp_path, value):
    from haptic_teleop.live.ros2_launch import launch_processes

    with pytest.raises(ConfigError) as exc:
        launch_processes({"scene": "wall_contact", "single_process": value}, "plant", tmp_path / "params")
    text = str(exc.value)
    assert "\\n" not in text and "single_process" in text and "allowed: true or false" in text, text
    assert not (tmp_path / "params").exists()  # no parameter file, no plan file


@pytest.mark.parametrize(
    ("device", "args"),
    [
        ("plant", {"scene": "wall_contact", "duration": "2.5", "sim_time": "true"}),
        ("topic", {"scene": "touch_dynamixel_wall", "set": "slave.backend=dynamixel;slave.hardware.port=/dev/ttyUSB7"}),
        ("plant", {"scene": "nve_two_clients", "seed": "3"}),
    ],
    ids=["teleop", "hardware", "nve"],
)
def test_single_process_starts_one_composed_process_with_every_nodes_parameter_file(tmp_path, device, args):
    """With `single_process:=true` the launch starts one process: the `composed` console script,
    given the plan file written next to the parameter files of every node of the plan (the same
    files, byte for byte, as one process per node gets), and no node name, parameter file or
    remapping as ROS arguments (they would apply to every node in it)."""
    from haptic_teleop.live.composed import read_plan
    from haptic_teleop.live.launcher import write_params_files
    from haptic_teleop.live.ros2_launch import COMPOSED, launch_processes

    record = {"record": str(tmp_path / "rec")}
    per_node = launch_processes({**args, **record}, device, tmp_path / "nodes")
    plan = [s for s, _ in plan_from_arguments({**args, **record}, device, tmp_path / "plan")]
    assert [p.node_name for p in per_node] == [s.name for s in plan] and len(per_node) > 1
    for p, spec in zip(per_node, plan, strict=True):
        assert p.command() == [spec.executable, "--ros-args", "-r", f"__node:={spec.name}", "--params-file",
                               str(tmp_path / "nodes" / f"{spec.name}.yaml")]  # fmt: skip

    folder = tmp_path / "composed"
    (process,) = launch_processes({**args, **record, "single_process": "True "}, device, folder)
    assert process.label == process.executable == COMPOSED
    plan_file = folder / "composed_plan.json"
    assert process.command() == [COMPOSED, str(plan_file), "--ros-args"]
    assert process.node_name is None and process.params_file is None and process.remaps == ()
    # every node of the plan, the recorder included (JSON gives lists for tuples: the same YAML)
    assert [(s.name, s.executable, params_yaml(s), s.remaps) for s in read_plan(plan_file)] == [
        (s.name, s.executable, params_yaml(s), s.remaps) for s in plan
    ]
    files = {p.stem: p.read_text() for p in folder.glob("*.yaml")}
    assert files == {p.node_name: Path(str(p.params_file)).read_text() for p in per_node}
    # what the composed process gives its nodes (run_single_process: write_params_files in the
    # plan file's folder) are those very files
    rewritten = write_params_files(read_plan(plan_file), tmp_path / "rewritten")
    assert {name: path.read_text() for name, path in rewritten.items()} == files
    assert process.sigterm_timeout_s is not None and process.sigterm_timeout_s > 5.0  # the bag gets closed


def test_the_composed_executable_is_a_console_script_of_the_package():
    """`ros2 run haptic_teleop composed PLAN` and launch_ros's Node find it in lib/haptic_teleop."""
    from haptic_teleop.live.ros2_launch import COMPOSED

    setup = (ROOT / "setup.py").read_text()
    assert f'"{COMPOSED} = haptic_teleop.live.composed:main"' in setup
    assert COMPOSED not in EXECUTABLES  # not a node: `haptic-teleop launch` never starts it as one


def test_single_process_refuses_a_plan_with_remappings(tmp_path, monkeypatch):
    """run_single_process gives each node its parameter file only: a plan that remaps topics is
    refused in one line (launch argument) and by the composed process itself, not run unremapped."""
    import dataclasses

    from haptic_teleop.live import ros2_launch
    from haptic_teleop.live.composed import main, write_plan

    real = ros2_launch.plan_from_arguments

    def remapped(values, device, folder, warm=False):
        pairs = real(values, device, folder, warm)
        return [(dataclasses.replace(pairs[0][0], remaps=(("/a", "/b"),)), pairs[0][1]), *pairs[1:]]

    monkeypatch.setattr(ros2_launch, "plan_from_arguments", remapped)
    with pytest.raises(ConfigError, match="single_process") as exc:
        ros2_launch.launch_processes({"scene": "wall_contact", "single_process": "true"}, "plant", tmp_path)
    assert "operator_source" in str(exc.value)
    assert ros2_launch.launch_processes({"scene": "wall_contact"}, "plant", tmp_path)[0].remaps == (("/a", "/b"),)
    plan = [s for s, _ in remapped({"scene": "wall_contact"}, "plant", tmp_path)]
    assert main([str(write_plan(plan, tmp_path / "p")), "--ros-args"]) == 2


def test_the_composed_process_refuses_a_missing_or_bad_plan_file(tmp_path, capsys):
    from haptic_teleop.live.composed import main

    assert main([str(tmp_path / "none.json")]) == 2
    (tmp_path / "bad.json").write_text('{"format": 1, "nodes": [{"name": "x"}]}')
    assert main([str(tmp_path / "bad.json"), "--ros-args", "-r", "__ns:=/x"]) == 2
    err = capsys.readouterr().err
    assert "none.json" in err and "node 0 needs name, executable, params" in err


def test_the_exit_of_the_composed_process_finishes_fails_or_is_the_launchs_own_stop():
    """The composed process exits 0 when its scene is over (the launch ends, 0), non-zero on a
    failure (NodeFailed: the launch exits 1) and 130 / 143 when the launch's own shutdown stopped it
    with SIGINT / SIGTERM (-2 / -15 before its nodes took the signals over): not a failure then."""
    from haptic_teleop.live.ros2_launch import COMPOSED, STOPPED_BY_SHUTDOWN, exit_verdict

    assert exit_verdict(COMPOSED, 0, False) == "finished"
    for code in (1, 2, -9, -11):
        assert exit_verdict(COMPOSED, code, False) == "failed"
        assert exit_verdict(COMPOSED, code, True) == "failed"
    for code in (130, 143, -2, -15):
        assert code in STOPPED_BY_SHUTDOWN
        assert exit_verdict(COMPOSED, code, True) is None
        assert exit_verdict(COMPOSED, code, False) == "failed"  # someone else's signal mid-run


def _composed(args: dict[str, str], folder: Path) -> Child:
    """`python -m haptic_teleop.live.composed PLAN --ros-args` as launch_ros starts the console
    script, on the files `plan_from_arguments` wrote (this module's ROS domain, DDS on this host)."""
    from haptic_teleop.live.ros2_launch import launch_processes

    (process,) = launch_processes({**args, "single_process": "true"}, "plant", folder)
    cmd = process.command()
    assert cmd[0] == "composed"
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    return Child([sys.executable, "-m", "haptic_teleop.live.composed", *cmd[1:]], env=env)


def test_the_composed_process_runs_the_launch_plan_to_the_end_and_writes_the_bag(tmp_path):
    """wall_contact for 1.5 s of scene, composed from the launch files' plan: exit 0 (the launch
    ends, 0) and the recorder's bag closed and readable."""
    from haptic_teleop.live.ros2_launch import COMPOSED, exit_verdict
    from haptic_teleop.record.reader import BagReader

    out = tmp_path / "rec"
    run = _composed({"scene": "wall_contact", "duration": "1.5", "record": str(out)}, tmp_path / "params")
    code = run.finish(300)
    assert code == 0, run.text
    assert exit_verdict(COMPOSED, code, False) == "finished"
    assert "loops (whole run):" in run.text and "Traceback" not in run.text
    assert (out / "bag" / "metadata.yaml").is_file()
    with BagReader(out / "bag") as bag:
        master = bag.read("/master/joint_states")
        slave = bag.read("/slave/joint_states")
    assert len(master.stamp_ns) > 0 and len(slave.stamp_ns) > 0


def test_sigint_to_the_composed_process_stops_it_as_the_launchs_shutdown_expects(tmp_path):
    """SIGINT mid-scene (what `ros2 launch` sends on shutdown): the nodes stop, the recorder closes
    its bag last, and the exit code is one `exit_verdict` takes for the launch's own stop."""
    import signal

    from haptic_teleop.live.ros2_launch import COMPOSED, STOPPED_BY_SHUTDOWN, exit_verdict

    out = tmp_path / "rec"
    run = _composed({"scene": "wall_contact", "duration": "120", "record": str(out)}, tmp_path / "params")
    run.wait_for(r"\[operator_source\]: scene time 0 at stamp", 240)
    wait_for_bag_messages(out / "bag", 120)
    run.proc.send_signal(signal.SIGINT)
    code = run.finish(180)
    assert code == 128 + signal.SIGINT, run.text  # 130
    assert code in STOPPED_BY_SHUTDOWN and exit_verdict(COMPOSED, code, True) is None
    assert exit_verdict(COMPOSED, code, False) == "failed"  # not the launch's: a failure
    assert (out / "bag" / "metadata.yaml").is_file(), run.text
    assert "Traceback" not in run.text


# The compiled side tick, built in the launch's own process before any node starts (issue: a
# fresh install's first arm launch timed out while a node compiled it).
_WARM_PROBE = """
import sys

from haptic_teleop.assembly import compiled_side
from haptic_teleop.live.ros2_launch import launch_processes

values = dict(scene=sys.argv[1], set=sys.argv[2])
launch_processes(values, "topic", sys.argv[3], warm=sys.argv[4] == "warm")
print("signatures", len(compiled_side.side_kernel().side_tick.signatures))
"""


def test_the_launch_builds_an_arm_scenes_side_tick_before_any_node_starts(tmp_path):
    """`launch_processes` (what the launch files run) builds the simulated side's compiled tick in
    the launch's own process (compiles it, saying so, on an empty numba cache: `warm_saying`, as
    test_live_arm's first-launch test sees for `haptic-teleop launch`; else loads it), so that no
    node compiles it within its start timeout; here with a real arm on the slave (its port is never
    opened: /dev/ttyUSB7 does not exist here), the simulated master's tick. Without the warm step
    nothing is built there."""
    env = dict(os.environ)
    scene, overrides = "touch_dynamixel_wall", "slave.backend=dynamixel;slave.hardware.port=/dev/ttyUSB7"
    runs = {}
    for mode in ("cold", "warm"):
        cmd = [sys.executable, "-c", _WARM_PROBE, scene, overrides, str(tmp_path / mode), mode]
        runs[mode] = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
        assert runs[mode].returncode == 0, runs[mode].stderr[-3000:]
    assert "signatures 0" in runs["cold"].stdout, runs["cold"].stdout
    assert "signatures 1" in runs["warm"].stdout, runs["warm"].stdout


def test_the_loop_table_says_what_its_packet_counts_are_beside_the_summary():
    """The launcher's loop table counts a relay's and a buffer's packets over each node's whole life
    (before scene time 0 too), the summary from scene time 0 on: the table says so under its rows
    when it shows packet counts, and not otherwise."""
    from haptic_teleop.live.launcher import LOOP_TABLE_LEGEND, format_loop_table

    loop = {"loop_rate_hz": 1000.0, "ticks": 5000, "late_ticks": 0, "skipped_ticks": 0}
    figures = {
        "master_eba": dict(loop),
        "forward_relay": {**loop, "delivered": 4990, "lost": 0},
        "forward_buffer": {**loop, "released": 4980, "late": 3},
    }
    table = format_loop_table(list(figures), figures)
    assert table.startswith("loops (whole run):") and table.endswith(LOOP_TABLE_LEGEND)
    assert "4990 delivered, 0 lost" in table and "4980 released, 3 late" in table
    assert "scene time 0" in LOOP_TABLE_LEGEND and "summary" in LOOP_TABLE_LEGEND
    bare = format_loop_table(["master_eba"], {"master_eba": loop})
    assert LOOP_TABLE_LEGEND not in bare
