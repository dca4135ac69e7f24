"""A body that reflects sunlight with its own shape and attitude: facets turned by an attitude law.

:class:`FacetReflector` is what a source block attaches to each object whose brightness
depends on its orientation (a tumbling rocket body, a spinning plate, a box with
panels). Given the object's position and velocity, the unit vectors to the Sun and to
the observer (GCRS) and the emission times, it returns ``R`` [m^2 sr^-1], the
reflectance-weighted area of :mod:`.facets`; the photon flux at the aperture is
:func:`.radiometry.photon_flux_of_reflectance` of it.

:func:`attitude_law` builds the law from the same parameters the ``satellite`` block
takes (``attitude``, ``spin_*``, ``inertia_kg_m2``, ``angular_velocity_deg_s``), so a
per-object source can read them from catalogue columns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .attitude import NadirPointing, Spin, Tumble, direction_of_radec
from .facets import FacetModel


@dataclass(frozen=True)
class FacetReflector:
    """A :class:`FacetModel` oriented by an attitude law (``.matrices(t_ns, r, v)`` -> body-to-GCRS ``[n, 3, 3]``)."""

    model: FacetModel
    attitude: object

    def reflectance_m2_sr(self, t_ns, r_sat: np.ndarray, v_sat: np.ndarray, to_sun: np.ndarray,
                          to_observer: np.ndarray) -> np.ndarray:
        """``sum A f (n.s)(n.o)`` at times ``t_ns`` [m^2 sr^-1]; GCRS vectors ``[n, 3]``, directions unit."""
        body_to_gcrs = self.attitude.matrices(t_ns, r_sat, v_sat)
        to_sun_body = np.einsum("nji,nj->ni", body_to_gcrs, to_sun)
        to_observer_body = np.einsum("nji,nj->ni", body_to_gcrs, to_observer)
        return self.model.reflectance_m2_sr(to_sun_body, to_observer_body)


def attitude_law(attitude: str, spin_axis_ra_deg: float = 0.0, spin_axis_dec_deg: float = 90.0,
                 spin_axis_body=(1.0, 0.0, 0.0), spin_rate_deg_s: float = 0.0, spin_phase_deg: float = 0.0,
                 inertia_kg_m2=None, angular_velocity_deg_s=None):
    """The attitude law of a ``satellite``'s parameters: ``fixed`` (nadir-pointing), ``spin`` or ``tumble``."""
    axis = direction_of_radec(spin_axis_ra_deg, spin_axis_dec_deg)
    phase = np.radians(spin_phase_deg)
    if attitude == "fixed":
        return NadirPointing()
    if attitude == "spin":
        return Spin(axis, np.asarray(spin_axis_body, dtype=np.float64), np.radians(spin_rate_deg_s), phase)
    if attitude == "tumble":
        return Tumble(np.asarray(inertia_kg_m2, dtype=np.float64), np.radians(np.asarray(angular_velocity_deg_s)),
                      axis, phase)
    raise ValueError(f"unknown attitude {attitude!r}; expected fixed, spin or tumble")
