"""Sunlight reflected by a satellite: band fluxes, magnitudes, phase functions, extinction (paper Eq. 1-2).

The band
    Johnson-Cousins V as defined by Bessell (1990, PASP 102, 1181, Table 2), used as a
    photon-counting response; V = 0 is a flux density of 363.1e-11 erg s^-1 cm^-2 A^-1
    = 3.631e-11 W m^-2 nm^-1 (Bessell, Castelli & Plez 1998, A&A 333, 231, Table A2),
    taken as flat across the band.
The Sun
    A 5772 K blackbody (IAU 2015 Resolution B3 nominal effective temperature) of
    nominal radius 6.957e8 m seen from 1 au: its integral is the nominal total solar
    irradiance 1361 W m^-2. Integrated over V it gives V_sun = -26.7 (the measured
    value is -26.74, Allen's Astrophysical Quantities; tested in tests/scene).
Reflection (paper Eq. 1-2)
    A surface of diffuse reflectivity rho lit by solar irradiance E has radiance
    ``L = rho E / pi`` (Eq. 2) and sends ``Phi = pi L A`` into its hemisphere (Eq. 1). The
    intensity towards the observer is ``L`` times the area projected towards the
    observer, integrated over the lit part: ``I = rho E A F`` with the phase function
    ``F`` [sr^-1] of the shape (Lambertian sphere of cross-section A or flat plate of
    area A), and the flux at the aperture is ``I / R^2`` times the atmosphere's
    transmission ``10**(-0.4 k X)``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

H_J_S = 6.62607015e-34              # Planck constant [J s]
C_M_PER_S = 299_792_458.0           # speed of light [m/s]
K_B_J_K = 1.380649e-23              # Boltzmann constant [J/K]
SUN_TEFF_K = 5772.0                 # IAU 2015 B3 nominal solar effective temperature [K]
SUN_RADIUS_M = 6.957e8              # IAU 2015 B3 nominal solar radius [m]
AU_M = 1.495978707e11               # astronomical unit (IAU 2012 B2) [m]

#: Bessell (1990) Table 2, V passband: wavelength [nm] and normalised response [1].
BESSELL_V_NM = np.arange(470.0, 701.0, 10.0)
BESSELL_V_RESPONSE = np.array([0.000, 0.030, 0.163, 0.458, 0.780, 0.967, 1.000, 0.973, 0.898, 0.792, 0.684, 0.574,
                               0.461, 0.359, 0.270, 0.197, 0.135, 0.081, 0.045, 0.025, 0.017, 0.013, 0.009, 0.000])
#: V = 0 flux density (Bessell, Castelli & Plez 1998, Table A2) [W m^-2 nm^-1]
V_ZERO_POINT_W_M2_NM = 3.631e-11


def planck_w_m2_nm_sr(wavelength_nm, temperature_k: float) -> np.ndarray:
    """Blackbody spectral radiance B_lambda [W m^-2 nm^-1 sr^-1] (Planck's law)."""
    lam = np.asarray(wavelength_nm, dtype=np.float64) * 1e-9
    x = H_J_S * C_M_PER_S / (lam * K_B_J_K * temperature_k)
    return 2.0 * H_J_S * C_M_PER_S**2 / lam**5 / np.expm1(x) * 1e-9


def solar_irradiance_w_m2_nm(wavelength_nm) -> np.ndarray:
    """Solar spectral irradiance at 1 au [W m^-2 nm^-1]: a blackbody disc of solid angle pi (R/au)^2."""
    return planck_w_m2_nm_sr(wavelength_nm, SUN_TEFF_K) * np.pi * (SUN_RADIUS_M / AU_M) ** 2


@dataclass(frozen=True)
class Band:
    """A photometric band: response curve and the flux density of magnitude 0."""

    name: str
    wavelength_nm: np.ndarray
    response: np.ndarray
    zero_point_w_m2_nm: float

    def photon_flux(self, spectral_irradiance_w_m2_nm) -> float:
        """Photon flux [photon s^-1 m^-2] of a spectrum (callable of wavelength in nm) in the band."""
        lam = np.linspace(self.wavelength_nm[0], self.wavelength_nm[-1], 2001)
        weight = np.interp(lam, self.wavelength_nm, self.response)
        photons = spectral_irradiance_w_m2_nm(lam) * lam * 1e-9 / (H_J_S * C_M_PER_S)
        return float(np.trapezoid(photons * weight, lam))

    @functools.cached_property
    def zero_point_photon_flux(self) -> float:
        """Photon flux of a magnitude-0 source in the band [photon s^-1 m^-2]."""
        return self.photon_flux(lambda lam: np.full_like(lam, self.zero_point_w_m2_nm))

    @functools.cached_property
    def sun_photon_flux(self) -> float:
        """The Sun's photon flux at 1 au in the band [photon s^-1 m^-2]."""
        return self.photon_flux(solar_irradiance_w_m2_nm)

    @functools.cached_property
    def sun_magnitude(self) -> float:
        """The Sun's apparent magnitude at 1 au in the band [mag]."""
        return magnitude(self.sun_photon_flux, self)

    @functools.cached_property
    def effective_wavelength_m(self) -> float:
        """Photon-weighted mean wavelength of sunlight in the band [m]."""
        lam = np.linspace(self.wavelength_nm[0], self.wavelength_nm[-1], 2001)
        weight = np.interp(lam, self.wavelength_nm, self.response) * solar_irradiance_w_m2_nm(lam) * lam
        return float(np.trapezoid(weight * lam, lam) / np.trapezoid(weight, lam)) * 1e-9


V_BAND = Band("V", BESSELL_V_NM, BESSELL_V_RESPONSE, V_ZERO_POINT_W_M2_NM)
BANDS = {"V": V_BAND}


def magnitude(photon_flux, band: Band) -> np.ndarray:
    """Apparent magnitude of a photon flux [photon s^-1 m^-2] in ``band`` (inf for no light)."""
    with np.errstate(divide="ignore"):
        return -2.5 * np.log10(np.asarray(photon_flux, dtype=np.float64) / band.zero_point_photon_flux)


def photon_flux_of_magnitude(mag, band: Band) -> np.ndarray:
    """Photon flux [photon s^-1 m^-2] of an apparent magnitude in ``band``."""
    return band.zero_point_photon_flux * 10.0 ** (-0.4 * np.asarray(mag, dtype=np.float64))


def lambertian_sphere_phase(phase_angle_rad) -> np.ndarray:
    """Phase function [sr^-1] of a diffuse sphere: ``I = rho E A F(phi)`` with cross-section A.

    ``F = 2 / (3 pi^2) * (sin phi + (pi - phi) cos phi)`` (Russell 1916, ApJ 43, 173;
    e.g. Hejduk 2011, AMOS, Eq. 1), phi the Sun-satellite-observer angle (0 = full phase).
    """
    phi = np.asarray(phase_angle_rad, dtype=np.float64)
    return 2.0 / (3.0 * np.pi**2) * (np.sin(phi) + (np.pi - phi) * np.cos(phi))


def flat_plate_phase(normal, to_sun, to_observer) -> np.ndarray:
    """Phase function [sr^-1] of a diffuse flat plate of area A: ``(n.s)(n.o) / pi``, 0 if either is negative.

    Paper Eq. 2 with the irradiance projected on the plate (``E n.s``) and the radiance
    seen over the projected area ``A n.o``. Unit vectors ``[n, 3]``.
    """
    cos_sun = np.sum(normal * to_sun, axis=-1)
    cos_obs = np.sum(normal * to_observer, axis=-1)
    return np.where((cos_sun > 0) & (cos_obs > 0), cos_sun * cos_obs / np.pi, 0.0)


def airmass(zenith_angle_rad) -> np.ndarray:
    """Relative optical airmass (Kasten & Young 1989, Applied Optics 28, 4735, Eq. 3); NaN below the horizon."""
    z_deg = np.degrees(np.asarray(zenith_angle_rad, dtype=np.float64))
    with np.errstate(invalid="ignore"):
        x = 1.0 / (np.cos(np.radians(z_deg)) + 0.50572 * (96.07995 - z_deg) ** -1.6364)
    return np.where(z_deg <= 90.0, x, np.nan)


def transmission(extinction_mag_per_airmass: float, zenith_angle_rad) -> np.ndarray:
    """Atmospheric transmission ``10**(-0.4 k X)`` (Bouguer's law); 1 when ``k`` is 0 (space)."""
    if extinction_mag_per_airmass == 0.0:
        return np.ones_like(np.asarray(zenith_angle_rad, dtype=np.float64))
    return 10.0 ** (-0.4 * extinction_mag_per_airmass * airmass(zenith_angle_rad))


def reflected_photon_flux(band: Band, albedo: float, area_m2: float, phase_function_sr, range_m,
                          sun_distance_m=AU_M) -> np.ndarray:
    """Photon flux [photon s^-1 m^-2] at the observer (above the atmosphere) from a diffuse reflector.

    ``N = N_sun(d) rho A F / R^2`` with the solar photon flux in the band at the
    reflector's distance ``d`` from the Sun (inverse square from 1 au).
    """
    sun = band.sun_photon_flux * (AU_M / np.asarray(sun_distance_m)) ** 2
    return sun * albedo * area_m2 * np.asarray(phase_function_sr) / np.asarray(range_m) ** 2
