"""The padded spectra's length-80 FFTs, compiled, with the bits of scipy's pocketfft.

The pupil path's zero-padded FFT (:class:`.render.PupilRenderer`) transforms the pupil's rows along x, then
every column along y. On the tracked pass (a 40-sample pupil padded to L = 80) pocketfft took ~11.5 us a PSF for
the 80 columns and ~6.5 for the 40 rows: scipy builds it for SSE2 (4 floats a vector) and it copies each group of
4 lines to a buffer and back. Here the same transforms run on many lines side by side as vector lanes: all 80
columns of a frame in place (:func:`columns`), or the pupil's 40 rows of a transposed field (:func:`rows`).

It is the mixed-radix FFTPACK algorithm (Swarztrauber 1982, in Vectorizing the FFTs, ed. Rodrigue, Academic
Press) in pocketfft's form (M. Reinecke, pocketfft, C++ header-only version as vendored by scipy 1.x; BSD-3-Clause):
length 80 factors as 2, 8, 5 (radix 8 first, then 4, then a 2 moved to the front, then odd factors), and each
pass below makes the same float32 operations in the same order as pocketfft's radix-2, radix-8 and radix-5 passes
(``ROTX45``/``ROTX135`` rotations, twiddles multiplied conjugated), with twiddles ``exp(2 pi i m / 80)`` rounded
once to float32. Nothing is fused or reassociated (no ``fastmath``: no fused multiply-adds), so the results equal
pocketfft's bit for bit; :func:`same_as_pocketfft` checks that on the running scipy, and the renderer uses these
passes only if it holds. Inputs 40-79 of every line are the padding's zeros: they are not read (the first pass
adds and subtracts a literal zero, the same operations).

Each pass is its own compiled function, its lane count a compile-time constant: in one function, or with the
lane count read from the arrays, the compiler left the radix-8 pass scalar.
Each asks for vectors of up to 512 bits (:func:`wide_vectors`; AVX-512 CPUs otherwise get 256-bit loops): the
same operations in each lane, so the same bits.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

#: transform length and lanes (the padded grid is square: 80 columns of 80 samples)
LENGTH = 80
_F32 = np.float32
#: twiddles exp(2 pi i m / 80) [1], rounded once to float32
_TWIDDLE_RE = np.cos(2 * np.pi * np.arange(LENGTH) / LENGTH).astype(np.float32)
_TWIDDLE_IM = np.sin(2 * np.pi * np.arange(LENGTH) / LENGTH).astype(np.float32)
#: both, for compiled callers of :func:`field_powers`
TWIDDLES = (_TWIDDLE_RE, _TWIDDLE_IM)
#: radix-5 constants cos/sin(2 pi / 5), cos/sin(4 pi / 5), the sines negated (forward transform), and sqrt(1/2)
_C1, _S1 = _F32(0.3090169943749474241022934171828191), -_F32(0.9510565162951535721164393333793821)
_C2, _S2 = _F32(-0.8090169943749474241022934171828191), -_F32(0.5877852522924731291687059546390728)
_HALF_SQRT2 = _F32(0.707106781186547524400844362104849)


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


def columns(grid: np.ndarray, scratch: np.ndarray) -> None:
    """``grid = fft(grid, axis=1)`` in place for complex64 ``grid`` (F, 80, 80) whose rows 40: are zero (not read);
    ``scratch``: float32 (4, 6400), this thread's."""
    _columns(grid.view(np.float32).reshape(len(grid), -1), scratch, _TWIDDLE_RE, _TWIDDLE_IM)


def rows(amplitude_t: np.ndarray, cosine_t: np.ndarray, sine_t: np.ndarray, grid: np.ndarray,
         scratch: np.ndarray) -> None:
    """``grid[:, :40] = fft(field, n=80, axis=2)`` for the fields ``field = amplitude (cosine + i sine)``, all given
    transposed (``field_t[f, x, y] = field[f, y, x]``): float32 ``cosine_t``, ``sine_t`` (F, 40, 40) and
    ``amplitude_t`` (1 or F, 40, 40), the products made in float32 as the transform reads them (numpy's complex64
    product with the real amplitude, :func:`.render.pupil_field`, bit for bit); the rows of 40 samples zero-padded to
    80; ``grid`` (F, 80, 80) complex64, rows 40: left as they are; ``scratch``: float32 (4, 6400), this thread's."""
    frames = len(cosine_t)
    _rows(amplitude_t.reshape(len(amplitude_t), -1), cosine_t.reshape(frames, -1), sine_t.reshape(frames, -1),
          grid.view(np.float32).reshape(len(grid), -1), scratch, _TWIDDLE_RE, _TWIDDLE_IM)


def column_powers(grid: np.ndarray, power: np.ndarray, scratch: np.ndarray) -> None:
    """``power = |fft(grid, axis=1)|^2`` (``re^2 + im^2`` in float32, as :func:`.render.squared_modulus`) for
    complex64 ``grid`` (F, 80, 80) whose rows 40: are zero (not read; ``grid`` is left as it is) into float32
    ``power`` (F, 80, 80); ``scratch``: float32 (4, 6400), this thread's."""
    _column_powers(grid.view(np.float32).reshape(len(grid), -1), power.reshape(len(power), -1), scratch,
                   _TWIDDLE_RE, _TWIDDLE_IM)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _column_powers(grid, power, scratch, twr, twi):
    wide_vectors()
    for f in range(grid.shape[0]):
        _radix2(grid[f], scratch[0], scratch[1], twr, twi, 80)
        _radix8(scratch[0], scratch[1], scratch[2], scratch[3], twr, twi, 80)
        _radix5_powers(scratch[2], scratch[3], power[f])


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _columns(grid, scratch, twr, twi):
    wide_vectors()
    for f in range(grid.shape[0]):
        _radix2(grid[f], scratch[0], scratch[1], twr, twi, 80)
        _radix8(scratch[0], scratch[1], scratch[2], scratch[3], twr, twi, 80)
        _radix5(scratch[2], scratch[3], grid[f], 80, 80, 1)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _rows(amplitude_t, cosine_t, sine_t, grid, scratch, twr, twi):
    wide_vectors()
    for f in range(cosine_t.shape[0]):
        _radix2_field(amplitude_t[f if amplitude_t.shape[0] > 1 else 0], cosine_t[f], sine_t[f], scratch[0],
                      scratch[1], twr, twi, 40)
        _radix8(scratch[0], scratch[1], scratch[2], scratch[3], twr, twi, 40)
        # the last pass writes along the lanes (the rows side by side), then one transposition into the grid's rows:
        # 0.9 us a frame less than the pass writing each row's outputs 80 samples apart
        _radix5(scratch[2], scratch[3], scratch[0], 40, 40, 1)
        _lanes_to_rows(scratch[0], grid[f])


@numba.njit(cache=True, error_model="numpy", nogil=True)
def field_powers(amplitude_t, cosine_t, sine_t, grid, power, scratch, twr, twi):
    """One frame of :func:`rows` then :func:`column_powers`: ``power = |fft2(field, (80, 80))|^2`` (float32, 80 x 80
    flat) of the field ``amplitude (cosine + i sine)`` given transposed and flat (float32, 1600 each); ``grid``: float32
    (6400,), the rows' spectra (40 rows of 80 samples, each row's real parts then its imaginary parts); ``scratch``:
    float32 (4, 6400). The same passes on the same values as the two calls, so the same bits, for a caller that
    renders frame by frame in compiled code; each transform's radix-2 pass is made inside its radix-8 pass
    (:func:`_radix2_8`), and the rows' spectra are transposed into real and imaginary rows for it
    (:func:`_lanes_to_split_rows`)."""
    wide_vectors()
    _radix2_8(amplitude_t, cosine_t, sine_t, scratch[2], scratch[3], twr, twi, 40, 40, True)
    _radix5(scratch[2], scratch[3], scratch[0], 40, 40, 1)
    _lanes_to_split_rows(scratch[0], grid)
    _radix2_8(grid, grid, grid[80:], scratch[2], scratch[3], twr, twi, 80, 160, False)      # rows 160 floats apart
    _radix5_powers(scratch[2], scratch[3], power)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _lanes_to_split_rows(lanes, grid):
    """``grid`` (flat float32, 80 x 80): row ``2 l`` the real parts and row ``2 l + 1`` the imaginary parts of row
    ``l`` of 80 samples, from ``lanes`` holding its element ``m`` at complex ``40 m + l`` (80 rows of 80 floats, whose
    float ``c = 2 l + p`` is part ``p`` of row ``l``): the 80 x 80 floats transposed, 16 x 16 at a time in vector
    registers (:func:`_transpose_16`; a copy: the same bits)."""
    wide_vectors()
    for m in range(0, LENGTH, 16):
        for c in range(0, LENGTH, 16):
            _transpose_16(lanes, m * LENGTH + c, LENGTH, grid, c * LENGTH + m, LENGTH)


def _swap_bit_masks() -> tuple[tuple[list[int], list[int]], ...]:
    """For :func:`_transpose_16`: stage ``k``'s shuffles of rows ``r`` and ``r + 2^k`` (``r``'s bit k clear) of a
    16 x 16 block, which swap bit k of the row and column indices (after the four stages, element (i, j) is (j, i)):
    the first row takes columns with bit k clear from itself and the rest from the second row's column with it
    cleared; the second row the rest. Indices 16-31 are the second row's."""
    stages = []
    for k in range(4):
        bit = 1 << k
        stages.append(([j if not j & bit else 16 + (j & ~bit) for j in range(16)],
                       [j | bit if not j & bit else 16 + j for j in range(16)]))
    return tuple(stages)


_SWAP_BIT_MASKS = _swap_bit_masks()


@intrinsic
def _transpose_16(typingctx, source, source_start, source_stride, target, target_start, target_stride):
    """``target[target_start + j target_stride + i] = source[source_start + i source_stride + j]`` for ``i, j < 16``
    (float32 arrays, flat; the rows need not be aligned): 16 vector loads, four stages of 16 two-row shuffles
    (:func:`_swap_bit_masks`) and 16 vector stores, in LLVM's IR (vectors of 16 floats: on a CPU without 512-bit
    registers LLVM splits them). A copy: the same bits. ~0.6 against ~1.0 us for the 80 x 80 floats element by
    element (docs/speed.md, seventeenth session)."""
    def codegen(context, builder, signature, args):
        vector = ir.VectorType(ir.FloatType(), 16)
        indices = ir.VectorType(ir.IntType(32), 16)
        (source_data, first, stride), (target_data, target_first, target_step) = (
            (context.make_array(signature.args[a])(context, builder, args[a]).data, args[a + 1], args[a + 2])
            for a in (0, 3))

        def row(data, start, step, i):
            at = builder.add(start, builder.mul(step, ir.Constant(step.type, i)))
            return builder.bitcast(builder.gep(data, [at]), vector.as_pointer())

        rows = [builder.load(row(source_data, first, stride, i), align=4) for i in range(16)]
        for k, (low, high) in enumerate(_SWAP_BIT_MASKS):
            swapped = list(rows)
            for r in (r for r in range(16) if not r & (1 << k)):
                a, b = rows[r], rows[r | 1 << k]
                swapped[r] = builder.shuffle_vector(a, b, ir.Constant(indices, low))
                swapped[r | 1 << k] = builder.shuffle_vector(a, b, ir.Constant(indices, high))
            rows = swapped
        for j, values in enumerate(rows):
            builder.store(values, row(target_data, target_first, target_step, j), align=4)
        return context.get_dummy_value()
    return types.none(source, source_start, source_stride, target, target_start, target_stride), codegen


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _lanes_to_rows(lanes, grid):
    """``grid``'s first 40 rows of 80 complex64 (flat float32) from ``lanes`` holding element ``m`` of row ``l`` at
    complex ``40 m + l`` (a copy: the same bits)."""
    wide_vectors()
    source, target = lanes.view(np.complex64), grid.view(np.complex64)
    for l in range(40):
        for m in range(LENGTH):
            target[l * LENGTH + m] = source[m * 40 + l]


def same_as_pocketfft() -> bool:
    """Whether :func:`columns` and :func:`rows` give scipy's FFTs bit for bit on random padded data (and compile)."""
    from scipy.fft import fft
    rng = np.random.default_rng(0)
    half = (3, LENGTH // 2, LENGTH)
    grid = np.zeros((3, LENGTH, LENGTH), np.complex64)
    grid[:, :LENGTH // 2] = rng.standard_normal(half) + 1j * rng.standard_normal(half)
    expected = fft(grid, axis=1)
    grid[:, LENGTH // 2:] = 1e30                                    # not read
    scratch = np.empty((4, LENGTH * LENGTH), np.float32)
    columns(grid, scratch)
    field = grid[:, :LENGTH // 2, :LENGTH // 2].copy()
    transformed = np.empty_like(grid)
    field_t = np.ascontiguousarray(field.transpose(0, 2, 1))
    rows(np.ones((1, LENGTH // 2, LENGTH // 2), np.float32), np.ascontiguousarray(field_t.real),
         np.ascontiguousarray(field_t.imag), transformed, scratch)
    return (np.array_equal(grid.view(np.uint64), expected.view(np.uint64))
            and np.array_equal(transformed[:, :LENGTH // 2].view(np.uint64), fft(field, LENGTH, axis=2).view(np.uint64)))


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _radix2(grid, re, im, twr, twi, w):
    """pocketfft's radix-2 pass (ido 40, l1 1) from the interleaved ``grid`` (80 x 160 flat) into planar ``re``, ``im``
    (80 x ``w`` lanes), its second half of inputs the padding's zeros."""
    numba.literally(w)
    wide_vectors()
    zero = _F32(0.0)
    for l in range(w):
        c0r, c0i = grid[2 * l], grid[2 * l + 1]
        re[l], im[l] = c0r + zero, c0i + zero
        re[40 * w + l], im[40 * w + l] = c0r - zero, c0i - zero
    for i in range(1, 40):
        wr, wi = twr[i], twi[i]
        for l in range(w):
            c0r, c0i = grid[2 * (i * w + l)], grid[2 * (i * w + l) + 1]
            re[i * w + l], im[i * w + l] = c0r + zero, c0i + zero
            dr, di = c0r - zero, c0i - zero
            re[(i + 40) * w + l], im[(i + 40) * w + l] = dr * wr + di * wi, di * wr - dr * wi


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _radix2_field(amplitude, cosine, sine, re, im, twr, twi, w):
    """:func:`_radix2` for the rows, its inputs the field ``amplitude (cosine + i sine)`` (``w`` lanes of 40 samples,
    flat float32) made as it reads them: ``cosine amplitude`` and ``sine amplitude`` in float32, the values numpy's
    complex64 product with a real amplitude gives."""
    numba.literally(w)
    wide_vectors()
    zero = _F32(0.0)
    for l in range(w):
        c0r, c0i = cosine[l] * amplitude[l], sine[l] * amplitude[l]
        re[l], im[l] = c0r + zero, c0i + zero
        re[40 * w + l], im[40 * w + l] = c0r - zero, c0i - zero
    for i in range(1, 40):
        wr, wi = twr[i], twi[i]
        for l in range(w):
            c0r, c0i = cosine[i * w + l] * amplitude[i * w + l], sine[i * w + l] * amplitude[i * w + l]
            re[i * w + l], im[i * w + l] = c0r + zero, c0i + zero
            dr, di = c0r - zero, c0i - zero
            re[(i + 40) * w + l], im[(i + 40) * w + l] = dr * wr + di * wi, di * wr - dr * wi


@numba.njit(inline="always")
def _butterfly8(c0r, c0i, c1r, c1i, c2r, c2i, c3r, c3i, c4r, c4i, c5r, c5i, c6r, c6i, c7r, c7i):
    """pocketfft's forward radix-8 butterfly up to its twiddles: outputs 0, 4, 2, 6, 1, 5, 3, 7 (re, im each)."""
    a1r, a1i, a5r, a5i = c1r + c5r, c1i + c5i, c1r - c5r, c1i - c5i
    a3r, a3i, a7r, a7i = c3r + c7r, c3i + c7i, c3r - c7r, c3i - c7i
    a7r, a7i = a7i, -a7r                                                    # ROTX90
    a1r, a1i, a3r, a3i = a1r + a3r, a1i + a3i, a1r - a3r, a1i - a3i
    a3r, a3i = a3i, -a3r
    a5r, a5i, a7r, a7i = a5r + a7r, a5i + a7i, a5r - a7r, a5i - a7i
    a5r, a5i = _HALF_SQRT2 * (a5r + a5i), _HALF_SQRT2 * (a5i - a5r)        # ROTX45
    a7r, a7i = _HALF_SQRT2 * (a7i - a7r), _HALF_SQRT2 * (-a7r - a7i)       # ROTX135
    a0r, a0i, a4r, a4i = c0r + c4r, c0i + c4i, c0r - c4r, c0i - c4i
    a2r, a2i, a6r, a6i = c2r + c6r, c2i + c6i, c2r - c6r, c2i - c6i
    a0r, a0i, a2r, a2i = a0r + a2r, a0i + a2i, a0r - a2r, a0i - a2i
    a6r, a6i = a6i, -a6r
    a4r, a4i, a6r, a6i = a4r + a6r, a4i + a6i, a4r - a6r, a4i - a6i
    return (a0r + a1r, a0i + a1i, a0r - a1r, a0i - a1i, a2r + a3r, a2i + a3i, a2r - a3r, a2i - a3i,
            a4r + a5r, a4i + a5i, a4r - a5r, a4i - a5i, a6r + a7r, a6i + a7i, a6r - a7r, a6i - a7i)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _radix8(re, im, out_re, out_im, twr, twi, w):
    """pocketfft's radix-8 pass (ido 5, l1 2) on planar 80 x ``w``-lane buffers (``w`` a compile-time constant, so
    that the compiler sees the buffers' rows apart and vectorizes along the lanes)."""
    numba.literally(w)
    wide_vectors()
    for k in range(2):
        for i in range(5):
            s0, s1, s2, s3 = (i + 40 * k) * w, (i + 5 + 40 * k) * w, (i + 10 + 40 * k) * w, (i + 15 + 40 * k) * w
            s4, s5, s6, s7 = (i + 20 + 40 * k) * w, (i + 25 + 40 * k) * w, (i + 30 + 40 * k) * w, (i + 35 + 40 * k) * w
            # output u goes to (i + 5 (k + 2 u)); the butterfly returns u = 0, 4, 2, 6, 1, 5, 3, 7
            d0, d4, d2, d6 = (i + 5 * k) * w, (i + 5 * (k + 8)) * w, (i + 5 * (k + 4)) * w, (i + 5 * (k + 12)) * w
            d1, d5, d3, d7 = (i + 5 * (k + 2)) * w, (i + 5 * (k + 10)) * w, (i + 5 * (k + 6)) * w, (i + 5 * (k + 14)) * w
            if i == 0:
                for l in range(w):
                    y = _butterfly8(re[s0 + l], im[s0 + l], re[s1 + l], im[s1 + l], re[s2 + l], im[s2 + l], re[s3 + l], im[s3 + l], re[s4 + l], im[s4 + l], re[s5 + l], im[s5 + l], re[s6 + l], im[s6 + l], re[s7 + l], im[s7 + l])
                    out_re[d0 + l], out_im[d0 + l] = y[0], y[1]
                    out_re[d4 + l], out_im[d4 + l] = y[2], y[3]
                    out_re[d2 + l], out_im[d2 + l] = y[4], y[5]
                    out_re[d6 + l], out_im[d6 + l] = y[6], y[7]
                    out_re[d1 + l], out_im[d1 + l] = y[8], y[9]
                    out_re[d5 + l], out_im[d5 + l] = y[10], y[11]
                    out_re[d3 + l], out_im[d3 + l] = y[12], y[13]
                    out_re[d7 + l], out_im[d7 + l] = y[14], y[15]
            else:
                # output u's twiddle exp(2 pi i u l1 i / 80), multiplied conjugated (forward)
                w1r, w1i, w2r, w2i = twr[2 * i], twi[2 * i], twr[4 * i], twi[4 * i]
                w3r, w3i, w4r, w4i = twr[6 * i], twi[6 * i], twr[8 * i], twi[8 * i]
                w5r, w5i, w6r, w6i = twr[10 * i], twi[10 * i], twr[12 * i], twi[12 * i]
                w7r, w7i = twr[14 * i], twi[14 * i]
                for l in range(w):
                    y = _butterfly8(re[s0 + l], im[s0 + l], re[s1 + l], im[s1 + l], re[s2 + l], im[s2 + l], re[s3 + l], im[s3 + l], re[s4 + l], im[s4 + l], re[s5 + l], im[s5 + l], re[s6 + l], im[s6 + l], re[s7 + l], im[s7 + l])
                    out_re[d0 + l], out_im[d0 + l] = y[0], y[1]
                    out_re[d4 + l], out_im[d4 + l] = y[2] * w4r + y[3] * w4i, y[3] * w4r - y[2] * w4i
                    out_re[d2 + l], out_im[d2 + l] = y[4] * w2r + y[5] * w2i, y[5] * w2r - y[4] * w2i
                    out_re[d6 + l], out_im[d6 + l] = y[6] * w6r + y[7] * w6i, y[7] * w6r - y[6] * w6i
                    out_re[d1 + l], out_im[d1 + l] = y[8] * w1r + y[9] * w1i, y[9] * w1r - y[8] * w1i
                    out_re[d5 + l], out_im[d5 + l] = y[10] * w5r + y[11] * w5i, y[11] * w5r - y[10] * w5i
                    out_re[d3 + l], out_im[d3 + l] = y[12] * w3r + y[13] * w3i, y[13] * w3r - y[12] * w3i
                    out_re[d7 + l], out_im[d7 + l] = y[14] * w7r + y[15] * w7i, y[15] * w7r - y[14] * w7i


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _radix2_8(amplitude, re, im, out_re, out_im, twr, twi, w, stride, field):
    """:func:`_radix2` (or with ``field`` :func:`_radix2_field`) then :func:`_radix8` in one pass, from planar inputs:
    ``w`` lanes of 40 samples, ``re``, ``im`` (sample ``r`` of lane ``l`` at ``r stride + l``, flat float32; the
    padding's zeros not read), or with
    ``field`` the field ``amplitude (re + i im)`` made as they are read; into planar ``out_re``, ``out_im`` (80 x ``w``
    lanes). Each radix-2 output is made where the radix-8 butterfly reads it (each once), with the same operations
    as :func:`_radix2`'s, so the same bits without the 80 x ``w`` intermediate written and read back (the
    columns' two passes 1.65 against 2.91 us a frame, docs/speed.md, seventeenth session). ``w``, ``stride`` and
    ``field`` are compile-time constants."""
    numba.literally(w)
    numba.literally(stride)
    numba.literally(field)
    wide_vectors()
    zero = _F32(0.0)
    for k in range(2):
        for i in range(5):
            # the radix-8 inputs i + 5 j + 40 k (j = 0..7) are radix-2 outputs: input r = i + 5 j as it is (k = 0),
            # or its difference with the padding's zero times the conjugated twiddle exp(2 pi i r / 80) (k = 1; none
            # for r = 0)
            r0, r1, r2, r3 = i * stride, (i + 5) * stride, (i + 10) * stride, (i + 15) * stride
            r4, r5, r6, r7 = (i + 20) * stride, (i + 25) * stride, (i + 30) * stride, (i + 35) * stride
            u0r, u1r, u2r, u3r = twr[i], twr[i + 5], twr[i + 10], twr[i + 15]
            u4r, u5r, u6r, u7r = twr[i + 20], twr[i + 25], twr[i + 30], twr[i + 35]
            u0i, u1i, u2i, u3i = twi[i], twi[i + 5], twi[i + 10], twi[i + 15]
            u4i, u5i, u6i, u7i = twi[i + 20], twi[i + 25], twi[i + 30], twi[i + 35]
            d = _destinations(i, k, w)
            t = _output_twiddles(i, twr, twi)
            for l in range(w):
                a0r, a0i = _sample(amplitude, re, im, r0 + l, field)
                a1r, a1i = _sample(amplitude, re, im, r1 + l, field)
                a2r, a2i = _sample(amplitude, re, im, r2 + l, field)
                a3r, a3i = _sample(amplitude, re, im, r3 + l, field)
                a4r, a4i = _sample(amplitude, re, im, r4 + l, field)
                a5r, a5i = _sample(amplitude, re, im, r5 + l, field)
                a6r, a6i = _sample(amplitude, re, im, r6 + l, field)
                a7r, a7i = _sample(amplitude, re, im, r7 + l, field)
                if k == 0:
                    y = _butterfly8(a0r + zero, a0i + zero, a1r + zero, a1i + zero, a2r + zero, a2i + zero,
                                    a3r + zero, a3i + zero, a4r + zero, a4i + zero, a5r + zero, a5i + zero,
                                    a6r + zero, a6i + zero, a7r + zero, a7i + zero)
                else:
                    b0r, b0i = a0r - zero, a0i - zero
                    if i > 0:
                        b0r, b0i = _conjugate_twiddled(b0r, b0i, u0r, u0i)
                    b1r, b1i = _conjugate_twiddled(a1r - zero, a1i - zero, u1r, u1i)
                    b2r, b2i = _conjugate_twiddled(a2r - zero, a2i - zero, u2r, u2i)
                    b3r, b3i = _conjugate_twiddled(a3r - zero, a3i - zero, u3r, u3i)
                    b4r, b4i = _conjugate_twiddled(a4r - zero, a4i - zero, u4r, u4i)
                    b5r, b5i = _conjugate_twiddled(a5r - zero, a5i - zero, u5r, u5i)
                    b6r, b6i = _conjugate_twiddled(a6r - zero, a6i - zero, u6r, u6i)
                    b7r, b7i = _conjugate_twiddled(a7r - zero, a7i - zero, u7r, u7i)
                    y = _butterfly8(b0r, b0i, b1r, b1i, b2r, b2i, b3r, b3i, b4r, b4i, b5r, b5i, b6r, b6i, b7r, b7i)
                _store8(y, out_re, out_im, d, l, t, i == 0)


@numba.njit(inline="always")
def _sample(amplitude, re, im, at, field):
    """Input ``at`` of :func:`_radix2_8`: ``(re, im)``, or with ``field`` ``(re amplitude, im amplitude)`` in float32
    (:func:`_radix2_field`'s products)."""
    if field:
        return re[at] * amplitude[at], im[at] * amplitude[at]
    return re[at], im[at]


@numba.njit(inline="always")
def _conjugate_twiddled(dr, di, wr, wi):
    """``(dr + i di)`` times the conjugate of ``wr + i wi``, as pocketfft's passes make it (nothing fused)."""
    return dr * wr + di * wi, di * wr - dr * wi


@numba.njit(inline="always")
def _destinations(i, k, w):
    """Where the radix-8 pass writes its butterfly's outputs 0, 4, 2, 6, 1, 5, 3, 7 (in that order) for ``i``, ``k``:
    output u to (i + 5 (k + 2 u)) ``w``."""
    return ((i + 5 * k) * w, (i + 5 * (k + 8)) * w, (i + 5 * (k + 4)) * w, (i + 5 * (k + 12)) * w,
            (i + 5 * (k + 2)) * w, (i + 5 * (k + 10)) * w, (i + 5 * (k + 6)) * w, (i + 5 * (k + 14)) * w)


@numba.njit(inline="always")
def _output_twiddles(i, twr, twi):
    """The radix-8 pass's twiddles for outputs 4, 2, 6, 1, 5, 3, 7 at ``i``: exp(2 pi i u l1 i / 80), (re, im) each."""
    return (twr[8 * i], twi[8 * i], twr[4 * i], twi[4 * i], twr[12 * i], twi[12 * i], twr[2 * i], twi[2 * i],
            twr[10 * i], twi[10 * i], twr[6 * i], twi[6 * i], twr[14 * i], twi[14 * i])


@numba.njit(inline="always")
def _store8(y, out_re, out_im, d, l, t, first):
    """The radix-8 butterfly's outputs ``y`` (:func:`_butterfly8`'s order) of lane ``l`` to ``d``
    (:func:`_destinations`), each but the first multiplied by its conjugated twiddle ``t`` (:func:`_output_twiddles`)
    unless ``first`` (i = 0: none)."""
    out_re[d[0] + l], out_im[d[0] + l] = y[0], y[1]
    if first:
        out_re[d[1] + l], out_im[d[1] + l] = y[2], y[3]
        out_re[d[2] + l], out_im[d[2] + l] = y[4], y[5]
        out_re[d[3] + l], out_im[d[3] + l] = y[6], y[7]
        out_re[d[4] + l], out_im[d[4] + l] = y[8], y[9]
        out_re[d[5] + l], out_im[d[5] + l] = y[10], y[11]
        out_re[d[6] + l], out_im[d[6] + l] = y[12], y[13]
        out_re[d[7] + l], out_im[d[7] + l] = y[14], y[15]
    else:
        out_re[d[1] + l], out_im[d[1] + l] = _conjugate_twiddled(y[2], y[3], t[0], t[1])
        out_re[d[2] + l], out_im[d[2] + l] = _conjugate_twiddled(y[4], y[5], t[2], t[3])
        out_re[d[3] + l], out_im[d[3] + l] = _conjugate_twiddled(y[6], y[7], t[4], t[5])
        out_re[d[4] + l], out_im[d[4] + l] = _conjugate_twiddled(y[8], y[9], t[6], t[7])
        out_re[d[5] + l], out_im[d[5] + l] = _conjugate_twiddled(y[10], y[11], t[8], t[9])
        out_re[d[6] + l], out_im[d[6] + l] = _conjugate_twiddled(y[12], y[13], t[10], t[11])
        out_re[d[7] + l], out_im[d[7] + l] = _conjugate_twiddled(y[14], y[15], t[12], t[13])


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _radix5(re, im, grid, w, element_stride, lane_stride):
    """pocketfft's radix-5 pass (ido 1, l1 16) from planar 80 x ``w``-lane buffers into the interleaved ``grid``
    (flat), element ``m`` of lane ``l`` at complex ``m element_stride + l lane_stride``."""
    numba.literally(w)
    numba.literally(element_stride)
    numba.literally(lane_stride)
    wide_vectors()
    es, ls = element_stride, lane_stride
    for k in range(16):
        for l in range(w):
            t0r, t0i = re[(5 * k) * w + l], im[(5 * k) * w + l]
            c1r, c1i = re[(5 * k + 1) * w + l], im[(5 * k + 1) * w + l]
            c2r, c2i = re[(5 * k + 2) * w + l], im[(5 * k + 2) * w + l]
            c3r, c3i = re[(5 * k + 3) * w + l], im[(5 * k + 3) * w + l]
            c4r, c4i = re[(5 * k + 4) * w + l], im[(5 * k + 4) * w + l]
            t1r, t1i, t4r, t4i = c1r + c4r, c1i + c4i, c1r - c4r, c1i - c4i
            t2r, t2i, t3r, t3i = c2r + c3r, c2i + c3i, c2r - c3r, c2i - c3i
            grid[2 * (k * es + l * ls)], grid[2 * (k * es + l * ls) + 1] = (t0r + t1r) + t2r, (t0i + t1i) + t2i
            ar, ai = (t0r + _C1 * t1r) + _C2 * t2r, (t0i + _C1 * t1i) + _C2 * t2i
            bi, br = _S1 * t4r + _S2 * t3r, -(_S1 * t4i + _S2 * t3i)
            grid[2 * ((k + 16) * es + l * ls)], grid[2 * ((k + 16) * es + l * ls) + 1] = ar + br, ai + bi
            grid[2 * ((k + 64) * es + l * ls)], grid[2 * ((k + 64) * es + l * ls) + 1] = ar - br, ai - bi
            ar, ai = (t0r + _C2 * t1r) + _C1 * t2r, (t0i + _C2 * t1i) + _C1 * t2i
            bi, br = _S2 * t4r - _S1 * t3r, -(_S2 * t4i - _S1 * t3i)
            grid[2 * ((k + 32) * es + l * ls)], grid[2 * ((k + 32) * es + l * ls) + 1] = ar + br, ai + bi
            grid[2 * ((k + 48) * es + l * ls)], grid[2 * ((k + 48) * es + l * ls) + 1] = ar - br, ai - bi


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _radix5_powers(re, im, power):
    """:func:`_radix5` for the 80 columns, each output's ``re^2 + im^2`` written to ``power`` (80 x 80 flat)."""
    wide_vectors()
    w = LENGTH
    for k in range(16):
        for l in range(w):
            t0r, t0i = re[(5 * k) * w + l], im[(5 * k) * w + l]
            c1r, c1i = re[(5 * k + 1) * w + l], im[(5 * k + 1) * w + l]
            c2r, c2i = re[(5 * k + 2) * w + l], im[(5 * k + 2) * w + l]
            c3r, c3i = re[(5 * k + 3) * w + l], im[(5 * k + 3) * w + l]
            c4r, c4i = re[(5 * k + 4) * w + l], im[(5 * k + 4) * w + l]
            t1r, t1i, t4r, t4i = c1r + c4r, c1i + c4i, c1r - c4r, c1i - c4i
            t2r, t2i, t3r, t3i = c2r + c3r, c2i + c3i, c2r - c3r, c2i - c3i
            yr, yi = (t0r + t1r) + t2r, (t0i + t1i) + t2i
            power[k * w + l] = yr * yr + yi * yi
            ar, ai = (t0r + _C1 * t1r) + _C2 * t2r, (t0i + _C1 * t1i) + _C2 * t2i
            bi, br = _S1 * t4r + _S2 * t3r, -(_S1 * t4i + _S2 * t3i)
            yr, yi = ar + br, ai + bi
            power[(k + 16) * w + l] = yr * yr + yi * yi
            yr, yi = ar - br, ai - bi
            power[(k + 64) * w + l] = yr * yr + yi * yi
            ar, ai = (t0r + _C2 * t1r) + _C1 * t2r, (t0i + _C2 * t1i) + _C1 * t2i
            bi, br = _S2 * t4r - _S1 * t3r, -(_S2 * t4i - _S1 * t3i)
            yr, yi = ar + br, ai + bi
            power[(k + 32) * w + l] = yr * yr + yi * yi
            yr, yi = ar - br, ai - bi
            power[(k + 48) * w + l] = yr * yr + yi * yi
