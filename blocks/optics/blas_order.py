"""The stamps' products ``B PSF B^T`` in the order of OpenBLAS's AVX-512 small-matrix ``sgemm``, bit for bit.

The renderer's frame path (:func:`.render._stamp_frames`) turns each PSF (80 x 80, float32) into its stamp
(7 x 7) with two products, ``half = PSF B^T`` (80 x 7) and ``image = B half`` (7 x 7), whose bits must be numpy's
``matmul`` (BLAS's ``sgemm``; :meth:`.render.PupilRenderer._frames_agree`). A product's bits are its sums' order,
which is the BLAS build's. OpenBLAS (0.3.x as numpy's and scipy's wheels ship it, ``DYNAMIC_ARCH``) runs products of
these shapes on AVX-512 CPUs (its ``SkylakeX`` kernels, Intel's and AMD's Zen 4) through its small-matrix kernel,
which makes every output as a dot product over ``k < 80``: 16 lane sums, lane ``q`` fused multiply-adds
from +0 over ``k = q, q + 16, ..., q + 64`` in turn, then the 16 lanes added in a tree: adjacent lanes first
(8 sums, then 4, 2, 1: :data:`_PAIRWISE`), except, in ``B half``, the outputs whose row and column are both past the
first four, whose lanes are added by halves (lane ``q`` and ``q + 8``, then 4, 2, 1: ``_mm512_reduce_add_ps``,
:data:`_HALVED`). :func:`products` makes the same operations, 16 outputs side by side in vector registers
(:func:`_dot16`, LLVM's IR): a stamp's products and scale 1.4 against 1.6 us, the stamp 3-4 % quicker
(docs/speed.md, twentieth session).

That order is one BLAS build's on one kind of CPU: the renderer takes :func:`products` only where
:func:`same_as_numpy` holds (numpy's ``matmul`` gives its bits on random PSFs and the renderer's own ``B``, checked
once a renderer), and numpy's products otherwise. An order that differs anywhere (another kernel, another
reduction, a BLAS other than OpenBLAS) rounds 80-term sums of random numbers differently in many of them, so the
check does not pass by chance (:func:`same_as_numpy`); the order does not depend on the data (no branch on the
values in these kernels), so what holds on the check's PSFs holds on every PSF.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from .column_fft import wide_vectors

#: the transform length (the PSF's side, the products' inner dimension) and the lanes of one 512-bit vector
LENGTH, LANES = 80, 16
#: the stamp's side the products are made for (7 x 7 pixels: the tracked pass's geometry)
STAMP = 7
#: :func:`products`' buffers: ``half_t`` (``B half``'s 16 lanes read rows 7-15, kept zero) and ``image`` (rows of 16)
HALF_T_SIZE, IMAGE_SIZE = LANES * LENGTH, STAMP * LANES


def _tree(pairs_of: callable) -> list[tuple[list[int], list[int]]]:
    """The lane tree's four levels: at level ``k`` two vectors, each holding ``16 >> k`` partial sums per output for
    ``2^k`` outputs, become one holding half as many per output for twice the outputs (the first vector's outputs
    first): the shuffles' indices of the two addends (0-15 the first vector's lanes, 16-31 the second's).
    ``pairs_of(width)`` gives, within one output's ``width`` partial sums, which pairs are added (first, second)."""
    levels = []
    for level in range(4):
        width = LANES >> level
        first, second = [], []
        for source in range(2):
            for output in range(LANES // width):
                base = LANES * source + output * width
                for a, b in pairs_of(width):
                    first.append(base + a)
                    second.append(base + b)
        levels.append((first, second))
    return levels


#: adjacent partial sums added (lanes 2i and 2i + 1)
_PAIRWISE = _tree(lambda width: [(2 * i, 2 * i + 1) for i in range(width // 2)])
#: partial sums added by halves (lanes i and i + width / 2: ``_mm512_reduce_add_ps``)
_HALVED = _tree(lambda width: [(i, i + width // 2) for i in range(width // 2)])


@intrinsic
def _dot16(typingctx, a, a_start, a_step, b, b_start, b_step, target, target_start, halved):
    """``target[target_start + o] = sum_k a[a_start + o a_step + k] b[b_start + o b_step + k]`` for ``o < 16`` and
    ``k < 80`` (flat float32 arrays; ``a_step`` or ``b_step`` 0 for one vector shared by the 16 outputs) in the small
    kernel's order (module docstring): each output's 16 lane sums (five fused multiply-adds from +0), added
    in the pairwise tree, or in the halves' tree for outputs whose bit is set in ``halved``; one 16-lane store."""
    def codegen(context, builder, signature, args):
        vector = ir.VectorType(ir.FloatType(), LANES)
        indices = ir.VectorType(ir.IntType(32), LANES)
        # llvmlite's declare_intrinsic names scalar types only: the vector one declared by its LLVM name
        fma = (builder.module.globals.get("llvm.fma.v16f32")
               or ir.Function(builder.module, ir.FunctionType(vector, [vector] * 3), name="llvm.fma.v16f32"))
        a_data, b_data, target_data = (context.make_array(signature.args[i])(context, builder, args[i]).data
                                       for i in (0, 3, 6))
        a_start, a_step, b_start, b_step, target_start, halved_bits = (args[i] for i in (1, 2, 4, 5, 7, 8))

        def load(data, start, step, output, part):
            at = builder.add(builder.add(start, builder.mul(step, ir.Constant(step.type, output))),
                             ir.Constant(start.type, LANES * part))
            return builder.load(builder.bitcast(builder.gep(data, [at]), vector.as_pointer()), align=4)

        sums, zero = [], ir.Constant(vector, [0.0] * LANES)
        for output in range(LANES):
            total = zero                                        # +0: a sum of -0 products is +0, as the kernel's
            for part in range(LENGTH // LANES):
                total = builder.call(fma, [load(a_data, a_start, a_step, output, part),
                                           load(b_data, b_start, b_step, output, part), total])
            sums.append(total)

        def added(rows, levels):
            for first, second in levels:
                rows = [builder.fadd(builder.shuffle_vector(rows[2 * i], rows[2 * i + 1], ir.Constant(indices, first)),
                                     builder.shuffle_vector(rows[2 * i], rows[2 * i + 1], ir.Constant(indices, second)))
                        for i in range(len(rows) // 2)]
            return rows[0]

        pairwise, halves = added(sums, _PAIRWISE), added(sums, _HALVED)
        bits = ir.VectorType(halved_bits.type, LANES)
        chosen = builder.icmp_unsigned("!=", builder.and_(
            builder.shuffle_vector(builder.insert_element(ir.Constant(bits, None), halved_bits,
                                                          ir.Constant(ir.IntType(32), 0)),
                                   ir.Constant(bits, None), ir.Constant(indices, [0] * LANES)),
            ir.Constant(bits, [1 << o for o in range(LANES)])), ir.Constant(bits, [0] * LANES))
        result = builder.select(chosen, halves, pairwise)
        builder.store(result, builder.bitcast(builder.gep(target_data, [target_start]), vector.as_pointer()), align=4)
        return context.get_dummy_value()
    return types.none(a, a_start, a_step, b, b_start, b_step, target, target_start, halved), codegen


#: ``B half``'s outputs of rows 4-6 whose columns 4-6 are summed by halves (bits 4, 5, 6)
_HALVED_COLUMNS = 0b1110000


@numba.njit(cache=True, error_model="numpy", nogil=True)
def products(psf, b, half_t, image):
    """``image = B (PSF B^T)`` in the small kernel's order: ``psf`` (80 x 80), ``b`` (7 x 80) flat float32;
    ``half_t`` (``HALF_T_SIZE``) the transposed ``PSF B^T`` (7 rows of 80, its rows 7-15 zero: read as the lanes
    ``image``'s rows do not use), ``image`` (``IMAGE_SIZE``) the stamp's 7 rows of 16 floats, columns 7-15 not
    part of it. Quickest on 64-byte aligned buffers (the renderer's): a 16-lane load across two cache lines costs
    two."""
    wide_vectors()
    for j in range(STAMP):                       # half_t[j, m] = sum_k b[j, k] psf[m, k], 16 m at a time
        for m in range(0, LENGTH, LANES):
            _dot16(b, LENGTH * j, 0, psf, LENGTH * m, LENGTH, half_t, LENGTH * j + m, 0)
    for i in range(STAMP):                       # image[i, j] = sum_k half_t[j, k] b[i, k], j < 7 of 16 lanes
        _dot16(half_t, 0, LENGTH, b, LENGTH * i, 0, image, LANES * i, _HALVED_COLUMNS if i >= 4 else 0)


def same_as_numpy(b: np.ndarray, trials: int = 24, matmul=np.matmul) -> bool:
    """Whether :func:`products` gives numpy's ``matmul`` bits (``PSF B^T``, then ``B`` times it, in float32;
    ``matmul``: the products to agree with) for this ``b`` (7 x 80), a random one and a negative one (whose
    products with zeros are -0), on ``trials`` random PSFs (non-negative, twelve decades of scale, as ``|.|^2``
    makes them) and on PSFs with zero rows, zero columns and a whole zero one (the signed zeros' sums), all in one
    batched ``matmul`` as the chunked path makes them; False where it does not compile. The smallest difference of
    order, one output's lanes added in the other tree, rounds differently on ~30 % of random PSFs (measured): over
    the ~65 random PSF-and-``B`` pairs it passes with a chance below 1e-9; a different kernel differs in many
    outputs. ~2-3 ms once a renderer."""
    if b.shape != (STAMP, LENGTH) or b.dtype != np.float32:
        return False
    rng = np.random.default_rng(29)
    psf = (rng.uniform(0.0, 1.0, (trials, LENGTH, LENGTH)) ** 3
           * 10.0 ** rng.uniform(-6.0, 6.0, (trials, 1, 1))).astype(np.float32)
    psf[1, 3:11] = 0.0
    psf[2, :, 5:40] = 0.0
    psf[3] = 0.0
    half_t, image = np.zeros(HALF_T_SIZE, np.float32), np.zeros(IMAGE_SIZE, np.float32)
    others = rng.standard_normal((2, STAMP, LENGTH)).astype(np.float32)
    for matrix in (b, others[0], -np.abs(others[1])):
        expected_half = matmul(psf, np.ascontiguousarray(matrix.T))
        expected = matmul(matrix, expected_half)
        flat_b = np.ascontiguousarray(matrix).reshape(-1)
        for frame, half, stamp in zip(psf, expected_half, expected):
            try:
                products(frame.reshape(-1), flat_b, half_t, image)
            except Exception:          # noqa: BLE001 -- not compiled here (an LLVM without these vectors): numpy's
                return False
            if not (np.array_equal(half_t[:STAMP * LENGTH].reshape(STAMP, LENGTH).T.view(np.uint32),
                                   half.view(np.uint32))
                    and np.array_equal(image.reshape(STAMP, LANES)[:, :STAMP].view(np.uint32),
                                       stamp.view(np.uint32))):
                return False
    return True
