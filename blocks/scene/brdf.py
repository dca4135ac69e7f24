"""Bidirectional reflectance distribution functions (BRDFs) of flat facets, with a diffuse and a specular term.

A facet of area ``A`` and unit normal ``n`` lit by irradiance ``E`` from direction ``s``
sends the intensity ``I = E A f(s, o) (n.s)(n.o)`` [W sr^-1] towards direction ``o``
(radiance ``f E (n.s)`` seen over the projected area ``A (n.o)``), for ``n.s > 0`` and
``n.o > 0``. Every function here returns ``f`` [sr^-1] from the cosines it needs, all
arrays broadcasting together:

* ``cos_s = n.s``, ``cos_o = n.o``, ``cos_so = s.o``.

Models
    * Lambert: ``f = rho_d / pi``.
    * Modified Phong (Lafortune & Willems 1994, "Using the modified Phong reflectance
      model for physically based rendering", KU Leuven CW 197): ``f = rho_d / pi +
      rho_s (m + 2) / (2 pi) cos^m(a)``, ``a`` the angle between ``o`` and the mirror
      direction of ``s``; ``cos a = 2 (n.s)(n.o) - s.o``. Reciprocal, and energy
      conserving for ``rho_d + rho_s <= 1`` (its directional albedo is ``rho_d + rho_s`` at
      normal incidence and less elsewhere).
    * Ashikhmin & Shirley (2000, "An anisotropic Phong BRDF model", J. Graphics Tools
      5(2), 25), isotropic (``n_u = n_v = m``): specular ``(m + 1) / (8 pi) (n.h)^m /
      ((h.s) max(n.s, n.o)) F(h.s)`` with Schlick's Fresnel ``F = R_s + (1 - R_s)(1 - h.s)^5``,
      plus the coupled diffuse ``28 R_d / (23 pi) (1 - R_s) (1 - (1 - n.s/2)^5)
      (1 - (1 - n.o/2)^5)``; ``h`` the half vector. Energy conserving for ``R_d, R_s <= 1``.

The Sun is not a point: its disc (angular radius ``a_sun`` = 4.65 mrad at 1 au) blurs
any lobe. Approximating a lobe ``cos^m`` by a Gaussian of variance ``1/m`` per axis and
the uniform disc by its variance ``a_sun^2 / 4``, the lobe seen is the one of exponent
``1 / (1/m + a_sun^2 / 4)`` (reflected-direction space; a quarter of that for the
half-vector lobe of Ashikhmin-Shirley), renormalised so energy is kept. A perfect
mirror (``m`` -> infinity) then glints with a finite peak of about twice
``rho_s E A cos / Omega_sun`` spread over the solar disc.
"""

from __future__ import annotations

import numpy as np

SUN_ANGULAR_RADIUS_RAD = 6.957e8 / 1.495978707e11      # IAU 2015 B3 nominal solar radius over 1 au [rad]

LAMBERT, PHONG, ASHIKHMIN_SHIRLEY = "lambert", "phong", "ashikhmin_shirley"
MODELS = (LAMBERT, PHONG, ASHIKHMIN_SHIRLEY)


def sun_blurred_exponent(exponent, half_vector: bool = False) -> np.ndarray:
    """Lobe exponent after convolution with the solar disc at 1 au [1] (see the module docstring)."""
    m = np.asarray(exponent, dtype=np.float64)
    sun_variance = SUN_ANGULAR_RADIUS_RAD**2 / (16.0 if half_vector else 4.0)
    with np.errstate(divide="ignore"):
        return np.where(m > 0, 1.0 / (1.0 / np.where(m > 0, m, 1.0) + sun_variance), 0.0)


def lambert(diffuse_albedo, cos_s, cos_o, cos_so) -> np.ndarray:
    """Lambertian BRDF ``rho_d / pi`` [sr^-1]."""
    return np.broadcast_to(np.asarray(diffuse_albedo, dtype=np.float64) / np.pi,
                           np.broadcast_shapes(np.shape(cos_s), np.shape(cos_o), np.shape(diffuse_albedo)))


def phong(diffuse_albedo, specular_albedo, exponent, cos_s, cos_o, cos_so) -> np.ndarray:
    """Energy-conserving modified Phong BRDF [sr^-1] (Lafortune & Willems 1994), lobe blurred by the Sun's disc."""
    m = sun_blurred_exponent(exponent)
    cos_mirror = np.clip(2.0 * cos_s * cos_o - cos_so, 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        lobe = np.where(cos_mirror > 0, np.exp(m * np.log(np.where(cos_mirror > 0, cos_mirror, 1.0))), 0.0)
    return np.asarray(diffuse_albedo) / np.pi + np.asarray(specular_albedo) * (m + 2.0) / (2.0 * np.pi) * lobe


def ashikhmin_shirley(diffuse_albedo, specular_albedo, exponent, cos_s, cos_o, cos_so) -> np.ndarray:
    """Isotropic Ashikhmin-Shirley (2000) BRDF [sr^-1]: Fresnel-weighted specular lobe and coupled diffuse term."""
    m = sun_blurred_exponent(exponent, half_vector=True)
    rs, rd = np.asarray(specular_albedo, dtype=np.float64), np.asarray(diffuse_albedo, dtype=np.float64)
    length = np.sqrt(np.maximum(2.0 + 2.0 * cos_so, 1e-300))             # |s + o|
    cos_nh = np.clip((cos_s + cos_o) / length, 0.0, 1.0)
    cos_hs = np.clip((1.0 + cos_so) / length, 1e-12, 1.0)
    fresnel = rs + (1.0 - rs) * (1.0 - cos_hs) ** 5
    with np.errstate(divide="ignore", invalid="ignore"):
        lobe = np.where(cos_nh > 0, np.exp(m * np.log(np.where(cos_nh > 0, cos_nh, 1.0))), 0.0)
        specular = (m + 1.0) / (8.0 * np.pi) * lobe / (cos_hs * np.maximum(np.maximum(cos_s, cos_o), 1e-12)) * fresnel
    diffuse = (28.0 * rd / (23.0 * np.pi) * (1.0 - rs) * (1.0 - (1.0 - cos_s / 2.0) ** 5)
               * (1.0 - (1.0 - cos_o / 2.0) ** 5))
    return specular + diffuse


def evaluate(model: str, diffuse_albedo, specular_albedo, exponent, cos_s, cos_o, cos_so) -> np.ndarray:
    """The BRDF ``model`` [sr^-1] (one of :data:`MODELS`)."""
    if model == LAMBERT:
        return lambert(diffuse_albedo, cos_s, cos_o, cos_so)
    if model == PHONG:
        return phong(diffuse_albedo, specular_albedo, exponent, cos_s, cos_o, cos_so)
    if model == ASHIKHMIN_SHIRLEY:
        return ashikhmin_shirley(diffuse_albedo, specular_albedo, exponent, cos_s, cos_o, cos_so)
    raise ValueError(f"unknown BRDF model {model!r}; expected one of {', '.join(MODELS)}")
