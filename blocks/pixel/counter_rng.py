"""Counter-based random numbers: the k-th draw of pixel i is a pure function of (key, stream, i, k).

The event-driven pixel advances each pixel only when something happens to it, so the
order in which pixels consume random numbers depends on how a run is cut into
windows. Addressing every draw by (pixel, per-pixel counter) instead of taking the next
number from a shared generator makes the result independent of that order: same seed,
same events, whatever the windows. The mixer is SplitMix64's finaliser (Steele, Lea &
Flood 2014, "Fast splittable pseudorandom number generators", OOPSLA), which passes
BigCrush as a counter-mode generator.

The scalar functions are compiled (Numba) for the event-driven loop; :func:`hash64`,
:func:`uniform_open` and :func:`normal` apply them to arrays.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_STREAM = np.uint64(0x632BE59BD9B4E019)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11, _ONE = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11), np.uint64(1)
_TWO_M53 = 2.0**-53

jit = numba.njit(cache=True)


@jit
def _mix(z):
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@jit
def hash64_one(key, stream, index, counter):
    """64 random bits (``uint64``) for draw ``counter`` of element ``index`` in ``stream``."""
    base = np.uint64(key) + np.uint64(stream) * _STREAM          # arithmetic modulo 2**64 is the point
    z = _mix(np.uint64(index) * _GOLDEN + base)
    return _mix(z + (np.uint64(counter) + _ONE) * _GOLDEN)


@jit
def unit_interval(bits):
    """The top 53 bits as a uniform number in [0, 1)."""
    return float(bits >> _S11) * _TWO_M53


@jit
def uniform_open_one(key, stream, index, counter):
    """A uniform number in (0, 1] (safe to take the logarithm of)."""
    return (float(hash64_one(key, stream, index, counter) >> _S11) + 1.0) * _TWO_M53


@jit
def normal_one(key, stream, index, counter):
    """A standard normal number (Box-Muller on two counter-addressed uniforms)."""
    u1 = uniform_open_one(key, 2 * stream, index, counter)
    u2 = uniform_open_one(key, 2 * stream + 1, index, counter)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@jit
def _hash_many(key, stream, index, counter):
    out = np.empty(index.size, np.uint64)
    for k in range(index.size):
        out[k] = hash64_one(key, stream, index[k], counter[k])
    return out


def _arrays(index, counter):
    index, counter = np.broadcast_arrays(np.atleast_1d(np.asarray(index, dtype=np.int64)),
                                         np.atleast_1d(np.asarray(counter, dtype=np.int64)))
    return np.ascontiguousarray(index), np.ascontiguousarray(counter)


def hash64(key: int, stream: int, index, counter) -> np.ndarray:
    """64 random bits for draw ``counter`` of element ``index`` in ``stream`` (arrays broadcast)."""
    return _hash_many(np.int64(key), np.int64(stream), *_arrays(index, counter))


def uniform_open(key: int, stream: int, index, counter) -> np.ndarray:
    """Uniform numbers in (0, 1] (safe to take the logarithm of)."""
    return ((hash64(key, stream, index, counter) >> _S11).astype(np.float64) + 1.0) * _TWO_M53


def normal(key: int, stream: int, index, counter) -> np.ndarray:
    """Standard normal numbers (Box-Muller on two counter-addressed uniforms)."""
    u1 = uniform_open(key, 2 * stream, index, counter)
    u2 = uniform_open(key, 2 * stream + 1, index, counter)
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)
