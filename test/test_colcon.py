"""colcon build of this package into a temporary directory: the install tree a ROS 2 user gets."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from haptic_teleop.nodes import EXECUTABLES

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def install(tmp_path_factory):
    colcon = shutil.which("colcon", path=str(BIN)) or shutil.which("colcon")
    if colcon is None:
        pytest.skip("colcon is not installed (pip install colcon-common-extensions ros-ament-package)")
    base = tmp_path_factory.mktemp("colcon")
    env = dict(os.environ, PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}")
    r = subprocess.run(
        [colcon, "--log-base", str(base / "log"), "build", "--base-paths", str(ROOT),
         "--build-base", str(base / "build"), "--install-base", str(base / "install")],
        cwd=base, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    return base / "install" / "haptic_teleop"


def test_install_tree_has_executables_launch_config_models(install):
    lib = install / "lib" / "haptic_teleop"
    for name in [*EXECUTABLES, "haptic-teleop", "composed"]:
        exe = lib / name
        assert exe.is_file() and os.access(exe, os.X_OK), f"missing executable {exe}"
    share = install / "share" / "haptic_teleop"
    assert (share / "package.xml").is_file()
    assert (install / "share" / "ament_index" / "resource_index" / "packages" / "haptic_teleop").is_file()
    for source, folder, pattern in (
        ("launch", "launch", "*_launch.py"),
        ("config/scenes", "config/scenes", "*.yaml"),
        ("haptic_teleop/models", "models", "*.xml"),
        ("config/sweeps", "config/sweeps", "*.yaml"),
    ):
        want = sorted(p.name for p in (ROOT / source).glob(pattern))
        got = sorted(p.name for p in (share / folder).glob(pattern))
        assert want and got == want, f"{folder}: {got} != {want}"


def _install_env(install: Path) -> tuple[Path, dict[str, str]]:
    """The install's site-packages and the environment `source install/setup.bash` gives (in short)."""
    site = next((install / "lib").glob("python3*/site-packages"))
    env = dict(os.environ, PYTHONPATH=str(site), AMENT_PREFIX_PATH=str(install))
    env.pop("HAPTIC_TELEOP_MODELS", None)
    return site, env


def test_installed_package_finds_its_share_files(install):
    """Run from the install tree alone (not the source tree): scenes and models come from share/."""
    site, env = _install_env(install)
    code = (
        "import haptic_teleop, sys;"
        "from haptic_teleop.scene.load import scenes_dir;"
        "from haptic_teleop.plants.mujoco_plant import models_dir;"
        "print(haptic_teleop.__file__); print(scenes_dir()); print(models_dir())"
    )
    r = subprocess.run([sys.executable, "-c", code], env=env, cwd=install, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    pkg, scenes, models = r.stdout.split()
    assert pkg.startswith(str(site)), f"imported {pkg}, not the installed copy"
    share = install / "share" / "haptic_teleop"
    assert Path(scenes) == share / "config" / "scenes"
    assert Path(models) == share / "models"
    assert (Path(scenes) / "wall_contact.yaml").is_file()
    # the package's own copies too (used when the ament index points at another install)
    assert (site / "haptic_teleop" / "config" / "scenes" / "wall_contact.yaml").is_file()
    assert (site / "haptic_teleop" / "models" / "wall_scene.xml").is_file()


def test_installed_executable_runs_a_bundled_scene_from_another_directory(install, tmp_path):
    """`haptic-teleop run wall_contact` from the colcon install, in a directory that is not the checkout."""
    _, env = _install_env(install)
    out = tmp_path / "out"
    cmd = [str(install / "lib" / "haptic_teleop" / "haptic-teleop"), "run", "wall_contact",
           "--set", "scene.duration_s=0.2", "--out", str(out), "--no-plots"]  # fmt: skip
    r = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert json.loads((out / "summary.json").read_text())["packets_sent_forward"] > 0
    assert (out / "bag" / "metadata.yaml").is_file()
