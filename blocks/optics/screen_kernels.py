"""Compiled loops of :class:`.layer_screen.LayerScreen`: plan a walk, extend, sample.

* :func:`plan_layers` decides, frame by frame, what keeps each footprint inside the screen's
  window (regenerations and one-column conditional extensions) from integers alone, so the
  values are then made in a few compiled calls instead of one Python call per frame.
* :func:`extend_columns` adds one column of B-spline coefficients per step by Assemat et al.
  2006's conditional draw (``x = A z + B w``, :mod:`.autoregressive`) on any side of the window,
  writing into a canvas that keeps every coefficient made during a walk.
* :func:`sample_grids_transposed` reads separable grids with the 4-tap cubic B-spline (Unser 1999,
  IEEE Signal Process. Mag. 16(6), 22, Eq. 4), its weights computed once per row and column of
  each frame (no dense scatter matrices).
* :func:`mode_tables` makes a draw of the large-scale modes' frequencies, amplitudes and phasor tables
  (:class:`.large_scales.LargeScales`).
* :func:`walk_canvases` makes a walk's canvases up to its next regeneration, adds the large-scale
  modes where their frames read (:func:`add_modes`) and reads them.
* :func:`plan_layers` and :func:`walk_segments` do both for every layer of a line of sight in one
  call each (the walks' regenerations in between, in Python; the conditional columns' normal draws in
  :func:`walk_segments`, from each screen's PCG64 state: :mod:`.normal_draws`).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils, errors
from numba.extending import intrinsic

from .normal_draws import _fill

jit = numba.njit(cache=True, error_model="numpy", nogil=True)
#: for the conditional draws' dot products: reassociated (SIMD) sums, the same machine code on every
#: call, so results still do not depend on threads or batching
fast_jit = numba.njit(cache=True, error_model="numpy", nogil=True, fastmath={"reassoc", "contract"})

#: samples kept between a footprint and the window's edge: the cubic B-spline's support (a value at u reads
#: the coefficients floor(u) - 1 .. floor(u) + 2)
MARGIN = 2
REGENERATE, EXTEND = 0, 1
RIGHT, LEFT, DOWN, UP = 0, 1, 2, 3


@jit
def _footprint_boxes(rows, cols, low, high):
    """Each frame's box, from its grid's first to last ``rows`` (F, ny) and ``cols`` (F, nx) [samples], into ``low``,
    ``high`` (F, 2) (row, column)."""
    for f in range(rows.shape[0]):
        low[f, 0], low[f, 1] = rows[f, 0], cols[f, 0]
        high[f, 0], high[f, 1] = rows[f, rows.shape[1] - 1], cols[f, cols.shape[1] - 1]


@jit
def _plan_arrays(capacity):
    """``_plan_into``'s arrays for ``capacity`` operations: ``kind``, ``side``, ``op_epoch``, ``centre``,
    ``before``, ``starts`` and ``renewals`` (arrays, not lists: they compile faster)."""
    return (np.empty(capacity, np.int8), np.empty(capacity, np.int8), np.empty(capacity, np.int64),
            np.empty((capacity, 2)), np.empty((capacity, 2), np.int64), np.empty(capacity + 2, np.int64),
            np.empty(capacity + 2, np.int64))


@jit
def _plan_into(low, high, epochs, n, margin, regenerate_only, origin, epoch, has_values, canvas_steps, kind, side,
               op_epoch, centre, before, frame_ops, starts, renewals):
    """Operations that keep each frame's box (``low`` .. ``high`` (F, 2) [samples]) inside an ``n``-sample window, into
    arrays of ``capacity = kind.shape[0]`` operations: ``kind``, ``side``, ``op_epoch``, ``centre`` (., 2), the
    window origin before each operation ``before`` (., 2); ``frame_ops`` (F,): operations done before frame f is
    read; ``starts``: the first operation of each canvas (at a regeneration, where the walk turns back on an axis,
    which would overwrite values earlier frames read, and every ``canvas_steps``), closed by the count of
    operations (``starts[0]`` must be 0); ``renewals``: the canvases (indices into ``starts``) that begin with a
    regeneration. A window is regenerated around a footprint at a new epoch, when the footprint is over 1.5 windows
    away, or always (``regenerate_only``); otherwise it grows one column or row at a time toward the footprint,
    dropping one on the opposite side.

    Returns the operations, canvas starts and renewals counted (operations -1: a footprint wider than the window
    allows; more than ``capacity``: it stopped at the first frame that did not fit, with the operations counted so
    far and that frame's)."""
    frames = low.shape[0]
    capacity = kind.shape[0]
    n_starts, n_renewals = 1, 0
    last_side = np.full(2, -1)               # last step's side on each axis in this canvas
    o0, o1 = origin[0], origin[1]
    count = 0
    for f in range(frames):
        c0 = 0.5 * (low[f, 0] + high[f, 0])
        c1 = 0.5 * (low[f, 1] + high[f, 1])
        if high[f, 0] - low[f, 0] > n - 1 - 2 * margin or high[f, 1] - low[f, 1] > n - 1 - 2 * margin:
            return -1, 0, 0
        inside = (low[f, 0] >= o0 + margin and low[f, 1] >= o1 + margin
                  and high[f, 0] <= o0 + n - 1 - margin and high[f, 1] <= o1 + n - 1 - margin)
        renew = (not has_values) or epochs[f] != epoch
        if not renew and not inside:
            far = abs(c0 - (o0 + n / 2)) > 1.5 * n or abs(c1 - (o1 + n / 2)) > 1.5 * n
            renew = regenerate_only or far
        steps = 0
        if not renew and not inside:
            steps = (max(0.0, math.ceil(high[f, 1] - (o1 + n - 1 - margin))) + max(0.0, math.ceil(o1 + margin - low[f, 1]))
                     + max(0.0, math.ceil(high[f, 0] - (o0 + n - 1 - margin)))
                     + max(0.0, math.ceil(o0 + margin - low[f, 0])))
        needed = count + 1 + int(steps)
        if needed > capacity:
            return needed, n_starts, n_renewals
        if renew:
            if count > starts[n_starts - 1]:
                starts[n_starts], n_starts = count, n_starts + 1
            renewals[n_renewals], n_renewals = n_starts - 1, n_renewals + 1
            last_side[:] = -1
            kind[count], side[count], op_epoch[count] = REGENERATE, 0, epochs[f]
            centre[count, 0], centre[count, 1] = c0, c1
            before[count, 0], before[count, 1] = o0, o1
            count += 1
            o0 = np.int64(math.floor(c0)) - n // 2
            o1 = np.int64(math.floor(c1)) - n // 2
            epoch, has_values = epochs[f], True
        elif not inside:
            # columns first (axis 1), then rows (axis 0), as many single steps as the footprint needs
            for axis in (1, 0):
                while True:
                    o = o1 if axis == 1 else o0
                    if high[f, axis] > o + n - 1 - margin:
                        step, direction = 1, (RIGHT if axis == 1 else DOWN)
                    elif low[f, axis] < o + margin:
                        step, direction = -1, (LEFT if axis == 1 else UP)
                    else:
                        break
                    a = 1 if axis == 1 else 0
                    if count > starts[n_starts - 1] and ((last_side[a] >= 0 and last_side[a] != direction)
                                                         or count - starts[n_starts - 1] >= canvas_steps):
                        starts[n_starts], n_starts = count, n_starts + 1
                        last_side[:] = -1
                    last_side[a] = direction
                    kind[count], side[count], op_epoch[count] = EXTEND, direction, epoch
                    centre[count, 0], centre[count, 1] = c0, c1
                    before[count, 0], before[count, 1] = o0, o1
                    count += 1
                    if axis == 1:
                        o1 += step
                    else:
                        o0 += step
        frame_ops[f] = count
    if count > starts[n_starts - 1]:
        starts[n_starts], n_starts = count, n_starts + 1
    return count, n_starts, n_renewals


@jit
def _grow(array, capacity):
    """``array`` (C order) in a new one of ``capacity`` rows. The compiled kernels copy arrays element by element,
    never by a slice assignment from an array: its shape-mismatch error message alone (Numba's string formatting)
    costs ~2-3 s of CPU on a first run without a cache (``benchmarks/optics_compile.py``)."""
    out = np.empty((capacity,) + array.shape[1:], array.dtype)
    source, target = array.reshape(-1), out.reshape(-1)
    for i in range(source.shape[0]):
        target[i] = source[i]
    return out


@jit
def _window_strides(side, top, left, n, width):
    """Where the sample (r, c) of the window at canvas (``top``, ``left``), seen with ``side`` on the right, lies in a
    C-ordered canvas ``width`` columns wide: the flat index ``start + r along + c across``."""
    if side == RIGHT:
        return top * width + left, width, 1
    if side == LEFT:
        return top * width + left + n - 1, width, -1
    if side == DOWN:
        return top * width + left, 1, width
    return (top + n - 1) * width + left, 1, -width


@fast_jit
def extend_columns(canvas, tops, lefts, sides, a, b, stencil_rows, stencil_back, noise, n):
    """One conditional column per step: window at canvas (``tops[i]``, ``lefts[i]``), grown on ``sides[i]``.

    ``a`` (n, n_stencil) and lower-triangular ``b`` (n, n) are :func:`.autoregressive.extension_operator`
    for one column; ``noise`` holds ``n`` standard normal draws per step; ``canvas`` is C-contiguous (its stencil
    read and its new column written through flat indices, :func:`_window_strides`).
    """
    n_stencil = stencil_rows.shape[0]
    z = np.empty(n_stencil)
    flat = canvas.reshape(-1)
    width = canvas.shape[1]
    for op in range(sides.shape[0]):
        start, along, across = _window_strides(sides[op], tops[op], lefts[op], n, width)
        for i in range(n_stencil):
            z[i] = flat[start + stencil_rows[i] * along + (n - 1 - stencil_back[i]) * across]
        w = noise[op * n:(op + 1) * n]
        for r in range(n):
            acc = 0.0
            for i in range(n_stencil):
                acc += a[r, i] * z[i]
            for j in range(r + 1):
                acc += b[r, j] * w[j]
            flat[start + r * along + n * across] = acc


@jit
def extend_in_stages(canvas, bounds, tops, lefts, sides, a, b, stencil_rows, stencil_back, operator_at, noise, n):
    """:func:`extend_columns` stage by stage in one call: stage ``s`` makes steps ``bounds[s] .. bounds[s + 1] - 1``
    (windows at ``tops``, ``lefts``, grown on ``sides``; ``n`` draws a step from ``noise``, in order) with its own
    operator, whose ``A`` (n, k), ``B`` (n, n) and stencil (k values) start at ``operator_at[s, 0:3]`` in the packed
    ``a``, ``b`` and ``stencil_rows``, ``stencil_back`` (``k = operator_at[s, 3]``): the same calls on the same
    values as one call a stage."""
    for s in range(bounds.shape[0] - 1):
        s0, s1 = bounds[s], bounds[s + 1]
        a0, b0, st0, k = operator_at[s, 0], operator_at[s, 1], operator_at[s, 2], operator_at[s, 3]
        extend_columns(canvas, tops[s0:s1], lefts[s0:s1], sides[s0:s1], a[a0:a0 + n * k].reshape((n, k)),
                       b[b0:b0 + n * n].reshape((n, n)), stencil_rows[st0:st0 + k], stencil_back[st0:st0 + k],
                       noise[n * s0:n * s1], n)


@intrinsic
def _fused_multiply_add(typingctx, a, b, c):
    """``a b + c`` rounded once (LLVM's ``llvm.fma.f64``: the FMA instruction, or libm's correctly rounded ``fma`` on
    a CPU without one)."""
    def codegen(context, builder, signature, args):
        double = ir.DoubleType()
        fma = builder.module.declare_intrinsic("llvm.fma", [double], ir.FunctionType(double, [double] * 3))
        return builder.call(fma, args)
    return types.float64(types.float64, types.float64, types.float64), codegen


#: 1/6 rounded to the nearest double (below 1/6 by 2^-55 / 3)
SIXTH = 1.0 / 6.0
#: positions ``u - offset`` in (0, this) [samples] are read with divisions (:func:`_taps`): their ``t^3`` could
#: fall below the 2^-1019 that :func:`_sixth` needs
SMALLEST_FAST_POSITION = 2.0 ** -300


@jit
def _sixth(a):
    """``a / 6`` correctly rounded (the division's bits) by a multiply and two fused multiply-adds, for ``a = +0`` or
    a finite ``|a| >= 2^-1019`` (not ``-0``: +0 comes back).

    Markstein's correction (Markstein 1990, IBM J. Res. Dev. 34(1), 111; Muller et al. 2018, Handbook of
    Floating-Point Arithmetic, 2nd ed., Markstein's theorem): ``q = RN(a y)``, ``y = RN(1/6)``; ``r = a - 6 q`` is exact (one
    FMA), ``RN(q + r y)`` (the other) is ``RN(a / 6)``. For 6 and ``2^E <= |a| < 2^(E+1)``: ``|q - a/6| < 2^(E-54)``,
    so ``r`` is a multiple of ``2^(E-55)`` below ``2^(E-51)`` (representable); ``q + r y = a/6 + r (y - 1/6)`` is
    within ``2^(E-107)`` of ``a/6``, while ``a/6 = (8 A / 3) 2^(E-56)`` (``A`` the integer significand) is either a
    double or at least ``2^(E-56) / 3`` from every rounding boundary (all of them there are multiples of
    ``2^(E-56)``), so both round alike. Tested against the division in ``tests/optics/test_optics_kernels_reference.py``."""
    q = a * SIXTH
    return _fused_multiply_add(_fused_multiply_add(-q, 6.0, a), SIXTH, q)


@jit
def _sixths_exact(u, offset):
    """Whether :func:`_sixth` gives every weight of :func:`_taps` at ``x = u - offset`` its division's bits: every
    ``x`` finite, not -0 (``t = -0`` there, ``t^3 / 6 = -0``) and none in (0, :data:`SMALLEST_FAST_POSITION`). Then
    ``t`` is +0 or in [2^-300, 1], so the numerators are +0 or in [2^-900, 4] (``(1 - t)^3`` is +0 or over 2^-160;
    the middle two are at least 1/2)."""
    risky = False
    for i in range(u.shape[0]):
        x = u[i] - offset
        risky |= (((x > 0.0) & (x < SMALLEST_FAST_POSITION)) | ((x == 0.0) & (math.copysign(1.0, x) < 0.0))
                  | (x != x) | (abs(x) == math.inf))
    return not risky


@jit
def _taps_divided(u, offset, index, weights):
    """:func:`_taps` with its divisions by 6 written as divisions: the reference, and the path for positions
    :func:`_sixths_exact` does not cover."""
    for i in range(u.shape[0]):
        x = u[i] - offset
        base = math.floor(x)
        t = x - base
        t2 = t * t
        t3 = t2 * t
        index[i] = np.int64(base) - 1
        weights[0, i] = (1.0 - t) ** 3 / 6.0
        weights[1, i] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0
        weights[2, i] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0
        weights[3, i] = t3 / 6.0


@jit
def _taps(u, offset, index, weights):
    """Cubic B-spline tap indices (first of 4) and weights (4, n) at positions ``u - offset`` [samples] (Unser 1999
    Eq. 4). Each weight kind is a contiguous row, so the loop vectorises; its divisions by 6 are :func:`_sixth`'s
    multiply and FMAs (the same bits; ~45 of ~120 ns for 40 positions), or divisions (:func:`_taps_divided`) where
    :func:`_sixths_exact` says a position needs them."""
    if not _sixths_exact(u, offset):
        _taps_divided(u, offset, index, weights)
        return
    for i in range(u.shape[0]):
        x = u[i] - offset
        base = math.floor(x)
        t = x - base
        t2 = t * t
        t3 = t2 * t
        index[i] = np.int64(base) - 1
        weights[0, i] = _sixth((1.0 - t) ** 3)
        weights[1, i] = _sixth(3.0 * t3 - 6.0 * t2 + 4.0)
        weights[2, i] = _sixth(-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0)
        weights[3, i] = _sixth(t3)


def _splat(builder, value, lanes):
    """A vector of ``lanes`` doubles, each ``value``."""
    vector = ir.VectorType(ir.DoubleType(), lanes)
    first = builder.insert_element(ir.Constant(vector, ir.Undefined), value, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(first, ir.Constant(vector, ir.Undefined),
                                  ir.Constant(ir.VectorType(ir.IntType(32), lanes), [0] * lanes))


def _lanes_at(context, builder, array_type, array, indices, lanes):
    """Pointer to the ``lanes`` doubles of ``array`` from ``indices`` along its last (contiguous) axis."""
    values = context.make_array(array_type)(context, builder, array)
    item = cgutils.get_item_pointer(context, builder, array_type, values, indices, wraparound=False)
    return builder.bitcast(item, ir.VectorType(ir.DoubleType(), lanes).as_pointer())


def _tap_sum(builder, weights, vectors):
    """``w0 v0 + w1 v1 + w2 v2 + w3 v3`` lane by lane, summed left to right (the scalar expression's order; no
    fused multiply-adds: plain ``fmul`` and ``fadd``)."""
    total = builder.fmul(weights[0], vectors[0])
    for w, v in zip(weights[1:], vectors[1:]):
        total = builder.fadd(total, builder.fmul(w, v))
    return total


def _contiguous_doubles(*arrays):
    """Typing check: the vector reads and writes below assume C-contiguous float64 arrays."""
    for array in arrays:
        if not (isinstance(array, types.Array) and array.layout == "C" and array.dtype == types.float64):
            raise errors.TypingError(f"expected a C-contiguous float64 array, got {array}")


@intrinsic
def _rows_combined_transposed(typingctx, coefficients, rows, weights, column, lines, q, i):
    """The y pass of four output rows and four columns at once: ``lines[q + p, i + l] = w[l, 0] C[r_l, c + p] +
    w[l, 1] C[r_l + 1, c + p] + w[l, 2] C[r_l + 2, c + p] + w[l, 3] C[r_l + 3, c + p]`` for ``l, p`` in 0..3, ``C``
    the coefficients, ``r_l = rows[l]``, ``w[l, t] = weights[4 l + t]``, ``c = column``. Each output row is one
    4-lane vector along a coefficient row (the scalar expression in each lane), the 4 x 4 block is transposed in
    registers (8 shuffles) and stored as four 4-lane runs of ``lines``' rows: no strided store per value."""
    _contiguous_doubles(coefficients, lines)

    def codegen(context, builder, signature, args):
        array, picked, taps, start, out, q, i = args
        lanes, mask = 4, lambda *m: ir.Constant(ir.VectorType(ir.IntType(32), 4), list(m))
        sums = []
        for l in range(4):
            r = builder.extract_value(picked, l)
            vectors = [builder.load(_lanes_at(context, builder, signature.args[0], array,
                                              [builder.add(r, r.type(t)), start], lanes), align=8) for t in range(4)]
            weights = [_splat(builder, builder.extract_value(taps, 4 * l + t), lanes) for t in range(4)]
            sums.append(_tap_sum(builder, weights, vectors))
        even01, odd01 = (builder.shuffle_vector(sums[0], sums[1], mask(0, 4, 2, 6)),
                         builder.shuffle_vector(sums[0], sums[1], mask(1, 5, 3, 7)))
        even23, odd23 = (builder.shuffle_vector(sums[2], sums[3], mask(0, 4, 2, 6)),
                         builder.shuffle_vector(sums[2], sums[3], mask(1, 5, 3, 7)))
        columns = [builder.shuffle_vector(even01, even23, mask(0, 1, 4, 5)),
                   builder.shuffle_vector(odd01, odd23, mask(0, 1, 4, 5)),
                   builder.shuffle_vector(even01, even23, mask(2, 3, 6, 7)),
                   builder.shuffle_vector(odd01, odd23, mask(2, 3, 6, 7))]
        for p in range(4):
            builder.store(columns[p], _lanes_at(context, builder, signature.args[4], out, [builder.add(q, q.type(p)), i],
                                                lanes), align=8)
        return context.get_dummy_value()
    return types.void(coefficients, rows, weights, column, lines, q, i), codegen


#: output rows the x pass makes per vector (8: one AVX-512 register, two AVX2 ones where the CPU has no AVX-512;
#: each lane the same sum either way)
X_LANES = 8


@intrinsic
def _lines_combined(typingctx, lines, c, taps, g, out_t, f, j, i, assign):
    """The x pass on :data:`X_LANES` output rows at once: ``out_t[f, j, i:i + X_LANES] += g (a0 lines[c, i:..] + a1
    lines[c + 1, i:..] + a2 lines[c + 2, i:..] + a3 lines[c + 3, i:..])`` (``0.0 +`` instead of the old values with
    ``assign``), ``taps = (a0, a1, a2, a3)``, each lane the scalar expression in its order."""
    _contiguous_doubles(lines, out_t)

    def codegen(context, builder, signature, args):
        rows, c, taps, g, out, f, j, i, assign = args
        lanes = X_LANES
        vectors = [builder.load(_lanes_at(context, builder, signature.args[0], rows, [builder.add(c, c.type(t)), i],
                                          lanes), align=8) for t in range(4)]
        weights = [_splat(builder, builder.extract_value(taps, t), lanes) for t in range(4)]
        target = _lanes_at(context, builder, signature.args[4], out, [f, j, i], lanes)
        kept = builder.select(assign, ir.Constant(ir.VectorType(ir.DoubleType(), lanes), [0.0] * lanes),
                              builder.load(target, align=8))
        builder.store(builder.fadd(kept, builder.fmul(_splat(builder, g, lanes), _tap_sum(builder, weights, vectors))),
                      target, align=8)
        return context.get_dummy_value()
    return types.void(lines, c, taps, g, out_t, f, j, i, assign), codegen


@jit
def _y_pass(coefficients, iy, wy, c0, c1, lines, combined):
    """``lines[q, i] = wy[0, i] C[iy[i], c0 + q] + .. + wy[3, i] C[iy[i] + 3, c0 + q]`` (``C`` the coefficients)
    for every output row ``i`` and column ``c0 + q < c1`` (``c1 - c0 >= 4``: a read spans 4 columns at least): by
    blocks of four rows and four columns (:func:`_rows_combined_transposed`), the columns past the last whole block
    by the block of the last four (its first columns made again: the same values), the rows left over one at a time
    (the same expression). A block costs ~55 ns where its 1-3 columns one value at a time cost ~115 ns each
    (``benchmarks/screen_parts.py``)."""
    ny, m = iy.shape[0], c1 - c0
    whole = m - m % 4
    for i0 in range(0, ny - ny % 4, 4):
        picked = (iy[i0], iy[i0 + 1], iy[i0 + 2], iy[i0 + 3])
        taps = (wy[0, i0], wy[1, i0], wy[2, i0], wy[3, i0], wy[0, i0 + 1], wy[1, i0 + 1], wy[2, i0 + 1],
                wy[3, i0 + 1], wy[0, i0 + 2], wy[1, i0 + 2], wy[2, i0 + 2], wy[3, i0 + 2], wy[0, i0 + 3],
                wy[1, i0 + 3], wy[2, i0 + 3], wy[3, i0 + 3])
        for q in range(0, whole, 4):
            _rows_combined_transposed(coefficients, picked, taps, c0 + q, lines, q, i0)
        if whole < m:
            _rows_combined_transposed(coefficients, picked, taps, c1 - 4, lines, m - 4, i0)
    for i in range(ny - ny % 4, ny):
        r = iy[i]
        w0, w1, w2, w3 = wy[0, i], wy[1, i], wy[2, i], wy[3, i]
        k0, k1, k2, k3 = (coefficients[r, c0:c1], coefficients[r + 1, c0:c1], coefficients[r + 2, c0:c1],
                          coefficients[r + 3, c0:c1])
        for q in range(m):
            combined[q] = w0 * k0[q] + w1 * k1[q] + w2 * k2[q] + w3 * k3[q]
        for q in range(m):
            lines[q, i] = combined[q]


@jit
def _x_pass(lines, ix, wx, c0, g, out_t, f, assign):
    """``out_t[f, j, i] (+)= g (wx[0, j] lines[c, i] + .. + wx[3, j] lines[c + 3, i])``, ``c = ix[j] - c0``, for every
    output column ``j`` and row ``i``: :data:`X_LANES` rows at once (:func:`_lines_combined`), the rows left over one
    at a time (the same expression; ``0.0 +`` it with ``assign``)."""
    ny, whole = lines.shape[1], lines.shape[1] - lines.shape[1] % X_LANES
    for j in range(ix.shape[0]):
        c = ix[j] - c0
        a0, a1, a2, a3 = wx[0, j], wx[1, j], wx[2, j], wx[3, j]
        taps = (a0, a1, a2, a3)
        for i in range(0, whole, X_LANES):
            _lines_combined(lines, c, taps, g, out_t, f, j, i, assign)
        l0, l1, l2, l3 = lines[c], lines[c + 1], lines[c + 2], lines[c + 3]
        target = out_t[f, j]
        for i in range(whole, ny):
            term = g * (a0 * l0[i] + a1 * l1[i] + a2 * l2[i] + a3 * l3[i])
            target[i] = 0.0 + term if assign else target[i] + term


@jit
def sample_grids_transposed(coefficients, top, left, rows, cols, weight, first, stop, out_t, assign):
    """``out_t[f] += weight[f] * screen(rows[f], cols[f]).T`` for frames ``first <= f < stop`` (with ``assign``,
    ``out_t[f] = 0.0 + ...``: the same bits as adding to zeros, whatever ``out_t`` held).

    ``rows`` (F, ny) and ``cols`` (F, nx) are increasing absolute positions [samples]; the
    coefficient array's first sample is at (``top``, ``left``); ``out_t`` is (F, nx, ny), the
    phase transposed; both C-contiguous. Each frame is read on its own (the same result in any batch): every
    output row combines 4 coefficient rows along y (:func:`_y_pass`), then 4 of those values along x
    (:func:`_x_pass`). The y-combined rows are stored by column (``lines[c, i]``, transposed in 4 x 4 blocks in
    registers), so the 4-tap combination along x runs over contiguous output rows of ``out_t`` (SIMD) instead of
    gathering columns for each output sample. Every value is the scalar expression, in its order, in each vector
    lane. Returns False (and stops) when a grid reaches outside the array.
    """
    height, width = coefficients.shape
    ny, nx = rows.shape[1], cols.shape[1]
    iy = np.empty(ny, np.int64)
    ix = np.empty(nx, np.int64)
    wy = np.empty((4, ny))
    wx = np.empty((4, nx))
    lines = np.empty((width, ny))               # the y-combined rows, column by column: contiguous in y
    combined = np.empty(width)
    for f in range(first, stop):
        _taps(rows[f], top, iy, wy)
        _taps(cols[f], left, ix, wx)
        if iy[0] < 0 or iy[ny - 1] + 3 >= height or ix[0] < 0 or ix[nx - 1] + 3 >= width:
            return False
        c0, c1 = ix[0], ix[nx - 1] + 4
        _y_pass(coefficients, iy, wy, c0, c1, lines, combined)
        _x_pass(lines, ix, wx, c0, weight[f], out_t, f, assign)
    return True


@jit
def mode_phasors(w, low_cos, low_sin, start, count, stride, cos_out, sin_out, at, cache):
    """``cos`` and ``sin`` of each mode's phase ``w[k] p`` (``w`` [rad per sample]) at integer positions ``p = start ..
    start + count - 1`` [samples] into ``cos_out``, ``sin_out`` (K, .) from column ``at``, from ``p = stride h + l``: ``low_*[k, l]``
    at ``w l`` (tabled) and ``cos``, ``sin`` of ``w (stride h)`` by the angle-addition formulas (each value from its
    own ``h`` and ``l`` only, wherever it lies in the output: the cosine and sine of each ``h`` are libm's, as NumPy's
    ``cos``, ``sin`` of the same double). One ``h`` at a time, its run of ``l`` in a loop of its own (vectorised).
    The cosines and sines of ``w (stride h)`` are kept between calls in ``cache`` (slots, 1 + 2 K), slot ``h mod
    slots``: ``h`` (a double; NaN: none yet), then the K cosines and K sines; a slot holding another ``h`` is made
    again (the same values: kept or made, the results are the same bits)."""
    modes, slots = low_cos.shape[0], cache.shape[0]
    h0 = start // stride
    span = float(stride)
    i, h, low = 0, h0, start - stride * h0
    while i < count:
        held = cache[h % slots]
        if held[0] != float(h):
            for k in range(modes):
                phase = w[k] * (span * h)
                held[1 + k], held[1 + modes + k] = math.cos(phase), math.sin(phase)
            held[0] = float(h)
        run = min(stride - low, count - i)
        for k in range(modes):
            ch, sh = held[1 + k], held[1 + modes + k]
            cl, sl = low_cos[k, low:low + run], low_sin[k, low:low + run]
            co, so = cos_out[k, at + i:at + i + run], sin_out[k, at + i:at + i + run]
            for j in range(run):
                co[j] = ch * cl[j] - sh * sl[j]
                so[j] = sh * cl[j] + ch * sl[j]
        i, h, low = i + run, h + 1, 0


@jit
def mode_tables(u, radius, power, two_pi_delta, normal, frequencies, amplitudes, low):
    """:class:`.large_scales.LargeScales`' frequencies, amplitudes and tables from its draws, in one call: ring ``r``,
    sector ``s`` (mode ``k = r S + s``, ``S = u.shape[1]`` sectors) at angle ``pi (s + u[r, s, 1]) / S`` and radius
    ``radius[r, s]`` [cycles m^-1] has ``frequencies[:, k]`` = ``2 pi delta radius`` (``two_pi_delta``, one double)
    times its sine and cosine [rad per sample] (y, x); ``amplitudes[:, k] = sqrt(power[r] / S) gain normal[:, k]``,
    ``gain = 3 / (2 + cos wy) 3 / (2 + cos wx)`` (samples to B-spline coefficients, Unser 1999 Eq. 4); ``low``
    (4, K, STRIDE): cos, sin of ``w l`` along y, then x, ``l = 0 .. STRIDE - 1``. The arithmetic of NumPy's arrays
    in the same order, value by value, and libm's ``cos``, ``sin`` (NumPy's here; tested bit for bit against NumPy's
    arrays in ``tests/optics/test_optics_large_scales.py``)."""
    rings, sectors = u.shape[0], u.shape[1]
    for r in range(rings):
        share = math.sqrt(power[r] / sectors)
        for s in range(sectors):
            k = r * sectors + s
            angle = np.pi * (s + u[r, s, 1]) / sectors
            w = two_pi_delta * radius[r, s]
            wy, wx = w * math.sin(angle), w * math.cos(angle)
            frequencies[0, k], frequencies[1, k] = wy, wx
            gain = 3.0 / (2.0 + math.cos(wy)) * 3.0 / (2.0 + math.cos(wx))
            scale = share * gain
            amplitudes[0, k], amplitudes[1, k] = scale * normal[0, k], scale * normal[1, k]
    for axis in range(2):
        for k in range(frequencies.shape[1]):
            for l in range(low.shape[2]):
                phase = frequencies[axis, k] * float(l)
                low[2 * axis, k, l] = math.cos(phase)
                low[2 * axis + 1, k, l] = math.sin(phase)


@jit
def read_spans(rows, cols, top, left, height, width, first, stop):
    """In each row of an array (first sample at absolute (``top``, ``left``), ``height x width``), the columns
    ``first[r] .. stop[r] - 1`` that the frames' grids ``rows`` (F, ny), ``cols`` (F, nx) [samples] read with the
    4-tap spline (:func:`_taps`' indices of the first and last positions, from the same ``rows - top``), clipped to
    the array (``first = width``, ``stop = 0`` where no frame reads)."""
    first[:] = width
    stop[:] = 0
    for f in range(rows.shape[0]):
        r0 = min(max(math.floor(rows[f, 0] - top) - 1, 0), height)
        r1 = min(max(math.floor(rows[f, rows.shape[1] - 1] - top) + 3, 0), height)
        c0 = min(max(math.floor(cols[f, 0] - left) - 1, 0), width)
        c1 = min(max(math.floor(cols[f, cols.shape[1] - 1] - left) + 3, 0), width)
        for r in range(r0, r1):
            first[r] = min(first[r], c0)
            stop[r] = max(stop[r], c1)


#: columns :func:`add_modes` makes at once: vectors of :data:`MODE_LANES` (one AVX-512 register, two AVX2 ones; each
#: lane the same sum either way), :data:`MODE_VECTORS` of them with a sum each, so that the modes' additions in
#: order (a chain of dependent adds per vector) overlap
MODE_LANES, MODE_VECTORS = 8, 4
MODE_COLUMNS = MODE_LANES * MODE_VECTORS


def _masked_lanes(builder, fn_name, vector, arguments):
    """A call of LLVM's ``llvm.masked.load`` / ``llvm.masked.store`` on ``vector``'s type (the 4-argument form, with
    an alignment of 8 bytes; later LLVMs upgrade it)."""
    i1s = ir.VectorType(ir.IntType(1), vector.count)
    if fn_name == "load":
        fnty = ir.FunctionType(vector, [vector.as_pointer(), ir.IntType(32), i1s, vector])
    else:
        fnty = ir.FunctionType(ir.VoidType(), [vector, vector.as_pointer(), ir.IntType(32), i1s])
    function = cgutils.get_or_insert_function(builder.module, fnty, f"llvm.masked.{fn_name}.v{vector.count}f64.p0")
    return builder.call(function, arguments)


@intrinsic
def _modes_added(typingctx, source, out, cos_x, sin_x, u, v, r, c, count):
    """``out[r, c + i] = source[r, c + i] + t_i`` for the columns ``i < count`` (at most :data:`MODE_COLUMNS`), ``t_i
    = (((0.0 + (u[0] cos_x[0, c + i] + v[0] sin_x[0, c + i])) + (u[1] cos_x[1, c + i] + ..)) + ..)`` over every mode
    in order: :func:`add_modes`' sum, each lane the scalar expression (plain ``fmul`` and ``fadd``); the other
    columns are neither read nor written (masked loads and stores)."""
    _contiguous_doubles(source, out, cos_x, sin_x, u, v)

    def codegen(context, builder, signature, args):
        values, target, cosines, sines, us, vs, r, c, count = args
        lanes = MODE_LANES
        vector = ir.VectorType(ir.DoubleType(), lanes)
        integers = ir.VectorType(ir.IntType(64), lanes)
        counts = builder.shuffle_vector(
            builder.insert_element(ir.Constant(integers, ir.Undefined), count, ir.Constant(ir.IntType(32), 0)),
            ir.Constant(integers, ir.Undefined), ir.Constant(ir.VectorType(ir.IntType(32), lanes), [0] * lanes))
        masks = [builder.icmp_signed("<", ir.Constant(integers, list(range(j * lanes, (j + 1) * lanes))), counts)
                 for j in range(MODE_VECTORS)]
        zeros, align = ir.Constant(vector, [0.0] * lanes), ir.Constant(ir.IntType(32), 8)

        def lanes_of(position, array, row, j):
            column = builder.add(c, c.type(j * lanes))
            pointer = _lanes_at(context, builder, signature.args[position], array, [row, column], lanes)
            return _masked_lanes(builder, "load", vector, [pointer, align, masks[j], zeros])

        def scalar_of(position, array, k):
            values = context.make_array(signature.args[position])(context, builder, array)
            return builder.load(cgutils.get_item_pointer(context, builder, signature.args[position], values, [k],
                                                         wraparound=False))
        modes = builder.extract_value(context.make_array(signature.args[4])(context, builder, us).shape, 0)
        totals = [cgutils.alloca_once_value(builder, zeros) for _ in range(MODE_VECTORS)]
        with cgutils.for_range(builder, modes) as loop:
            k = loop.index
            uk, vk = _splat(builder, scalar_of(4, us, k), lanes), _splat(builder, scalar_of(5, vs, k), lanes)
            for j, total in enumerate(totals):
                term = builder.fadd(builder.fmul(uk, lanes_of(2, cosines, k, j)),
                                    builder.fmul(vk, lanes_of(3, sines, k, j)))
                builder.store(builder.fadd(builder.load(total), term), total)
        for j, total in enumerate(totals):
            summed = builder.fadd(lanes_of(0, values, r, j), builder.load(total))
            column = builder.add(c, c.type(j * lanes))
            _masked_lanes(builder, "store", vector, [summed, _lanes_at(context, builder, signature.args[1], target,
                                                                       [r, column], lanes), align, masks[j]])
        return context.get_dummy_value()
    return types.void(source, out, cos_x, sin_x, u, v, r, c, count), codegen


@jit
def add_modes(source, out, cos_y, sin_y, cos_x, sin_x, a, b, first, stop):
    """``out[r, c] = source[r, c] + sum_k a[k] cos(y_r + x_c) + b[k] sin(y_r + x_c)`` for ``first[r] <= c < stop[r]``
    (``out`` may be ``source``), from the cosines and sines of the modes' phases along y (K, H) and x (K, W)
    [:mod:`.large_scales`]; all C-contiguous.

    With ``u = a cos y + b sin y`` and ``v = b cos y - a sin y`` each term is ``u cos x + v sin x``. No
    reassociation: every value is the same sum in the same order (k ascending, from 0.0) wherever it lies in ``out``;
    :data:`MODE_COLUMNS` columns of a row take every mode in one pass (:func:`_modes_added`: the sums stay in a
    register, each column's terms loaded once).
    """
    modes = a.shape[0]
    u, v = np.empty(modes), np.empty(modes)
    for r in range(source.shape[0]):
        c0, c1 = first[r], stop[r]
        if c1 <= c0:
            continue
        for k in range(modes):
            u[k] = a[k] * cos_y[k, r] + b[k] * sin_y[k, r]
            v[k] = b[k] * cos_y[k, r] - a[k] * sin_y[k, r]
        for c in range(c0, c1, MODE_COLUMNS):
            _modes_added(source, out, cos_x, sin_x, u, v, r, c, min(c1 - c, MODE_COLUMNS))


@jit
def walk_canvases(window, origin, n, sides, before, edges, as_is, noise, a, b, stencil_rows,
                  stencil_back, frame_ops, frame, rows, cols, weight, out_t, assign, low, frequencies, amplitudes,
                  stride, phasors):
    """Make and read a run of a walk's canvases (:func:`plan_layers`' operations ``edges[c] .. edges[c + 1] - 1``,
    no regeneration among them; with ``as_is``, the present window before them) in one call: each canvas holds the
    window (``window`` (n, n),
    its first sample at absolute ``origin``, both updated) and the windows of its one-column steps
    (:func:`extend_columns`, ``n`` normal draws per step from ``noise``, in order); then the frames from ``frame``
    whose operations it completes (``frame_ops[f] <= canvas_stop[c]``) are read from it (:func:`sample_grids_transposed`
    into ``out_t``, written rather than added to with ``assign``; none when ``weight`` has no frames), with the
    large-scale modes added where they read
    (:func:`read_spans`, :func:`add_modes`; their phasors by :func:`mode_phasors` from the angular frequencies
    ``frequencies`` (2, K) along y, x and the tables ``low`` (4, K, stride): cos, sin along y, then x; ``amplitudes``
    (2, K), no modes when K = 0; the cosines and sines at whole strides kept between reads in ``phasors`` (2, slots,
    1 + 2 K), y then x, :func:`mode_phasors`' caches). An empty operation range is the window as it is.

    The same arithmetic on the same arrays as making the canvases and reading them one call at a time. Returns the
    next frame to read, or -1 when a grid reaches outside its canvas.
    """
    frames = frame_ops.shape[0]
    reading = weight.shape[0] == frames and frames > 0
    modes = amplitudes.shape[1]
    used = 0
    for c in range(-1 if as_is else 0, edges.shape[0] - 1):
        s, e = (edges[0], edges[0]) if c < 0 else (edges[c], edges[c + 1])
        if e > s:
            last = sides[e - 1]
            after0 = before[e - 1, 0] + (1 if last == DOWN else (-1 if last == UP else 0))
            after1 = before[e - 1, 1] + (1 if last == RIGHT else (-1 if last == LEFT else 0))
            lo0, lo1, hi0, hi1 = after0, after1, after0, after1
            for op in range(s, e):
                lo0, hi0 = min(lo0, before[op, 0]), max(hi0, before[op, 0])
                lo1, hi1 = min(lo1, before[op, 1]), max(hi1, before[op, 1])
            canvas = np.empty((hi0 + n - lo0, hi1 + n - lo1))      # only windows are written and read
            top, left = origin[0] - lo0, origin[1] - lo1
            for r in range(n):
                for q in range(n):
                    canvas[top + r, left + q] = window[r, q]
            extend_columns(canvas, before[s:e, 0] - lo0, before[s:e, 1] - lo1, sides[s:e], a, b, stencil_rows,
                           stencil_back, noise[used * n:(used + e - s) * n], n)
            used += e - s
            origin[0], origin[1] = after0, after1
            for r in range(n):
                for q in range(n):
                    window[r, q] = canvas[after0 - lo0 + r, after1 - lo1 + q]
            top, left = lo0, lo1
        else:
            canvas = window
            top, left = origin[0], origin[1]
        stop = frame
        while stop < frames and frame_ops[stop] <= e:
            stop += 1
        if reading and stop > frame:
            if modes:
                height, width = canvas.shape
                first = np.empty(height, np.int64)
                end = np.empty(height, np.int64)
                read_spans(rows[frame:stop], cols[frame:stop], top, left, height, width, first, end)
                # the phasors of the rows and columns read only (the tables' other entries are never used)
                r0, r1, c0, c1 = height, 0, width, 0
                for r in range(height):
                    if end[r] > first[r]:
                        r0, r1 = min(r0, r), r + 1
                        c0, c1 = min(c0, first[r]), max(c1, end[r])
                cos_y, sin_y = np.empty((modes, height)), np.empty((modes, height))
                cos_x, sin_x = np.empty((modes, width)), np.empty((modes, width))
                mode_phasors(frequencies[0], low[0], low[1], top + r0, max(r1 - r0, 0), stride, cos_y, sin_y, r0,
                             phasors[0])
                mode_phasors(frequencies[1], low[2], low[3], left + c0, max(c1 - c0, 0), stride, cos_x, sin_x, c0,
                             phasors[1])
                source = canvas
                canvas = np.empty((height, width))
                add_modes(source, canvas, cos_y, sin_y, cos_x, sin_x, amplitudes[0], amplitudes[1], first, end)
            if not sample_grids_transposed(canvas, top, left, rows, cols, weight, frame, stop, out_t, assign):
                return -1
        frame = stop
    return frame


#: columns of :func:`plan_layers`' segments: the layer, its edges ``edges[e0:e1]`` (the walk's canvases, operations
#: counted from the layer's first), whether the window is read as it is first, and the regeneration before it (the
#: layer's operation; -1: none)
SEGMENT_COLUMNS = 5


@jit
def plan_layers(rows, cols, epochs, ns, margin, regenerate_only, origins, layer_epochs, has_values, canvas_steps):
    """``_plan_into`` for each layer ``l`` of ``rows`` (L, F, ny), ``cols`` (L, F, nx) [samples] (window of ``ns[l]``
    samples at ``origins[l]``, ``layer_epochs[l]``, ``has_values[l]``), packed for :func:`walk_segments`.

    Returns the first layer whose footprint does not fit its window (-1: none); the operations' ``sides``,
    ``before`` (T, 2), ``centre`` (T, 2) and ``op_epoch`` of every layer, layer ``l``'s from ``op_at[l]``;
    ``frame_ops`` (L, F) (counted from the layer's first operation); the canvases' ``edges``; and the walk's
    segments (:data:`SEGMENT_COLUMNS`), one per run of canvases between regenerations, in the order the
    layers' walks make them.
    """
    layers, frames = rows.shape[0], rows.shape[1]
    frame_ops = np.empty((layers, frames), np.int64)
    op_at = np.zeros(layers + 1, np.int64)
    sides = np.empty(16, np.int8)
    op_epochs = np.empty(16, np.int64)
    centres = np.empty((16, 2))
    befores = np.empty((16, 2), np.int64)
    edges = np.empty(16, np.int64)
    segments = np.empty((layers + 1, SEGMENT_COLUMNS), np.int64)
    # one layer's plan, into arrays made once for all layers (grown where a plan needs more operations)
    room = 4 * frames + 16                  # a footprint seldom moves more than a few samples a frame
    low, high = np.empty((frames, 2)), np.empty((frames, 2))
    kind, side, op_epoch, centre, before, starts, renewals = _plan_arrays(room)
    failed, e, g = -1, 0, 0
    for l in range(layers):
        _footprint_boxes(rows[l], cols[l], low, high)
        while True:
            starts[0] = 0
            count, n_starts, n_renewals = _plan_into(low, high, epochs, ns[l], margin, regenerate_only[l], origins[l],
                                                     layer_epochs[l], has_values[l], canvas_steps, kind, side,
                                                     op_epoch, centre, before, frame_ops[l], starts, renewals)
            if count <= room:
                break
            room = 2 * count                # the plan needs more operations than fit: plan again with room
            kind, side, op_epoch, centre, before, starts, renewals = _plan_arrays(room)
        if count < 0:
            failed = l
            break
        a0, a1 = op_at[l], op_at[l] + count
        op_at[l + 1] = a1
        if a1 > sides.shape[0]:
            capacity = max(2 * sides.shape[0], a1)
            sides, op_epochs = _grow(sides, capacity), _grow(op_epochs, capacity)
            # the (T, 2) arrays grown through their flat views: _grow's 1-D int64 and float64 specialisations only
            centres = _grow(centres.reshape(-1), 2 * capacity).reshape((capacity, 2))
            befores = _grow(befores.reshape(-1), 2 * capacity).reshape((capacity, 2))
        for i in range(a1 - a0):
            sides[a0 + i], op_epochs[a0 + i] = side[i], op_epoch[i]
            centres[a0 + i, 0], centres[a0 + i, 1] = centre[i, 0], centre[i, 1]
            befores[a0 + i, 0], befores[a0 + i, 1] = before[i, 0], before[i, 1]
        if e + n_starts + n_renewals > edges.shape[0]:
            edges = _grow(edges, 2 * (e + n_starts + n_renewals))
        if g + n_renewals + 1 > segments.shape[0]:
            grown = 2 * (g + n_renewals + 1)
            segments = _grow(segments.reshape(-1), grown * SEGMENT_COLUMNS).reshape((grown, SEGMENT_COLUMNS))
        # the window as it is, then its canvases up to the first regeneration; then from each regeneration's fresh
        # window to the next (LayerScreen.walk's runs)
        last = renewals[0] if n_renewals else n_starts - 1
        e0 = e
        for c in range(last + 1):
            edges[e] = starts[c]
            e += 1
        renew = -1
        for r in range(n_renewals + 1):
            if r > 0:
                renew = starts[renewals[r - 1]]
                following = renewals[r] if r < n_renewals else n_starts - 1
                e0 = e
                edges[e] = renew + 1
                e += 1
                for c in range(renewals[r - 1] + 1, following + 1):
                    edges[e] = starts[c]
                    e += 1
            segments[g, 0], segments[g, 1], segments[g, 2], segments[g, 3], segments[g, 4] = l, e0, e, r == 0, renew
            g += 1
    total = op_at[layers] if failed < 0 else 0
    return (failed, sides[:total], befores[:total], centres[:total], op_epochs[:total], op_at, frame_ops, edges[:e],
            segments[:g])


#: columns of :func:`walk_segments`' layout: the segment's layer, window size ``n``, edges ``e0``, ``e1``, ``as_is``,
#: then where its arrays start in the packed ones: the layer's operations (first, stop), its window, noise (first,
#: stop); its operator (a row of ``operator_at``; -1: none, without noise) and the stencil's length; the large-scale
#: modes' count ``K`` and their row of ``mode_at`` (-1: none)
LAYOUT_COLUMNS = 14


@jit
def walk_segments(layout, windows, origins, sides, before, edges, noise, states, draw, unscaled, ki, wi, fi, a, b,
                  stencil_rows, stencil_back, operator_at, frame_ops, rows, cols, weight, out_t, layer_out, assign, low,
                  amplitudes, frequencies, mode_at, stride, phasors, slots):
    """Every segment of :func:`plan_layers` (a run of one layer's canvases, :func:`walk_canvases`) in one call, in
    order: each from its window (``windows`` packed, updated in place, its origin ``origins[s]`` too), reading that
    layer's frames (``rows[l]`` (F, ny), ``cols[l]``, ``weight[l]``: none when it has no frames) into its output
    ``out_t[layer_out[l]]`` (``out_t`` (outputs, F, nx, ny): one a line of sight), from where its layer's previous
    segment stopped; its operator, noise and the modes (:data:`LAYOUT_COLUMNS`) are
    views into the packed arrays (the operators' ``A``, ``B`` and stencil from ``operator_at``'s first three columns,
    the modes' ``low``, ``amplitudes``, ``frequencies`` and their phasor caches ``phasors`` (2, ``slots``, 1 + 2 K;
    :func:`mode_phasors`', kept between walks) from ``mode_at``'s). With ``draw``, each segment's noise is first drawn into ``noise`` from its
    screen's PCG64 state ``states[s]`` (:func:`.normal_draws._fill` with NumPy's ziggurat tables ``ki``, ``wi``,
    ``fi``; the state left as the draws leave it), else ``noise`` holds it. The reads of a layer with ``assign[l]``
    (its output's first layer) are written into its output (as if added to zeros: each layer reads every frame once),
    the others' added.
    Returns the first segment that read outside its canvas (-1: none)."""
    frame = np.zeros(rows.shape[0], np.int64)
    for s in range(layout.shape[0]):
        layer, n, e0, e1, as_is = layout[s, 0], layout[s, 1], layout[s, 2], layout[s, 3], layout[s, 4] != 0
        op0, op1, w0, z0, z1 = layout[s, 5], layout[s, 6], layout[s, 7], layout[s, 8], layout[s, 9]
        operator, n_st, k, mode = layout[s, 10], layout[s, 11], layout[s, 12], layout[s, 13]
        a0 = b0 = st0 = low0 = amp0 = freq0 = ph0 = 0
        if operator >= 0:
            a0, b0, st0 = operator_at[operator, 0], operator_at[operator, 1], operator_at[operator, 2]
        if mode >= 0:
            low0, amp0, freq0, ph0 = mode_at[mode, 0], mode_at[mode, 1], mode_at[mode, 2], mode_at[mode, 3]
        window = windows[w0:w0 + n * n].reshape((n, n))
        held = slots if k else 0                # the modes' phasor caches' slots (none without modes)
        m = n if z1 > z0 else 0                 # the operator's rows (none when nothing is drawn)
        if draw and z1 > z0:
            _fill(states[s], noise[z0:z1], unscaled, False, ki, wi, fi)
        stop = walk_canvases(window, origins[s], n, sides[op0:op1], before[op0:op1], edges[e0:e1], as_is,
                             noise[z0:z1], a[a0:a0 + m * n_st].reshape((m, n_st)), b[b0:b0 + m * m].reshape((m, m)),
                             stencil_rows[st0:st0 + n_st], stencil_back[st0:st0 + n_st], frame_ops[layer],
                             frame[layer], rows[layer], cols[layer], weight[layer], out_t[layer_out[layer]],
                             assign[layer],
                             low[low0:low0 + 4 * k * stride].reshape((4, k, stride)),
                             frequencies[freq0:freq0 + 2 * k].reshape((2, k)),
                             amplitudes[amp0:amp0 + 2 * k].reshape((2, k)), stride,
                             phasors[ph0:ph0 + 2 * held * (1 + 2 * k)].reshape((2, held, 1 + 2 * k)))
        if stop < 0:
            return s
        frame[layer] = stop
    return -1


@jit
def layer_grids(altitude, wind, cn2_dh, delta, t_s, sight, cos_zenith, range_m, turbulent, xp, k2, rows, cols,
                weight):
    """Every layer's footprint grids [samples] and phase weights, frame by frame (:meth:`.Imager.footprints_of`'s
    footprints and the pupil path's weights in one pass, the same arithmetic).

    A layer at ``altitude[l]`` [m] with wind ``wind[l]`` (x, y) [m/s] seen along ``sight[f]`` (x, y) [rad] at
    ``t_s[f]`` [s] has its footprint centred at ``altitude sight - wind t`` [m] and scaled by ``1 - L / R`` (``L =
    altitude / cos_zenith[f]`` the slant distance, ``R = range_m[f]`` [m]; 1 for a source at infinity), so
    ``rows[l, f, i] = (centre_y + scale xp[i]) / delta[l]`` and ``cols`` from ``centre_x`` (pupil coordinates
    ``xp`` [m], screen spacings ``delta`` [m]); ``weight[l, f] = sqrt(0.423 k2 / cos_zenith[f] cn2_dh[l])``, the
    layer's ``r0^(-5/6)`` (Hardy 1998 Eq. 3.40; ``k2 = (2 pi / lambda)^2`` [m^-2], ``cn2_dh`` [m^(1/3)]), 0 where
    the frame is not ``turbulent``."""
    for layer in range(altitude.shape[0]):
        h, d, j = altitude[layer], delta[layer], cn2_dh[layer]
        wx, wy = wind[layer, 0], wind[layer, 1]
        for f in range(t_s.shape[0]):
            r = range_m[f]
            s = 1.0 - h / cos_zenith[f] / r if math.isfinite(r) else 1.0
            cx = h * sight[f, 0] - wx * t_s[f]
            cy = h * sight[f, 1] - wy * t_s[f]
            for i in range(xp.shape[0]):
                rows[layer, f, i] = (cy + s * xp[i]) / d
                cols[layer, f, i] = (cx + s * xp[i]) / d
            weight[layer, f] = math.sqrt(0.423 * k2 / cos_zenith[f] * j) if turbulent[f] else 0.0


@jit
def layer_grids_drifting(altitude, drift, cn2_dh, delta, sight, cos_zenith, range_m, turbulent, xp, k2, rows, cols,
                         weight):
    """:func:`layer_grids` for footprints that drift frame by frame (``follow_sight_rate``,
    :meth:`.Imager.source_drift`): the footprint's centre ``altitude sight - drift[l, f]`` [m] (``drift`` (L, F, 2))
    instead of ``altitude sight - wind t``; the rest the same arithmetic."""
    for layer in range(altitude.shape[0]):
        h, d, j = altitude[layer], delta[layer], cn2_dh[layer]
        for f in range(sight.shape[0]):
            r = range_m[f]
            s = 1.0 - h / cos_zenith[f] / r if math.isfinite(r) else 1.0
            cx = h * sight[f, 0] - drift[layer, f, 0]
            cy = h * sight[f, 1] - drift[layer, f, 1]
            for i in range(xp.shape[0]):
                rows[layer, f, i] = (cy + s * xp[i]) / d
                cols[layer, f, i] = (cx + s * xp[i]) / d
            weight[layer, f] = math.sqrt(0.423 * k2 / cos_zenith[f] * j) if turbulent[f] else 0.0
