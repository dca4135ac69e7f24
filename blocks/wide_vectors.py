"""Compiled loops with vectors of up to 512 bits, for any block's Numba kernels.

LLVM's x86 tuning keeps loops to 256-bit vectors on AVX-512 CPUs (``prefer-256-bit``) and splits explicit 512-bit
vector types in two, unless a function asks for more. :func:`wide_vectors`, called first in an ``@njit`` function,
asks. The optics' stamps (:mod:`evsda.blocks.optics.column_fft`, :mod:`evsda.blocks.optics.render`) and the pixels'
vectorised loops (:mod:`evsda.blocks.pixel.fastmath` and its callers) use it (docs/speed.md, sixteenth session).
"""

from __future__ import annotations

from numba.core import types
from numba.extending import intrinsic

#: LLVM function attributes of :func:`wide_vectors`: vectors up to 512 bits in the loops and as legal types
WIDE_VECTOR_ATTRIBUTES = ('"prefer-vector-width"="512"', '"min-legal-vector-width"="512"')


@intrinsic
def wide_vectors(typingctx):
    """Compile the calling function with vectors of up to 512 bits where the CPU has them (AVX-512): LLVM's x86
    tuning keeps loops to 256-bit vectors on AVX-512 CPUs unless a function asks for more
    (``WIDE_VECTOR_ATTRIBUTES``). The lanes make the same operations either way (no reductions, nothing fused), so
    the bits are the same; on a CPU without AVX-512 nothing changes. A stamp takes ~0.87x the time with them
    (docs/speed.md, sixteenth session). A call compiles to nothing."""
    def codegen(context, builder, signature, args):
        # llvmlite's attribute set names only LLVM's keyword attributes; these string attributes are written as given
        for attribute in WIDE_VECTOR_ATTRIBUTES:
            set.add(builder.function.attributes, attribute)
        return context.get_dummy_value()
    return types.none(), codegen
