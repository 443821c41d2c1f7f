"""The package's layers and its import graph (docs/architecture.md, "Layers").

Every module of haptic_teleop is parsed (ast, nothing is imported) and every import it makes, at
module level, inside a function or for types only (`if TYPE_CHECKING:`), is an edge to the most
specific module of the package it names (`from haptic_teleop.core import eba` is an edge to
`haptic_teleop.core.eba`). The layer table of docs/architecture.md says which layer may import
which; an edge between two layers that the table does not allow fails, and so does any cycle.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "haptic_teleop"
ARCHITECTURE = ROOT / "docs" / "architecture.md"


def _modules() -> dict[str, Path]:
    mods = {}
    for p in PACKAGE.rglob("*.py"):
        parts = list(p.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        mods[".".join(parts)] = p
    return mods


def import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports (module level, inside functions, for types)."""
    mods = _modules()

    def target(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for mod, path in mods.items():
        out: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                assert node.level == 0, f"{mod}: relative import (the package uses absolute imports)"
                names = [f"{node.module}.{a.name}" for a in node.names]
            for name in names:
                t = target(name)
                if t is not None and t != mod:
                    out.add(t)
        graph[mod] = out
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return found


def layer_table(text: str) -> dict[str, tuple[str, frozenset[str]]]:
    """layer -> (its folder, the layers it may import), from the table under "## Layers"."""
    section = text.split("## Layers", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("|")]
    header = [c.strip() for c in rows[0].strip("|").split("|")]
    col = {name: header.index(name) for name in ("layer", "folder", "may import")}
    table = {}
    for line in rows[2:]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        folder = cells[col["folder"]].strip("`")
        allowed = frozenset(x.strip() for x in cells[col["may import"]].split(",") if x.strip())
        table[cells[col["layer"]]] = (folder, allowed)
    return table


def layer_of(module: str, path: Path, table: dict[str, tuple[str, frozenset[str]]]) -> str:
    """The layer whose folder holds `module` (the longest folder that does; the package's own
    top-level modules are the layer whose folder is `haptic_teleop/*.py`)."""
    rel = path.relative_to(ROOT).as_posix()
    best, best_len = None, -1
    for name, (folder, _) in table.items():
        if folder.endswith("*.py"):
            ok = re.fullmatch(re.escape(folder[:-4]) + r"[^/]+\.py", rel) is not None
            length = len(folder) - 4
        else:
            ok = rel.startswith("haptic_teleop/" + folder)
            length = len(folder)
        if ok and length > best_len:
            best, best_len = name, length
    assert best is not None, f"{module} ({rel}) is in no layer's folder of docs/architecture.md"
    return best


def layer_violations(graph: dict[str, set[str]], table: dict[str, tuple[str, frozenset[str]]]) -> list[str]:
    mods = _modules()
    layer = {m: layer_of(m, p, table) for m, p in mods.items()}
    bad = []
    for a, targets in graph.items():
        for b in targets:
            la, lb = layer[a], layer[b]
            if la != lb and lb not in table[la][1]:
                bad.append(f"{a} ({la}) -> {b} ({lb})")
    return sorted(bad)


def test_the_graph_sees_function_level_and_type_only_imports():
    graph = import_graph()
    # cli imports the launch command inside a function only; the outputs module at module level.
    assert "haptic_teleop.cli.launch" in graph["haptic_teleop.cli.main"]
    assert "haptic_teleop.analysis.outputs" in graph["haptic_teleop.cli.main"]
    # the stages name ArmParts for the type checker only
    assert "haptic_teleop.assembly.parts" in graph["haptic_teleop.assembly.stages"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycles():
    found = cycles(import_graph())
    assert not found, (
        "import cycles (a module imports, maybe inside a function or for types only, one that imports it back): "
        + "; ".join(" <-> ".join(c) for c in found)
    )


def test_every_import_keeps_to_the_layer_table():
    table = layer_table(ARCHITECTURE.read_text())
    bad = layer_violations(import_graph(), table)
    assert not bad, "imports the layer table of docs/architecture.md does not allow: " + "; ".join(bad)


def test_the_layer_table_is_read_and_catches_an_upward_import():
    table = layer_table(ARCHITECTURE.read_text())
    assert {"ground", "core", "record", "plants", "engine", "engine.compiled", "nodes", "analysis", "cli"} <= set(table)
    assert table["core"][1] == {"ground"} and "engine" not in table["nodes"][1]
    graph = import_graph()
    graph["haptic_teleop.core.eba"].add("haptic_teleop.scene.schema")  # core reaching up
    graph["haptic_teleop.nodes.arm_side"].add("haptic_teleop.engine.lockstep")  # nodes into the engine
    graph["haptic_teleop.engine.compiled.windows"].add("haptic_teleop.engine.lockstep")  # compiled above itself
    bad = layer_violations(graph, table)
    assert len(bad) == 3, bad
    mods = _modules()
    assert layer_of("haptic_teleop.errors", mods["haptic_teleop.errors"], table) == "ground"
    assert layer_of("haptic_teleop.engine.compiled.layout", mods["haptic_teleop.engine.compiled.layout"], table) == (
        "engine.compiled"
    )


@pytest.mark.parametrize("limit", [6])
def test_the_package_root_holds_only_the_ground(limit):
    root = sorted(p.name for p in PACKAGE.glob("*.py") if p.name != "__init__.py")
    assert len(root) <= limit, root


def test_no_module_is_over_800_lines():
    big = {str(p.relative_to(ROOT)): n for p in PACKAGE.rglob("*.py") if (n := len(p.read_text().splitlines())) > 800}
    assert not big, big


# The compiled loops pack the kernels' arrays from, and carry the kernels' state back into, core
# objects and plants through their public seams (`constants()`, `state()`/`set_state()`,
# `axis_state()`, `remote`, ...), never through their private attributes: a refactor of a core
# class then cannot silently desynchronise the compiled loop from the Python one.
SEAM_USERS = ("engine/compiled/axis_host.py", "engine/compiled/arm_host.py")
ALLOWED_PRIVATE = {"_address"}  # MuJoCo's bindings: the MjModel/MjData addresses the kernels call with


def private_accesses(source: str) -> list[str]:
    """'line: expression' for every private attribute `source` reads or writes on another object:
    `obj._name` with obj anything but `self`, and getattr/setattr/hasattr(obj, "_name"). Dunders
    and ALLOWED_PRIVATE pass; a module's own private names are bare names, not attributes."""

    def private(name: str) -> bool:
        return name.startswith("_") and not name.startswith("__") and name not in ALLOWED_PRIVATE

    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and private(node.attr):
            if not (isinstance(node.value, ast.Name) and node.value.id == "self"):
                found.append(f"{node.lineno}: {ast.unparse(node)}")
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in ("getattr", "setattr", "hasattr", "delattr")
            and len(node.args) >= 2
            and isinstance(node.args[1], ast.Constant)
            and isinstance(node.args[1].value, str)
            and private(node.args[1].value)
        ):
            found.append(f"{node.lineno}: {ast.unparse(node)}")
    return found


def test_the_private_access_check_sees_every_form():
    src = (
        "a._x = 1\nb.c._y\ngetattr(d, '_z', None)\nself.k._w()\n"  # flagged
        "self._ok\nm._address\nx.__dict__\ngetattr(e, 'public')\n_own_helper()\n"  # allowed
    )
    assert sorted(int(f.split(":")[0]) for f in private_accesses(src)) == [1, 2, 3, 4]


def test_compiled_loops_use_only_public_seams():
    for name in SEAM_USERS:
        path = PACKAGE / name
        found = private_accesses(path.read_text())
        assert not found, (
            f"{name} reads private attributes of other objects (give their class a public seam): " + "; ".join(found)
        )


def test_every_module_of_the_package_imports():
    """Every module of the package is imported, in a fresh interpreter (the graph above is read from
    the source, which a broken import passes: a helper's commit once broke core/event_codec.py's
    import and only mypy noticed). `__main__` modules run their command when imported: left out."""
    import subprocess
    import sys

    code = (
        "import importlib, pkgutil, haptic_teleop\n"
        "bad = []\n"
        "for m in pkgutil.walk_packages(haptic_teleop.__path__, 'haptic_teleop.'):\n"
        "    if m.name.rpartition('.')[2] == '__main__':\n"
        "        continue\n"
        "    try:\n"
        "        importlib.import_module(m.name)\n"
        "    except Exception as exc:\n"
        "        bad.append(f'{m.name}: {exc!r}')\n"
        "print('\\n'.join(bad) or 'ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stdout + out.stderr
    assert len(_modules()) > 150  # (the walk and the graph see the same package)
