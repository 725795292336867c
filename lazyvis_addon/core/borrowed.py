"""Arrays without reference counting inside compiled kernels.

Numba counts references to every array it hands around inside a compiled function: an array passed to an
inlined helper, or a row view such as ``start[i]``, costs an atomic increment and decrement of the array's
reference count (``NRT_incref`` / ``NRT_decref``), unless its pruning pass can pair them up, which it mostly
cannot across loops and branches. In pass 2's kernels those atomic operations were most of the time: perf
put 64 % of detection's samples on the two functions (the tree at 256 px), and the two render threads
contend for the same counters (numba/numba#4261, #9393 discuss the cost).

``borrowed(a)`` is the same array (data, shape, strides) with no owner: Numba's reference counting skips
it, and LLVM drops the calls altogether. It is only safe while the owner lives, so a kernel borrows only

- its arguments (the caller holds them for the whole call), and
- arrays it allocated itself and keeps by their own name until it returns (the borrowed copy goes by
  another name; Numba frees a variable after its last use);

and never returns, stores or yields a borrowed array.
"""

from __future__ import annotations

from numba.core import types
from numba.extending import intrinsic


@intrinsic
def borrowed(typing_context, array):
    """``array`` (any Numba array type) with no owner: the same type, data, shape and strides, a null
    meminfo and parent. See the module docstring for when that is safe."""
    if not isinstance(array, types.Array):
        return None

    def codegen(context, builder, signature, args):
        source = context.make_array(array)(context, builder, args[0])
        out = context.make_array(array)(context, builder)
        context.populate_array(out, data=source.data, shape=source.shape, strides=source.strides,
                               itemsize=source.itemsize, meminfo=None, parent=None)
        return out._getvalue()

    return array(array), codegen
