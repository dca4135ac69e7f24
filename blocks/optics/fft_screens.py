"""FFT phase screens with subharmonics, and the structure function of a screen.

The FFT method (McGlamery 1976; Schmidt 2010 Sec. 9.3, Listing 9.2) draws complex
Gaussian Fourier coefficients with variance ``PSD(f) df^2`` on the grid's frequencies
and transforms them; the real and imaginary parts are two independent screens. Its
lowest frequency is ``1 / (N delta)``, so large scales (tilt) are missing; the
subharmonic method of Lane, Glindemann & Dainty 1992 (Waves Random Media 2, 209),
as in Schmidt 2010 Listing 9.3 (three levels of 3 x 3 frequencies spaced
``1 / (3^p N delta)``), adds them back.

One change from Listing 9.3: each subharmonic's variance is the PSD *integrated over
its frequency cell* rather than the PSD at the cell centre times the cell area
(Johansson & Gavel 1994, Proc. SPIE 2200, 372, reweight these cells for the same
reason). The ``f^(-11/3)`` PSD varies by orders of magnitude across a subharmonic
cell and the point value leaves the structure function 15-35 % low at large
separations; with cell integrals it stays within 9 % of ``6.88 (r/r0)^(5/3)`` from
one sample to half the screen (tests/optics).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.fft as sfft

from .kolmogorov import phase_psd
from .normal_draws import scaled_pair


def fft_phase_screens(rng: np.random.Generator, n: int, delta: float, r0: float, L0: float = np.inf,
                      subharmonics: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Two independent ``n x n`` screens [rad] sampled every ``delta`` [m] with Fried parameter ``r0`` [m]
    (the real and imaginary parts of one complex array: views, not copies).

    ``L0`` is the von Karman outer scale [m]; ``subharmonics`` adds Lane et al. 1992's low frequencies.
    The spectra depend only on ``(n, delta, r0, L0)`` and are kept (:func:`_spectra`), so a screen
    costs its random draws and one FFT. The FFT runs on the calling thread (callers render
    sources on every core).
    """
    amplitude, low = _spectra(int(n), float(delta), float(r0), float(L0), bool(subharmonics))
    screen = sfft.ifft2(_coefficients(rng, amplitude), workers=1, overwrite_x=True)
    if subharmonics:
        screen += _subharmonics(rng, *low)
    return screen.real, screen.imag                               # views: a caller keeping one copies only it


def fft_phase_screen_corner(rng: np.random.Generator, n: int, m: int, delta: float, r0: float,
                            L0: float = np.inf) -> np.ndarray:
    """The first screen of :func:`fft_phase_screens` (with subharmonics), only its first ``m x m`` samples [rad]:
    the same numbers bit for bit, from the same draws (``rng`` ends in the same state), for less work.

    ``ifft2`` transforms the columns, scaled by ``1 / n^2``, then the rows (pocketfft applies the
    whole factor on its first axis); here the rows' pass runs on the first ``m`` rows only and the
    subharmonics are summed on them only (tests/optics/test_optics_screens.py checks the identity).
    """
    return np.ascontiguousarray(fft_phase_screen_corners(rng, n, m, delta, r0, L0).real)


def fft_phase_screen_corners(rng: np.random.Generator, n: int, m: int, delta: float, r0: float,
                             L0: float = np.inf) -> np.ndarray:
    """Both screens of :func:`fft_phase_screens` (with subharmonics), their first ``m x m`` samples, as the real
    and imaginary parts of one complex ``m x m`` array [rad]: the real part is :func:`fft_phase_screen_corner`'s
    screen bit for bit, the imaginary part an independent screen of the same statistics from the same draws
    (Lane, Glindemann & Dainty 1992; Johansson & Gavel 1994): two screens for the draws and transforms of one."""
    n, m = int(n), int(m)
    amplitude, low = _spectra(n, float(delta), float(r0), float(L0), True)
    columns = sfft.ifft(_coefficients(rng, amplitude), axis=0, norm="forward", workers=1, overwrite_x=True)[:m]
    scale = np.float64(np.longdouble(1) / np.longdouble(n * n))  # pocketfft's factor, rounded from long double
    columns.view(np.float64)[...] *= scale                        # both parts in one pass (the same products)
    screen = sfft.ifft(columns, axis=1, norm="forward", workers=1, overwrite_x=True)
    screen += _subharmonics(rng, *low, rows=m)
    return screen[:, :m]


def fft_spline_corners(rng: np.random.Generator, n: int, m: int, first: int, delta: float, r0: float,
                       L0: float = np.inf) -> np.ndarray:
    """Cubic B-spline coefficients (Unser 1999) of both screens of :func:`fft_phase_screen_corners` (with
    subharmonics, the same draws: ``rng`` ends in the same state) over the samples ``first .. first + m - 1`` of
    each axis, as the real and imaginary parts of one complex ``m x m`` array [rad]: the spline through them takes
    the screens' values on the grid.

    The inverse B-spline filter of Unser 1999 (Eq. 10, ``6 / (z + 4 + 1/z)``) is applied exactly in the Fourier
    domain: each FFT coefficient and each subharmonic is divided by the cubic B-spline's response
    ``(2 + cos(2 pi f delta)) / 3`` along each axis (a real, even filter: it filters the real and imaginary
    screens alike). The piston removed is the unfiltered screen's, as in :func:`fft_phase_screen_corners`."""
    n, m, first = int(n), int(m), int(first)
    amplitude, low = _spectra(n, float(delta), float(r0), float(L0), True, True)
    columns = sfft.ifft(_coefficients(rng, amplitude), axis=0, norm="forward", workers=1,
                        overwrite_x=True)[first:first + m]
    scale = np.float64(np.longdouble(1) / np.longdouble(n * n))  # pocketfft's factor, rounded from long double
    columns.view(np.float64)[...] *= scale                        # both parts in one pass (the same products)
    screen = sfft.ifft(columns, axis=1, norm="forward", workers=1, overwrite_x=True)[:, first:first + m]
    powers, ey, ex, ey_mean, ex_mean, gains = low
    subharmonics = _subharmonics(rng, powers, ey[first:first + m], ex[:, first:first + m], ey_mean, ex_mean,
                                 gains=gains)
    # the screen plus its subharmonics written into the latter's contiguous rows: the same sums, for about half the
    # time of the sum written into the strided cut of the transform (NumPy's loop over it is slower)
    return np.add(screen, subharmonics, out=subharmonics)


def spline_response(f: np.ndarray, delta: float) -> np.ndarray:
    """The sampled cubic B-spline's frequency response ``(2 + cos(2 pi f delta)) / 3`` [1] at frequencies ``f``
    [cycles/m] (its samples 1/6, 2/3, 1/6; Unser 1999 Eq. 10 is the inverse)."""
    return (2.0 + np.cos(2 * np.pi * np.asarray(f) * delta)) / 3.0


def _coefficients(rng: np.random.Generator, amplitude: np.ndarray) -> np.ndarray:
    """Complex Gaussian Fourier coefficients of standard deviation ``amplitude``: the real parts' draws, then
    the imaginary parts' (NumPy's ``rng.standard_normal((2, n, n))`` times ``amplitude``, compiled:
    :func:`.normal_draws.scaled_pair`)."""
    return scaled_pair(rng, amplitude)


@lru_cache(maxsize=64)
def _spectra(n: int, delta: float, r0: float, L0: float, subharmonics: bool, spline: bool = False):
    """Amplitudes of the ``n x n`` FFT coefficients and, with ``subharmonics``, the three levels' powers and phasors;
    with ``spline``, those of the screen's B-spline coefficients (:func:`fft_spline_corners`): the amplitudes
    divided by :func:`spline_response` along each axis, and each level's 3 x 3 gains (iy, ix) for its draws."""
    amplitude = _amplitudes(n, delta, r0, L0, spline)
    amplitude.setflags(write=False)
    if not subharmonics:
        return amplitude, None
    x = (np.arange(n) - n / 2) * delta
    powers, frequencies = [], []
    for p in (1, 2, 3):
        df_p = 1.0 / (3**p * n * delta)
        f1 = np.array([-1.0, 0.0, 1.0]) * df_p
        powers.append(np.sqrt(_cell_integrated_psd(f1, df_p, r0, L0)))
        frequencies.append(f1)
    f = np.concatenate(frequencies)
    ey = np.exp(2j * np.pi * np.outer(x, f))                     # rows: y, columns: fy
    ex = np.exp(2j * np.pi * np.outer(f, x))                     # rows: fx, columns: x
    for a in (*powers, ey, ex):
        a.setflags(write=False)
    low = (tuple(powers), ey, ex, ey.mean(axis=0), ex.mean(axis=1))
    if not spline:
        return amplitude, low
    inverse = [1.0 / spline_response(f1, delta) for f1 in frequencies]
    gains = tuple(np.outer(g, g) for g in inverse)
    return amplitude, (*low, gains)


def _amplitudes(n: int, delta: float, r0: float, L0: float, spline: bool) -> np.ndarray:
    """``sqrt(PSD(|f|)) df n^2`` [rad] on the ``n x n`` FFT frequencies (no piston), divided by the B-spline's response
    along each axis with ``spline`` (:func:`_spectra`).

    fftfreq's frequency k is the exact negative of its frequency n - k (k times 1/(n delta), negated), and every step
    is a function of ``|f|`` element by element: they are computed on the frequencies 0..n/2 of each axis (a quarter
    of the grid) and mirrored, the same numbers. That is checked on the grid's last row and on the spline's response
    computed in full (a vectorised kernel that rounded by position would fail it): the whole grid otherwise."""
    fx = sfft.fftfreq(n, delta)
    inverse = 1.0 / spline_response(fx, delta) if spline else None
    half = n // 2 + 1
    u = np.abs(fx[:half])
    psd = phase_psd(np.hypot(u[:, None], u[None, :]), r0, L0)
    mirrored = (np.array_equal(_mirrored(psd[1], n), phase_psd(np.hypot(fx[-1], fx), r0, L0))
                and (inverse is None or np.array_equal(_mirrored(inverse[:half], n), inverse)))
    if not mirrored:
        half = n
        psd = phase_psd(np.hypot(fx[:, None], fx[None, :]), r0, L0)
    psd[0, 0] = 0.0                                             # no piston
    # coefficients c_k = (a + i b) sqrt(PSD) df, times n^2 to undo ifft2's 1/n^2: sum_k c_k exp(2 pi i f_k . x)
    amplitude = np.sqrt(psd) * (1.0 / (n * delta) * n * n)
    if spline:
        amplitude *= inverse[:half, None] * inverse[None, :half]
    return _mirrored(amplitude, n) if mirrored else amplitude


def _mirrored(quarter: np.ndarray, n: int) -> np.ndarray:
    """The values at fftfreq's frequencies 0..n-1 along each axis (C-contiguous) from those at 0..n/2 (``quarter``,
    1-D or 2-D): frequency ``k >= n/2 + 1`` takes the value of ``n - k``."""
    half = n // 2 + 1
    negatives = slice(n - half, 0, -1)                           # n - k for k = half .. n - 1
    if quarter.ndim == 1:
        return np.concatenate([quarter, quarter[negatives]])
    full = np.empty((n, n), dtype=quarter.dtype)
    full[:half, :half] = quarter
    full[:half, half:] = quarter[:, negatives]
    full[half:, :half] = quarter[negatives]
    full[half:, half:] = quarter[negatives, negatives]
    return full


def _subharmonics(rng: np.random.Generator, powers, ey, ex, ey_mean, ex_mean, rows: int | None = None,
                  gains=None) -> np.ndarray:
    """Low-frequency complex screen from three levels of 3 x 3 subharmonics (Schmidt 2010 Listing 9.3); with
    ``rows``, only its first ``rows`` rows (the same numbers); with ``gains`` (3 x 3 per level), each subharmonic
    times its gain, the piston removed that of the screen without them."""
    c = np.zeros((9, 9), dtype=complex)                          # block-diagonal: one 3 x 3 block per level
    for p, power in enumerate(powers):
        c[3 * p:3 * p + 3, 3 * p:3 * p + 3] = (rng.standard_normal((3, 3)) + 1j * rng.standard_normal((3, 3))) \
            * power                                              # c[iy, ix]
    piston = ey_mean @ c @ ex_mean
    if gains is not None:
        for p, gain in enumerate(gains):
            c[3 * p:3 * p + 3, 3 * p:3 * p + 3] *= gain
    low = (ey @ c)[:rows] @ ex                                   # the three levels in one product
    low -= piston                                                # no piston
    return low


def _cell_integrated_psd(f1: np.ndarray, df: float, r0: float, L0: float, samples: int = 16) -> np.ndarray:
    """``integral of PSD over the df x df cell around each of the 3 x 3 frequencies`` [rad^2], centre cell 0."""
    offsets = ((np.arange(samples) + 0.5) / samples - 0.5) * df
    power = np.zeros((3, 3))
    for iy in range(3):
        for ix in range(3):
            if iy == 1 and ix == 1:
                continue
            fy = f1[iy] + offsets[:, None]
            fx = f1[ix] + offsets[None, :]
            power[iy, ix] = phase_psd(np.hypot(fx, fy), r0, L0).mean() * df * df
    return power


def structure_function_2d(phase: np.ndarray, mask: np.ndarray, delta: float) -> np.ndarray:
    """Structure function ``D(dx, dy)`` [rad^2] of ``phase`` over ``mask``, by FFT (Schmidt 2010 Listing 3.7).

    The result is centred: index ``[n//2, n//2]`` is zero separation. ``mask`` should not
    fill more than half of the grid so that the correlations do not wrap.
    """
    n = phase.shape[0]
    w = mask.astype(float)
    p = sfft.fft2(phase * w)
    s = sfft.fft2(phase**2 * w)
    wf = sfft.fft2(w)
    overlap = sfft.ifft2(np.abs(wf) ** 2).real
    numerator = 2 * sfft.ifft2((s * np.conj(wf)).real - np.abs(p) ** 2).real
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(overlap > 0.5, numerator / np.maximum(overlap, 0.5), np.nan)
    return sfft.fftshift(d)


def radial_profile(values: np.ndarray, delta: float, radii: np.ndarray) -> np.ndarray:
    """Mean of a centred 2-D array along rings at ``radii`` [m] (bins of width ``delta``), NaNs ignored."""
    n = values.shape[0]
    y, x = np.indices(values.shape) - n // 2
    r = np.hypot(x, y) * delta
    out = np.empty(len(radii))
    for i, radius in enumerate(radii):
        ring = np.abs(r - radius) < 0.5 * delta
        out[i] = np.nanmean(values[ring])
    return out
