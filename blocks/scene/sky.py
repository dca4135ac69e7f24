"""Diffuse sky brightness collected by each pixel."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from evsda.blocks.ports import FocalPlane, SkyBackground
from evsda.blocks.ports.scene import Observer, Pointing
from evsda.graph import NS_PER_S, Block, BlockParams, Input, Output, Window

from . import radiometry
from .geometry import ObserverModel
from .pointing import PointingModel

ARCSEC_PER_RAD = 180.0 * 3600.0 / np.pi


def sky_photon_flux_per_pixel(surface_brightness_mag_arcsec2, focal_plane: FocalPlane,
                              band: radiometry.Band = radiometry.V_BAND) -> np.ndarray:
    """Photon flux [photon s^-1 m^-2 pixel^-1] of a sky of ``mu`` mag/arcsec^2 over one pixel's solid angle.

    ``N = N0 10**(-0.4 mu) Omega_pix`` with ``Omega_pix = (pitch / f)^2`` in arcsec^2.
    """
    omega_arcsec2 = (focal_plane.pixel_scale_rad * ARCSEC_PER_RAD) ** 2
    return radiometry.photon_flux_of_magnitude(surface_brightness_mag_arcsec2, band) * omega_arcsec2


def sky_brightness_at_zenith_angle(zenith_mag_arcsec2: float, zenith_angle_rad, extinction_mag_per_airmass: float):
    """Sky surface brightness [mag/arcsec^2] away from the zenith.

    Krisciunas & Schaefer (1991, PASP 103, 1033), Eq. (2): the airglow and scattered
    light grow with the path length ``X = (1 - 0.96 sin^2 Z)^(-1/2)`` and are dimmed by
    extinction: ``B(Z) = B_zen 10**(-0.4 k (X - 1)) X``.
    """
    x = 1.0 / np.sqrt(1.0 - 0.96 * np.sin(np.asarray(zenith_angle_rad, dtype=np.float64)) ** 2)
    return zenith_mag_arcsec2 - 2.5 * np.log10(x) + extinction_mag_per_airmass * (x - 1.0)


class SkyBackgroundBlock(Block):
    """Sky background photon flux per pixel from a surface brightness in V mag/arcsec^2.

    From the ground the brightness is given at the zenith and follows the boresight's
    zenith angle (Krisciunas & Schaefer 1991, Eq. 2) with the site's extinction; from
    space it is used as given (zodiacal light and unresolved Galaxy).
    """

    type_name = "sky_background"

    class Params(BlockParams):
        surface_brightness_mag_arcsec2: float = Field(21.0, ge=5, le=30, description="Sky brightness at the "
                                                      "zenith (ground) or in the field (space), in V "
                                                      "(dark site ~21.5-22, suburban ~19-20) [mag]")
        follow_zenith_angle: bool = Field(True, description="Brighten the sky away from the zenith "
                                          "(ground observers) [-]")
        cadence_s: float = Field(0.1, gt=0, le=3600, description="Sample spacing (the sky changes slowly; "
                                 "values hold until the next sample) [s]")

    inputs = {
        "observer": Input(Observer, "where the sensor is"),
        "pointing": Input(Pointing, "where the sensor looks"),
        "focal_plane": Input(FocalPlane, "the detector geometry"),
    }
    outputs = {"background": Output(SkyBackground, "sky photon flux per pixel")}

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._model_key, self._model = None, None

    def _pointing_model(self, window: Window, observer: Observer, pointing: Pointing) -> PointingModel:
        key = (window.epoch, repr(observer.to_arrays()), repr(pointing.to_arrays()))
        if key != self._model_key:
            knot_ns = 10 * NS_PER_S
            self._model = PointingModel(pointing, ObserverModel(observer, window.epoch, knot_ns), window.epoch, knot_ns)
            self._model_key = key
        return self._model

    def step(self, window: Window, observer: Observer, pointing: Pointing, focal_plane: FocalPlane) -> dict:
        p = self.params
        cadence = max(1, round(p.cadence_s * NS_PER_S))
        stamps = window.sample_times_ns(cadence)
        evaluated = stamps
        if len(stamps) == 0 or stamps[0] != window.start_ns:
            # the value holding at the window's start is the one of the last grid sample before it
            evaluated = np.concatenate([[window.start_ns // cadence * cadence], stamps]).astype(np.int64)
            stamps = np.concatenate([[window.start_ns], stamps]).astype(np.int64)
        mu = np.full(len(stamps), p.surface_brightness_mag_arcsec2)
        if observer.is_ground and p.follow_zenith_angle:
            model = self._pointing_model(window, observer, pointing)
            b, _, _ = model.frame(evaluated)
            zenith = np.minimum(model.zenith_angle(evaluated, b), np.radians(89.0))
            mu = sky_brightness_at_zenith_angle(p.surface_brightness_mag_arcsec2, zenith,
                                                observer.extinction_mag_per_airmass)
        return {"background": SkyBackground(t_ns=stamps,
                                            photon_flux_per_pixel=sky_photon_flux_per_pixel(mu, focal_plane))}
