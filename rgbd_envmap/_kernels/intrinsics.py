"""LLVM operations the numba kernels need and numba does not offer, as numba intrinsics.

- :func:`f32_bits`, :func:`bits_f32`: a float32's IEEE-754 bits as int32 and back (positive
  floats order like their bits, so a distance and an index pack into one int64 key whose ``min``
  is "closest, then first": the map update's and the translation's z-buffers).
- :func:`prefetch`: a software prefetch of one array element (never faults, so the index may lie
  outside the array): scattered reads that the hardware prefetcher does not follow (the map's pixels
  under a frame's samples, the translation's z-buffer keys, the SH tracker's fill state).
- :func:`store_nt`: a non-temporal (streaming) store, for output written once and not read back.
- :func:`min_run8`: ``min`` of up to 8 consecutive int64 entries and a key, as one masked vector
  load / min / store.
- :func:`compress16`: the flagged columns of 16 appended to a list, as one compress-store.
- :func:`fetch_add`: an atomic add that returns the previous value (a work counter shared by threads).
- :data:`PRANGE_ONLY`: numba's parallel options of the two-thread kernels (and the threading
  layer they run on).

Each is tested through the kernels that use it (tests/rgbd_envmap/test_envmap.py, test_sh.py).

numba's on-disk cache keys a kernel on its own source file only: after editing this file alone, the
kernels that inline these intrinsics keep their old machine code until their modules change or the
cache files go (``find rgbd_envmap -name '*.nb[ci]' -delete``). A fresh clone or install has none.
"""

from __future__ import annotations

import numba
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.core.cpu import ParallelOptions
from numba.extending import intrinsic

__all__ = ["f32_bits", "bits_f32", "prefetch", "store_nt", "min_run8", "compress16", "fetch_add", "PRANGE_ONLY",
           "AVX512", "host_has_avx512"]

#: numba's parallel transforms for the two-thread kernels: the explicit prange loops only, so nothing
#: else in them (array expressions, reductions) is turned into threaded loops behind the code's back.
#: (An options object, not a dict: numba empties the dict it is given, as it reads it.)
PRANGE_ONLY = ParallelOptions({"prange": True, "numpy": False, "reduction": False, "setitem": False, "stencil": False,
                                "fusion": False, "comprehension": False, "inplace_binop": False})


@intrinsic
def f32_bits(typingctx, x):  # pragma: no cover - compiled
    """The IEEE-754 bits of a float32 as int32 (positive floats order like their bits)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.int32))
    return types.int32(types.float32), codegen


@intrinsic
def bits_f32(typingctx, x):  # pragma: no cover - compiled
    """Inverse of :func:`f32_bits`."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.float32))
    return types.float32(types.int32), codegen


@intrinsic
def prefetch(typingctx, arr, i):  # pragma: no cover - compiled
    """Hint that arr[i] of a 1-D array will be read soon (LLVM's prefetch: read, keep in all cache
    levels, data). A hint never faults, so i may lie outside the array (a pole row's neighbour, a
    list entry past its end)."""
    sig = types.void(arr, i)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1]], wraparound=False, boundscheck=False)
        i8p, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            "llvm.prefetch.p0")
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def store_nt(typingctx, arr, i, value):  # pragma: no cover - compiled
    """a[i] = value for a 1-D array, as a non-temporal (streaming) store: written to memory without
    first reading the line into the cache (the output map, 34 MB, is not read back here)."""
    sig = types.void(arr, i, value)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = builder.gep(ary.data, [context.cast(builder, args[1], signature.args[1], types.intp)])
        val = context.cast(builder, args[2], signature.args[2], signature.args[0].dtype)
        val = context.get_value_as_data(builder, signature.args[0].dtype, val)
        st = builder.store(val, ptr)
        st.set_metadata("nontemporal", builder.module.add_metadata([ir.Constant(ir.IntType(32), 1)]))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def min_run8(typingctx, arr, q, m, kk):  # pragma: no cover - compiled
    """arr[q + j] = min(arr[q + j], kk) for 0 ≤ j < min(m, 8) of a 1-D int64 array: one masked
    load, min and store (AVX-512 on this machine; LLVM splits or scalarises it elsewhere). Masked-off
    lanes are neither read nor written, so q + 7 may lie past the array's end."""
    sig = types.void(arr, q, m, kk)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        i32, i64 = ir.IntType(32), ir.IntType(64)
        vty, mty = ir.VectorType(i64, 8), ir.VectorType(ir.IntType(1), 8)

        def splat(x):
            v = builder.insert_element(ir.Constant(vty, ir.Undefined), x, ir.Constant(i32, 0))
            return builder.shuffle_vector(v, ir.Constant(vty, ir.Undefined), ir.Constant(ir.VectorType(i32, 8), [0] * 8))

        ptr = builder.gep(ary.data, [context.cast(builder, args[1], signature.args[1], types.intp)])
        vptr = builder.bitcast(ptr, vty.as_pointer())
        lanes = ir.Constant(vty, [ir.Constant(i64, j) for j in range(8)])
        mask = builder.icmp_signed("<", lanes, splat(context.cast(builder, args[2], signature.args[2], types.int64)))
        k = splat(context.cast(builder, args[3], signature.args[3], types.int64))
        load = cgutils.get_or_insert_function(builder.module, ir.FunctionType(vty, [vty.as_pointer(), i32, mty, vty]),
                                              "llvm.masked.load.v8i64.p0v8i64")
        store = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [vty, vty.as_pointer(), i32, mty]),
                                               "llvm.masked.store.v8i64.p0v8i64")
        old = builder.call(load, [vptr, ir.Constant(i32, 8), mask, k])
        builder.call(store, [builder.select(builder.icmp_signed("<", k, old), k, old), vptr, ir.Constant(i32, 8), mask])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def fetch_add(typingctx, arr, i, v):  # pragma: no cover - compiled
    """arr[i] += v atomically for a 1-D int64 array; returns the value before (LLVM's atomicrmw add,
    sequentially consistent): threads taking work items from a shared counter."""
    sig = types.int64(arr, i, v)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1]], wraparound=False, boundscheck=False)
        val = context.cast(builder, args[2], signature.args[2], types.int64)
        return builder.atomic_rmw("add", ptr, val, "seq_cst")

    return sig, codegen


def host_has_avx512() -> bool:
    """Whether numba compiles for a CPU with AVX-512F (its host CPU, unless NUMBA_CPU_NAME says otherwise)."""
    try:
        import llvmlite.binding as llvm

        name = numba.config.CPU_NAME
        return (name is None or name == "host") and bool(llvm.get_host_cpu_features().get("avx512f", False))
    except Exception:  # noqa: BLE001 - any doubt: the portable form
        return False


#: :func:`compress16` compresses in a register where AVX-512 has it (the memory form of
#: ``vpcompressd`` is microcoded on Zen 4: 3 ms slower a map than the scalar appends it replaced).
AVX512 = host_has_avx512()


@intrinsic
def compress16(typingctx, flags, c0, out, n):  # pragma: no cover - compiled
    """Appends to ``out`` (1-D int32) from index ``n`` the columns c0 + j, 0 ≤ j < 16, whose byte
    ``flags[c0 + j]`` is not zero, in order; returns the new length. With AVX-512: ``vpcompressd``
    into a register and a store of all 16 lanes (entries past the new length are scratch);
    elsewhere LLVM's portable compress-store. ``flags[c0:c0 + 16]`` must lie in the array, and
    ``out`` have room for 16 entries from ``n``."""
    sig = types.int64(flags, c0, out, n)

    def codegen(context, builder, signature, args):
        i1, i8, i16, i32, i64 = ir.IntType(1), ir.IntType(8), ir.IntType(16), ir.IntType(32), ir.IntType(64)
        fl = context.make_array(signature.args[0])(context, builder, args[0])
        ot = context.make_array(signature.args[2])(context, builder, args[2])
        c0 = context.cast(builder, args[1], signature.args[1], types.int64)
        n = context.cast(builder, args[3], signature.args[3], types.int64)
        fptr = builder.bitcast(builder.gep(fl.data, [c0]), ir.VectorType(i8, 16).as_pointer())
        bytes16 = builder.load(fptr, align=1)
        mask = builder.icmp_unsigned("!=", bytes16, ir.Constant(ir.VectorType(i8, 16), [0] * 16))
        base = builder.insert_element(ir.Constant(ir.VectorType(i32, 16), ir.Undefined), builder.trunc(c0, i32),
                                      ir.Constant(i32, 0))
        base = builder.shuffle_vector(base, ir.Constant(ir.VectorType(i32, 16), ir.Undefined),
                                      ir.Constant(ir.VectorType(i32, 16), [0] * 16))
        cols = builder.add(base, ir.Constant(ir.VectorType(i32, 16), list(range(16))))
        v16 = ir.VectorType(i32, 16)
        optr = builder.bitcast(builder.gep(ot.data, [n]), v16.as_pointer())
        if AVX512:
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(v16, [v16, v16, ir.VectorType(i1, 16)]),
                                                "llvm.x86.avx512.mask.compress.v16i32")
            packed = builder.call(fn, [cols, ir.Constant(v16, [0] * 16), mask])
            builder.store(packed, optr, align=4)  # all 16 lanes: those past the new length are scratch
        else:
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [v16, i32.as_pointer(), ir.VectorType(i1, 16)]),
                                                "llvm.masked.compressstore.v16i32")
            builder.call(fn, [cols, builder.bitcast(optr, i32.as_pointer()), mask])
        bits = builder.bitcast(mask, i16)
        pop = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i16, [i16]), "llvm.ctpop.i16")
        cnt = builder.zext(builder.call(pop, [bits]), i64)
        return builder.add(n, cnt)

    return sig, codegen
