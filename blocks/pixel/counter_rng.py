"""Counter-based random numbers: the k-th draw of pixel i is a pure function of (key, stream, i, k).

The event-driven pixel advances each pixel only when something happens to it, so the
order in which pixels consume random numbers depends on how a run is cut into
windows. Addressing every draw by (pixel, per-pixel counter) instead of taking the next
number from a shared generator makes the result independent of that order: same seed,
same events, whatever the windows. The mixer is SplitMix64's finaliser (Steele, Lea &
Flood 2014, "Fast splittable pseudorandom number generators", OOPSLA), which passes
BigCrush as a counter-mode generator.
"""

from __future__ import annotations

import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TWO_M53 = 2.0**-53


def _mix(z: np.ndarray) -> np.ndarray:
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


def hash64(key: int, stream: int, index, counter) -> np.ndarray:
    """64 random bits for draw ``counter`` of element ``index`` in ``stream``."""
    index = np.atleast_1d(np.asarray(index, dtype=np.int64)).astype(np.uint64)
    counter = np.atleast_1d(np.asarray(counter, dtype=np.int64)).astype(np.uint64)
    base = np.uint64((int(key) + int(stream) * 0x632BE59BD9B4E019) & 0xFFFFFFFFFFFFFFFF)
    with np.errstate(over="ignore"):      # arithmetic modulo 2**64 is the point
        z = _mix(index * _GOLDEN + base)
        return _mix(z + (counter + np.uint64(1)) * _GOLDEN)


def uniform_open(key: int, stream: int, index, counter) -> np.ndarray:
    """Uniform numbers in (0, 1] (safe to take the logarithm of)."""
    return ((hash64(key, stream, index, counter) >> _S11).astype(np.float64) + 1.0) * _TWO_M53


def normal(key: int, stream: int, index, counter) -> np.ndarray:
    """Standard normal numbers (Box-Muller on two counter-addressed uniforms)."""
    u1 = uniform_open(key, 2 * stream, index, counter)
    u2 = uniform_open(key, 2 * stream + 1, index, counter)
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)
