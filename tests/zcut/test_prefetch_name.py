"""The name ``zcut.cut_tree`` declares ``llvm.prefetch`` under (``PREFETCH_INTRINSIC``): LLVM renames a declaration
of any spelling of this overloaded intrinsic to its own mangled name (``llvm.prefetch.p0i8`` with typed pointers,
``llvm.prefetch.p0`` with opaque ones), so the name need not follow llvmlite's LLVM version. Checked here on the
installed LLVM; by hand on numba 0.60 / llvmlite 0.43 / LLVM 14 (the dependency floor) and 0.61 / 0.44 / LLVM 15
(docs/performance.md)."""

from __future__ import annotations

import platform

import llvmlite.binding as llvm
import numba
import numpy as np
import pytest
from llvmlite import ir

from zcut.cut_tree import PREFETCH_INTRINSIC, _prefetch, _prefetch_w, finite_range


def declaration(name: str) -> str:
    """The declaration LLVM keeps of a call to ``name`` (as :func:`zcut.cut_tree._prefetch_codegen` declares it)
    once it has parsed and verified the module."""
    i8p = ir.IntType(8).as_pointer()
    i32 = ir.IntType(32)
    module = ir.Module()
    f = ir.Function(module, ir.FunctionType(ir.VoidType(), [i8p]), "f")
    builder = ir.IRBuilder(f.append_basic_block())
    fn = ir.Function(module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]), name)
    builder.call(fn, [f.args[0], ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
    builder.ret_void()
    parsed = llvm.parse_assembly(str(module))
    parsed.verify()
    (line,) = [s for s in str(parsed).splitlines() if s.startswith("declare")]
    return line


def test_every_spelling_is_the_same_intrinsic() -> None:
    """The name used, the unmangled one and both manglings give LLVM's one declaration of the intrinsic."""
    ours = declaration(PREFETCH_INTRINSIC)
    assert "@llvm.prefetch." in ours
    for name in ("llvm.prefetch", "llvm.prefetch.p0", "llvm.prefetch.p0i8"):
        assert declaration(name) == ours


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="x86-64's prefetch instructions")
def test_the_kernels_emit_prefetches() -> None:
    """A kernel using the intrinsics (compiled here, not from the cache: its machine code is inspected) holds a
    read and a write prefetch, and computes what it computes without them."""

    @numba.njit(cache=False)
    def total(a):  # type: ignore[no-untyped-def]  # numba kernel
        s = 0.0
        for i in range(a.size):
            _prefetch(a, np.uint64(min(i + 64, a.size - 1)))
            _prefetch_w(a, np.uint64(min(i + 64, a.size - 1)))
            s += a[i]
        return s

    a = np.arange(1000.0)
    assert total(a) == a.sum()
    asm = total.inspect_asm(total.signatures[0])
    assert "prefetcht0" in asm
    seg = np.empty((3, 1))
    assert finite_range(np.arange(6.0).reshape(3, 2), seg)[1:] == (0.0, 5.0)
