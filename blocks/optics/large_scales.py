"""The large scales of a layer screen: random Fourier modes added to the conditional draws' screen.

Conditional draws (:mod:`.autoregressive`) see only a stencil reaching back ``R`` columns, so
scales far beyond ``R`` samples come out wrong: with von Karman's ``L0 = 25 m`` the structure
function along a walk was 0.92 of von Karman's at 64 samples and 0.77 at 256 (``R = 16``, 2 cm
samples; benchmarks/screen_statistics.py). The spectrum is
therefore split (the idea of the subharmonic method, Lane, Glindemann & Dainty 1992, Waves Random
Media 2, 209, and of Johansson & Gavel 1994, Proc. SPIE 2200, 372: the low frequencies drawn
apart and added)::

    PSD(f; L0) = PSD(f; L1) + [PSD(f; L0) - PSD(f; L1)],    L1 = min(SPLIT R delta, SPLIT_OF_L0 L0)

The first term, von Karman's with the shorter outer scale ``L1``, is what the conditional draws
make (its covariance falls as ``exp(-2 pi r / L1)``; their structure function along a walk stays
within 2 % of its own at every lag for L1 of 2 to 30 reaches); the second,
non-negative because ``(f^2 + L0^-2)^(-11/6) > (f^2 + L1^-2)^(-11/6)``, is drawn once per screen
and revisit period as ``K`` Fourier modes (the randomised spectral method, Shinozuka & Deodatis
1991, Appl. Mech. Rev. 44, 191)::

    phi(x) = sum_k sqrt(P_k) (a_k cos 2 pi f_k.x + b_k sin 2 pi f_k.x),   a_k, b_k ~ N(0, 1)

over cells of the frequency plane (rings spaced by ``RING_RATIO`` from ``1 / (3 L0)`` to past
``3 / L1``, the first a disc, the last unbounded; ``SECTORS`` sectors of the half plane each),
``P_k`` the cell's integral of the PSD difference and ``f_k`` drawn in the cell with density
proportional to it. The covariance averaged over the draws is then exactly the difference's,
``sum_k P_k E[cos 2 pi f_k.r] = integral PSD_low(f) cos(2 pi f.r) d^2f``, at every separation:
no periodicity, no truncation. The modes are added as B-spline coefficients (a sinusoid of
angular frequency ``w`` per sample is the spline of coefficients ``3 / (2 + cos w)`` times
itself on the grid, Unser 1999 Eq. 4), so screens are read as before.

The price is ergodicity: a mode keeps its amplitude along a whole walk, so one walk's statistics
stand less for the ensemble's than a Gaussian field's would. ``L1`` is chosen large (``SPLIT``
reaches) to leave the modes only the scales that a walk samples few times anyway: the spread of
one 5000-column walk's structure function at 16 samples was 4x a Gaussian field's at 4 reaches,
1.5x at 30 (1.9x over 10 000 columns; benchmarks/screen_statistics.py prints it).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .autoregressive import stencil_width
from .kolmogorov import phase_psd, von_karman_covariance
from .screen_kernels import add_modes, mode_phasors, mode_tables

#: the conditional draws' outer scale in stencil reaches [1]
SPLIT = 30.0
#: the conditional draws' outer scale at most, in outer scales: the modes carry at least the scales beyond [1]
SPLIT_OF_L0 = 0.4
#: ratio of successive rings' radii (as the subharmonic levels of Lane et al. 1992) [1]
RING_RATIO = 3.0
#: sectors of the half plane in each ring [1]
SECTORS = 4
#: positions ``p = STRIDE h + l``: the modes' cosines are tabulated at ``l`` once and computed at ``STRIDE h`` per read
STRIDE = 16
#: whole strides ``STRIDE h`` whose modes' cosines and sines a walked screen keeps between reads, per axis (a read
#: spans a few; :class:`.layer_screen.ModesPool`) [1]
PHASOR_SLOTS = 16
#: last word of a large-scale draw's seed (a screen's own draws end in a regeneration count, far below it)
SEED_WORD = 0xFFFFFFFF


def split_outer_scale(n: int, delta: float, L0: float) -> float:
    """``L1`` [m]: the outer scale the conditional draws of an ``n``-sample screen of spacing ``delta`` [m] make;
    ``L0`` itself (no large-scale modes) for Kolmogorov's infinite ``L0``, whose low frequencies have no finite
    variance to draw."""
    reach = stencil_width(n)            # the stencil's columns reach back 0 .. reach - 1
    return L0 if not np.isfinite(L0) else min(SPLIT * reach * delta, SPLIT_OF_L0 * L0)


@dataclass(frozen=True)
class Cells:
    """Rings of the frequency plane: the edges [cycles m^-1], each ring's power [rad^2, r0 = 1 m], and the cumulative
    radial power [rad^2] on a fine grid of ``log f`` (to draw a radius by inverting it)."""

    edges: np.ndarray
    power: np.ndarray
    cumulative_start: np.ndarray      # cumulative power at each ring's inner edge
    log_f: np.ndarray
    cumulative: np.ndarray

    def radius(self, u: np.ndarray) -> np.ndarray:
        """Radii [cycles m^-1] at quantiles ``u[ring, ...]`` of each ring's power: distributed as the PSD difference."""
        shape = (-1,) + (1,) * (u.ndim - 1)
        levels = self.cumulative_start.reshape(shape) + u * self.power.reshape(shape)
        return np.exp(np.interp(levels, self.cumulative, self.log_f))


@lru_cache(maxsize=64)
def cells(L0: float, L1: float) -> Cells:
    """The rings and their powers for the PSD difference ``PSD(f; L0) - PSD(f; L1)`` (r0 = 1 m)."""
    inner, outer = 1.0 / (3.0 * L0), 3.0 / L1
    rings = int(np.ceil(np.log(outer / inner) / np.log(RING_RATIO)))
    edges = np.r_[0.0, inner * RING_RATIO ** np.arange(rings + 1), np.inf]
    # the radial density 2 pi f PSD_low(f) per unit of ln f, integrated on a fine grid of ln f (relative error ~1e-7);
    # below the grid it grows as f^2 (PSD_low(0) finite): its integral there is half the first value
    f = np.geomspace(inner * 1e-4, outer * 1e4, 40001)
    density = 2 * np.pi * f * (phase_psd(f, 1.0, L0) - phase_psd(f, 1.0, L1)) * f
    cumulative = density[0] / 2 + np.r_[0.0, np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(np.log(f)))]
    total = von_karman_covariance(0.0, 1.0, L0) - von_karman_covariance(0.0, 1.0, L1)
    cumulative *= total / cumulative[-1]           # the grid misses ~1e-10 above 1e4 / L1: the total is exact
    at_edges = np.r_[0.0, np.interp(np.log(edges[1:-1]), np.log(f), cumulative), total]
    out = Cells(edges, np.diff(at_edges), at_edges[:-1], np.log(f), cumulative)
    for a in (out.edges, out.power, out.cumulative_start):      # (np.interp copies read-only tables: 40x slower)
        a.setflags(write=False)
    return out


class LargeScales:
    """The Fourier modes of one screen's large scales: frequencies per sample and coefficient amplitudes, drawn from
    ``rng`` (a NumPy generator, or :class:`.normal_draws.SeededDraws`: its ``random`` and ``standard_normal``)."""

    def __init__(self, rng: np.random.Generator, delta: float, L0: float, L1: float):
        c = cells(L0, L1)
        rings = len(c.power)
        u = rng.random((rings, SECTORS, 2))                      # radius quantile, angle within the sector
        radius = c.radius(u[:, :, 0])                            # (NumPy's exp: not libm's, so not compiled)
        k = rings * SECTORS
        normal = rng.standard_normal((2, k))
        # angular frequencies per sample [rad] (y, x), B-spline coefficient amplitudes (2, K) and the phasors within a
        # stride (cos, sin along y, then x), in one compiled call (NumPy's calls on 20-element arrays cost ~45 us)
        self.frequencies, self.amplitudes, self.low = np.empty((2, k)), np.empty((2, k)), np.empty((4, k, STRIDE))
        mode_tables(u, radius, c.power, 2 * np.pi * delta, normal, self.frequencies, self.amplitudes, self.low)
        self.wy, self.wx = self.frequencies
        self.a, self.b = self.amplitudes

    def add_to(self, coefficients: np.ndarray, top: int, left: int) -> np.ndarray:
        """``coefficients`` (an array whose first sample is at absolute (``top``, ``left``)) plus the modes' B-spline
        coefficients, a new array; each value depends only on its absolute position."""
        height, width = coefficients.shape
        return self.added(np.ascontiguousarray(coefficients, dtype=float), top, left, np.zeros(height, np.int64),
                          np.full(height, width, np.int64))

    def added(self, coefficients: np.ndarray, top: int, left: int, first: np.ndarray, stop: np.ndarray) -> np.ndarray:
        """An array of the shape of ``coefficients`` (first sample at absolute (``top``, ``left``)) holding, in each
        row ``r`` from column ``first[r]`` to ``stop[r]`` (exclusive), the coefficients plus the modes' B-spline
        coefficients, and nothing defined elsewhere (the reads stay within those spans)."""
        height, width = coefficients.shape
        cos_y, sin_y = self._phasors(0, top, height)
        cos_x, sin_x = self._phasors(1, left, width)
        out = np.empty((height, width))
        add_modes(coefficients, out, cos_y, sin_y, cos_x, sin_x, self.a, self.b, first, stop)
        return out

    def _phasors(self, axis: int, start: int, count: int):
        """``cos``, ``sin`` of ``w[k] p`` (K, count) along ``axis`` (0: y, 1: x) at ``p = start ..``."""
        cos, sin = np.empty((2, len(self.a), count))
        mode_phasors(self.frequencies[axis], self.low[2 * axis], self.low[2 * axis + 1], start, count, STRIDE, cos, sin,
                     0, np.full((PHASOR_SLOTS, 1 + 2 * len(self.a)), np.nan))
        return cos, sin
