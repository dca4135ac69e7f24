"""Standard normal draws of a NumPy ``PCG64`` generator, compiled: NumPy's numbers bit for bit, and the generator left
in NumPy's state.

``Generator.standard_normal`` is NumPy's ziggurat (Marsaglia & Tsang 2000, J. Stat. Softw. 5(8), in NumPy's
256-layer double-precision form: ``random_standard_normal`` of numpy/random/src/distributions/distributions.c):
one 64-bit word a draw, its low 8 bits the layer, the next the sign, 52 bits the magnitude, accepted at once
~99 % of the time; the wedges take a uniform and an ``exp``, the tail two uniforms and two ``log1p``. The words come
from PCG64 (O'Neill 2014, "PCG: a family of simple fast space-efficient statistically good algorithms for random
number generation", HMC-CS-2014-0905; NumPy's ``pcg64.h``): a 128-bit linear congruential step, multiplier
``0x2360ED051FC65DA44385DF649FCCF645``, then the XSL-RR output of the new state. NumPy calls the generator through
a function pointer for every word (~9 ns a draw here); compiled with the step inlined as one 128-bit product it
takes ~3 ns. The tables are NumPy's (``ziggurat_constants.h``, as Numba ships them for its own generators);
:func:`same_as_numpy` checks the draws and the state they leave against NumPy's once per process, and NumPy draws
where it fails or the generator is not a ``PCG64``.
"""

from __future__ import annotations

from functools import lru_cache

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

try:                                      # NumPy's tables, as Numba copies them (checked against NumPy below)
    from numba.np.random._constants import fi_double, ki_double, wi_double, ziggurat_nor_inv_r, ziggurat_nor_r
except ImportError:                       # pragma: no cover - a Numba without them: NumPy draws
    ki_double = None

#: PCG64's multiplier (PCG_DEFAULT_MULTIPLIER_128)
MULTIPLIER = 0x2360ED051FC65DA44385DF649FCCF645
_WORD = 2**64 - 1


@intrinsic
def _pcg64_step(typingctx, high, low, inc_high, inc_low):
    """``state * MULTIPLIER + inc`` modulo 2^128 on the halves (high, low) of the state and increment."""
    signature = types.UniTuple(types.uint64, 2)(types.uint64, types.uint64, types.uint64, types.uint64)

    def codegen(context, builder, sig, args):
        wide, word = ir.IntType(128), ir.IntType(64)

        def joined(h, lo):
            return builder.or_(builder.shl(builder.zext(h, wide), ir.Constant(wide, 64)), builder.zext(lo, wide))

        state = builder.add(builder.mul(joined(args[0], args[1]), ir.Constant(wide, MULTIPLIER)),
                            joined(args[2], args[3]))
        halves = [builder.trunc(builder.lshr(state, ir.Constant(wide, 64)), word), builder.trunc(state, word)]
        return context.make_tuple(builder, sig.return_type, halves)

    return signature, codegen


@numba.njit(cache=True)
def _word(high, low, inc_high, inc_low):
    """PCG64's step and output: the new state's halves and its 64-bit output (XSL-RR of the new state)."""
    high, low = _pcg64_step(high, low, inc_high, inc_low)
    x = high ^ low
    rotation = high >> np.uint64(58)
    return high, low, (x >> rotation) | (x << ((np.uint64(64) - rotation) & np.uint64(63)))


@numba.njit(cache=True)
def _uniform(word):
    """A uniform double in [0, 1) from a word's top 53 bits (NumPy's ``next_double``)."""
    return np.float64(word >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, nogil=True)
def _fill(state, out, scale, scaled, ki, wi, fi):
    """``out[i k + part] = z * scale[i]`` (``z`` alone unless ``scaled``) for the draws ``z`` of NumPy's
    ``random_standard_normal`` in order, ``part`` in ``range(k)`` outer, ``i`` in ``range(m)`` inner, ``m k =
    out.size`` with ``m = scale.size`` when ``scaled`` (else ``m = out.size``, ``k = 1``); ``state``: uint64 (state
    high, state low, increment high, increment low), left as the draws leave it. The state is kept in locals and
    the helpers take scalars, so that the loop counts no references."""
    high, low, inc_high, inc_low = state[0], state[1], state[2], state[3]
    m = scale.size if scaled else out.size
    k = out.size // m
    for part in range(k):
        for i in range(m):
            while True:
                high, low, r = _word(high, low, inc_high, inc_low)
                layer = np.intp(r & np.uint64(0xFF))
                r >>= np.uint64(8)
                negative = r & np.uint64(1)
                magnitude = (r >> np.uint64(1)) & np.uint64(0x000FFFFFFFFFFFFF)
                x = np.float64(magnitude) * wi[layer]
                if negative:
                    x = -x
                if magnitude < ki[layer]:
                    break
                if layer == 0:            # the tail beyond r (Marsaglia 1964), with 1 - U against log(0)
                    while True:
                        high, low, r = _word(high, low, inc_high, inc_low)
                        xx = -ziggurat_nor_inv_r * np.log1p(-_uniform(r))
                        high, low, r = _word(high, low, inc_high, inc_low)
                        yy = -np.log1p(-_uniform(r))
                        if yy + yy > xx * xx:
                            break
                    x = -(ziggurat_nor_r + xx) if (magnitude >> np.uint64(8)) & np.uint64(1) else ziggurat_nor_r + xx
                    break
                high, low, r = _word(high, low, inc_high, inc_low)
                if (fi[layer - 1] - fi[layer]) * _uniform(r) + fi[layer] < np.exp(-0.5 * x * x):
                    break
            out[i * k + part] = x * scale[i] if scaled else x
    state[0] = high
    state[1] = low


# NumPy's SeedSequence (numpy/random/bit_generator.pyx, after O'Neill's seed_seq_fe): its hash constants
# (uint64 scalars: the compiled words stay unsigned; a Python int would make them signed, or floats)
_INIT_A, _MULT_A, _INIT_B, _MULT_B = (np.uint64(c) for c in (0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED))
_MIX_MULT_L, _MIX_MULT_R, _XSHIFT = np.uint64(0xCA01F9DD), np.uint64(0x4973F715), np.uint64(16)
_LOW32 = np.uint64(0xFFFFFFFF)
_POOL_SIZE = 4


@numba.njit(cache=True)
def _hashmix(value, constant):
    """SeedSequence's ``hashmix`` on 32-bit words (held in uint64): the hashed value and the next constant."""
    value = (value ^ constant) & _LOW32
    constant = (constant * _MULT_A) & _LOW32
    value = (value * constant) & _LOW32
    return value ^ (value >> _XSHIFT), constant


@numba.njit(cache=True)
def _mix(x, y):
    """SeedSequence's ``mix`` of two 32-bit words."""
    result = (_MIX_MULT_L * x - _MIX_MULT_R * y) & _LOW32
    return result ^ (result >> _XSHIFT)


@numba.njit(cache=True, nogil=True)
def seeded_state(entropy, state):
    """``state`` (uint64: state high, low, increment high, low) as ``np.random.PCG64(np.random.SeedSequence(e))``
    starts, for the entropy ``e`` whose 32-bit words (NumPy's ``_coerce_to_uint32_array``, no spawn key) are
    ``entropy``: the pool mixed from them (``mix_entropy``), four 64-bit words generated from it
    (``generate_state(4, np.uint64)``, little-endian pairs of 32-bit words), the first two PCG64's initial state
    and the last two its stream (``pcg_setseq_128_srandom_r``: ``inc = 2 seq + 1``, a step, the state added, a
    step)."""
    pool = np.empty(_POOL_SIZE, np.uint64)
    constant = _INIT_A
    for i in range(_POOL_SIZE):
        word = np.uint64(entropy[i]) if i < entropy.shape[0] else np.uint64(0)
        pool[i], constant = _hashmix(word, constant)
    for source in range(_POOL_SIZE):
        for target in range(_POOL_SIZE):
            if source != target:
                hashed, constant = _hashmix(pool[source], constant)
                pool[target] = _mix(pool[target], hashed)
    for source in range(_POOL_SIZE, entropy.shape[0]):
        for target in range(_POOL_SIZE):
            hashed, constant = _hashmix(np.uint64(entropy[source]), constant)
            pool[target] = _mix(pool[target], hashed)
    words = np.empty(4, np.uint64)
    constant = _INIT_B
    for i in range(8):
        value = (pool[i % _POOL_SIZE] ^ constant) & _LOW32
        constant = (constant * _MULT_B) & _LOW32
        value = (value * constant) & _LOW32
        value ^= value >> _XSHIFT
        words[i // 2] = value if i % 2 == 0 else words[i // 2] | (value << np.uint64(32))
    inc_high = (words[2] << np.uint64(1)) | (words[3] >> np.uint64(63))
    inc_low = (words[3] << np.uint64(1)) | np.uint64(1)
    high, low = _pcg64_step(np.uint64(0), np.uint64(0), inc_high, inc_low)
    low, carry = low + words[1], np.uint64(0)
    if low < words[1]:
        carry = np.uint64(1)
    high, low = _pcg64_step(high + words[0] + carry, low, inc_high, inc_low)
    state[0], state[1], state[2], state[3] = high, low, inc_high, inc_low


@numba.njit(cache=True, nogil=True)
def uniform_fill(state, out):
    """``out[i]``: NumPy's ``Generator.random`` draws in order (``next_double``: a word's top 53 bits) from the PCG64
    ``state`` (as :func:`_fill`'s), left as they leave it."""
    high, low, inc_high, inc_low = state[0], state[1], state[2], state[3]
    for i in range(out.shape[0]):
        high, low, r = _word(high, low, inc_high, inc_low)
        out[i] = _uniform(r)
    state[0] = high
    state[1] = low


def entropy_words(values) -> np.ndarray | None:
    """The 32-bit words NumPy's ``SeedSequence`` makes of a sequence of non-negative ints (each int's words, least
    significant first; 0 is one word), as uint32; None for a negative int (NumPy refuses it)."""
    words = []
    for value in values:
        value = int(value)
        if value < 0:
            return None
        words.append(value & 0xFFFFFFFF)
        value >>= 32
        while value:
            words.append(value & 0xFFFFFFFF)
            value >>= 32
    return np.array(words, np.uint32)


class SeededDraws:
    """NumPy's ``Generator(PCG64(SeedSequence(entropy)))`` for the draws :class:`.large_scales.LargeScales` makes
    (``random``, ``standard_normal``), seeded and drawn compiled (:func:`seeded_state`, :func:`uniform_fill`,
    :func:`_fill`): the same numbers in the same order, for ~1 us of seeding instead of NumPy's ~20. Only where
    :func:`same_as_numpy`; ``entropy``: :func:`entropy_words`' uint32 words."""

    def __init__(self, entropy: np.ndarray):
        self.state = np.empty(4, np.uint64)
        seeded_state(entropy, self.state)

    def random(self, shape) -> np.ndarray:
        out = np.empty(shape)
        uniform_fill(self.state, out.reshape(-1))
        return out

    def standard_normal(self, shape) -> np.ndarray:
        out = np.empty(shape)
        _fill(self.state, out.reshape(-1), _UNSCALED, False, *_TABLES)
        return out


def _tables():
    return np.asarray(ki_double, dtype=np.uint64), np.asarray(wi_double, dtype=float), np.asarray(fi_double, dtype=float)


def _compiled(rng: np.random.Generator, out: np.ndarray, scale: np.ndarray, scaled: bool) -> None:
    """:func:`_fill` ``out`` from ``rng``'s PCG64 state, and write the state it leaves back."""
    bit_generator = rng.bit_generator
    with bit_generator.lock:
        kept = bit_generator.state
        words = kept["state"]
        state = np.array([words["state"] >> 64, words["state"] & _WORD, words["inc"] >> 64, words["inc"] & _WORD],
                         dtype=np.uint64)
        _fill(state, out, scale, scaled, *_TABLES)
        words["state"] = (int(state[0]) << 64) | int(state[1])
        bit_generator.state = kept


def _compiled_here(rng: np.random.Generator) -> bool:
    return type(rng.bit_generator) is np.random.PCG64 and same_as_numpy()


def standard_normal(rng: np.random.Generator, count: int) -> np.ndarray:
    """``rng.standard_normal(count)``, the same numbers and final state, compiled where :func:`same_as_numpy`."""
    if not _compiled_here(rng):
        return rng.standard_normal(count)
    out = np.empty(int(count))
    _compiled(rng, out, _UNSCALED, False)
    return out


def scaled_pair(rng: np.random.Generator, amplitude: np.ndarray) -> np.ndarray:
    """Complex ``a + i b`` with ``a = z[0] * amplitude``, ``b = z[1] * amplitude`` and ``z =
    rng.standard_normal((2, *amplitude.shape))``: the same numbers and final state, each product rounded once."""
    out = np.empty(amplitude.shape, dtype=complex)
    if not _compiled_here(rng):
        draws = rng.standard_normal((2, *amplitude.shape))
        np.multiply(draws[0], amplitude, out=out.real)
        np.multiply(draws[1], amplitude, out=out.imag)
        return out
    scale = np.ascontiguousarray(amplitude, dtype=float).reshape(-1).view()
    scale.setflags(write=False)                # one compiled signature: a read-only scale
    _compiled(rng, out.reshape(-1).view(np.float64), scale, True)
    return out


_TABLES = _tables() if ki_double is not None else None
_UNSCALED = np.empty(0)
_UNSCALED.setflags(write=False)


@lru_cache(maxsize=1)
def same_as_numpy(count: int = 20_000) -> bool:
    """Whether the compiled draws equal NumPy's bit for bit on ``count`` draws (some ~5 from the tail, ~200 from the
    wedges) of a fixed seed, and leave the same state; checked once per process."""
    if _TABLES is None:
        return False
    expected = np.random.Generator(np.random.PCG64(20251126))
    drawn = np.random.Generator(np.random.PCG64(20251126))
    numbers = expected.standard_normal(count)
    try:
        out = np.empty(count)
        _compiled(drawn, out, _UNSCALED, False)
    except Exception:                      # pragma: no cover - a Numba that cannot compile it: NumPy draws
        return False
    return bool(np.array_equal(out.view(np.uint64), numbers.view(np.uint64))
                and drawn.bit_generator.state == expected.bit_generator.state)
