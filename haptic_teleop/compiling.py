"""Compiled code's ground: core's plain functions compiled with what they call (`compile_tree`),
numba's on-disk cache kept honest (`drop_stale`, `load`), and a kernel compiled once among
processes that start together (`first_compile`). numba is imported only when something is
compiled: this module imports without it.


numba caches a compiled function beside its source (`__pycache__/<module>.<function>-<line>.pyXY.nb[ic]`)
and checks only that one file's time stamp before it reuses the machine code. A kernel, though,
holds compiled copies of everything it calls: core's rules, the layout constants and the record
schema's column indices it freezes at compile time. So before a kernel module is imported,
`drop_stale` hashes the source of the module and of every module of this package it imports,
transitively (at module level: `package_imports`), and drops the module's cached
machine code when that digest differs from the one written beside the cache the last time. It
does the same for each package module in that closure, since each one's cached functions hold
compiled copies of what it imports in turn. Nothing is listed by hand: a new import is a new
dependency.
"""

from __future__ import annotations

import ast
import contextlib
import fcntl
import functools
import glob
import hashlib
import importlib
import importlib.util
import os
import tempfile
import types
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

PACKAGE = "haptic_teleop"


@functools.cache
def _package_dir(top: str) -> Path:
    """The folder of top-level package `top` (this package, or another one numba compiles)."""
    spec = importlib.util.find_spec(top)
    if spec is None or spec.origin is None:
        raise ModuleNotFoundError(f"no package {top!r}")
    return Path(spec.origin).resolve().parent


def module_path(module: str) -> Path:
    """The source file of module `module` (dotted) of a package, a package's `__init__.py` included."""
    top, *rest = module.split(".")
    rel = Path(*rest) if rest else Path()
    file = _package_dir(top) / rel.with_suffix(".py") if rest else None
    return file if file is not None and file.is_file() else _package_dir(top) / rel / "__init__.py"


def _is_module(module: str) -> bool:
    return module_path(module).is_file()


@functools.cache
def direct_imports(module: str) -> frozenset[str]:
    """The modules of `module`'s top-level package that it imports at module level (an `if
    TYPE_CHECKING:` block left out). What compiled code holds comes from those: numba compiles a
    function with the module-level names it reads, and cannot run an import inside a function, so
    an import inside a function only serves Python code. `from pkg import name` counts `pkg.name`
    when that is a module, else `pkg`."""
    path = module_path(module)
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    top = module.split(".", maxsplit=1)[0]
    found: set[str] = set()

    def owner(name: str) -> str | None:
        while name.startswith(top + ".") and not _is_module(name):
            name = name.rpartition(".")[0]
        return name if name.startswith(top + ".") or name == top else None

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.If):
                if "TYPE_CHECKING" not in ast.unparse(node.test):
                    visit(node.body)
                visit(node.orelse)
            elif isinstance(node, ast.Try):
                for part in (node.body, *(h.body for h in node.handlers), node.orelse, node.finalbody):
                    visit(part)
            elif isinstance(node, ast.Import):
                found.update(m for a in node.names if (m := owner(a.name)) is not None)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                for a in node.names:
                    m = owner(f"{base}.{a.name}") if _is_module(f"{base}.{a.name}") else owner(base)
                    if m is not None:
                        found.add(m)

    visit(tree.body)
    found.discard(module)
    return frozenset(found)


def package_imports(module: str) -> frozenset[str]:
    """Every package module `module` imports, transitively (`direct_imports`), itself left out."""
    seen: set[str] = set()
    todo = [module]
    while todo:
        for dep in direct_imports(todo.pop()):
            if dep not in seen and dep != module:
                seen.add(dep)
                todo.append(dep)
    return frozenset(seen)


def sources_digest(module: str) -> str:
    """SHA-256 over the sources of `module` and of `package_imports(module)`, in name order."""
    digest = hashlib.sha256()
    for name in sorted({module, *package_imports(module)}):
        digest.update(name.encode() + b"\0" + module_path(name).read_bytes() + b"\0")
    return digest.hexdigest()


def _drop_one(module: str) -> None:
    path = module_path(module)
    stem = path.stem
    cache = path.parent / "__pycache__"
    stamp = cache / f"{stem}.sources"
    digest = sources_digest(module)
    with contextlib.suppress(OSError):
        if stamp.read_text() == digest:
            return
    found = glob.glob(str(cache / f"{stem}.*.nb[ic]"))
    elsewhere = os.environ.get("NUMBA_CACHE_DIR")
    if elsewhere:  # numba's caches under another root, in a tree named after the source's path
        found += glob.glob(os.path.join(elsewhere, "**", f"{stem}.*.nb[ic]"), recursive=True)
    try:
        for name in found:
            os.remove(name)
        cache.mkdir(exist_ok=True)
        stamp.write_text(digest)
    except OSError:  # a read-only install: numba caches elsewhere or not at all
        pass


def drop_stale(module: str) -> None:
    """Drop numba's cached machine code of `module` and of each package module it imports
    (transitively) whose sources, or whose own imports' sources, changed since it was cached."""
    direct_imports.cache_clear()  # the files may have changed since the last look in this process
    _package_dir.cache_clear()
    for name in sorted({module, *package_imports(module)}):
        _drop_one(name)


def load(module: str) -> Any:
    """Import compiled module `module` (dotted) after `drop_stale(module)`."""
    drop_stale(module)
    return importlib.import_module(module)


# Called with the kernel's module name when a compiled loop is about to be compiled rather than
# loaded from numba's cache (the command line prints what is being compiled, why and how long).
compile_notice: Callable[[str], None] | None = None
# ... and when another process is compiling it right now (this one waits, then loads the cache).
wait_notice: Callable[[str], None] | None = None


def is_cached(dispatcher: Any) -> bool:
    """Whether numba's on-disk cache holds machine code of `dispatcher` for its current source (its
    index file, stamped with the source's). Reads numba's private cache object (setup.py bounds
    numba below 0.69); True when that cannot be told, so a notice is never given by mistake."""
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # noqa: BLE001 (numba's private API moved, or an unreadable index: cannot tell)
        return True


def lock_path(dispatcher: Any) -> str:
    """The file `first_compile` locks for `dispatcher`: per kernel module, source file and cache."""
    py = getattr(dispatcher, "py_func", None)
    name = getattr(py, "__module__", "haptic_teleop.kernel")
    where = f"{getattr(getattr(py, '__code__', None), 'co_filename', '')}\0{os.environ.get('NUMBA_CACHE_DIR', '')}"
    key = hashlib.sha256(where.encode()).hexdigest()[:16]
    return os.path.join(tempfile.gettempdir(), f"haptic_teleop-{os.getuid()}-{name}-{key}.compile.lock")


@contextlib.contextmanager
def first_compile(dispatcher: Any) -> Iterator[None]:
    """Around a compiled loop's first call in this process: an inter-process lock per kernel, so
    that processes that start together (a sweep's workers, a test session and its warm-up,
    `haptic-teleop compile`) compile a kernel once: the first one compiles and writes numba's
    cache, the others wait for it and then load the cache. Nothing is held once the kernel is
    compiled or loaded in this process (numba lists its signatures), nor where no lock file can be
    opened (the call then compiles as it would without the lock). The lock is per kernel and per
    cache: the kernel's source file and NUMBA_CACHE_DIR name it, so another checkout or install
    compiling its own copy never holds up this one (seen: a run in one clone waited minutes for a
    test session's compile in another)."""
    if getattr(dispatcher, "signatures", None):
        yield
        return
    name = getattr(getattr(dispatcher, "py_func", None), "__module__", "haptic_teleop.kernel")
    path = lock_path(dispatcher)
    try:
        fh = open(path, "a")  # noqa: SIM115 - held across the yield
    except OSError:
        yield
        return
    with fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # another process holds it: say so, then wait
            if wait_notice is not None:
                wait_notice(name)
            fcntl.flock(fh, fcntl.LOCK_EX)
        if compile_notice is not None and not is_cached(dispatcher):  # (another process may have just built it)
            compile_notice(name)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def compile_message(module: str) -> str:
    """What the command line says when a tick loop is compiled rather than loaded from numba's
    cache: which, why, about how long, and how to build them all ahead (`run`, `launch`)."""
    kernel = module.rsplit(".", 1)[-1]
    return (
        f"haptic-teleop: compiling the tick loop {kernel} with numba, once for this kind of scene on this "
        f"machine (seconds to about two minutes on 2 cores; later runs load it from numba's cache); "
        f"`haptic-teleop compile` builds every loop ahead"
    )


def wait_message(module: str) -> str:
    """What the command line says while another process compiles the tick loop this run needs."""
    kernel = module.rsplit(".", 1)[-1]
    return (
        f"haptic-teleop: waiting for another haptic-teleop process that is compiling the tick loop {kernel} "
        f"(a run, a sweep's worker or `haptic-teleop compile`); this run then loads it from numba's cache"
    )


_compiled: dict[tuple[Any, ...], Any] = {}


def compile_tree(
    f: Callable[..., Any], inline: bool = False, bound: Mapping[str, Any] | None = None, counted: bool = True
) -> Any:
    """`f` compiled by numba (`njit(cache=True, nogil=True)`) from its own definition, with every
    plain function of this package it calls (by global name) compiled the same way: numba cannot
    call uncompiled functions, and the core modules must not import numba, so the calls are bound
    to the compiled callees here. `inline`: `f` and the callees compiled with it are inlined
    into their compiled callers (numba's `inline="always"`, as the kernels' tick parts).
    `bound`: callees, by global name, bound to the compiled functions given instead (one compiled
    once and called, where inlining it at every call would cost compile time; numba's cache
    tells a function's compilations apart by signature only, so a function compiled with two
    bindings must be inlined in both). `counted=False`: `f` is compiled without reference
    counting (numba's private `_nrt=False`, as the tick kernels; it must not allocate), which
    costs a loop that hands arrays to its callees a third of its time less (as with `bound`, a
    function compiled both ways must be inlined in both). Each function is compiled once per
    process (and way)."""
    key = (f, inline, tuple(sorted((name, id(g)) for name, g in bound.items())) if bound else (), counted)
    done = _compiled.get(key)
    if done is not None:
        return done
    import numba

    glob = dict(f.__globals__)  # type: ignore[attr-defined]
    for name in f.__code__.co_names:  # type: ignore[attr-defined]
        g = glob.get(name)
        if bound is not None and name in bound:
            glob[name] = bound[name]
        elif isinstance(g, types.FunctionType) and g.__module__.startswith(PACKAGE + "."):
            glob[name] = compile_tree(g, inline, bound, counted)
    code = f.__code__  # type: ignore[attr-defined]
    fn = types.FunctionType(code, glob, f.__name__, f.__defaults__, f.__closure__)  # type: ignore[attr-defined]
    fn.__qualname__ = f.__qualname__
    fn.__module__ = f.__module__
    opts: dict[str, Any] = {} if counted else {"_nrt": False}
    if inline:
        done = numba.njit(cache=True, nogil=True, inline="always", **opts)(fn)
    else:
        done = numba.njit(cache=True, nogil=True, **opts)(fn)
    _compiled[key] = done
    return done
