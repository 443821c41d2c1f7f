"""The ROS 2 launch files and the launcher build one node plan from one scene file.

ROS 2's `launch` cannot be installed here, so the launch files themselves are checked for what
they consume (their arguments) and `ros2_launch.plan_from_arguments`, which they call, is
checked against the plan `haptic-teleop launch` starts.
"""

from pathlib import Path

import pytest
import yaml

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
        assert f'arg("{name}")' in body, f"launch argument {name} is declared but not read"


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
    # No operator source publishes the scene start: the relays' links start at their first sample.
    relays = [s for s, _ in pairs if s.executable == "network_relay"]
    assert len(relays) == 2 and all(s.params["scene_start"] == "first_sample" for s in relays)
    plant = plan_from_arguments({"scene": "wall_contact"}, "plant", tmp_path / "plant")
    assert not any("scene_start" in s.params for s, _ in plant if s.executable == "network_relay")


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
    """ARQ on the forward direction (docs/live.md, "Codecs live"): the codec direction's relay
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
    assert set(FINISHING_NODES) == {"operator_source", "nve_server"}
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
