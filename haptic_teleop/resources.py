"""Where the bundled scenes, MuJoCo models and example sweeps are, however the package was installed.

The files live once in the source tree: the scenes and sweeps in the top-level `config/`
(`config/scenes/*.yaml`, `config/sweeps/*.yaml`), the models in the package
(`haptic_teleop/models/*.xml`). A wheel (and an sdist install) carries `config/` as the package's
own `haptic_teleop/config/`, so it finds them from any directory; an editable install or a source
checkout reads the top-level `config/` beside the package. The same files are also installed as
ROS 2 share data
(`share/haptic_teleop/config/scenes`, `share/haptic_teleop/models`, `share/haptic_teleop/config/sweeps`,
see setup.py): when the ament index knows this package and this very module was installed under that
prefix (a colcon install), the share folders are used; otherwise
(a wheel in a venv, an editable or `colcon build --symlink-install` install, or an ament index that
holds another copy of the package) the package's own folders are. `HAPTIC_TELEOP_MODELS` names
another models folder.
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE = "haptic_teleop"
PACKAGE_DIR = Path(__file__).resolve().parent
# kind -> (folder inside the installed package, folder inside share/haptic_teleop; in a source tree
# the scenes and sweeps are in the top-level config/ beside the package folder)
FOLDERS = {
    "scenes": ("config/scenes", "config/scenes"),
    "models": ("models", "models"),
    "sweeps": ("config/sweeps", "config/sweeps"),
    "foxglove": ("config/foxglove", "config/foxglove"),
}
MODELS_ENV = "HAPTIC_TELEOP_MODELS"


def ament_share() -> Path | None:
    """`share/haptic_teleop` of the ament install this module belongs to, or None.

    None when ament_index_python is missing, the index does not know the package, or the index's
    copy is not the one running (another prefix): its files could be another version's."""
    try:
        from ament_index_python.packages import get_package_prefix, get_package_share_directory
    except ImportError:
        return None
    try:
        prefix = Path(get_package_prefix(PACKAGE)).resolve()
        share = Path(get_package_share_directory(PACKAGE))
    except (LookupError, OSError, ValueError):  # not indexed, AMENT_PREFIX_PATH unset, bad name
        return None
    if not PACKAGE_DIR.is_relative_to(prefix):
        return None
    return share


def _folder(kind: str) -> Path:
    inside, shared = FOLDERS[kind]
    share = ament_share()
    if share is not None and (share / shared).is_dir():
        return share / shared
    installed = PACKAGE_DIR / inside
    if installed.is_dir() or not inside.startswith("config/"):
        return installed
    return PACKAGE_DIR.parent / inside  # a source tree (editable install): the top-level config/


def foxglove_dir() -> Path:
    """The folder of the Foxglove layouts (record/foxglove_layouts.py: bag_one_axis.json, ...)."""
    return _folder("foxglove")


def scenes_dir() -> Path:
    """The folder of the bundled scene files (`wall_contact.yaml`, ...)."""
    return _folder("scenes")


def models_dir() -> Path:
    """The folder of the bundled MJCF models (`$HAPTIC_TELEOP_MODELS` if set)."""
    env = os.environ.get(MODELS_ENV)
    if env:
        return Path(env)
    return _folder("models")


def sweeps_dir() -> Path:
    """The folder of the bundled example sweep files (`haptic-teleop sweep NAME`, docs/sweep.md)."""
    return _folder("sweeps")


def bundled_sweeps() -> list[str]:
    """Names of the bundled sweep files, sorted."""
    return sorted(p.stem for p in sweeps_dir().glob("*.yaml"))


def bundled_scenes() -> list[str]:
    """Names of the bundled scenes, sorted (what `haptic-teleop run NAME` accepts)."""
    return sorted(p.stem for p in scenes_dir().glob("*.yaml"))


def docs_dir() -> Path | None:
    """The project's docs/ folder of a source tree (a clone, an editable install), or None: a
    wheel or an ament install does not ship it (`haptic-teleop experiment all` compares with it)."""
    docs = PACKAGE_DIR.parent / "docs"
    return docs if (docs / "index.md").is_file() else None
