"""The package's import graph has no cycles (docs/architecture.md, "Layers").

Every module of haptic_teleop is parsed (ast, nothing is imported) and every import it makes,
at module level or inside a function, is an edge to the most specific module of the package it
names (`from haptic_teleop.core import eba` is an edge to `haptic_teleop.core.eba`). Imports under
`if TYPE_CHECKING:` run only for the type checker and are left out. Known cycles are listed in
KNOWN_BACK_EDGES, one edge per cycle: the list only shrinks. When a change removes one of its
imports, the test fails until the entry is removed too.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "haptic_teleop"

# (importer, imported): the import that closes a known cycle, with why it is still there.
KNOWN_BACK_EDGES = {
    # The compiled kernel takes the layout of its parameter and state arrays (P_*, S_*) from the
    # loop that drives it; they belong in a module below both.
    (
        "haptic_teleop.engine.axis_kernel",
        "haptic_teleop.engine.compiled_loop",
    ): "array layout shared through compiled_loop",
}


def _modules() -> dict[str, Path]:
    mods = {}
    for p in PACKAGE.rglob("*.py"):
        parts = list(p.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        mods[".".join(parts)] = p
    return mods


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports (module level and inside functions)."""
    mods = _modules()

    def target(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for mod, path in mods.items():
        out: set[str] = set()

        def visit(node: ast.AST, mod: str = mod, out: set[str] = out) -> None:
            if isinstance(node, ast.If) and _is_type_checking(node.test):
                for n in node.orelse:
                    visit(n)
                return
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
            for child in ast.iter_child_nodes(node):
                visit(child)

        visit(ast.parse(path.read_text(), str(path)))
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


def test_the_graph_sees_function_level_imports():
    graph = import_graph()
    # cli imports the launcher inside a function only; the outputs module at module level.
    assert "haptic_teleop.launcher" in graph["haptic_teleop.cli"]
    assert "haptic_teleop.analysis.outputs" in graph["haptic_teleop.cli"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycles_but_the_known_ones():
    graph = import_graph()
    stale = [e for e in KNOWN_BACK_EDGES if e[1] not in graph.get(e[0], set())]
    assert not stale, f"these imports are gone: remove them from KNOWN_BACK_EDGES: {stale}"
    for a, b in KNOWN_BACK_EDGES:
        graph[a].discard(b)
    found = cycles(graph)
    assert not found, (
        "import cycles (a module imports, maybe inside a function, one that imports it back): "
        + "; ".join(" <-> ".join(c) for c in found)
    )


# The compiled loops pack the kernels' arrays from, and carry the kernels' state back into, core
# objects and plants through their public seams (`constants()`, `state()`/`set_state()`,
# `axis_state()`, `remote`, ...), never through their private attributes: a refactor of a core
# class then cannot silently desynchronise the compiled loop from the Python one.
SEAM_USERS = ("engine/compiled_loop.py", "engine/compiled_arm_loop.py")
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
