"""Eqs. 12-16, 19 and 20 compiled: the event-driven loop's input columns for one photon flux.

The fast implementation needs a pixel's drive (lin-log target ``Y``, filter retention
``ln a``, parasitic rate, shot-noise acceptance) at every input change. :meth:`.model.PixelModel.drive`
computes these with NumPy from the physics modules (:mod:`.photoreceptor`, :mod:`.lowpass`,
:mod:`.noise`, which carry the equations and their sources); :func:`drive_one` evaluates the
same equations for one flux, compiled, so that the sparse path (rows per input change,
:func:`drive_rows`) and the dense path (computed while it walks the frames, vectorised over
pixels, :mod:`.dense_loop`) share one scalar function and give bit-identical inputs. It agrees
with ``PixelModel.drive`` to rounding (tested): the logarithms are :mod:`.fastmath`'s, and
the filter's retention is written ``ln(1 - eps) = -ln(1 + w)`` with ``eps = w / (1 + w)``
(Eq. 16's backward-Euler gain, ``w = 2 pi dt f_3dB``); the constants are folded into products,
so that no division is made per pixel beyond those of the logarithms.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from . import lowpass, photoreceptor
from .fastmath import exp_, log1p_, log_, wide_vectors
from .model import PixelModel
from .pixel_loop import ACCEPT, FLUX, LOG_A, PARA, Y

# entries of the constants array (see drive_constants)
(CURRENT_PER_FLUX, DARK, LOG_TO_DARK, KNEE, KNEE_SLOPE, CUTOFF_MAX, CUTOFF_LAW, CUTOFF_PER_CURRENT, CUTOFF_PER_Y,
 CUTOFF_EXPONENT, LOG_SATURATION, SQUARE_LAW, CUTOFF_SQUARED_PER_CURRENT, W_PER_HZ, PARA_PER_FLUX, PARA_MAX,
 SHOT_FLOOR, SHOT_PER_Y, SHOT_SLOPE, ACCEPT_DARK, ACCEPT_FLAT, N_CONSTANTS) = range(22)
LAWS = {"paper": 0.0, "proportional": 1.0, "power": 2.0}          # cutoff laws of Eq. 16 (:mod:`.lowpass`)

jit = numba.njit(cache=True, error_model="numpy", nogil=True)      # runs beside other blocks' steps (pipelined windows)
inline = numba.njit(cache=True, error_model="numpy", inline="always")      # so that loops over pixels vectorise


def drive_constants(model: PixelModel) -> np.ndarray:
    """The model's constants for :func:`drive_one`: Eqs. 12-20 folded into products (no division per pixel)."""
    p = model.params
    k = np.zeros(N_CONSTANTS)
    photon_j = photoreceptor.photon_energy_J(model.wavelength_m)                            # [J]
    k[CURRENT_PER_FLUX] = photon_j * model.responsivity_A_per_W / p.reference_current_A       # [s photon^-1]
    k[DARK] = model.dark_current_A / p.reference_current_A                                  # [1]
    k[LOG_TO_DARK] = float(model._log_to_dark)
    k[KNEE], k[KNEE_SLOPE] = p.linear_knee, np.log(p.linear_knee) / p.linear_knee            # [1], [1]
    k[CUTOFF_MAX], k[CUTOFF_LAW] = p.cutoff_max_hz, LAWS[p.cutoff_model]                     # [Hz], law
    k[CUTOFF_PER_CURRENT] = p.cutoff_max_hz / p.cutoff_saturation                           # [Hz]
    k[CUTOFF_PER_Y] = p.cutoff_max_hz / lowpass.PAPER_SCALE                                 # [Hz]
    k[CUTOFF_EXPONENT], k[LOG_SATURATION] = p.cutoff_exponent, np.log(p.cutoff_saturation)  # [1], [1]
    k[SQUARE_LAW] = float(p.cutoff_model == "power" and p.cutoff_exponent == 0.5)          # the power law is a root
    k[CUTOFF_SQUARED_PER_CURRENT] = p.cutoff_max_hz ** 2 / p.cutoff_saturation               # [Hz^2]
    k[W_PER_HZ] = 2.0 * np.pi * model.dt_s                                                  # [s]
    k[PARA_PER_FLUX] = photon_j * p.luminous_efficacy_lm_per_W / model.pixel_area_m2 * p.parasitic_rate_per_lux_hz
    k[PARA_MAX] = model.parasitic_max_hz                                                    # [Hz]
    span = p.log_current_max - model.shot_noise_floor                                       # [1]
    k[SHOT_FLOOR], k[SHOT_PER_Y] = model.shot_noise_floor, 1.0 / span if span > 0 else 0.0  # [1], [1]
    k[SHOT_SLOPE] = p.shot_noise_intensity_factor - 1.0                                     # [1]
    accept = p.shot_noise_rate_hz * model.dt_s / model.shot_p_max if model.shot_p_max > 0 else 0.0
    k[ACCEPT_DARK] = accept                                                                 # [1]
    k[ACCEPT_FLAT] = accept * (p.shot_noise_intensity_factor if span <= 0 else np.nan)     # [1]
    return k


@inline
def drive_one(flux, k, square_law):
    """``(Y, ln a, R_para, accept)`` for a photon flux [photon s^-1] (see :meth:`PixelModel.drive`).

    ``square_law``: ``k[SQUARE_LAW] != 0``, the power cutoff law with exponent 1/2, whose
    ``(x / x_sat)^(1/2) f_max`` is ``sqrt(x f_max^2 / x_sat)`` (one rounding instead of an ``exp``
    of a logarithm); a loop over pixels passes it as a constant (the dense sweep: two versions of
    its loop) or a flag the compiler takes out of the loop (:func:`drive_rows`), so that the other
    is not computed. In three stages (:func:`drive_log`, :func:`drive_cutoff`,
    :func:`drive_rest`), which a loop over pixels may take in three loops: short loops overlap
    more pixels' work.
    """
    x, log_x = drive_log(flux, k)
    y, w = drive_cutoff(x, log_x, k, square_law)
    return drive_rest(flux, y, w, k)


@inline
def drive_log(flux, k):
    """``(x, ln x)``: the normalised current of a photon flux (Eqs. 12, 13, 15) and its logarithm."""
    x = flux * k[CURRENT_PER_FLUX] + k[DARK]
    return x, log_(x)


@inline
def drive_cutoff(x, log_x, k, square_law):
    """``(Y, w)`` from ``(x, ln x)``: the lin-log target (Eq. 14) and ``w = 2 pi dt f_3dB`` (Eq. 16)."""
    # the constants are read first and every alternative is computed and one selected (no branches, no
    # conditional loads), so that loops over pixels vectorise
    log_to_dark, knee, knee_slope = k[LOG_TO_DARK], k[KNEE], k[KNEE_SLOPE]
    f_max, law, per_current, per_y, w_per_hz = (k[CUTOFF_MAX], k[CUTOFF_LAW], k[CUTOFF_PER_CURRENT], k[CUTOFF_PER_Y],
                                                k[W_PER_HZ])
    exponent, log_saturation = k[CUTOFF_EXPONENT], k[LOG_SATURATION]
    y = log_x if (log_to_dark != 0.0) | (not x < knee) else x * knee_slope            # lin-log, Eq. 14
    f_power = (math.sqrt(x * k[CUTOFF_SQUARED_PER_CURRENT]) if square_law else
               f_max * exp_(min(max(exponent * (log_x - log_saturation), -700.0), 700.0)))   # (x / x_sat)^n f_max
    f_power = f_power if x > 0.0 else 0.0
    f = x * per_current if law == 1.0 else (f_power if law == 2.0 else (y + lowpass.PAPER_OFFSET) * per_y)  # Eq. 16
    return y, w_per_hz * min(max(f, 0.0), f_max)


@inline
def drive_rest(flux, y, w, k):
    """:func:`drive_one` from ``(Y, w)`` (:func:`drive_cutoff`)."""
    f_max, para_per_flux, para_max, floor, per_y_shot, slope = (k[CUTOFF_MAX], k[PARA_PER_FLUX], k[PARA_MAX],
                                                                k[SHOT_FLOOR], k[SHOT_PER_Y], k[SHOT_SLOPE])
    accept_dark, accept_flat = k[ACCEPT_DARK], k[ACCEPT_FLAT]
    log_a = -log1p_(w)                                                     # ln(1 - eps) = -ln(1 + w)
    log_a = log_a if f_max > 0.0 else -math.inf                            # no filter: L follows Y
    para = min(flux * para_per_flux, para_max)                             # Eq. 19
    level = min(max((y - floor) * per_y_shot, 0.0), 1.0)                   # shot noise, Eq. 20
    accept = (slope * level + 1.0) * accept_dark
    accept = accept_flat if accept_flat == accept_flat else accept        # no span of Eq. 20 (NaN: there is one)
    return y, log_a, para, accept


@jit
def drive_into(row, flux, k):
    """Set ``row[FLUX, Y, LOG_A, PARA, ACCEPT]`` for a photon flux [photon s^-1] (:func:`drive_one`)."""
    row[FLUX] = flux
    row[Y], row[LOG_A], row[PARA], row[ACCEPT] = drive_one(flux, k, k[SQUARE_LAW] != 0.0)


@jit
def drive_rows(flux, k, rows):
    """:func:`drive_into` for every flux of ``flux``, into the rows of ``rows`` (the same bits: tested).

    In :func:`drive_one`'s three stages, each a loop over the fluxes that the compiler vectorises.
    ``square_law`` is a run-time flag here, not a constant: the compiler takes its test out of the
    loop (as fast as a copy of the loop per value, measured), and one loop is compiled instead of two
    (4.0 -> 1.4 s CPU cold, ``benchmarks/pixel_compile.py``).
    """
    wide_vectors()
    square_law = k[SQUARE_LAW] != 0.0
    n = flux.size
    x, log_x = np.empty(n), np.empty(n)
    for i in range(n):
        x[i], log_x[i] = drive_log(flux[i], k)
    for i in range(n):
        x[i], log_x[i] = drive_cutoff(x[i], log_x[i], k, square_law)       # Y, w
    for i in range(n):
        rows[i, FLUX] = flux[i]
        rows[i, Y], rows[i, LOG_A], rows[i, PARA], rows[i, ACCEPT] = drive_rest(flux[i], x[i], log_x[i], k)
