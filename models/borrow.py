"""Borrowed array views for the compiled hot loops: no reference counting on the views they make.

Every view numba makes of an array (``a[j]``, ``a[i:k]``) takes a reference
on the array's memory with an atomic increment, and gives it back with an
atomic decrement; in a loop that steps hundreds of candidates thousands of
times through the play operators' row views, these atomics were a third of
the time. :func:`borrow` returns a view of an array with no owner: the views
made from it skip the atomics (numba's ``NRT_incref`` returns at once on no
owner). The caller keeps the original alive: a kernel borrows its own
arguments, which live until it returns.

:func:`pointer` goes one step further for the live loop's calls of one
candidate: a kernel takes the integer address of a buffer (``a.ctypes.data``)
and views it with ``numba.carray(pointer(address, np.float64), shape)``, an
array without an owner too. Numba's entry point unboxes an array argument
into a new owner record (an allocation, a reference, a free after the call;
~0.5 µs an array on cold caches, measured) and an integer into a register:
the caller keeps the buffer alive and in place for as long as it passes its
address.
"""
from __future__ import annotations

from numba.core import types
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array


@intrinsic
def borrow(typingctx, arr):
    """A view of ``arr`` (same type) without an owner, valid while ``arr`` is alive."""
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, sig, args):
        src = make_array(sig.args[0])(context, builder, args[0])
        out = make_array(sig.return_type)(context, builder)
        populate_array(out, data=src.data, shape=src.shape, strides=src.strides, itemsize=src.itemsize,
                       meminfo=None)
        return out._getvalue()

    return arr(arr), codegen


@intrinsic
def pointer(typingctx, address, dtype):
    """A pointer to ``dtype`` (a numpy scalar type, e.g. ``np.float64``) at the integer ``address``."""
    if not isinstance(address, types.Integer) or not isinstance(dtype, types.NumberClass):
        return None
    ptr = types.CPointer(dtype.instance_type)

    def codegen(context, builder, sig, args):
        return builder.inttoptr(args[0], context.get_value_type(ptr))

    return ptr(address, dtype), codegen
