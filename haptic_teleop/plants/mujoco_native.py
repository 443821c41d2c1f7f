"""MuJoCo called from compiled code: the bindings' own libmujoco and its C functions linked by
name for numba (`mj_step`, the split step, `mj_jacSite`, `mj_contactForce`), reads of its structs
in place (`load_*`, with mjData's and mjContact's field offsets laid out from `mujoco.introspect`
and checked against the bindings: `contact_layout`), array views without reference counting for
the loops around it (`borrowed`), and the profiling-timer callback switched off around a compiled
run. Imported only by compiled modules (it needs numba and llvmlite)."""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
from collections.abc import Iterator
from typing import Any

import llvmlite.binding as llvm
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic
from numba.np.arrayobj import populate_array


def _mujoco_library() -> ctypes.CDLL:
    import mujoco

    here = os.path.dirname(mujoco.__file__)
    found = sorted(glob.glob(os.path.join(here, "libmujoco.so*")) + glob.glob(os.path.join(here, "libmujoco*.dylib")))
    if not found:
        raise RuntimeError(f"no libmujoco shared library next to {mujoco.__file__}")
    return ctypes.CDLL(found[0])  # already loaded by the bindings: the same library, the same state


# mj_step is linked by name: the compiled code (and numba's on-disk cache of it) calls the symbol,
# resolved here to the bindings' libmujoco. Pointers are passed as integers: the MjModel/MjData
# addresses the bindings expose (`_address`), the same objects the plants step.
libmujoco = _mujoco_library()
llvm.add_symbol("mj_step", ctypes.cast(libmujoco.mj_step, ctypes.c_void_p).value)
mj_step = types.ExternalFunction("mj_step", types.void(types.intp, types.intp))


for _name in ("mj_step1", "mj_step2", "mj_jacSite", "mj_contactForce"):
    llvm.add_symbol(_name, ctypes.cast(getattr(libmujoco, _name), ctypes.c_void_p).value)
# void mj_step1(const mjModel* m, mjData* d); void mj_step2(...): the split step (mujoco.h)
mj_step1 = types.ExternalFunction("mj_step1", types.void(types.intp, types.intp))
mj_step2 = types.ExternalFunction("mj_step2", types.void(types.intp, types.intp))
# void mj_jacSite(const mjModel* m, const mjData* d, mjtNum* jacp, mjtNum* jacr, int site)
mj_jacSite = types.ExternalFunction(
    "mj_jacSite", types.void(types.intp, types.intp, types.intp, types.intp, types.int32)
)
# void mj_contactForce(const mjModel* m, const mjData* d, int id, mjtNum result[6])
mj_contactForce = types.ExternalFunction("mj_contactForce", types.void(types.intp, types.intp, types.int32, types.intp))


@intrinsic
def load_i32(typingctx: Any, addr: Any) -> Any:
    """The int32 at byte address `addr` (a field of MuJoCo's mjData or mjContact)."""

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        return builder.load(builder.inttoptr(args[0], ir.IntType(32).as_pointer()))

    return types.int32(types.intp), codegen


@intrinsic
def load_i64(typingctx: Any, addr: Any) -> Any:
    """The int64 (a pointer) at byte address `addr`."""

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        return builder.load(builder.inttoptr(args[0], ir.IntType(64).as_pointer()))

    return types.int64(types.intp), codegen


@intrinsic
def load_f64(typingctx: Any, addr: Any) -> Any:
    """The float64 at byte address `addr`."""

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        return builder.load(builder.inttoptr(args[0], ir.DoubleType().as_pointer()))

    return types.float64(types.intp), codegen


@intrinsic
def borrowed(typingctx: Any, arr: Any) -> Any:
    """`arr` without its reference count (a view with no owner): passing it around costs no
    atomic increments and decrements, which were about a sixth of a tick (docs/performance_arms.md).
    The caller keeps the owner alive for as long as the view is used."""

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        src = context.make_array(sig.args[0])(context, builder, args[0])
        out = context.make_array(sig.return_type)(context, builder)
        populate_array(out, src.data, src.shape, src.strides, src.itemsize, None)
        return out._getvalue()

    return arr(arr), codegen


_PRIMITIVES = {
    "char": 1, "unsigned char": 1, "mjtByte": 1, "mjtBool": 1, "int": 4, "unsigned int": 4, "float": 4,
    "double": 8, "mjtNum": 8, "size_t": 8, "mjtSize": 8, "uintptr_t": 8, "uint64_t": 8, "int64_t": 8,
}  # fmt: skip


def _c_size_align(t: Any) -> tuple[int, int]:
    """sizeof and alignof of a mujoco.introspect type on this (64-bit) machine."""
    from mujoco.introspect import structs

    kind = type(t).__name__
    if kind == "PointerType":
        return 8, 8
    if kind == "ArrayType":
        size, align = _c_size_align(t.inner_type)
        for n in t.extents:
            size *= n
        return size, align
    name = t.name
    if name in _PRIMITIVES:
        return _PRIMITIVES[name], _PRIMITIVES[name]
    if name in structs.STRUCTS:
        return _c_struct(name)[0:2]  # type: ignore[return-value]
    raise KeyError(name)


def _c_struct(name: str) -> tuple[int, int, dict[str, int]]:
    """sizeof, alignof and the field offsets of a MuJoCo struct, laid out by C's rules from the
    field list of `mujoco.introspect` (MuJoCo's own description of its headers)."""
    from mujoco.introspect import structs

    offset, align, fields = 0, 1, {}
    for f in structs.STRUCTS[name].fields:
        size, a = _c_size_align(f.type)
        offset = -(-offset // a) * a
        fields[f.name] = offset
        offset += size
        align = max(align, a)
    return -(-offset // align) * align, align, fields


def contact_layout() -> tuple[int, int, int, int, int, int, int, int] | str:
    """(ncon offset in mjData, contact-pointer offset in mjData, mjContact stride, and the offsets
    in mjContact of pos, frame, geom[0], geom[1], efc_address); or why not (then arm scenes run in
    the Python loop).

    The offsets come from the layout of MuJoCo's structs by C's rules (`_c_struct`, from
    `mujoco.introspect`), and are used only if they read what the bindings read on a probe model
    with one contact: `ncon`, the contact array's address, and its first record's geoms, efc
    address and position (each field read from memory inside the struct, never beyond it)."""
    import mujoco

    try:
        data_size, _, data_fields = _c_struct("mjData")
        stride, _, contact_fields = _c_struct("mjContact")
        layout = (
            data_fields["ncon"],
            data_fields["contact"],
            stride,
            contact_fields["pos"],
            contact_fields["frame"],
            contact_fields["geom"],
            contact_fields["geom"] + 4,
            contact_fields["efc_address"],
        )
    except (ImportError, KeyError, AttributeError) as exc:
        return f"cannot lay out mjData from mujoco.introspect ({type(exc).__name__}: {exc})"
    xml = """<mujoco><worldbody><geom name="floor" type="plane" size="1 1 .1"/>
      <body pos="0 0 0.05"><freejoint/><geom name="ball" type="sphere" size="0.1" mass="1"/></body>
      </worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    if not hasattr(d, "_address"):
        return "this mujoco's bindings do not expose MjData._address"
    mujoco.mj_forward(m, d)
    if d.ncon != 1:
        return f"probe model: expected one contact, got {d.ncon}"
    c = d.contact
    base = int(c.dist.__array_interface__["data"][0])
    if not (layout[0] >= 0 and layout[1] + 8 <= data_size and c.dist.strides[0] == stride):
        return "mjData's layout from mujoco.introspect does not match the bindings (mjContact's size)"
    read = ctypes.c_int32.from_address(d._address + layout[0]).value
    ptr = ctypes.c_uint64.from_address(d._address + layout[1]).value
    if read != d.ncon or ptr != base:
        return "mjData's layout from mujoco.introspect does not read ncon and contact as the bindings do"
    pos = np.frombuffer((ctypes.c_double * 3).from_address(ptr + layout[3]), dtype=np.float64)
    frame = np.frombuffer((ctypes.c_double * 9).from_address(ptr + layout[4]), dtype=np.float64)
    g = ctypes.c_int32.from_address(ptr + layout[5]).value, ctypes.c_int32.from_address(ptr + layout[6]).value
    efc = ctypes.c_int32.from_address(ptr + layout[7]).value
    if not (
        np.array_equal(pos, c.pos[0])
        and np.array_equal(frame, c.frame[0])
        and g == tuple(c.geom[0])
        and efc == c.efc_address[0]
    ):
        return "mjContact's layout from mujoco.introspect does not read what the bindings read"
    return layout


@contextlib.contextmanager
def mujoco_timers_off() -> Iterator[None]:
    """Clear libmujoco's `mjcb_time` for the duration, then put it back.

    The Python bindings install a time callback that MuJoCo calls about 30 times a step to fill
    its profiling timers (`MjData.timer`); from the compiled loop it was 40 % of a bare step
    (docs/performance.md). Nothing but the timers reads it: states and forces are unchanged
    (test_compiled_loop.py compares them with the Python loop's, where the callback is on)."""
    slot = ctypes.c_void_p.in_dll(libmujoco, "mjcb_time")
    before = slot.value
    slot.value = None
    try:
        yield
    finally:
        slot.value = before
