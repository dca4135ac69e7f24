"""Extending a von Karman phase screen by conditional Gaussian draws (Assemat, Wilson & Gendron 2006).

New columns ``X`` beyond the right edge of a screen are drawn conditionally on a stencil
``Z`` of existing values (Assemat et al. 2006, Opt. Express 14, 988, Eq. 9-12)::

    X = A Z + B w,   A = C_XZ C_ZZ^-1,   B B^T = C_XX - A C_ZX,   w ~ N(0, I)

with the covariances of von Karman turbulence (finite outer scale ``L0``). The stencil
is the last three columns plus every fourth row of columns ``3, 7, 15, ...`` back from
the edge, which carries the large scales (Assemat's sparse stencil, with one more full
column: conditioned on two, the spline's structure function along a walk came out 5-8 %
low at lags of 4-20 samples; the same 40 walks on three, within 1 %). Extensions to the
left, top and bottom reuse the same matrices on a flipped or transposed screen, the
covariance being symmetric under both. Screens are drawn for ``r0 = 1 m``; the phase of
a layer with Fried parameter ``r0`` is ``r0^(-5/6)`` times the screen.

The screens hold cubic B-spline *coefficients* ``c`` (Unser 1999, IEEE Signal Process. Mag.
16(6), 22), not samples: the spline ``s = sum c[k, l] beta3(y - k) beta3(x - l)`` takes the
screen's values on the grid, ``s = (b x b) * c`` with ``b = [1, 4, 1] / 6`` (Unser Eq. 4), so
``c = (h x h) * s`` with ``h`` the inverse filter ``h[k] = sqrt(3) z1^|k|``, ``z1 = sqrt(3) - 2``
(Unser Eq. 10), and the coefficients are a stationary Gaussian field of covariance
``C_c = (g x g) * C_s``, ``g = h * h``, ``C_s`` von Karman's on the grid
(:func:`spline_coefficient_covariance`). Drawing ``c`` directly, conditionally on ``c``, makes the
same spline as drawing the samples and prefiltering them, without the prefilter (and the
margin of samples it needs around every footprint).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.linalg import cho_factor, cho_solve, cholesky

from .kolmogorov import von_karman_covariance


@dataclass(frozen=True)
class ExtensionOperator:
    """``A`` and ``B`` for adding ``k`` columns of B-spline coefficients to an ``n``-row screen of spacing ``delta`` [m]."""

    n: int
    k: int
    stencil_rows: np.ndarray      # row index of each stencil value
    stencil_cols: np.ndarray      # column index counted back from the last column (0 = last)
    A: np.ndarray                 # (n k, n_stencil)
    B: np.ndarray                 # (n k, n k)

    def extend_right(self, screen: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """The ``n x k`` block of coefficients [rad] that continues ``screen`` (``n x m``, ``m > max stencil column``)
        to the right."""
        last = screen.shape[1] - 1
        z = screen[self.stencil_rows, last - self.stencil_cols]
        block = self.A @ z + self.B @ noise
        return block.reshape(self.k, self.n).T


#: columns of the stencil taken whole, counted back from the edge [1]
FULL_COLUMNS = 3


def stencil(n: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns-back of the stencil for an ``n``-row screen ``width`` columns wide."""
    rows, cols = [], []
    for back in range(FULL_COLUMNS):
        rows.append(np.arange(n))
        cols.append(np.full(n, back))
    back = 3
    sparse_rows = np.unique(np.r_[np.arange(0, n, 4), n - 1])
    while back < width:
        rows.append(sparse_rows)
        cols.append(np.full(sparse_rows.size, back))
        back = 2 * back + 1
    return np.concatenate(rows), np.concatenate(cols)


#: half-width of the inverse B-spline filter summed for the coefficients' covariance: |z1|^32 ~ 5e-19 [samples]
_INVERSE_HALF_WIDTH = 32


@lru_cache(maxsize=32)
def spline_coefficient_covariance(extent: int, delta: float, L0: float) -> np.ndarray:
    """Covariance [rad^2, r0 = 1 m] of the cubic B-spline coefficients of a von Karman screen sampled every ``delta``
    [m]: ``table[|dy|, |dx|]`` for offsets 0 .. ``extent`` samples.

    ``C_c[m, n] = sum_ab g[a] g[b] C_s[m - a, n - b]`` with ``g = h * h`` the autocorrelation of Unser 1999's
    inverse filter ``h[k] = sqrt(3) z1^|k|`` (Eq. 10), summed to ``|k| <= 32``.
    """
    z1 = np.sqrt(3.0) - 2.0
    k = np.arange(-_INVERSE_HALF_WIDTH, _INVERSE_HALF_WIDTH + 1)
    h = np.sqrt(3.0) * z1 ** np.abs(k)
    g = np.convolve(h, h)                                      # symmetric, 4 K + 1 taps
    reach = extent + 2 * _INVERSE_HALF_WIDTH
    m = np.abs(np.arange(-reach, reach + 1))
    samples = _covariance_quadrant(reach, delta, L0)[m[:, None], m[None, :]]
    # the valid part of the separable convolution, only the non-negative offsets kept
    rows = sliding_window_view(samples[reach - 2 * _INVERSE_HALF_WIDTH:], g.size, axis=0) @ g
    both = sliding_window_view(rows, g.size, axis=1) @ g
    table = np.ascontiguousarray(both[:extent + 1, reach - 2 * _INVERSE_HALF_WIDTH:][:, :extent + 1])
    table.setflags(write=False)
    return table


def _covariance_quadrant(reach: int, delta: float, L0: float) -> np.ndarray:
    """von Karman's covariance [rad^2, r0 = 1 m] at the grid offsets ``(dy, dx)`` [samples], ``0 <= dy, dx <= reach``:
    the grid's other quadrants are its mirror images (``hypot`` takes magnitudes), a quarter of the Bessel functions'
    evaluations. Each value is an element-by-element function of the same double ``hypot(dy, dx) delta`` wherever it
    lies (tests/optics/test_optics_screens.py compares the whole grid's)."""
    d = np.arange(reach + 1)
    return von_karman_covariance(np.hypot(d[:, None], d[None, :]) * delta, 1.0, L0)


def stencil_width(width: int) -> int:
    """The narrowest screen with the stencil of a screen ``width`` columns wide (the operators' cache key)."""
    back, widest = 3, FULL_COLUMNS - 1
    while back < width:
        widest, back = back, 2 * back + 1
    return widest + 1


@lru_cache(maxsize=32)
def first_columns(n: int, delta: float, L0: float) -> np.ndarray:
    """Lower Cholesky factor of the coefficients' covariance over ``FULL_COLUMNS`` columns of ``n`` rows, column by
    column (an exact draw the extension can start from)."""
    rows, cols = np.meshgrid(np.arange(n), np.arange(FULL_COLUMNS), indexing="xy")
    y, x = rows.ravel(), cols.ravel()
    table = spline_coefficient_covariance(2 * n + 1, delta, L0)
    covariance = table[np.abs(y[:, None] - y[None]), np.abs(x[:, None] - x[None])]
    factor = cholesky(covariance + 1e-10 * table[0, 0] * np.eye(len(y)), lower=True)
    factor.setflags(write=False)
    return factor


def extension_operator(n: int, k: int, delta: float, L0: float, width: int) -> ExtensionOperator:
    """The conditional-draw matrices for ``k`` new columns of B-spline coefficients on a screen ``width`` columns
    wide (cached; ``r0 = 1 m``)."""
    return _extension_operator(n, k, delta, L0, stencil_width(width))


@lru_cache(maxsize=64)
def _extension_operator(n: int, k: int, delta: float, L0: float, width: int) -> ExtensionOperator:
    z_rows, z_back = stencil(n, width)
    z_y, z_x = z_rows.astype(float), -z_back.astype(float)
    new_cols, new_rows = np.meshgrid(np.arange(1, k + 1), np.arange(n), indexing="ij")   # column-major block
    x_y, x_x = new_rows.ravel().astype(float), new_cols.ravel().astype(float)

    table = spline_coefficient_covariance(2 * n + k, delta, L0)

    def cov(ya, xa, yb, xb):
        # separations are integer on the grid: look the covariance up by |dy|, |dx|
        dy = np.abs(ya[:, None] - yb[None, :]).astype(np.int64)
        dx = np.abs(xa[:, None] - xb[None, :]).astype(np.int64)
        return table[dy, dx]

    c_zz = cov(z_y, z_x, z_y, z_x)
    c_xz = cov(x_y, x_x, z_y, z_x)
    c_xx = cov(x_y, x_x, x_y, x_x)
    # A = C_XZ C_ZZ^-1 and B = chol(C_XX - A C_ZX); a jitter of 1e-10 of the variance keeps the
    # nearly singular fine-grid covariances positive definite
    jitter = 1e-10 * table[0, 0]
    factor = cho_factor(c_zz + jitter * np.eye(len(c_zz)), lower=True)
    a = cho_solve(factor, c_xz.T).T
    conditional = c_xx - a @ c_xz.T
    conditional = 0.5 * (conditional + conditional.T) + jitter * np.eye(len(c_xx))
    b = cholesky(conditional, lower=True)
    return ExtensionOperator(n, k, z_rows, z_back, np.ascontiguousarray(a), np.ascontiguousarray(b))
