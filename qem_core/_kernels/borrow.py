"""Array views without reference counting, for the arrays of the contraction loop.

Numba counts references to every array with atomic increments and decrements, and its
pruning pass leaves many in place: when LLVM merges the exits of a function it sinks the
decrements into one call on a phi of pointers, which the pass no longer pairs with the
increments at entry. In the contraction loop, where a dozen small kernels each take a
dozen arrays and run several times per contraction, those atomics were a fifth of the
time. A view whose meminfo is null costs nothing to count (NRT_incref and NRT_decref
return at once on null).

Such a view does not keep its memory alive: borrow only arrays that the caller holds for
the whole kernel call, and never return or store the view.
"""

from numba.core import types
from numba.extending import intrinsic


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


__all__ = ["borrow"]
