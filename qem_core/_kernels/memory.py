"""Memory helpers for the contraction loop: arrays without reference counting, and
prefetching of the rows a contraction is about to read.

**Borrowed views.** Numba counts references to every array with atomic increments and
decrements, and its pruning pass leaves many in place: when LLVM merges the exits of a
function it sinks the decrements into one call on a phi of pointers, which the pass no
longer pairs with the increments at entry. In the contraction loop, where a dozen small
kernels each take a dozen arrays and run several times per contraction, those atomics
were a fifth of the time. A view whose meminfo is null costs nothing to count
(NRT_incref and NRT_decref return at once on null). Such a view does not keep its memory
alive: borrow only arrays that the caller holds for the whole kernel call, and never
return or store the view.

**Kernels without reference counting.** Borrowed views make each count a call that
returns at once, but the calls stay: a kernel that is not inlined counts every array
argument up at entry and down at each exit, a few hundred calls per contraction in
``update_vertex_edges`` alone (a fifth of its time). ``borrowing_kernel`` compiles a
kernel with numba's ``_nrt=False``, which emits no counting at all: for kernels that
allocate nothing and return no array, whose callers hold every array they pass.

**Prefetching.** A contraction reads the rows of a dozen vertices scattered over arrays
far larger than the cache, and each cost evaluation is long enough (a few hundred
cycles) that the processor never runs ahead into the next vertex's loads: the misses
come one after another. Asking for all the rows as soon as the neighbours are known lets
them arrive together.
"""

import numba
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic


def borrowing_kernel(function, nogil=False):
    """``numba.njit(cache=True)`` without reference counting (see the module docstring).
    The kernel must not allocate (numba refuses to compile it then) nor return an array.
    ``nogil``: it releases the GIL, for calls from Python threads at once."""
    return numba.njit(cache=True, _nrt=False, nogil=nogil)(function)


@intrinsic
def borrow(typingctx, array):
    """The same array (data, shape, strides), with no meminfo and no parent object."""
    if not isinstance(array, types.Array):
        return None

    def codegen(context, builder, signature, args):
        source = context.make_array(array)(context, builder, value=args[0])
        view = context.make_array(array)(context, builder)
        context.populate_array(view, data=source.data, shape=source.shape,
                               strides=source.strides, itemsize=source.itemsize,
                               meminfo=None)
        return view._getvalue()

    return array(array), codegen


@intrinsic
def prefetch(typingctx, array, row, offset):
    """Hint that byte ``offset`` of row ``row`` of ``array`` will be read soon (no
    bounds check: a prefetch never faults)."""
    if not isinstance(array, types.Array):
        return None

    def codegen(context, builder, signature, args):
        view = context.make_array(signature.args[0])(context, builder, value=args[0])
        row_bytes = builder.extract_value(view.strides, 0)
        position = builder.add(builder.mul(args[1], row_bytes), args[2])
        byte_pointer = ir.IntType(8).as_pointer()
        address = builder.gep(builder.bitcast(view.data, byte_pointer), [position])
        int32 = ir.IntType(32)
        function = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [byte_pointer, int32, int32, int32]),
            "llvm.prefetch.p0",
        )
        # read, high temporal locality, data cache
        builder.call(function, [address, int32(0), int32(3), int32(1)])
        return context.get_dummy_value()

    return types.none(array, types.intp, types.intp), codegen
