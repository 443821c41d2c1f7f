"""numba's on-disk cache is dropped when any source a compiled module is built from changes
(haptic_teleop/compiling.py): the sources are the module's transitive module-level imports inside
its package, computed, not listed by hand."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from haptic_teleop import compiling

KERNEL = """
import numba

from ckpkg.dep import SCALE


@numba.njit(cache=True)
def value():
    return SCALE
"""


def _package(root: Path, scale: int) -> None:
    pkg = root / "ckpkg"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "dep.py").write_text(f"SCALE = {scale}\n")  # a compile-time constant of the kernel
    if not (pkg / "kern.py").exists():
        (pkg / "kern.py").write_text(KERNEL)


def _value(root: Path, through_compiling: bool) -> int:
    """The kernel's result in a fresh process, imported through `compiling.load` or plainly."""
    load = "compiling.load('ckpkg.kern')" if through_compiling else "importlib.import_module('ckpkg.kern')"
    code = textwrap.dedent(f"""
        import importlib, sys
        sys.path.insert(0, {str(root)!r})
        from haptic_teleop import compiling
        print({load}.value())
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


def test_a_changed_dependency_rebuilds_the_cache(tmp_path: Path) -> None:
    _package(tmp_path, 1)
    assert _value(tmp_path, True) == 1  # compiled and cached beside kern.py
    assert list((tmp_path / "ckpkg" / "__pycache__").glob("kern.value-*.nbi"))
    _package(tmp_path, 2)  # only the dependency changes; kern.py keeps its time stamp
    # numba alone checks kern.py's stamp and runs the stale machine code ...
    assert _value(tmp_path, False) == 1
    # ... compiling.load sees the dependency's change, drops the cache, compiles anew.
    assert _value(tmp_path, True) == 2
    assert _value(tmp_path, False) == 2  # and the cache now holds the new code
    assert _value(tmp_path, True) == 2  # unchanged sources: the cache is kept (loaded, not rebuilt)


def test_the_kernels_sources_are_their_imports() -> None:
    deps = compiling.package_imports("haptic_teleop.engine.compiled.axis_kernel")
    # the column indices the kernel freezes at compile time, the rules it compiles, its layout
    for name in ("record.columns", "core.eba", "core.operator", "engine.compiled.layout", "plants.mujoco_plant"):
        assert f"haptic_teleop.{name}" in deps
    assert "haptic_teleop.engine.compiled.axis_host" not in deps  # the host imports the kernel, not back
    arm = compiling.package_imports("haptic_teleop.engine.compiled.arm_codec_kernel")
    assert {"haptic_teleop.assembly.side_kernel", "haptic_teleop.engine.compiled.codec_arq"} <= arm


def test_imports_inside_functions_and_for_types_are_not_sources(tmp_path: Path) -> None:
    pkg = tmp_path / "ckpkg2"
    pkg.mkdir()
    for name in ("__init__", "a", "b", "c", "d"):
        (pkg / f"{name}.py").write_text("X = 1\n")
    (pkg / "k.py").write_text(
        "from typing import TYPE_CHECKING\nfrom ckpkg2 import a\nfrom ckpkg2.b import X\n"
        "if TYPE_CHECKING:\n    from ckpkg2 import c\n"
        "def f():\n    from ckpkg2 import d\n"
    )
    sys.path.insert(0, str(tmp_path))
    try:
        assert compiling.direct_imports("ckpkg2.k") == {"ckpkg2.a", "ckpkg2.b"}
    finally:
        sys.path.remove(str(tmp_path))
