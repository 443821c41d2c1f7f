"""The command line: Ctrl-C and SIGTERM at every phase, bad input (exit 2, one line), and what users reach for."""

import filecmp
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from haptic_teleop.cli.main import main
from haptic_teleop.record.reader import BagReader
from haptic_teleop.scene.load import bundled_scenes, find_scene, load_scene

CLI = [sys.executable, "-m", "haptic_teleop.cli"]
SHORT = ["--set", "scene.duration_s=1.0"]


# --- signals ---------------------------------------------------------------------------------------


def _run_until_phase(out: Path, phase: str, extra: list[str], pause: str | None = None) -> subprocess.Popen:
    env = dict(os.environ, PYTHONUNBUFFERED="1", HAPTIC_TELEOP_TEST_PAUSE=pause or phase)
    p = subprocess.Popen(
        [*CLI, "run", "wall_contact", "--out", str(out), *SHORT, *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert p.stderr is not None
    seen = []
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:  # a generous timeout while waiting for the marker, not a timing
        line = p.stderr.readline()
        if not line:
            break
        seen.append(line)
        if f"haptic-teleop: phase {phase}" in line:  # after a progress bar, maybe on its line
            return p
    p.kill()
    pytest.fail(f"no phase line {phase!r}; stderr: {''.join(seen)}")


def _finish(p: subprocess.Popen) -> tuple[str, str]:
    stdout, stderr = p.communicate(timeout=240)
    return stdout, stderr


def _bag_ticks(bag: Path) -> tuple[int, dict]:
    with BagReader(bag) as r:
        n = len(r.read("/master/joint_states").log_ns)
        info = json.loads(r.string("/haptic_teleop/run_info"))
    return n, info


@pytest.mark.parametrize(
    ("phase", "sig"),
    [
        ("startup", signal.SIGINT),
        ("startup", signal.SIGTERM),
        ("scene", signal.SIGINT),
        ("engine", signal.SIGTERM),
        ("loop", signal.SIGINT),
        ("loop", signal.SIGTERM),
        ("summary", signal.SIGINT),
        ("summary", signal.SIGTERM),
        ("plots", signal.SIGINT),
    ],
)
def test_signal_at_any_phase_exits_cleanly_with_what_ran(tmp_path, phase, sig):
    out = tmp_path / "run"
    plots = phase == "plots"
    p = _run_until_phase(out, phase, [] if plots else ["--no-plots"])
    p.send_signal(sig)
    stdout, stderr = _finish(p)
    assert p.returncode == (130 if sig == signal.SIGINT else 143), stderr
    assert "Traceback" not in stderr
    if phase in ("startup", "scene"):
        assert not out.exists()  # nothing was written before the run started
        assert "before anything was written" in stderr
        return
    n, info = _bag_ticks(out / "bag")  # closed and readable
    summary = json.loads((out / "summary.json").read_text())
    if phase in ("engine", "loop"):
        assert info["interrupted"] is True and summary["interrupted"] is True
        assert 0 < n < 1000
        assert "(interrupted)" in stdout
    else:  # the loop had ended: everything after it is still written, complete
        assert info["interrupted"] is False and summary["interrupted"] is False
        assert n == 1000
    assert (out / "scene.yaml").is_file() and (out / "timing.json").is_file()
    if plots:
        assert (out / "plots" / "forces.png").stat().st_size > 0


def test_a_second_signal_aborts_at_once_without_a_traceback(tmp_path):
    out = tmp_path / "run"
    p = _run_until_phase(out, "summary", ["--no-plots"], pause="summary:2")
    p.send_signal(signal.SIGINT)
    p.send_signal(signal.SIGTERM)
    _, stderr = _finish(p)
    assert p.returncode == 130, stderr  # the first signal names the exit code
    assert "Traceback" not in stderr and "aborted by a second signal" in stderr
    n, _ = _bag_ticks(out / "bag")  # the bag had been closed before
    assert n == 1000
    assert not (out / "summary.json").exists()  # no half-written summary
    assert not list(out.glob(".*.tmp"))


def _popen_until_phase(argv: list[str], phase: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONUNBUFFERED="1", HAPTIC_TELEOP_TEST_PAUSE=phase)
    p = subprocess.Popen([*CLI, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    assert p.stderr is not None
    seen = []
    for line in p.stderr:
        seen.append(line)
        if f"haptic-teleop: phase {phase}" in line:
            return p
    p.kill()
    pytest.fail(f"no phase line {phase!r}; stderr: {''.join(seen)}")


def test_sigint_in_a_sweep_keeps_the_runs_done(tmp_path):
    out = tmp_path / "sweep"
    argv = ["sweep", "wall_contact", "--set", "scene.duration_s=0.3", "--param", "scene.seed=1,2,3", "--out", str(out)]
    p = _popen_until_phase([*argv, "--no-plots", "--workers", "1"], "sweep-run")  # after the first run
    p.send_signal(signal.SIGINT)
    _, stderr = p.communicate(timeout=240)
    assert p.returncode == 130, stderr
    assert "Traceback" not in stderr and "sweep interrupted after 1 of 3 runs" in stderr
    lines = (out / "sweep.csv").read_text().splitlines()
    assert len(lines) == 2  # header and the one run done
    run_hash = lines[1].split(",")[lines[0].split(",").index("run_hash")]
    assert [d.name for d in (out / "runs").iterdir()] == [run_hash]


def test_sigterm_in_analyze_still_writes_the_summary(tmp_path, small_bag):
    out = tmp_path / "an"
    p = _popen_until_phase(["analyze", str(small_bag), "--out", str(out), "--no-plots"], "summary")
    p.send_signal(signal.SIGTERM)
    _, stderr = p.communicate(timeout=240)
    assert p.returncode == 143, stderr
    assert "Traceback" not in stderr
    assert json.loads((out / "summary.json").read_text())["interrupted"] is False


# --- bad input: exit 2, one line naming the problem, no traceback ---------------------------------


def _main_err(capsys, argv) -> tuple[int, str]:
    code = main(argv)
    err = capsys.readouterr().err
    return code, err


def _one_line(err: str) -> str:
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_binary_scene_file_is_a_config_error(tmp_path):
    scene = tmp_path / "bin.yaml"
    scene.write_bytes(b"scene:\n  name: x\n\xff\xfe\x00\x81 binary")
    r = subprocess.run([*CLI, "run", str(scene), "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert r.returncode == 2
    line = _one_line(r.stderr)
    assert str(scene) in line and "line 3" in line and "UTF-8" in line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n"])
def test_empty_scene_file_is_an_error(tmp_path, capsys, text):
    scene = tmp_path / "empty.yaml"
    scene.write_text(text)
    code, err = _main_err(capsys, ["run", str(scene), "--out", str(tmp_path / "o")])
    assert code == 2
    assert "the file is empty" in _one_line(err) and str(scene) in err
    assert not (tmp_path / "o").exists()


def test_an_explicit_empty_mapping_is_the_default_scene(tmp_path):
    scene = tmp_path / "braces.yaml"
    scene.write_text("{}\n")
    assert load_scene(scene).config.scene.name == "scene"


def test_duplicate_keys_are_errors_naming_key_and_both_lines(tmp_path, capsys):
    scene = tmp_path / "dup.yaml"
    scene.write_text("scene:\n  name: a\n  duration_s: 1.0\nslave:\n  mass_kg: 1.0\n  mass_kg: 2.0\n")
    code, err = _main_err(capsys, ["run", str(scene), "--dry-run"])
    assert code == 2
    line = _one_line(err)
    assert "'mass_kg'" in line and "lines 5 and 6" in line and str(scene) in line
    scene.write_text("scene: {name: a}\nscene: {name: b}\n")
    code, err = _main_err(capsys, ["run", str(scene), "--dry-run"])
    assert code == 2 and "'scene'" in err and "lines 1 and 2" in err


@pytest.mark.parametrize(
    ("text", "expect"),
    [
        ("- 1\n- 2\n", "a mapping of sections"),
        ("just a string\n", "a mapping of sections"),
        ("scene: {duration_s: .nan}\n", "finite"),
        ("scene: {duration_s: 1e999}\n", "finite"),
        ("master: {mass_kg: " + "9" * 400 + "}\n", "finite"),
        ("scene: {seed: " + "9" * 30 + "}\n", "<= 9223372036854775807"),
        ("scene: [unclosed\n", "not valid YAML"),
        ("scene: {a: 1}\n---\nscene: {}\n", "not valid YAML"),
        ("slave: {mass_kg: 5.0e-324}\n", "out of range together"),
    ],
)
def test_malformed_scene_documents_exit_2(tmp_path, capsys, text, expect):
    scene = tmp_path / "bad.yaml"
    scene.write_text(text)
    code, err = _main_err(capsys, ["run", str(scene), "--dry-run"])
    assert code == 2
    assert expect in _one_line(err)


def test_scene_path_that_is_a_directory(tmp_path, capsys):
    code, err = _main_err(capsys, ["run", str(tmp_path), "--dry-run"])
    assert code == 2 and "is a directory" in _one_line(err)


def test_bad_set_key_is_blamed_on_the_set_argument(capsys):
    code, err = _main_err(capsys, ["run", "wall_contact", "--dry-run", "--set", "slave.wall.stifness=1"])
    assert code == 2
    line = _one_line(err)
    assert "--set slave.wall.stifness=1: slave.wall.stifness" in line and "unknown key" in line
    assert "wall_contact.yaml" not in line
    code, err = _main_err(capsys, ["run", "wall_contact", "--dry-run", "--set", "master.mass_kg=-2"])
    assert code == 2 and "--set master.mass_kg=-2: master.mass_kg = -2" in err
    code, err = _main_err(capsys, ["run", "wall_contact", "--dry-run", "--set", "nosuchsection.key=1"])
    assert code == 2 and "--set nosuchsection.key=1: nosuchsection" in err
    # A contradiction between a --set value and the file's keys names both.
    code, err = _main_err(capsys, ["run", "wall_contact", "--dry-run", "--set", "slave.wall.position_m=-1"])
    assert code == 2 and "wall_contact.yaml with --set slave.wall.position_m=-1" in err


@pytest.mark.parametrize("seed", ["-1", str(2**63)])
def test_seed_out_of_range_is_blamed_on_the_seed_flag(capsys, seed):
    code, err = _main_err(capsys, ["run", "wall_contact", "--dry-run", "--seed", seed])
    assert code == 2 and _one_line(err).startswith(f"haptic-teleop: config error: --seed {seed}: scene.seed")


def _sweep(out: Path) -> list[str]:
    return ["sweep", "wall_contact", *SHORT, "--param", "scene.seed=1,2", "--out", str(out)]


def _commands(out: Path, bag: Path) -> dict[str, list[str]]:
    return {
        "run": ["run", "wall_contact", *SHORT, "--out", str(out)],
        "analyze": ["analyze", str(bag), "--out", str(out)],
        "sweep": _sweep(out),
    }


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bag") / "run"
    assert main(["run", "wall_contact", "--set", "scene.duration_s=0.3", "--out", str(out), "--quiet"]) == 0
    return out / "bag"


@pytest.mark.parametrize("command", ["run", "analyze", "sweep"])
def test_out_that_is_a_file_exits_2_before_anything_runs(tmp_path, capsys, small_bag, command):
    target = tmp_path / "a_file"
    target.write_text("keep me\n")
    code, err = _main_err(capsys, _commands(target, small_bag)[command])
    assert code == 2
    line = _one_line(err)
    assert f"--out {target}: is a file" in line
    assert target.read_text() == "keep me\n"


def _unwritable(tmp_path: Path) -> Path:
    if os.geteuid() == 0:  # root writes anywhere mode bits forbid: use a filesystem that refuses
        return Path("/sys/haptic_teleop_test_out")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    return ro / "out"


@pytest.mark.parametrize("command", ["run", "analyze", "sweep"])
def test_unwritable_out_exits_2_before_anything_runs(tmp_path, capsys, small_bag, command):
    target = _unwritable(tmp_path)
    code, err = _main_err(capsys, _commands(target, small_bag)[command])
    assert code == 2
    assert f"--out {target}: cannot write there" in _one_line(err)
    assert not target.exists()


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_out_not_empty_exits_2(tmp_path, capsys, small_bag, command):
    (tmp_path / "x").write_text("")
    code, err = _main_err(capsys, _commands(tmp_path, small_bag)[command])
    assert code == 2 and "not empty" in _one_line(err)


def test_analyze_a_bag_that_does_not_exist_exits_2(tmp_path, capsys):
    code, err = _main_err(capsys, ["analyze", str(tmp_path / "nope")])
    assert code == 2 and "no such bag" in _one_line(err)
    assert not (tmp_path / "nope").exists()


def test_analyze_never_writes_over_a_runs_summary_without_force(tmp_path, capsys, small_bag):
    """`analyze RUN/bag` would write RUN/summary.json, the run's own: refused (exit 2, one line naming
    --out and --force) and left as it was; --force writes it again, the same."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(small_bag.parent, run)
    before = (run / "summary.json").read_bytes()
    code, err = _main_err(capsys, ["analyze", str(run / "bag"), "--no-plots"])
    line = _one_line(err)
    assert code == 2 and "--force" in line and "--out" in line and "summary.json exists" in line
    assert (run / "summary.json").read_bytes() == before
    (run / "summary.json").write_text("{}")
    assert main(["analyze", str(run / "bag"), "--no-plots", "--force", "--quiet"]) == 0
    assert json.loads((run / "summary.json").read_text()) == json.loads(before)


def test_a_serial_port_that_does_not_exist_is_refused_before_anything_is_written(tmp_path, capsys):
    """A wrong port is found before the engine is built: one line naming the key and the port,
    exit 2, and --out is not made."""
    out = tmp_path / "run"
    code, err = _main_err(capsys, ["run", "touch_dynamixel_wall", "--set", "slave.backend=dynamixel",
                                   "--set", "slave.hardware.port=/dev/ttyUSB_not_here", "--out", str(out)])  # fmt: skip
    line = _one_line(err)
    assert code == 2 and "slave.hardware.port" in line and "/dev/ttyUSB_not_here" in line and "does not exist" in line
    assert not out.exists()


def test_a_port_that_is_no_serial_port_is_refused_before_anything_is_written(tmp_path, capsys):
    """A port that exists but does not open as a serial port (/dev/null) is found before the engine
    is built too: the driver's own reason in one line, exit 2, no --out."""
    pytest.importorskip("dynamixel_sdk")
    out = tmp_path / "run"
    code, err = _main_err(capsys, ["run", "touch_dynamixel_wall", "--set", "slave.backend=dynamixel",
                                   "--set", "slave.hardware.port=/dev/null", "--out", str(out)])  # fmt: skip
    line = _one_line(err)
    assert code == 2 and "slave.hardware.port" in line and "/dev/null" in line and "cannot be opened" in line
    assert not out.exists()


@pytest.mark.parametrize("out_exists", [False, True], ids=["new_out", "empty_out"])
def test_a_start_that_fails_leaves_out_as_it_was(tmp_path, capsys, out_exists):
    """A port that opens but where no servo answers (a pseudo-terminal nobody serves) fails at the
    start, after the engine was built: one line, exit 1, and --out as it was before (absent, or
    empty), so the same command runs again once the servos answer."""
    pytest.importorskip("dynamixel_sdk")
    import os

    master_fd, slave_fd = os.openpty()
    try:
        out = tmp_path / "run"
        if out_exists:
            out.mkdir()
        code, err = _main_err(capsys, ["run", "touch_dynamixel_wall", "--set", "slave.backend=dynamixel",
                                       "--set", f"slave.hardware.port={os.ttyname(slave_fd)}", "--no-plots",
                                       "--quiet", "--out", str(out)])  # fmt: skip
    finally:
        os.close(master_fd)
        os.close(slave_fd)
    line = _one_line(err)
    assert code == 1 and "answer" in line, err
    assert out.exists() == out_exists and (not out_exists or not any(out.iterdir()))


# --- what users reach for --------------------------------------------------------------------------


def test_version(capsys):
    from haptic_teleop import __version__

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"haptic-teleop {__version__}"


def test_scenes_lists_every_bundled_scene_with_its_description(capsys):
    assert main(["scenes"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = [name for name, _ in bundled_scenes()]
    assert "wall_contact" in names and len(lines) == len(names)
    for line, name in zip(lines, names, strict=True):
        first, _, desc = line.partition(" ")
        assert first == name and len(desc.strip()) > 20
        assert find_scene(name).is_file()


def test_dry_run_prints_the_resolved_scene_and_writes_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "wall_contact", "--dry-run", "--set", "scene.duration_s=2.5", "--seed", "7"]) == 0
    resolved = yaml.safe_load(capsys.readouterr().out)
    assert resolved["scene"]["duration_s"] == 2.5 and resolved["scene"]["seed"] == 7
    assert resolved["slave"]["wall"]["stiffness_n_per_m"] == 1e4  # defaults filled in
    assert list(tmp_path.iterdir()) == []


def test_the_saved_scene_reproduces_the_same_bag(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    sets = ["--set", "scene.duration_s=0.5", "--set", "network.forward.effects.loss.probability=0.2", "--seed", "5"]
    assert main(["run", "wall_contact", *sets, "--out", str(a), "--quiet", "--no-plots"]) == 0
    assert main(["run", str(a / "scene.yaml"), "--out", str(b), "--quiet", "--no-plots"]) == 0
    assert filecmp.cmp(a / "bag" / "bag.mcap", b / "bag" / "bag.mcap", shallow=False)
    assert (a / "bag" / "metadata.yaml").read_text() == (b / "bag" / "metadata.yaml").read_text()
    assert (a / "scene.yaml").read_text() == (b / "scene.yaml").read_text()


@pytest.mark.parametrize("name", [name for name, _ in bundled_scenes()])
def test_every_bundled_scene_resolves_to_a_scene_that_loads_the_same(tmp_path, name):
    first = load_scene(find_scene(name))
    saved = tmp_path / "scene.yaml"
    saved.write_text(first.to_yaml())
    again = load_scene(saved)
    assert again.config == first.config and again.to_yaml() == first.to_yaml()


def test_quiet_prints_nothing_but_errors(tmp_path, small_bag):
    out = tmp_path / "run"
    for argv in (
        ["run", "wall_contact", "--set", "scene.duration_s=0.3", "--out", str(out), "--quiet", "--no-plots"],
        ["analyze", str(small_bag), "--out", str(tmp_path / "an"), "--quiet", "--no-plots"],
        [*_sweep(tmp_path / "sw"), "--quiet", "--no-plots"],
    ):
        r = subprocess.run([*CLI, *argv], capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        assert (r.stdout, r.stderr) == ("", ""), argv[0]
    r = subprocess.run([*CLI, "run", "nonexistent_scene", "--quiet"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stdout == "" and "nonexistent_scene" in r.stderr


def test_a_missing_model_file_is_a_config_error_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "o"
    code, err = _main_err(capsys, ["run", "wall_contact", "--set", "master.model=nope.xml", "--out", str(out)])
    assert code == 2
    assert "--set master.model=nope.xml: master.model = 'nope.xml': no such model file" in _one_line(err)
    assert not out.exists()


def test_the_saved_scene_finds_relative_trace_files_from_anywhere(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    (src / "hand.csv").write_text("time_s,position_m\n0.0,0.0\n1.0,0.01\n2.0,0.02\n")
    (src / "scene.yaml").write_text("scene: {duration_s: 1.0}\noperator: {profile: trace, trace_file: hand.csv}\n")
    first = load_scene(src / "scene.yaml")
    saved = tmp_path / "elsewhere" / "scene.yaml"
    saved.parent.mkdir()
    saved.write_text(first.to_yaml())
    again = load_scene(saved)
    assert again.operator_trace == first.operator_trace and again.to_yaml() == first.to_yaml()


@pytest.mark.parametrize(
    ("content", "expect"),
    [
        (b"time_s,position_m\n0,0\n\xff\xfe,1\n", "not UTF-8"),
        (b"0,0\n1,nan\n2,0.01\n", "finite numbers"),
        (b"0,0\n1,0\x00\n", "two numbers"),
    ],
)
def test_a_bad_operator_trace_file_is_a_config_error(tmp_path, capsys, content, expect):
    (tmp_path / "hand.csv").write_bytes(content)
    scene = tmp_path / "scene.yaml"
    scene.write_text("operator: {profile: trace, trace_file: hand.csv}\n")
    code, err = _main_err(capsys, ["run", str(scene), "--dry-run"])
    assert code == 2 and expect in _one_line(err)


def test_version_falls_back_to_the_package_version_when_not_installed(monkeypatch):
    import importlib.metadata

    from haptic_teleop import __version__
    from haptic_teleop.cli.main import package_version

    def missing(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", missing)
    assert package_version() == __version__


def test_compression_flag_writes_a_compressed_bag_that_analyses_the_same(tmp_path, capsys):
    """`run --compression zstd`: the chunks are zstd (bag info says so), the file is smaller, and
    the metrics are those of the uncompressed run."""
    base = ["run", "wall_contact", "--set", "scene.duration_s=0.5", "--no-plots", "--quiet"]
    assert main([*base, "--out", str(tmp_path / "plain")]) == 0
    assert main([*base, "--out", str(tmp_path / "zstd"), "--compression", "zstd"]) == 0
    capsys.readouterr()
    assert main(["bag", "info", str(tmp_path / "zstd" / "bag")]) == 0
    assert "(compression: zstd)" in capsys.readouterr().out
    plain = next((tmp_path / "plain" / "bag").glob("*.mcap")).stat().st_size
    packed = next((tmp_path / "zstd" / "bag").glob("*.mcap")).stat().st_size
    assert packed < plain / 2
    a = json.loads((tmp_path / "plain" / "summary.json").read_text())
    b = json.loads((tmp_path / "zstd" / "summary.json").read_text())
    a.pop("realtime_factor"), b.pop("realtime_factor")
    assert a == b
    assert yaml.safe_load((tmp_path / "zstd" / "scene.yaml").read_text())["recording"]["compression"] == "zstd"


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "speed", "--repeat", "0"],
        ["bench", "effects", "--duration-s", "-1"],
        ["bench", "recording", "--rounds", "x"],
        ["bench", "network", "--packets", "0"],
        ["bench", "live", "--duration", "nan"],
        ["bench", "codec", "--samples", "0"],
    ],
)
def test_bench_arguments_are_checked_before_anything_runs(capsys, argv):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "allowed:" in err and "> 0" in err and "Traceback" not in err


def test_a_compile_is_announced_only_when_numba_really_compiles(tmp_path, monkeypatch):
    """`first_compile` tells `compiling.compile_notice` which kernel it is about to compile when
    numba's cache has none for its source, and says nothing when it loads the cache; the command
    line's text names the kernel, why, about how long and `haptic-teleop compile`."""
    import importlib
    import sys as _sys

    from haptic_teleop import compiling
    from haptic_teleop.cli.main import compile_notice

    (tmp_path / "tiny_kernel.py").write_text(
        "from numba import njit\n\n@njit(cache=True)\ndef add(a, b):\n    return a + b\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    said: list[str] = []
    monkeypatch.setattr(compiling, "compile_notice", said.append)
    mod = importlib.import_module("tiny_kernel")
    with compiling.first_compile(mod.add):
        assert mod.add(1, 2) == 3
    assert said == ["tiny_kernel"]  # cold: compiled, and said so
    del _sys.modules["tiny_kernel"]
    mod = importlib.import_module("tiny_kernel")  # a new process's view: a fresh dispatcher
    with compiling.first_compile(mod.add):
        assert mod.add(1, 2) == 3
    assert said == ["tiny_kernel"]  # warm: loaded from the cache, nothing said
    text = compile_notice("haptic_teleop.engine.compiled.axis_kernel")
    assert "axis_kernel" in text and "numba" in text and "cache" in text and "haptic-teleop compile" in text


def test_a_run_waiting_for_another_process_compiling_says_so(tmp_path, monkeypatch):
    """While another process holds a kernel's compile lock, `first_compile` tells
    `compiling.wait_notice` before it waits (here the holder lets go when told), so a run does not
    wait silently; the command line's text names the kernel and what it waits for."""
    import fcntl
    import importlib

    from haptic_teleop import compiling

    (tmp_path / "tiny_kernel_b.py").write_text(
        "from numba import njit\n\n@njit(cache=True)\ndef one():\n    return 1\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("tiny_kernel_b")
    holder = open(compiling.lock_path(mod.one), "a")
    fcntl.flock(holder, fcntl.LOCK_EX)
    said: list[str] = []

    def told(name: str) -> None:
        said.append(name)
        fcntl.flock(holder, fcntl.LOCK_UN)  # the other process finished

    monkeypatch.setattr(compiling, "wait_notice", told)
    try:
        with compiling.first_compile(mod.one):
            assert mod.one() == 1
    finally:
        holder.close()
    assert said == ["tiny_kernel_b"]
    with compiling.first_compile(mod.one):  # nobody holds it (and it is compiled): nothing said
        pass
    assert said == ["tiny_kernel_b"]
    text = compiling.wait_message("haptic_teleop.engine.compiled.axis_kernel")
    assert "axis_kernel" in text and "waiting" in text and "cache" in text
