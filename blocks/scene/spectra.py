"""Source spectra and detector responses: the photons a sensor counts from a source of known V magnitude.

A source's magnitude fixes its photon flux in V, ``N_V = N0 10^(-0.4 V)`` (:mod:`.radiometry`). A detector of
quantum efficiency ``QE`` at 550 nm and response ``r(lambda)`` (its QE over that value) makes ``QE N_V kappa``
electrons per second, with the band factor

    kappa = integral F(l) r(l) l dl / integral F(l) V(l) l dl

of the source's spectral flux density ``F`` (its shape only: the level cancels), photons being ``F l / (h c)``;
``V`` is Bessell's (1990) V response, so a detector whose response *is* V has ``kappa = 1`` (evsda's model for
presets without a spectral curve: :attr:`SpectralResponse.is_v_band`).

Spectra (shapes, 350-1100 nm)
    The Sun: ASTM G173-03's extraterrestrial spectrum (SMARTS 2.9.2, Gueymard 2004, Solar Energy 76, 423), bundled
    in ``library/spectra/sun_astm_g173_etr.csv``; satellites reflect it (grey: a flat albedo). The sky: taken as
    sunlight-coloured (moonlight, twilight, zodiacal light and starlight are; airglow and light pollution are
    redder: an assumption, docs/scene.md). Stars: blackbodies at the effective temperature of their B - V
    (Ballesteros 2012, EPL 97, 34008, Eq. 14), normalised to their V.
Detectors
    Silicon, collecting the carriers made within a depth ``d`` of its surface: ``r ~ 1 - exp(-alpha d)`` with
    ``alpha = 4 pi k / lambda`` from Green's (2008, Sol. Energ. Mat. Sol. Cells 92, 1305) extinction
    coefficient of intrinsic silicon at 300 K (``library/spectra/silicon_green2008.csv``); reflection and
    microlenses are taken as flat across the band (they cancel in the normalised shape). Optionally
    behind a V filter (Bessell's V curve as its transmission).
"""

from __future__ import annotations

import functools

import numpy as np

from evsda import library
from evsda.blocks.ports import SpectralResponse

from . import radiometry

#: wavelength grid of every band integral: the span of the bundled tables [nm]
GRID_NM = np.arange(350.0, 1100.5, 1.0)
#: wavelength at which a silicon response is 1, so that the pixel's ``quantum_efficiency`` is the QE (x fill factor)
#: there: the centre of the V band, where the presets' QE values were meant [nm]
REFERENCE_NM = 550.0
#: B - V of the synthetic stars drawn from star counts and, by default, of injected sources: the mean B - V of
#: the 3 792 stars of V 6.0-6.5 in the bundled Hipparcos excerpt, where it is complete (0.66; the Sun: 0.653,
#: Ramirez et al. 2012, ApJ 752, 5). Field stars of V 6-12 are mostly F-K dwarfs and K giants of similar mean.
FIELD_STAR_B_V = 0.66
#: B - V grid on which star band factors are tabulated (interpolated in between) [mag]
B_V_GRID = np.linspace(-0.4, 2.4, 141)


def _table(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Two-column table bundled in ``library/spectra/`` (``#`` comments and one header line)."""
    data = np.loadtxt(library.path(f"spectra/{name}"), delimiter=",", comments="#", skiprows=4)
    return data[:, 0], data[:, 1]


@functools.cache
def sun_irradiance_w_m2_nm() -> np.ndarray:
    """The measured solar spectral irradiance at 1 au on :data:`GRID_NM` (ASTM G173-03) [W m^-2 nm^-1]."""
    wavelength, irradiance = _table("sun_astm_g173_etr.csv")
    return np.interp(GRID_NM, wavelength, irradiance)


@functools.cache
def silicon_absorption_per_m() -> np.ndarray:
    """Absorption coefficient of intrinsic silicon at 300 K on :data:`GRID_NM`: ``4 pi k / lambda`` with
    Green's (2008) ``k``, interpolated in ``log k`` [m^-1]."""
    wavelength, k = _table("silicon_green2008.csv")
    return 4.0 * np.pi * np.exp(np.interp(GRID_NM, wavelength, np.log(k))) / (GRID_NM * 1e-9)


def v_response() -> np.ndarray:
    """Bessell's (1990) V response on :data:`GRID_NM` (0 outside 470-700 nm) [1]."""
    return np.interp(GRID_NM, radiometry.BESSELL_V_NM, radiometry.BESSELL_V_RESPONSE, left=0.0, right=0.0)


def response(spec: SpectralResponse) -> np.ndarray:
    """The detector's response on :data:`GRID_NM`: its quantum efficiency over the value at :data:`REFERENCE_NM`
    (silicon; the pixel's ``quantum_efficiency`` is that value), or V's own curve, peak 1 [1]."""
    if spec.detector == "V":
        curve = v_response()
    elif spec.detector == "silicon":
        curve = -np.expm1(-silicon_absorption_per_m() * spec.silicon_depth_m)
        curve = curve / np.interp(REFERENCE_NM, GRID_NM, curve)
    else:
        raise ValueError(f"unknown detector response {spec.detector!r}: expected 'V' or 'silicon'")
    if spec.filter == "V":
        curve = curve * v_response()
    elif spec.filter != "none":
        raise ValueError(f"unknown filter {spec.filter!r}: expected 'none' or 'V'")
    return curve


def photon_rate(spectral_flux_w_m2_nm: np.ndarray, weight: np.ndarray) -> float:
    """``integral F(l) w(l) l / (h c) dl`` over :data:`GRID_NM` (trapezoid) [photon s^-1 m^-2 per unit F]."""
    photons = spectral_flux_w_m2_nm * GRID_NM * 1e-9 / (radiometry.H_J_S * radiometry.C_M_PER_S)
    return float(np.trapezoid(photons * weight, GRID_NM))


def band_factor(spec: SpectralResponse, spectral_flux_w_m2_nm: np.ndarray) -> float:
    """``kappa``: photons the detector's response counts over those V counts, for a source of this spectrum
    (exactly 1 for the V band) [1]."""
    if spec.is_v_band:
        return 1.0
    return photon_rate(spectral_flux_w_m2_nm, response(spec)) / photon_rate(spectral_flux_w_m2_nm, v_response())


def _key(spec: SpectralResponse) -> tuple:
    """The response's values (port values compare by identity; caches key on these)."""
    return spec.detector, spec.silicon_depth_m, spec.filter


def sun_band_factor(spec: SpectralResponse) -> float:
    """``kappa`` of sunlight (satellites and, as assumed, the sky) [1]."""
    return _sun_band_factor(_key(spec))


@functools.cache
def _sun_band_factor(key: tuple) -> float:
    return band_factor(SpectralResponse(*key), sun_irradiance_w_m2_nm())


def temperature_of_b_v(b_v) -> np.ndarray:
    """Blackbody temperature of a star of colour ``B - V``: ``T = 4600 K (1 / (0.92 (B-V) + 1.7) + 1 / (0.92 (B-V)
    + 0.62))`` (Ballesteros 2012, EPL 97, 34008, Eq. 14) [K]."""
    x = 0.92 * np.asarray(b_v, dtype=np.float64)
    return 4600.0 * (1.0 / (x + 1.7) + 1.0 / (x + 0.62))


@functools.cache
def _star_factors(key: tuple) -> np.ndarray:
    """:func:`band_factor` of the blackbody of each colour of :data:`B_V_GRID` (a detector other than V), the
    141 spectra as one array: each row's products and trapezoid sum are the ones :func:`band_factor` makes, in
    about half its CPU (~4.5 against ~8 ms once a process, before the optics' first window)."""
    spec = SpectralResponse(*key)
    blackbodies = radiometry.planck_w_m2_nm_sr(GRID_NM, temperature_of_b_v(B_V_GRID)[:, None])
    photons = blackbodies * GRID_NM * 1e-9 / (radiometry.H_J_S * radiometry.C_M_PER_S)
    return (np.trapezoid(photons * response(spec), GRID_NM, axis=-1)
            / np.trapezoid(photons * v_response(), GRID_NM, axis=-1))


def star_band_factor(spec: SpectralResponse, b_v) -> np.ndarray:
    """``kappa`` of stars of colour ``B - V`` (blackbodies at :func:`temperature_of_b_v`; colours beyond
    -0.4 .. 2.4 take the end values; NaN takes :data:`FIELD_STAR_B_V`) [1]."""
    b_v = np.asarray(b_v, dtype=np.float64)
    if spec.is_v_band:
        return np.ones_like(b_v)
    return np.interp(np.where(np.isfinite(b_v), b_v, FIELD_STAR_B_V), B_V_GRID, _star_factors(_key(spec)))


def effective_wavelength_m(spec: SpectralResponse) -> float:
    """Photon-weighted mean wavelength of sunlight in the detector's response [m] (the V band's own value,
    :attr:`radiometry.Band.effective_wavelength_m`, for a V-band detector): the wavelength of the PSF."""
    if spec.is_v_band:
        return radiometry.V_BAND.effective_wavelength_m
    return _effective_wavelength_m(_key(spec))


@functools.cache
def _effective_wavelength_m(key: tuple) -> float:
    weight = sun_irradiance_w_m2_nm() * GRID_NM * response(SpectralResponse(*key))
    return float(np.trapezoid(weight * GRID_NM, GRID_NM) / np.trapezoid(weight, GRID_NM)) * 1e-9
