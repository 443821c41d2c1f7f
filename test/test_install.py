"""A normal (non-editable) install, as a user gets it: sdist, wheel, a fresh venv, run from elsewhere.

The fresh venv gets this package from the wheel only; its dependencies come from the environment
running the tests (a `.pth` file adds its site-packages), so nothing is downloaded but the build
backend. The checkout must not be importable from the venv: the test checks where
`haptic_teleop` was imported from.
"""

from __future__ import annotations

import ast
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

from haptic_teleop import resources

ROOT = Path(__file__).resolve().parents[1]
SCENES = sorted(p.name for p in (ROOT / "config" / "scenes").glob("*.yaml"))
MODELS = sorted(p.name for p in (ROOT / "haptic_teleop" / "models").glob("*.xml"))
SWEEPS = sorted(p.name for p in (ROOT / "config" / "sweeps").glob("*.yaml"))
LAYOUTS = sorted(p.name for p in (ROOT / "config" / "foxglove").glob("*.json"))
SKIP_DIRS = {".git", ".venv", "build", "install", "log", "runs", "__pycache__", ".pytest_cache", ".mypy_cache",
             ".ruff_cache", ".hypothesis"}  # fmt: skip


def _clean_env() -> dict[str, str]:
    """The environment without anything that points at the checkout or a ROS 2 install."""
    env = dict(os.environ)
    for key in ("PYTHONPATH", "AMENT_PREFIX_PATH", "HAPTIC_TELEOP_MODELS", "PYTHONHOME"):
        env.pop(key, None)
    return env


def _copy_checkout(dst: Path) -> None:
    """The project's files (tracked and untracked, not ignored) into dst: builds leave the checkout alone."""
    git = shutil.which("git")
    files: list[str] | None = None
    if git and (ROOT / ".git").exists():
        r = subprocess.run([git, "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                           cwd=ROOT, capture_output=True)  # fmt: skip
        if r.returncode == 0:
            files = [f for f in r.stdout.decode().split("\0") if f and (ROOT / f).is_file()]
    if files is None:
        files = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*")
                 if p.is_file() and not SKIP_DIRS.intersection(p.relative_to(ROOT).parts)]  # fmt: skip
    for f in files:
        (dst / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / f, dst / f)


def _run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """(sdist, wheel), built from a copy of the checkout: sdist first, the wheel from the sdist."""
    base = tmp_path_factory.mktemp("build")
    src, dist = base / "src", base / "dist"
    src.mkdir()
    _copy_checkout(src)
    env = _clean_env()
    r = _run([sys.executable, "setup.py", "-q", "sdist", "-d", str(dist)], src, env)
    assert r.returncode == 0, r.stdout + r.stderr
    (sdist,) = dist.glob("*.tar.gz")
    r = _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dist), str(sdist)], base, env)
    assert r.returncode == 0, r.stdout + r.stderr
    (wheel,) = dist.glob("*.whl")
    return sdist, wheel


@pytest.fixture(scope="module")
def venv(built, tmp_path_factory):
    """A fresh venv outside the checkout with the wheel installed (--no-deps); returns its bin folder."""
    _, wheel = built
    base = tmp_path_factory.mktemp("venv")
    env = _clean_env()
    r = _run([sys.executable, "-m", "venv", "--without-pip", str(base / "v")], base, env)
    assert r.returncode == 0, r.stdout + r.stderr
    bindir = base / "v" / ("Scripts" if os.name == "nt" else "bin")
    py = bindir / "python"
    purelib = _run([str(py), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], base, env)
    site = Path(purelib.stdout.strip())
    # the dependencies (pip included): this interpreter's path, less any folder that holds the package
    deps = [p for p in sys.path if p and Path(p).is_dir() and not (Path(p) / "haptic_teleop").exists()]
    (site / "zz_test_dependencies.pth").write_text("".join(f"{p}\n" for p in deps))
    r = _run([str(py), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)], base, env)
    assert r.returncode == 0, r.stdout + r.stderr
    return bindir


def test_sdist_and_wheel_carry_scenes_models_and_ros_files(built):
    sdist, wheel = built
    assert SCENES and MODELS and SWEEPS and LAYOUTS
    with tarfile.open(sdist) as tf:
        names = {n.split("/", 1)[1] for n in tf.getnames() if "/" in n}
    want = {f"config/scenes/{s}" for s in SCENES} | {f"haptic_teleop/models/{m}" for m in MODELS}
    want |= {f"config/sweeps/{s}" for s in SWEEPS} | {f"config/foxglove/{s}" for s in LAYOUTS}
    want |= {"package.xml", "setup.cfg", "resource/haptic_teleop", "launch/teleop_launch.py"}
    assert want <= names, f"missing from the sdist: {sorted(want - names)}"
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
    data = "haptic_teleop-0.1.0.data/data/share/haptic_teleop"
    want = {f"haptic_teleop/config/scenes/{s}" for s in SCENES} | {f"haptic_teleop/models/{m}" for m in MODELS}
    want |= {f"{data}/config/scenes/{s}" for s in SCENES} | {f"{data}/models/{m}" for m in MODELS}
    want |= {f"haptic_teleop/config/sweeps/{s}" for s in SWEEPS} | {f"{data}/config/sweeps/{s}" for s in SWEEPS}
    want |= {f"haptic_teleop/config/foxglove/{s}" for s in LAYOUTS} | {f"{data}/config/foxglove/{s}" for s in LAYOUTS}
    assert want <= names, f"missing from the wheel: {sorted(want - names)}"


def test_wheel_install_runs_a_bundled_scene_from_another_directory(venv, tmp_path):
    env = _clean_env()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    code = (
        "import haptic_teleop, haptic_teleop.scene.load as s, haptic_teleop.plants.mujoco_plant as m;"
        "print(haptic_teleop.__file__); print(s.scenes_dir()); print(m.models_dir())"
    )
    r = _run([str(venv / "python"), "-c", code], elsewhere, env)
    assert r.returncode == 0, r.stderr
    module, scenes, models = (Path(line) for line in r.stdout.split())
    assert module.is_relative_to(venv.parent), f"imported {module}, not the installed wheel"
    assert not module.is_relative_to(ROOT)
    assert sorted(p.name for p in scenes.glob("*.yaml")) == SCENES
    assert sorted(p.name for p in models.glob("*.xml")) == MODELS

    out = elsewhere / "out"
    cmd = [str(venv / "haptic-teleop"), "run", "wall_contact", "--set", "scene.duration_s=0.2", "--out", str(out)]
    r = _run(cmd, elsewhere, env)
    assert r.returncode == 0, r.stdout + r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["contact_force_max_n"] >= 0.0

    from rosbags.rosbag2 import Reader

    with Reader(out / "bag") as reader:
        topics = {c.topic for c in reader.connections}
        count, expected = sum(1 for _ in reader.messages()), reader.message_count
    assert {"/slave/contact_wrench", "/master/joint_states", "/forward/packets"} <= topics, topics
    assert count == expected > 0


def test_ament_share_is_used_only_for_this_install(tmp_path, monkeypatch):
    """A ROS 2 prefix that holds another copy of the package is not where this copy's files are."""
    other = tmp_path / "other_prefix"
    (other / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (other / "share" / "ament_index" / "resource_index" / "packages" / "haptic_teleop").write_text("")
    (other / "share" / "haptic_teleop" / "config" / "scenes").mkdir(parents=True)
    (other / "share" / "haptic_teleop" / "models").mkdir(parents=True)
    pytest.importorskip("ament_index_python")
    monkeypatch.delenv("HAPTIC_TELEOP_MODELS", raising=False)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(other))
    assert resources.ament_share() is None
    assert resources.scenes_dir() == resources.PACKAGE_DIR.parent / "config" / "scenes"  # this source tree
    assert resources.models_dir() == resources.PACKAGE_DIR / "models"
    assert "wall_contact" in resources.bundled_scenes()
    # the same prefix layout around this very module: its share folders are used
    monkeypatch.setattr(resources, "PACKAGE_DIR", other / "lib" / "python3" / "site-packages" / "haptic_teleop")
    assert resources.ament_share() == other / "share" / "haptic_teleop"
    assert resources.scenes_dir() == other / "share" / "haptic_teleop" / "config" / "scenes"
    assert resources.models_dir() == other / "share" / "haptic_teleop" / "models"
    monkeypatch.setenv("HAPTIC_TELEOP_MODELS", str(tmp_path))
    assert resources.models_dir() == tmp_path


def _install_requires() -> dict[str, str]:
    """setup.py's install_requires, name -> requirement, read without running setup()."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == "install_requires":
            reqs = ast.literal_eval(node.value)
            return {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0].lower(): r for r in reqs}
    raise AssertionError("setup.py has no install_requires")


def test_readme_ros2_pip_command_has_the_bounds_of_setup_py():
    """The README's pip line for a ROS 2 workspace installs what rosdep cannot, with setup.py's bounds."""
    requires = _install_requires()
    text = (ROOT / "docs" / "install.md").read_text().replace("\\\n", " ")  # the command may go on over lines
    lines = [line for line in text.splitlines() if line.startswith("venv/bin/pip install ")]
    assert len(lines) == 1, lines
    specs = re.findall(r"'([^']+)'", lines[0])
    by_name = {re.split(r"[<>=!~\[; ]", s, maxsplit=1)[0].lower(): s for s in specs}
    assert set(by_name) == {"mujoco", "rosbags", "numba", "lz4", "backports.zstd", "ruamel.yaml", "isal"}, specs
    for name, spec in by_name.items():
        assert spec.replace(" ", "") == requires[name].replace(" ", ""), f"README {spec!r}, setup.py {requires[name]!r}"
    # everything else in install_requires has a rosdep key declared in package.xml
    declared = set(re.findall(r"<exec_depend>([^<]+)</exec_depend>", (ROOT / "package.xml").read_text()))
    keys = {
        "numpy": "python3-numpy",
        "pyyaml": "python3-yaml",
        "matplotlib": "python3-matplotlib",
        "tqdm": "python3-tqdm",
    }
    assert set(requires) - set(by_name) == set(keys), sorted(requires)
    assert set(keys.values()) <= declared, sorted(declared)
