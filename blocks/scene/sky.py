"""Diffuse sky brightness collected by each pixel: night sky, scattered moonlight, twilight."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
from pydantic import Field

from evsda.blocks.ports import FocalPlane, SkyBackground
from evsda.blocks.ports.scene import Observer, Pointing
from evsda.graph import NS_PER_S, Block, BlockParams, Input, Output, ParameterError, SceneError, Window

from . import radiometry, spectra
from .geometry import consecutive_rows
from .moon import MOON_MEAN_DISTANCE_M, MOON_RADIUS_M, MoonModel, MoonSamples, require_ephemeris
from .moonlight import magnitude_of_nanolamberts, moonlight_nanolamberts
from .passes import iso
from .pointing import PointingModel, fingerprint, shared_models
from .twilight import MIN_SUN_DEPRESSION_DEG, twilight_surface_brightness

ARCSEC_PER_RAD = 180.0 * 3600.0 / np.pi
#: the sky's samples whose boresight the block takes in one call of the pointing model (10 s of the run at the
#: default 0.1 s cadence; :meth:`SkyBackgroundBlock._boresight`)
SAMPLES_AHEAD = 100


def sky_photon_flux_per_pixel(surface_brightness_mag_arcsec2, focal_plane: FocalPlane,
                              band: radiometry.Band = radiometry.V_BAND) -> np.ndarray:
    """Photon flux [photon s^-1 m^-2 pixel^-1] of a sky of ``mu`` mag/arcsec^2 over one pixel's solid angle,
    in the detector's response.

    ``N = N0 10**(-0.4 mu) Omega_pix kappa`` with ``Omega_pix = (pitch / f)^2`` in arcsec^2 and the band
    factor ``kappa`` of a sunlight-coloured sky (:func:`.spectra.sun_band_factor`; 1 for a V-band detector).
    """
    omega_arcsec2 = (focal_plane.pixel_scale_rad * ARCSEC_PER_RAD) ** 2
    kappa = spectra.sun_band_factor(focal_plane.spectral_response)
    return radiometry.photon_flux_of_magnitude(surface_brightness_mag_arcsec2, band) * omega_arcsec2 * kappa


def sky_brightness_at_zenith_angle(zenith_mag_arcsec2: float, zenith_angle_rad, extinction_mag_per_airmass: float):
    """Sky surface brightness [mag/arcsec^2] away from the zenith.

    Krisciunas & Schaefer (1991, PASP 103, 1033), Eq. (2): the airglow and scattered
    light grow with the path length ``X = (1 - 0.96 sin^2 Z)^(-1/2)`` and are dimmed by
    extinction: ``B(Z) = B_zen 10**(-0.4 k (X - 1)) X``.
    """
    x = 1.0 / np.sqrt(1.0 - 0.96 * np.sin(np.asarray(zenith_angle_rad, dtype=np.float64)) ** 2)
    return zenith_mag_arcsec2 - 2.5 * np.log10(x) + extinction_mag_per_airmass * (x - 1.0)


def add_surface_brightness(*mag_arcsec2) -> np.ndarray:
    """Surface brightness [mag/arcsec^2] of sky components added as fluxes."""
    with np.errstate(divide="ignore"):
        return -2.5 * np.log10(sum(10.0 ** (-0.4 * np.asarray(m, dtype=np.float64)) for m in mag_arcsec2))


def _utc(window: Window, t_ns) -> str:
    """ISO UTC time of ``t_ns`` after the run's epoch."""
    return iso(window.epoch + timedelta(microseconds=int(t_ns) // 1000))


class SkyBackgroundBlock(Block):
    """Sky background photon flux per pixel from a surface brightness in V mag/arcsec^2.

    From the ground the brightness is given at the zenith and follows the boresight's
    zenith angle (Krisciunas & Schaefer 1991, Eq. 2) with the site's extinction; from
    space it is used as given (zodiacal light and unresolved Galaxy). From the ground
    it can add scattered moonlight (Krisciunas & Schaefer 1991, :mod:`.moonlight`) and
    twilight (Patat et al. 2006, :mod:`.twilight`), with the Moon and the Sun from JPL
    DE421. The sky is one value for the whole field: the boresight's.

    ``moon_exclusion_deg`` refuses the run, before any work, if the boresight comes
    closer than that to the Moon while the Moon is up (or not behind the Earth, from
    space) at any of the block's samples over the run.
    """

    type_name = "sky_background"

    class Params(BlockParams):
        surface_brightness_mag_arcsec2: float = Field(21.0, ge=5, le=30, description="Sky brightness at the "
                                                      "zenith (ground) or in the field (space), in V "
                                                      "(dark site ~21.5-22, suburban ~19-20) [mag]")
        follow_zenith_angle: bool = Field(True, description="Brighten the sky away from the zenith "
                                          "(ground observers) [-]")
        cadence_s: float = Field(0.1, ge=1e-3, le=3600, description="Sample spacing (the sky changes slowly; "
                                 "values hold until the next sample; at least 1 ms) [s]")
        moonlight: bool = Field(False, description="Add moonlight scattered by the atmosphere (Krisciunas & "
                                "Schaefer 1991; ground observers) [-]")
        twilight: bool = Field(False, description="Add twilight (Patat et al. 2006, valid with the Sun 5 deg or "
                               "more below the horizon; ground observers) [-]")
        moon_exclusion_deg: float = Field(0.0, ge=0, le=180, description="Refuse the run if the boresight comes "
                                          "closer than this to the Moon while it is up (0: no limit) [deg]")

    inputs = {
        "observer": Input(Observer, "where the sensor is"),
        "pointing": Input(Pointing, "where the sensor looks"),
        "focal_plane": Input(FocalPlane, "the detector geometry"),
    }
    outputs = {"background": Output(SkyBackground, "sky photon flux per pixel")}

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._model_key, self._model, self._moon = None, None, None
        self._run_checked = False
        self._ahead: tuple | None = None     # (model, sample times, boresight, zenith angle) taken ahead

    @property
    def _uses_moon(self) -> bool:
        p = self.params
        return p.moonlight or p.twilight or p.moon_exclusion_deg > 0

    def _pointing_model(self, window: Window, observer: Observer, pointing: Pointing) -> PointingModel:
        key = (window.epoch, fingerprint(observer), fingerprint(pointing))
        if key != self._model_key:
            knot_ns = 10 * NS_PER_S
            observer_model, self._model = shared_models(observer, pointing, window.epoch, knot_ns)
            self._moon = MoonModel(observer_model, window.epoch, knot_ns) if self._uses_moon else None
            self._model_key = key
            self._run_checked = False
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
        if self._uses_moon:
            model = self._pointing_model(window, observer, pointing)
            if not self._run_checked:
                self._check_run(window, observer, cadence)
                self._run_checked = True
        if observer.is_ground and (p.follow_zenith_angle or p.moonlight or p.twilight):
            b, zenith = self._boresight(self._pointing_model(window, observer, pointing), window, evaluated,
                                        cadence)
            if p.follow_zenith_angle:
                mu = sky_brightness_at_zenith_angle(p.surface_brightness_mag_arcsec2, zenith,
                                                    observer.extinction_mag_per_airmass)
            if p.moonlight or p.twilight:
                mu = self._add_moon_and_twilight(mu, self._moon.sample(evaluated), b, zenith, observer)
        return {"background": SkyBackground(t_ns=stamps,
                                            photon_flux_per_pixel=sky_photon_flux_per_pixel(mu, focal_plane))}

    def _boresight(self, model: PointingModel, window: Window, evaluated: np.ndarray,
                   cadence_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """The boresight and its zenith angle (at most 89 deg) at the grid samples ``evaluated`` (consecutive),
        from one call of the pointing model for the next :data:`SAMPLES_AHEAD` samples, kept for the windows after.

        The model works sample by sample (its results do not depend on which samples are asked together; the
        satellite's longer calls rest on the same), so the rows are what a call of their own makes. A call costs
        mostly its NumPy calls' overhead, and in a pipelined run the sky steps up to ~18 windows ahead of the
        satellite, whose kept samples it would otherwise miss (a call of the frame and the horizon axes each
        window); one step at a time, the two lookups of a window's times among the scene's kept results go."""
        kept = self._ahead
        if kept is not None and kept[0] is model:
            rows = consecutive_rows(kept[1], evaluated)
            if rows is not None:
                return kept[2][rows], kept[3][rows]
        stop = max(int(evaluated[-1]) + cadence_ns,
                   min(int(evaluated[0]) + SAMPLES_AHEAD * cadence_ns, self.run_span_ns(window)[1]))
        t_ns = np.arange(int(evaluated[0]), stop, cadence_ns, dtype=np.int64)
        b, _, _ = model.frame(t_ns)
        zenith = np.minimum(model.zenith_angle(t_ns, b), np.radians(89.0))
        zenith.flags.writeable = False
        self._ahead = (model, t_ns, b, zenith)
        rows = slice(0, len(evaluated))
        return b[rows], zenith[rows]

    def _add_moon_and_twilight(self, mu, moon: MoonSamples, boresight, zenith, observer: Observer) -> np.ndarray:
        """The night sky ``mu`` plus scattered moonlight and twilight [mag/arcsec^2]."""
        parts = [mu]
        if self.params.moonlight:
            nanolamberts = moonlight_nanolamberts(
                np.degrees(moon.phase_angle_rad), np.degrees(moon.separation_rad(boresight)),
                np.pi / 2 - moon.elevation_rad, zenith, observer.extinction_mag_per_airmass,
                distance_ratio=moon.distance_m / MOON_MEAN_DISTANCE_M)
            parts.append(magnitude_of_nanolamberts(nanolamberts))
        if self.params.twilight:
            parts.append(twilight_surface_brightness(-np.degrees(moon.sun_elevation_rad)))
        return add_surface_brightness(*parts)

    def _check_run(self, window: Window, observer: Observer, cadence_ns: int) -> None:
        """Refuse, before any work, a run the Moon and twilight models cannot describe."""
        p = self.params
        who = self.label
        if (p.moonlight or p.twilight) and not observer.is_ground:
            raise ParameterError(f"{who}: moonlight and twilight are light scattered by the atmosphere, which a "
                                 f"space observer ({observer.name}) does not look through; set moonlight and "
                                 f"twilight to false (moon_exclusion_deg still applies)")
        start, stop = self.run_span_ns(window)
        require_ephemeris(window.epoch, start, stop, who)
        t_ns = np.arange(start // cadence_ns * cadence_ns, max(stop, start + 1), cadence_ns, dtype=np.int64)
        for chunk in np.array_split(t_ns, max(1, len(t_ns) // 20_000)):
            moon = self._moon.sample(chunk)
            b, _, _ = self._model.frame(chunk)
            separation = np.degrees(moon.separation_rad(b))
            moon_radius = np.degrees(np.arcsin(MOON_RADIUS_M / moon.distance_m))
            limit = np.maximum(p.moon_exclusion_deg, moon_radius if p.moonlight else np.zeros(len(chunk)))
            inside = moon.up & (separation < limit)
            if inside.any():
                i = int(np.argmax(inside))
                where = (f"up at {np.degrees(moon.elevation_rad[i]):.1f} deg elevation" if observer.is_ground
                         else "not behind the Earth")
                raise SceneError(f"{who}: the boresight comes within {separation[i]:.2f} deg of the Moon ({where}, "
                                 f"{100 * moon.illuminated_fraction[i]:.0f} % lit) at {_utc(window, chunk[i])}, "
                                 f"inside the exclusion angle of {limit[i]:.2f} deg; point elsewhere, choose "
                                 f"another time or lower moon_exclusion_deg")
            if p.twilight:
                depression = -np.degrees(moon.sun_elevation_rad)
                bright = depression < MIN_SUN_DEPRESSION_DEG
                if bright.any():
                    i = int(np.argmax(bright))
                    sun = (f"{-depression[i]:.2f} deg above" if depression[i] < 0
                           else f"only {depression[i]:.2f} deg below")
                    raise SceneError(f"{who}: the Sun is {sun} the horizon at {_utc(window, chunk[i])}; the "
                                     f"twilight model (Patat et al. 2006) covers the Sun {MIN_SUN_DEPRESSION_DEG:g} "
                                     f"deg or more below the horizon. Start the run later in the evening (or earlier "
                                     f"in the morning)")
