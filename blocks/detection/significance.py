"""Detection thresholds from a false-alarm rate: Poisson and Gaussian tails with a trials factor.

A detector tests ``n_trials`` hypotheses per look (positions times candidate velocities). To
keep the expected number of false alarms at ``F`` per hour per megapixel, each test is held to
the local p-value

    p_thr = F * (look / 3600 s) * (n_pixels / 10^6) / n_trials

(the Bonferroni bound: the expected number of false alarms is at most ``n_trials * p_thr``;
correlated trials make the true rate lower). A count ``k`` over a Poisson background of mean
``mu`` has the p-value ``P(N >= k) = P(k, mu)``, the regularised lower incomplete gamma
function (e.g. Gehrels 1986, ApJ 303, 336, Eq. 1); a Gaussian statistic ``z`` has ``P(Z >= z)``.
Significances are quoted as the one-sided Gaussian equivalent ``Phi^-1(1 - p)``.
"""

from __future__ import annotations

import numpy as np
from scipy import special, stats

SECONDS_PER_HOUR = 3600.0
PIXELS_PER_MEGAPIXEL = 1e6


def local_p_threshold(false_alarm_rate_per_hour_per_mpx: float, look_s: float, n_pixels: int,
                      n_trials: float) -> float:
    """The p-value each of ``n_trials`` tests must reach for ``F`` false alarms per hour per megapixel [1]."""
    allowed = false_alarm_rate_per_hour_per_mpx * look_s / SECONDS_PER_HOUR * n_pixels / PIXELS_PER_MEGAPIXEL
    return float(min(1.0, allowed / max(n_trials, 1.0)))


def poisson_p_value(k, mu):
    """``P(N >= k)`` for ``N ~ Poisson(mu)`` [1] (1 for ``k <= 0``)."""
    k = np.asarray(k, dtype=float)
    mu = np.asarray(mu, dtype=float)
    with np.errstate(invalid="ignore"):
        p = special.gammainc(np.maximum(k, 1.0), mu)     # regularised lower gamma P(k, mu) = P(N >= k)
    return np.where(k <= 0, 1.0, p)


def poisson_count_threshold(mu: float, p_threshold: float) -> int:
    """The smallest count ``k`` with ``P(N >= k) <= p_threshold`` for ``N ~ Poisson(mu)``."""
    if mu <= 0:
        return 1
    k = int(stats.poisson.isf(p_threshold, mu)) + 1     # a first guess, refined on the exact tail below
    while k > 1 and poisson_p_value(k - 1, mu) <= p_threshold:
        k -= 1
    while poisson_p_value(k, mu) > p_threshold:
        k += 1
    return k


def gaussian_sigma(p_value):
    """One-sided Gaussian equivalent of a p-value, ``Phi^-1(1 - p)`` [1] (capped at 38 for p underflowing)."""
    p = np.clip(np.asarray(p_value, dtype=float), 1e-300, 1.0)
    return np.minimum(stats.norm.isf(p), 38.0)
