"""A layer's Karhunen-Loeve (Zernike) phase screen over the pupil's footprint, under frozen flow.

The paper's modal screen (Sec. 2.2, Eq. 7-11; Roddier 1990) is the sum of Zernike modes
over the *aperture*: ``phi = sum_j a_j Z_j(r / (D/2))`` with Karhunen-Loeve coefficients of
Noll's covariance for ``D / r0``. On a layer the aperture's footprint has diameter
``s D`` (``s = 1 - L/R`` for a source at range ``R``), so the coefficients are drawn for
``s D / r0`` and the modes are evaluated on the pupil grid itself: the pupil then sees
exactly Noll's statistics (residual variances ``Delta_J``, Noll 1976 Table IV, less the
modes beyond ``n_modes``).

A modal screen exists only over the footprint, so frozen flow cannot translate it.
Instead the coefficients are a field over the layer: independent KL draws ``a_ij`` sit on a
square lattice of spacing ``D`` [m] (absolute layer coordinates, one lattice per revisit
epoch), and a footprint centred at ``p`` takes ``a(p) = sum w_ij a_ij`` over the four
surrounding nodes with ``w = c(fx) c(fy)``, ``c`` being ``cos(pi f / 2)`` toward the lower
node and ``sin(pi f / 2)`` toward the upper one. Since ``sum w^2 = 1`` the covariance of
``a(p)`` is Noll's at every position, the phase changes continuously as the flow carries the
footprint (no jumps, which a DVS would see as event bursts) and decorrelates over a shift of
about ``2 D``. The correlation of the tip/tilt this gives (0.93, 0.76 at shifts D/4, D/2)
is close to frozen-flow Kolmogorov tilt (about 0.92, 0.78 for L0 = 25 m, FFT screens,
tests/optics); higher orders decorrelate faster in reality (over ~D/(n+1)), so use
``screen_method: fft`` where temporal statistics matter. The coefficients depend only on the
footprint's position and epoch: results do not depend on windows, and there is no state.
"""

from __future__ import annotations

import numpy as np

from .karhunen_loeve import KarhunenLoeve
from .zernike import zernike_basis

#: lattice nodes whose draws are kept between calls (a footprint uses 4; a window's sweep a few hundred)
NODE_CACHE = 4096


class ModalScreen:
    """KL coefficients of one layer as a function of the footprint's position (for ``r0 = 1 m``)."""

    def __init__(self, seed: tuple[int, ...], aperture_m: float, n_modes: int):
        self.seed, self.aperture_m, self.n_modes = tuple(int(s) for s in seed), float(aperture_m), int(n_modes)
        self._kl = KarhunenLoeve.of(self.n_modes)
        self._nodes: dict[tuple[int, int, int], np.ndarray] = {}

    def _node(self, epoch: int, i: int, j: int) -> np.ndarray:
        """Unit KL coefficients (D/r0 = 1) of lattice node (i, j) of ``epoch``."""
        key = (epoch, i, j)
        if key not in self._nodes:
            if len(self._nodes) >= NODE_CACHE:
                self._nodes.clear()
            words = [*self.seed, epoch & 0xFFFFFFFF, i & 0xFFFFFFFF, j & 0xFFFFFFFF]
            rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(words)))
            self._nodes[key] = self._kl.sample_coefficients(rng, 1.0)
        return self._nodes[key]

    def coefficients(self, centre_m: np.ndarray, epochs: np.ndarray) -> np.ndarray:
        """Zernike coefficients (F, n_modes) [rad] for D/r0 = 1 of footprints centred at ``centre_m`` (F, 2) [m]."""
        position = np.asarray(centre_m, dtype=float) / self.aperture_m
        base = np.floor(position).astype(np.int64)
        half_pi_f = 0.5 * np.pi * (position - base)
        weights = np.stack([np.cos(half_pi_f), np.sin(half_pi_f)], axis=-1)        # (F, axis, lower/upper)
        out = np.zeros((len(position), self.n_modes))
        for f, (epoch, (ix, iy)) in enumerate(zip(np.asarray(epochs, dtype=np.int64), base)):
            for dx in (0, 1):
                for dy in (0, 1):
                    w = weights[f, 0, dx] * weights[f, 1, dy]
                    out[f] += w * self._node(int(epoch), int(ix + dx), int(iy + dy))
        return out


def pupil_modes(n_modes: int, n_pupil: int, delta_m: float, aperture_m: float) -> np.ndarray:
    """Zernike modes ``j = 2 .. n_modes + 1`` on the pupil grid, ``(n_modes, n_pupil, n_pupil)`` [1]."""
    x = (np.arange(n_pupil) - n_pupil // 2) * delta_m
    return zernike_basis(n_modes, x[None, :], x[:, None], aperture_m / 2, first=2)
