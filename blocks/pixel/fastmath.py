"""``exp``, ``log`` and ``log1p`` as plain arithmetic, so that compiled loops over pixels vectorise.

The C library's functions are opaque calls: a loop that takes a logarithm per pixel runs one
pixel at a time. These are the same algorithms written out in arithmetic and bit operations,
which the compiler turns into SIMD code, and which give the same bits in a vectorised loop
as in scalar code (no contraction or reassociation without fast-math). The event-driven
pixels use them wherever a pixel's drive or its filter's relaxation is computed, on every
input path, so the paths agree bit for bit.

* :func:`exp_`: fdlibm ``e_exp.c`` (Sun Microsystems 1993): ``x = k ln 2 + r``, ``|r| <= ln 2 / 2``
  (``ln 2`` split in two parts), a degree-5 minimax rational form for ``e^r``, scaled by ``2^k``;
  error < 1 ulp. Domain ``[-708, 709]`` (callers flush below).
* :func:`log_`: fdlibm ``e_log.c``: ``x = 2^k m``, ``sqrt(2)/2 <= m < sqrt(2)``, ``ln m`` from
  ``s = (m - 1)/(m + 1)`` with a degree-14 minimax polynomial in ``s``; error < 1 ulp. Zero,
  negative, infinite and NaN inputs give the IEEE results; subnormals are rescaled.
* :func:`log1p_`: ``ln(1 + w) = ln(u) w / (u - 1)``, ``u = 1 + w`` rounded (Goldberg 1991, "What
  every computer scientist should know about floating-point arithmetic", Theorem 4): a
  few ulp, for ``w > -1``.

Accuracy is checked against NumPy over the pixels' range (tests).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import types
from numba.extending import intrinsic

_LN2_HI = 6.93147180369123816490e-01        # upper bits of ln 2 (fdlibm)
_LN2_LO = 1.90821492927058770002e-10        # ln 2 - _LN2_HI
_INV_LN2 = 1.44269504088896338700e+00
_P1, _P2, _P3, _P4, _P5 = (1.66666666666666019037e-01, -2.77777777770155933842e-03, 6.61375632143793436117e-05,
                           -1.65339022054652515390e-06, 4.13813679705723846039e-08)          # e_exp.c
_LG1, _LG2, _LG3, _LG4, _LG5, _LG6, _LG7 = (6.666666666666735130e-01, 3.999999999940941908e-01,
                                            2.857142874366239149e-01, 2.222219843214978396e-01,
                                            1.818357216161805012e-01, 1.531383769920937332e-01,
                                            1.479819860511658591e-01)                          # e_log.c
_SMALLEST_NORMAL = 2.2250738585072014e-308
_TWO_54 = 18014398509481984.0

jit = numba.njit(cache=True, error_model="numpy", inline="always")     # inlined: loops over pixels vectorise


#: LLVM function attributes of :func:`wide_vectors` (as the optics' ``column_fft.WIDE_VECTOR_ATTRIBUTES``)
WIDE_VECTOR_ATTRIBUTES = ('"prefer-vector-width"="512"', '"min-legal-vector-width"="512"')


@intrinsic
def wide_vectors(typingctx):
    """Compile the calling function with vectors of up to 512 bits where the CPU has them (AVX-512), as the optics'
    ``column_fft.wide_vectors``: the same lane-wise operations, so the same bits. Defined here, not imported from
    there, because the pixels' compiled code must read only this folder's code (their Numba cache is stamped by it,
    ``evsda.graph.numba_stamps``). A call compiles to nothing."""
    def codegen(context, builder, signature, args):
        # llvmlite's attribute set names only LLVM's keyword attributes; these string attributes are written as given
        for attribute in WIDE_VECTOR_ATTRIBUTES:
            set.add(builder.function.attributes, attribute)
        return context.get_dummy_value()
    return types.none(), codegen


@intrinsic
def _bits_to_float(typingctx, bits):
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.float64))
    return types.float64(types.int64), codegen


@intrinsic
def _float_to_bits(typingctx, x):
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.int64))
    return types.int64(types.float64), codegen


@jit
def exp_(x):
    """``e^x`` for ``-708 <= x <= 709`` (fdlibm ``e_exp.c``)."""
    k = math.floor(x * _INV_LN2 + 0.5)
    hi = x - k * _LN2_HI
    lo = k * _LN2_LO
    r = hi - lo
    t = r * r
    c = r - t * (_P1 + t * (_P2 + t * (_P3 + t * (_P4 + t * _P5))))
    y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi)
    return y * _bits_to_float((np.int64(k) + np.int64(1023)) << np.int64(52))


@jit
def log_(x):
    """``ln x`` (fdlibm ``e_log.c``); ``-inf`` at 0, NaN below 0 or for NaN, ``inf`` at ``inf``."""
    tiny = x < _SMALLEST_NORMAL
    bits = _float_to_bits(x * _TWO_54 if tiny else x)
    high = bits >> np.int64(32)
    i = ((high & np.int64(0x000fffff)) + np.int64(0x95f64)) & np.int64(0x100000)    # m above sqrt(2): halve it
    k = (high >> np.int64(20)) - np.int64(1023) + (i >> np.int64(20)) - (np.int64(54) if tiny else np.int64(0))
    m = _bits_to_float((bits & np.int64(0x000fffffffffffff)) | ((i ^ np.int64(0x3ff00000)) << np.int64(32)))
    f = m - 1.0
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    r = z * (_LG1 + w * (_LG3 + w * (_LG5 + w * _LG7))) + w * (_LG2 + w * (_LG4 + w * _LG6))
    half_f2 = 0.5 * f * f
    dk = float(k)
    result = dk * _LN2_HI - ((half_f2 - (s * (half_f2 + r) + dk * _LN2_LO)) - f)
    special = -math.inf if x == 0.0 else (x if x > 0.0 else math.nan)
    return result if (x > 0.0) & (x < math.inf) else special


@jit
def log1p_(w):
    """``ln(1 + w)`` for ``w > -1`` (Goldberg 1991, Theorem 4)."""
    u = 1.0 + w
    ratio = log_(u) * (w / (u - 1.0))          # selects, not branches: vectorises
    ratio = u if u == math.inf else ratio
    return w if u == 1.0 else ratio
