"""Python's own float results in compiled code (numba), where the compiled form would round differently.

The compiled models keep the bits of the plain-Python formulas they replaced. Arithmetic, `min`, `max`, `abs`,
`%` and the math functions that call the C library (sin, cos, tanh, atan2, sqrt, pow) give the same floats in
numba as in CPython, with two exceptions handled here:

- `x ** y` is the C library's pow(x, y) in CPython (Objects/floatobject.c, float_pow), but LLVM rewrites a
  pow(x, 2.0) call as x * x, which rounds differently from glibc's pow for ~0.1% of x. `py_pow` calls pow under
  a name LLVM does not know, so no rewrite happens.
- `math.hypot` is not the C library's hypot in CPython (numba calls that one, which differs in the last bit for
  ~0.2% of inputs) but CPython's `vector_norm` (Modules/mathmodule.c): lossless scaling by a power of two, exact
  squares, compensated sums and one differential correction of the square root. `py_hypot` is that algorithm
  for two coordinates, as CPython 3.11 has it (Dekker's exact product; below the normal range 3.11 divides by
  the largest coordinate instead of scaling).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import math

from llvmlite import binding
from numba import njit, types


def _c_pow_address() -> int:
    """The address of the C library's pow, the one CPython links: libm on Linux and macOS, the UCRT on Windows."""
    library = next(filter(None, map(ctypes.util.find_library, ("m", "ucrtbase", "c"))))
    return ctypes.cast(ctypes.CDLL(library).pow, ctypes.c_void_p).value


binding.add_symbol("ftcgym_libm_pow", _c_pow_address())
#: the C library's pow(x, y), the function CPython's x ** y calls, under a name LLVM does not rewrite
py_pow = types.ExternalFunction("ftcgym_libm_pow", types.float64(types.float64, types.float64))

_VELTKAMP = 134217729.0            # 2**27 + 1: splits a double into two halves of 26 bits
_MIN_EXPONENT = -1023              # frexp exponent of the smallest normal double


@njit(cache=True)
def _exact_square(x):  # pragma: no cover (compiled)
    """(hi, lo) with hi + lo = x * x exactly, hi = fl(x * x) (Dekker's product, CPython's dl_mul)."""
    t = x * _VELTKAMP
    high = t - (t - x)
    low = x - high
    square = x * x
    return square, ((high * high - square) + 2.0 * high * low) + low * low


@njit(cache=True)
def _accumulate(csum, frac1, frac2, hi, lo):  # pragma: no cover (compiled)
    """One term into vector_norm's sums: csum + hi split exactly (dl_fast_sum), the errors kept in frac1, frac2."""
    total = csum + hi
    return total, frac1 + lo, frac2 + ((csum - total) + hi)


@njit(cache=True)
def py_hypot(x, y):  # pragma: no cover (compiled)
    """math.hypot(x, y) as CPython 3.11 computes it (Modules/mathmodule.c, math_hypot and vector_norm)."""
    a, b = abs(x), abs(y)
    if math.isinf(a) or math.isinf(b):
        return math.inf
    if math.isnan(a) or math.isnan(b):
        return math.nan
    biggest = max(a, b)
    if biggest == 0.0:
        return biggest
    exponent = math.frexp(biggest)[1]
    if exponent < _MIN_EXPONENT:            # 2**-exponent would overflow: divide by the largest instead
        csum, frac = 1.0, 0.0
        for value in (a, b):
            square = (value / biggest) * (value / biggest)
            total = csum + square
            frac += (csum - total) + square
            csum = total
        return biggest * math.sqrt(csum - 1.0 + frac)
    scale = math.ldexp(1.0, -exponent)     # lossless scaling into [0.5, 1)
    csum, frac1, frac2 = 1.0, 0.0, 0.0
    for value in (a, b):
        hi, lo = _exact_square(value * scale)
        csum, frac1, frac2 = _accumulate(csum, frac1, frac2, hi, lo)
    h = math.sqrt(csum - 1.0 + (frac1 + frac2))
    hi, lo = _exact_square(h)
    csum, frac1, frac2 = _accumulate(csum, frac1, frac2, -hi, -lo)
    h += (csum - 1.0 + (frac1 + frac2)) / (2.0 * h)     # differential correction
    return h / scale
