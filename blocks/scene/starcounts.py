"""Star counts versus magnitude and galactic position: Bahcall & Soneira (1980), Appendix B.

Bahcall & Soneira (1980, ApJS 44, 73), Eq. (B1), give an analytic fit to their
Galaxy model's integrated V-band counts, stars per square degree brighter than V:

    N(m, l, b) = C1 10^(beta (m - m*)) / [1 + 10^(alpha (m - m*))]^delta
                   / [sin b (1 - mu cot b cos l)]^(3 - 5 gamma)
               + C2 10^(eta (m - m+)) / [1 + 10^(kappa (m - m+))]^lambda / (1 - cos b cos l)^sigma

with the constants below, ``mu``, ``gamma`` varying linearly between V = 12 and 20 and
``sigma = 1.45 - 0.20 cos b cos l``. The authors quote it as good to about 15% for
|b| >= 20 deg; nearer the plane this module holds |b| at 20 deg, which underestimates
the counts there.
"""

from __future__ import annotations

import numpy as np

#: Eq. (B1) constants for integrated V counts (Bahcall & Soneira 1980, Appendix B)
C1, ALPHA, BETA, DELTA, M_STAR = 925.0, -0.132, 0.035, 3.0, 15.75
C2, KAPPA, ETA, LAMBDA, M_DAGGER = 1050.0, -0.180, 0.087, 2.5, 17.5
MIN_ABS_LATITUDE_DEG = 20.0


def integrated_counts_per_deg2(v_mag, l_deg: float, b_deg: float) -> np.ndarray:
    """Stars per square degree brighter than ``v_mag`` at galactic longitude ``l_deg``, latitude ``b_deg``."""
    m = np.asarray(v_mag, dtype=np.float64)
    l = np.radians(l_deg)
    b = np.radians(max(abs(b_deg), MIN_ABS_LATITUDE_DEG))
    mu = np.clip(0.03 + 0.0075 * (m - 12.0), 0.03, 0.09)
    gamma = np.clip(0.36 - 0.04 * (m - 12.0), 0.04, 0.36)
    sigma = 1.45 - 0.20 * np.cos(b) * np.cos(l)
    disk = (C1 * 10 ** (BETA * (m - M_STAR)) / (1 + 10 ** (ALPHA * (m - M_STAR))) ** DELTA
            / (np.sin(b) * (1 - mu / np.tan(b) * np.cos(l))) ** (3 - 5 * gamma))
    spheroid = C2 * 10 ** (ETA * (m - M_DAGGER)) / (1 + 10 ** (KAPPA * (m - M_DAGGER))) ** LAMBDA \
        / (1 - np.cos(b) * np.cos(l)) ** sigma
    return disk + spheroid


def draw_magnitudes(rng: np.random.Generator, n: int, bright: float, faint: float, l_deg: float,
                    b_deg: float) -> np.ndarray:
    """``n`` V magnitudes in ``[bright, faint)`` distributed as the model's counts (inverse CDF)."""
    grid = np.linspace(bright, faint, 512)
    cumulative = integrated_counts_per_deg2(grid, l_deg, b_deg)
    cumulative = cumulative - cumulative[0]
    return np.interp(rng.uniform(0.0, cumulative[-1], n), cumulative, grid)
