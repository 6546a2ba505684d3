"""Compiled functions called without numba's dispatcher, for the live loop's few calls per step.

Calling a numba function from Python goes through its dispatcher, which
types every argument (``typeof`` of each, then a lookup of the signature)
before it calls the machine code. Warm, that costs ~0.1 µs an argument; in a
1 kHz loop, whose step runs on caches the rest of the period (other
processes, the hypervisor's exits) has cooled, the dispatcher's branchy C
path is most of the call: a 9-argument call measured ~15 µs cold against
~6 µs for its machine code alone. :func:`direct` resolves the signature once
and returns the compiled function's own entry point (numba's CPython
wrapper: it unboxes the arguments and calls the machine code), which the
caller then calls with arguments of the same types.
"""
from __future__ import annotations


def direct(dispatcher, *args):
    """The entry point of ``dispatcher`` (a ``numba.njit`` function) for the types of ``args``.

    Compiled, or loaded from numba's cache, now. The caller must pass
    arguments of the same types every time: the entry point converts
    scalars (a float parameter takes an int) but checks nothing else.
    """
    return dispatcher.compile(tuple(dispatcher.typeof_pyval(a) for a in args))
