"""The pixels' state when a run starts (shared by both implementations, so they start identical).

The photoreceptor starts settled on its first input (``L = Y``), as in v2e. The memorised
value starts a uniformly random fraction of the ON threshold below it (``dI`` uniform in
``[0, theta_ON)``), the stationary phase of the leak drift of Eqs. 18-19: a sensor that has
been running shows leak events at a steady rate from the first moment instead of all
pixels firing together one leak period after switch-on. That head start is charged to the
leak and parasitic contributions in proportion to their rates; without either leak
(``R_leak = R_para = 0``) the memorised value starts equal to ``L``. Each pixel also draws its
factor on the noise rates (hot pixels, :func:`noise_scale`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .comparator import draw_thresholds
from .model import PixelModel


class InitialPixels(NamedTuple):
    theta_on: np.ndarray     # [n] (in ln of current)
    theta_off: np.ndarray    # [n]
    filtered: np.ndarray     # L [n]
    memorised: np.ndarray    # M [n]
    credit: np.ndarray       # [2, n] leak and parasitic contributions to L - M
    noise_scale: np.ndarray  # [n] each pixel's factor on the junction-leak and shot-noise rates [1]


class InitialDraws(NamedTuple):
    """The random numbers of every pixel's start, drawn in this order."""

    theta_on: np.ndarray     # [n] (in ln of current)
    theta_off: np.ndarray    # [n]
    phase: np.ndarray        # [n] the memory's head start as a fraction of theta_ON, uniform in [0, 1)
    noise_scale: np.ndarray  # [n] (:func:`noise_scale`)


def initial_draws(model: PixelModel, n: int, rng: np.random.Generator) -> InitialDraws:
    """Thresholds (paper Sec. 2.4), the memory's head start and the noise rates' factors of ``n`` pixels."""
    p = model.params
    theta_on = draw_thresholds(rng, n, p.threshold_on, p.threshold_sigma, p.threshold_floor)
    theta_off = draw_thresholds(rng, n, p.threshold_off, p.threshold_sigma, p.threshold_floor)
    phase = rng.random(n)
    return InitialDraws(theta_on, theta_off, phase, noise_scale(model, n, rng))


def initial_pixels(model: PixelModel, photon_flux: np.ndarray, rng: np.random.Generator) -> InitialPixels:
    """Thresholds (paper Sec. 2.4) and settled photoreceptor and memory of every pixel.

    The event-driven implementation computes the same values pixel by pixel in its first pass over the state
    (:func:`.pixel_loop.start_pixels`, from :func:`initial_draws`; tested)."""
    p = model.params
    n = photon_flux.shape[0]
    theta_on, theta_off, phase, scale = initial_draws(model, n, rng)
    drive = model.drive(photon_flux)
    rate = p.leak_rate_hz + drive.parasitic_hz
    head = np.where(rate > 0, phase * theta_on, 0.0)
    share = np.divide(p.leak_rate_hz, rate, out=np.zeros(n), where=rate > 0)
    credit = np.zeros((2, n))
    credit[0] = head * share
    credit[1] = head - credit[0]
    return InitialPixels(theta_on, theta_off, drive.y.copy(), drive.y - head, credit, scale)


def noise_scale(model: PixelModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """Each pixel's factor on its junction-leak and shot-noise rates: hot pixels [1].

    Log-normal with ``noise_rate_spread_decades`` as the standard deviation of its log10 and
    mean 1 (``exp(s z - s^2/2)``, ``s = spread ln 10``), so the array's mean rate stays the
    configured one while a few pixels fire far more often; v2e's ``noise_rate_cov_decades`` is
    the same spread with the median at 1 instead. Capped where a pixel's shot-noise trial would
    come every step. Without a spread every pixel has 1 and no random number is drawn.
    """
    spread = model.params.noise_rate_spread_decades
    if spread == 0:
        return np.ones(n)
    s = spread * np.log(10.0)
    scale = np.exp(s * rng.standard_normal(n) - 0.5 * s * s)
    cap = 1.0 / (2.0 * model.shot_p_max) if model.shot_p_max > 0 else np.inf
    return np.minimum(scale, cap)
