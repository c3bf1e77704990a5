"""Calling compiled (numba) code from the per-step Python at the cost of the call alone."""
from __future__ import annotations


def without_dispatch(function, *example):
    """The numba `function` compiled for the types of `example`, as a callable that skips numba's type dispatch
    on every call (about 1 us on the development machine: more than the work of the small compiled calls of each
    physics step). Only for calls whose argument types are fixed by construction, as the physics step's are: the
    compiled entry converts its arguments to the compiled types without checking them. With numba's JIT off
    (NUMBA_DISABLE_JIT=1) `function` is plain Python and comes back as it is."""
    if not hasattr(function, "compile"):
        return function
    entry = function.compile(tuple(function.typeof_pyval(value) for value in example))
    return entry if callable(entry) else function
