"""Extending a von Karman phase screen by conditional Gaussian draws (Assemat, Wilson & Gendron 2006).

New columns ``X`` beyond the right edge of a screen are drawn conditionally on a stencil
``Z`` of existing values (Assemat et al. 2006, Opt. Express 14, 988, Eq. 9-12)::

    X = A Z + B w,   A = C_XZ C_ZZ^-1,   B B^T = C_XX - A C_ZX,   w ~ N(0, I)

with the covariances of von Karman turbulence (finite outer scale ``L0``). The stencil
is the last two columns plus every fourth row of columns ``3, 7, 15, ...`` back from
the edge, which carries the large scales (Assemat's sparse stencil). Extensions to the
left, top and bottom reuse the same matrices on a flipped or transposed screen, the
covariance being isotropic. Screens are drawn for ``r0 = 1 m``; the phase of a layer with
Fried parameter ``r0`` is ``r0^(-5/6)`` times the screen.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import cho_factor, cho_solve, cholesky

from .kolmogorov import von_karman_covariance


@dataclass(frozen=True)
class ExtensionOperator:
    """``A`` and ``B`` for adding ``k`` columns to an ``n``-row screen of spacing ``delta`` [m]."""

    n: int
    k: int
    stencil_rows: np.ndarray      # row index of each stencil value
    stencil_cols: np.ndarray      # column index counted back from the last column (0 = last)
    A: np.ndarray                 # (n k, n_stencil)
    B: np.ndarray                 # (n k, n k)

    def extend_right(self, screen: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """The ``n x k`` block [rad] that continues ``screen`` (``n x m``, ``m > max stencil column``) to the right."""
        last = screen.shape[1] - 1
        z = screen[self.stencil_rows, last - self.stencil_cols]
        block = self.A @ z + self.B @ noise
        return block.reshape(self.k, self.n).T


def stencil(n: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns-back of the stencil for an ``n``-row screen ``width`` columns wide."""
    rows, cols = [], []
    for back in (0, 1):
        rows.append(np.arange(n))
        cols.append(np.full(n, back))
    back = 3
    sparse_rows = np.unique(np.r_[np.arange(0, n, 4), n - 1])
    while back < width:
        rows.append(sparse_rows)
        cols.append(np.full(sparse_rows.size, back))
        back = 2 * back + 1
    return np.concatenate(rows), np.concatenate(cols)


@lru_cache(maxsize=16)
def extension_operator(n: int, k: int, delta: float, L0: float, width: int) -> ExtensionOperator:
    """The conditional-draw matrices for ``k`` new columns (cached; ``r0 = 1 m``)."""
    z_rows, z_back = stencil(n, width)
    z_y, z_x = z_rows.astype(float), -z_back.astype(float)
    new_cols, new_rows = np.meshgrid(np.arange(1, k + 1), np.arange(n), indexing="ij")   # column-major block
    x_y, x_x = new_rows.ravel().astype(float), new_cols.ravel().astype(float)

    max_r2 = (n + k + width) ** 2 * 2
    table = von_karman_covariance(np.sqrt(np.arange(max_r2 + 1)) * delta, 1.0, L0)

    def cov(ya, xa, yb, xb):
        # separations are integer on the grid: look the covariance up by r^2
        r2 = ((ya[:, None] - yb[None, :]) ** 2 + (xa[:, None] - xb[None, :]) ** 2).astype(np.int64)
        return table[r2]

    c_zz = cov(z_y, z_x, z_y, z_x)
    c_xz = cov(x_y, x_x, z_y, z_x)
    c_xx = cov(x_y, x_x, x_y, x_x)
    # A = C_XZ C_ZZ^-1 and B = chol(C_XX - A C_ZX); a jitter of 1e-10 of the variance keeps the
    # nearly singular fine-grid covariances positive definite
    jitter = 1e-10 * table[0]
    factor = cho_factor(c_zz + jitter * np.eye(len(c_zz)), lower=True)
    a = cho_solve(factor, c_xz.T).T
    conditional = c_xx - a @ c_xz.T
    conditional = 0.5 * (conditional + conditional.T) + jitter * np.eye(len(c_xx))
    b = cholesky(conditional, lower=True)
    return ExtensionOperator(n, k, z_rows, z_back, np.ascontiguousarray(a), np.ascontiguousarray(b))
