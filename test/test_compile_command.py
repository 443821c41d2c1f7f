"""`haptic-teleop compile` (engine/warm.py) and the lock that makes processes starting together
compile a kernel once (compiling.first_compile)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading
import types

import pytest

from haptic_teleop.cli.main import main
from haptic_teleop.compiling import first_compile
from haptic_teleop.engine.compiled.axis_host import kernel


def test_compile_builds_the_named_kernel_and_marks_it_done(tmp_path, capsys):
    if kernel() is None:
        pytest.skip("no numba here: the compiled loop cannot load")
    assert main(["compile", "--only", "axis", "--done-dir", str(tmp_path)]) == 0
    assert (tmp_path / "axis.done").is_file()
    assert not (tmp_path / "codec.done").exists()  # only what was named
    assert capsys.readouterr().out.startswith("axis: ready in ")


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["compile", "--only", "axis,nope"], "unknown kernel nope; allowed: axis, codec, arm, arm_codec"),
        (["compile", "--only", ","], "allowed: axis, codec, arm, arm_codec"),
        (["compile", "--done-dir", "/nonexistent/dir"], "--done-dir: /nonexistent/dir is not a directory"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(argv, says, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1


KERNEL_FILE = "/checkout/haptic_teleop/engine/compiled/test_kernel.py"  # where a kernel's source is


def _function(module: str, source_file: str) -> types.FunctionType:
    """A kernel's Python function as numba holds it: its module and the file it was defined in."""
    ns: dict = {}
    exec(compile("def fn():\n    pass\n", source_file, "exec"), ns)
    fn = ns["fn"]
    fn.__module__ = module
    return fn


def _dispatcher(module: str, signatures: list[str], source_file: str = KERNEL_FILE) -> types.SimpleNamespace:
    return types.SimpleNamespace(py_func=_function(module, source_file), signatures=signatures)


def _holder(name: str, source_file: str) -> subprocess.Popen:
    """Another process holding kernel `name`'s compile lock (as one compiling it does) until told."""
    return subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(f"""
            import sys, types
            from haptic_teleop.compiling import first_compile
            ns = {{}}
            exec(compile("def fn():\\n    pass\\n", {source_file!r}, "exec"), ns)
            ns["fn"].__module__ = {name!r}
            with first_compile(types.SimpleNamespace(py_func=ns["fn"], signatures=[])):
                print("held", flush=True)
                sys.stdin.readline()
        """)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip


def _first_call(name: str) -> tuple[threading.Event, threading.Thread]:
    """Kernel `name`'s first call in this process, in a thread: the event is set once it got in."""
    entered = threading.Event()

    def first_call() -> None:
        with first_compile(_dispatcher(name, [])):
            entered.set()

    waiter = threading.Thread(target=first_call, daemon=True)
    waiter.start()
    return entered, waiter


def test_a_kernel_being_compiled_by_another_process_is_waited_for():
    """Another process holds the kernel's compile lock (as a process compiling it does): the first
    call here waits until it lets go; a kernel already loaded in this process does not wait."""
    name = f"test_kernel_{threading.get_ident()}"
    holder = _holder(name, KERNEL_FILE)
    try:
        assert holder.stdout is not None and holder.stdin is not None
        assert holder.stdout.readline().strip() == "held"
        entered, waiter = _first_call(name)
        with first_compile(_dispatcher(name, ["(float64,)"])):  # compiled here already: no wait
            pass
        assert not entered.wait(1.0)  # still held by the other process
        holder.stdin.write("\n")
        holder.stdin.flush()
        assert entered.wait(60.0)  # a safety net only: it enters as soon as the lock is free
        waiter.join(60.0)
    finally:
        holder.kill()
        holder.wait()


def test_the_same_kernel_of_another_checkout_is_not_waited_for():
    """Another process compiles the same kernel from another checkout's source (its own numba cache):
    this one's first call does not wait for it."""
    name = f"test_kernel_{threading.get_ident()}_other"
    holder = _holder(name, "/another/checkout/haptic_teleop/engine/compiled/test_kernel.py")
    try:
        assert holder.stdout is not None and holder.stdin is not None
        assert holder.stdout.readline().strip() == "held"
        entered, waiter = _first_call(name)
        assert entered.wait(30.0)  # a safety net only: nothing holds this checkout's lock
        waiter.join(30.0)
    finally:
        holder.kill()
        holder.wait()
