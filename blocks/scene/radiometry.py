"""Sunlight reflected by a satellite: band fluxes, magnitudes, phase functions, extinction (paper Eq. 1-2).

The band
    Johnson-Cousins V as defined by Bessell (1990, PASP 102, 1181, Table 2), used as a
    photon-counting response; V = 0 is a flux density of 363.1e-11 erg s^-1 cm^-2 A^-1
    = 3.631e-11 W m^-2 nm^-1 (Bessell, Castelli & Plez 1998, A&A 333, 231, Table A2),
    taken as flat across the band.
The Sun
    Its photon flux in a band is the measured one: V_sun = -26.76 at 1 au (Willmer 2018,
    ApJS 236, 47: M_V = 4.81 in the Vega system, less the distance modulus 31.57 of 1 au),
    on the same Vega-based system as the zero point below. The spectral *shape* across
    the band (which only sets the photon-weighted wavelength) is a 5772 K blackbody (IAU
    2015 Resolution B3 nominal effective temperature) of nominal radius 6.957e8 m seen
    from 1 au, whose integral is the nominal total solar irradiance 1361 W m^-2. That
    blackbody alone would give V_sun = -26.69: 6 % too few V photons, because the real
    Sun is brighter than a 5772 K blackbody in the visible and fainter in the
    ultraviolet, so it is not used for the flux.
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
PARSEC_AU = 648_000.0 / np.pi       # parsec in astronomical units (IAU 2015 Resolution B2) [au]
#: The Sun's apparent V magnitude at 1 au, Vega system: M_V = 4.81 (Willmer 2018, ApJS 236, 47, Table 3)
#: minus the distance modulus of 1 au, 5 log10(10 pc / 1 au) = 31.572: -26.762 [mag]
SUN_V_MAG = 4.81 - 5.0 * np.log10(10.0 * PARSEC_AU)


def planck_w_m2_nm_sr(wavelength_nm, temperature_k: float) -> np.ndarray:
    """Blackbody spectral radiance B_lambda [W m^-2 nm^-1 sr^-1] (Planck's law)."""
    lam = np.asarray(wavelength_nm, dtype=np.float64) * 1e-9
    x = H_J_S * C_M_PER_S / (lam * K_B_J_K * temperature_k)
    return 2.0 * H_J_S * C_M_PER_S**2 / lam**5 / np.expm1(x) * 1e-9


def blackbody_sun_irradiance_w_m2_nm(wavelength_nm) -> np.ndarray:
    """The Sun as a 5772 K blackbody disc of solid angle pi (R/au)^2 at 1 au [W m^-2 nm^-1].

    Its shape weights wavelengths inside a band; its level is not used for fluxes (see
    :attr:`Band.sun_photon_flux`).
    """
    return planck_w_m2_nm_sr(wavelength_nm, SUN_TEFF_K) * np.pi * (SUN_RADIUS_M / AU_M) ** 2


@dataclass(frozen=True)
class Band:
    """A photometric band: response curve and the flux density of magnitude 0."""

    name: str
    wavelength_nm: np.ndarray
    response: np.ndarray
    zero_point_w_m2_nm: float
    sun_magnitude: float             # measured apparent magnitude of the Sun at 1 au in this band [mag]

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
        """The Sun's photon flux at 1 au in the band [photon s^-1 m^-2], from its measured magnitude."""
        return float(photon_flux_of_magnitude(self.sun_magnitude, self))

    @functools.cached_property
    def blackbody_sun_magnitude(self) -> float:
        """The magnitude the 5772 K blackbody Sun would have at 1 au in the band [mag] (not used for fluxes)."""
        return float(magnitude(self.photon_flux(blackbody_sun_irradiance_w_m2_nm), self))

    @functools.cached_property
    def effective_wavelength_m(self) -> float:
        """Photon-weighted mean wavelength of sunlight in the band [m] (blackbody shape)."""
        lam = np.linspace(self.wavelength_nm[0], self.wavelength_nm[-1], 2001)
        weight = np.interp(lam, self.wavelength_nm, self.response) * blackbody_sun_irradiance_w_m2_nm(lam) * lam
        return float(np.trapezoid(weight * lam, lam) / np.trapezoid(weight, lam)) * 1e-9


V_BAND = Band("V", BESSELL_V_NM, BESSELL_V_RESPONSE, V_ZERO_POINT_W_M2_NM, SUN_V_MAG)
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


def photon_flux_of_reflectance(band: Band, reflectance_m2_sr, range_m, sun_distance_m=AU_M) -> np.ndarray:
    """Photon flux [photon s^-1 m^-2] at the observer (above the atmosphere) from a body of reflectance ``R``.

    ``N = N_sun(d) R / range^2`` with ``R = sum A f (n.s)(n.o)`` [m^2 sr^-1] of a facet
    model (:mod:`.facets`), the generalisation of ``rho A F`` above.
    """
    sun = band.sun_photon_flux * (AU_M / np.asarray(sun_distance_m)) ** 2
    return sun * np.asarray(reflectance_m2_sr) / np.asarray(range_m) ** 2
