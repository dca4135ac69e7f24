"""The ``optics`` block: point sources through a turbulent atmosphere and a telescope onto the pixels."""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from evsda.blocks.threads import worker_threads
from evsda.blocks.ports import FocalPlane, Irradiance, PointSources, SkyBackground, Truth
from evsda.graph import Block, BlockParams, Input, InputError, Output, ParameterError, RunInfo, UserError, Window
from evsda.graph.threads import parallel_map
from evsda.graph.params import DataFile

from .atmosphere import Atmosphere
from .equivalent_layers import equivalent_layers
from .imaging import Imager, line_of_sight_at, same_bits
from .render_interval import RenderInterval
from .telescope import Telescope
from .truth import truth_rows


#: sources walked and stamped in one call (:meth:`.Imager.render_many`): four. Since each frame goes from its phase to
#: its stamp in one compiled call (no 1.6 MB blocks of sines), four against two hold the interpreter lock ~7 % less
#: in the step on the tracked pass for the same CPU (1.003x); eight against four ~2 % less for 2 % more CPU (the
#: phases, 1.3 MB a source at 1 kHz on its 40-sample pupil, out of cache; docs/speed.md, thirteenth session). Before
#: that, a window's ~8 at once made the walk ~8 % and the tilted phase ~55 % slower (tenth session)
TOGETHER = 4


def _isclose(a, b, rtol: float, atol: float = 1e-8) -> bool:
    """``np.isclose(a, b, rtol, atol)`` of two numbers (``|a - b| <= atol + rtol |b|``; non-finite ones close only
    where equal) without its array set-up (~30 us)."""
    a, b = float(a), float(b)
    if not (math.isfinite(a) and math.isfinite(b)):
        return a == b
    return abs(a - b) <= atol + rtol * abs(b)


class PointSourceOptics(Block):
    """Photon flux on the detector from point sources seen through turbulence (paper Sec. 2.2, Eq. 3-11).

    Each source's flux at the aperture [photon s^-1 m^-2] times the collecting area
    ``pi D^2 (1 - eps^2) / 4`` [m^2], the throughput and the fraction of the PSF's energy
    in each pixel gives the stamps of :class:`~evsda.blocks.ports.Irradiance`
    [photon s^-1 pixel^-1], sampled every ``1 / render_rate_hz`` on the run's global grid, each
    source's PSF rendered every ``m``-th sample as its pixels need and held between
    (``source_intervals``, :mod:`evsda.blocks.optics.render_interval`); the sky background is
    uniform. The PSF follows the cheapest path whose estimated
    error stays within ``tolerance`` (``airy``, ``long_exposure``, ``pupil_fft``,
    ``reference``; see :mod:`evsda.blocks.optics.paths`), or the one ``psf_path`` forces;
    the choice and its reasons are logged on ``evsda.blocks.optics``. Turbulence is a
    Cn^2 profile lumped into layers with frozen flow (:mod:`evsda.blocks.optics.imaging`).

    Example::

        optics = PointSourceOptics(aperture_m=0.3, obscuration=0.3, seed=1)
        optics.setup(RunInfo())
        out = optics.step(Window.from_seconds(0, 0.1), sources=[point_sources])
    """

    type_name = "optics"

    class Params(BlockParams):
        aperture_m: float = Field(0.35, gt=0, le=50, description="Telescope aperture diameter [m]")
        obscuration: float = Field(0.0, ge=0, lt=0.95,
                                   description="Central obscuration diameter over the aperture diameter [1]")
        throughput: float = Field(1.0, gt=0, le=1, description="Optical transmission of the telescope [1]")
        # 1 kHz: within the noise floor of 2 kHz on the tracked LEO pass and the staring main job; 500 Hz loses
        # 2-16 % of the satellite's events in every noise draw (its PSF hops ~1 pixel per sample on a stare, and
        # the tracked ISS's speckle decorrelates in ~1 ms): docs/speed.md, "Speed against error"
        render_rate_hz: float = Field(1000.0, gt=0, le=1e6,
                                      description="Base rate of rendered PSF samples, the render times' grid [Hz]")
        # on: within the noise floor of the faithful run on every statistic of the tracked pass and the staring main
        # job, and -10 % CPU on the main job (docs/speed.md, "Fewer PSFs: a render interval per source")
        source_intervals: bool = Field(
            True, description="Render each source every m-th render time, m the largest power of two within its "
                              "image's pixel-crossing time and interval_factor times its coherence time tau0 and its "
                              "pixels' response time (the stamp held between; render_interval); False: every source "
                              "at every render time [-]")
        # 2: the tracked pass's satellite, whose pixels follow its speckle, keeps its events held 1.8 tau0 (1 kHz)
        # and loses them held 3.6 tau0 (500 Hz): docs/speed.md, "Speed against error"
        interval_factor: float = Field(
            2.0, gt=0, le=16, description="How many of its coherence times tau0 and pixel response times a source's "
                                          "held stamp may span (source_intervals) [1]")
        psf_path: Literal["auto", "airy", "long_exposure", "pupil_fft", "reference"] = Field(
            "auto", description="PSF path; 'auto' picks the cheapest whose error is within tolerance [-]")
        tolerance: float = Field(0.1, gt=0, lt=1,
                                 description="Largest expected fraction of a source's flux (a mean over the "
                                             "turbulence) a fast path may misplace [1]")
        # on: the same choices and events on the tracked pass, the main job and every example, window 0's probes
        # -23 % CPU (docs/optics.md, "The far bin's probes for a finite-range source")
        share_far_probes: bool = Field(
            True, description="A finite-range source's pupil-error bin takes the far bin's reference probes where, "
                              "at its nearest range and within 5 %, the spherical wave's Rytov variance is the plane "
                              "wave's and the aperture-averaged scintillation term is the far bin's, and its defocus "
                              "(telescope focused at infinity) is at most 0.1 rad rms (paths); False: every range "
                              "bin probed on its own [-]")
        focus: Literal["source", "infinity"] = Field(
            "source", description="Focus on the source (paper Eq. 4 collimation) or at infinity [-]")
        atmosphere: Literal["hufnagel_valley", "table", "none"] = Field(
            "hufnagel_valley", description="Cn^2 profile: Hufnagel-Valley, a CSV table, or none [-]")
        profile_file: DataFile | None = Field(
            None, description="Cn^2 table (CSV altitude_m, cn2_dh_m13, wind_speed_m_s, wind_direction_deg) [-]")
        r0_500nm_m: float | None = Field(None, gt=0, le=10,
                                         description="Rescale the profile to this zenith r0 at 500 nm [m]")
        hv_wind_rms_m_s: float = Field(21.0, ge=0, le=100,
                                       description="Hufnagel-Valley high-altitude rms wind (21 for HV5/7) [m/s]")
        hv_ground_cn2: float = Field(1.7e-14, ge=0, le=1e-11,
                                     description="Hufnagel-Valley ground term A (1.7e-14 for HV5/7) [m^-2/3]")
        n_layers: int = Field(4, ge=1, le=32, description="Layers the Hufnagel-Valley profile is lumped into [1]")
        # 'auto' by default (seventeenth session): 3 groups keep every benchmarks/speed_vs_error.py statistic within
        # the every-layer noise floor on the five library profiles (tracked pass) and on the staring main job
        # (docs/speed.md, docs/optics.md "Equivalent layers"); None renders every layer
        equivalent_layers: Annotated[int, Field(ge=1, le=32)] | Literal["auto"] | None = Field(
            "auto", description="Render the profile's screens as this many equivalent layers (summed Cn^2 dh, "
                              "5/3-moment altitudes and winds, each source's own winds: r0, theta0 and every "
                              "source's tau0 kept; equivalent_layers); 'auto': the fewest, at least 3, that keep "
                              "the scintillation's sum J h^(5/6) and sum J h^2 and the winds' sum J v^2 within 10 %; "
                              "None: every layer [1]")
        follow_sight_rate: bool = Field(
            True, description="On equivalent layers, move each source's footprints at the winds of its line of "
                               "sight's rate at each render time (its tau0 the full profile's all along a long "
                               "pass), not at those of its first two render times [1]")
        ground_wind_m_s: float = Field(5.0, ge=0, le=100, description="Ground wind of the Bufton profile [m/s]")
        wind_direction_deg: float = Field(0.0, ge=-360, le=360,
                                          description="Wind direction from the focal plane's +x toward +y at the first render "
                                                      "time (the layers are fixed to the ground) [deg]")
        outer_scale_m: float = Field(25.0, gt=0, le=1e4, description="Von Karman outer scale L0 [m]")
        screen_method: Literal["fft", "zernike"] = Field(
            "fft", description="Layer screens: FFT with subharmonics, or Karhunen-Loeve Zernike modes [-]")
        screen_update: Literal["extend", "regenerate"] = Field(
            "extend", description="When a footprint runs off a screen: extend it, or draw a new one [-]")
        n_zernike_modes: int = Field(66, ge=2, le=1000,
                                     description="Zernike modes (from tilt) of 'zernike' screens [1]")
        screen_revisit_s: float | None = Field(None, gt=0, description="Redraw all screens after this time [s]")
        pupil_samples: int | None = Field(None, ge=8, le=4096,
                                          description="Pupil grid width; None chooses from D/r0 [1]")
        stamp_size_px: int | None = Field(None, ge=1, le=511,
                                          description="Stamp width; None encloses all but tolerance/2 [pixel]")
        grid_size: int | None = Field(None, ge=16, le=16384,
                                      description="Reference propagation grid width; None picks a valid one [1]")
        detector: DataFile | None = Field(
            None, description="Sensor preset whose dvs_pixel the irradiance feeds: 'auto' then chooses from what "
                              "its pixels see (response time, threshold; see paths) [-]")

        @model_validator(mode="after")
        def _consistent(self):
            if self.screen_method == "zernike" and self.screen_update == "extend":
                raise ValueError("screen_method 'zernike' needs screen_update 'regenerate' "
                                 "(modal screens cannot be extended)")
            if self.atmosphere == "table" and not self.profile_file:
                raise ValueError("atmosphere 'table' needs profile_file")
            return self

    inputs = {
        "sources": Input(PointSources, "point sources on the focal plane (satellites, stars)", multi=True),
        "background": Input(SkyBackground, "diffuse sky brightness per pixel", required=False),
    }
    outputs = {"irradiance": Output(Irradiance, "photon flux per pixel: stamps around sources plus background"),
               "truth": Output(Truth, "every source on the detector at each render time (the run store keeps it)")}
    state = ("optics_state", "held", "held_stamps")
    # its chain of windows is a run's longest (12 of the 10 s tracked pass's 22 s of CPU), and its per-window Python
    # holds the interpreter lock for ~40 % of it (docs/speed.md): on several cores it steps in a process of its own
    worth_a_process = True

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.optics_state: dict | None = None
        self.held: dict = {}
        #: with ``source_intervals``: each source's last stamp (energy fractions, placement, path) and the last render
        #: time it was in view [ns], while that is the last render time so far (the hold carries across windows)
        self.held_stamps: dict = {}
        self._imager: Imager | None = None
        self._intervals: RenderInterval | None = None
        self._atmosphere: Atmosphere | None = None
        self._atmosphere_ready = False
        #: :meth:`_named`'s sources and what it made of them
        self._names: tuple | None = None

    # -- configuration --------------------------------------------------------------------------
    @property
    def telescope(self) -> Telescope:
        p = self.params
        return Telescope(p.aperture_m, p.obscuration, p.throughput)

    def build_atmosphere(self) -> Atmosphere | None:
        p = self.params
        if p.atmosphere == "none":
            return None
        if p.atmosphere == "hufnagel_valley":
            atmosphere = Atmosphere.hufnagel_valley(p.n_layers, p.hv_wind_rms_m_s, p.hv_ground_cn2, p.ground_wind_m_s,
                                                    np.deg2rad(p.wind_direction_deg), p.outer_scale_m)
        else:
            from evsda.library import resolve
            path = resolve(p.profile_file)
            try:
                atmosphere = Atmosphere.from_table(path, p.outer_scale_m)
            except (OSError, ValueError, UserError) as exc:
                raise ParameterError(f"{self.label} parameter 'profile_file': {exc}") from None
        if atmosphere.total_cn2_dh <= 0:
            return None
        if p.r0_500nm_m is not None:
            atmosphere = atmosphere.scaled_to_r0(p.r0_500nm_m)
        return atmosphere

    def setup(self, run: RunInfo) -> None:
        super().setup(run)
        self._atmosphere = self.build_atmosphere()
        self._atmosphere_ready = True
        self._imager = None

    def _ensure_imager(self, focal_plane: FocalPlane, wavelength: float) -> Imager:
        if self._imager is None:
            if not self._atmosphere_ready:
                self._atmosphere, self._atmosphere_ready = self.build_atmosphere(), True
            p = self.params
            seed = tuple(int(w) for w in self.rng.bit_generator.seed_seq.generate_state(2))
            rendered = (self._atmosphere if self._atmosphere is None or p.equivalent_layers is None
                        else equivalent_layers(self._atmosphere, p.equivalent_layers))
            self._imager = Imager(self.telescope, focal_plane, wavelength, rendered, p, seed=seed,
                                  label=self.label, pixels=self._pixels(focal_plane, wavelength))
            # the full profile: equivalent layers change the screens, not how often a source is rendered
            self._intervals = (RenderInterval(self._atmosphere, wavelength, focal_plane.pixel_scale_rad,
                                              self._imager.chooser.pixels, p.interval_factor)
                               if p.source_intervals else None)
            if self.optics_state:
                self._imager.set_state(self.optics_state)
        return self._imager

    def _pixels(self, focal_plane: FocalPlane, wavelength: float):
        """The detector's pixels (:class:`.PixelView`) from the ``detector`` preset, or None."""
        if self.params.detector is None:
            return None
        from evsda.library import resolve

        from .pixel_view import PixelView, load_pixel_params
        try:
            path = resolve(self.params.detector)
        except (OSError, UserError) as exc:
            raise ParameterError(f"{self.label} parameter 'detector': {exc}") from None
        return PixelView.of(load_pixel_params(path, self.label), focal_plane.pixel_area_m2, wavelength)

    # -- state ----------------------------------------------------------------------------------
    def get_state(self) -> dict:
        if self._imager is not None:
            self.optics_state = self._imager.state()
        return super().get_state()

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        self.held = self.held or {}
        self.held_stamps = self.held_stamps or {}
        if self._imager is not None and self.optics_state:
            self._imager.set_state(self.optics_state)

    # -- work -----------------------------------------------------------------------------------
    def _common(self, sources: list[PointSources]) -> tuple[FocalPlane, float]:
        if not sources:
            raise InputError(f"{self.label} input 'sources' received no PointSources")
        first = sources[0]
        for other in sources[1:]:
            a, b = first.focal_plane, other.focal_plane
            if (a.width_px, a.height_px, a.pixel_pitch_m, a.focal_length_m) != \
                    (b.width_px, b.height_px, b.pixel_pitch_m, b.focal_length_m):
                raise InputError(f"{self.label} input 'sources': connected PointSources disagree on the "
                                 f"focal plane ({a} vs {b})")
            if not _isclose(first.wavelength_m, other.wavelength_m, rtol=1e-9):
                raise InputError(f"{self.label} input 'sources': connected PointSources disagree on the "
                                 f"wavelength ({first.wavelength_m} m vs {other.wavelength_m} m)")
        return first.focal_plane, float(first.wavelength_m)

    def _named(self, sources: list[PointSources]) -> tuple[list[str], np.ndarray, np.ndarray]:
        """Every source's key (``input:source_id``) and, for the truth table, their ids (str) and kinds (int8): made
        again only when the inputs' sources change (a star field lists every star of the run, window after window)."""
        listed = [(np.asarray(src.source_id), np.asarray(src.kind)) for src in sources]
        # ids and kinds given as numbers or fixed-width strings are known by their bytes (not objects: an address)
        signature = tuple((a.dtype.str, a.shape, a.tobytes()) for pair in listed for a in pair) \
            if all(a.dtype.kind in "biuSU" for pair in listed for a in pair) else None
        if signature is None or self._names is None or self._names[0] != signature:
            ids = [f"{i}:{source_id}" for i, (source_ids, _) in enumerate(listed) for source_id in source_ids]
            kinds = [int(kind) for _, source_kinds in listed for kind in source_kinds]
            self._names = (signature, ids, np.asarray([key.partition(":")[2] for key in ids], dtype=str),
                           np.asarray(kinds, dtype=np.int8))
        return self._names[1:]

    def _held_samples(self, key: str, src: PointSources, t_ns: np.ndarray) -> tuple[np.ndarray, dict, np.ndarray]:
        """Sample-and-hold the input at the render times ``t_ns``, carrying the last sample across windows: the
        input's sources on the detector (finite ``x`` and ``y``) at one of these render times (their indices, in
        order), their held samples there by quantity (render times, those sources), and the boresight's azimuth,
        zenith angle and field rotation [rad] at the render times (render times, 3; the input's, the same for all
        its sources; None without sources). The others, off the detector throughout (a star field lists every star
        of the run: ~20 of 180 in view at a time on the tracked pass), are left out; every source's last sample is
        kept for the next window."""
        n_src, n_t = src.n_sources, len(src.t_ns)
        held = self.held.get(key)
        fields = {"x": src.x_px, "y": src.y_px, "flux": src.photon_flux, "range": src.range_m,
                  "magnitude": src.magnitude,
                  "zenith": np.broadcast_to(np.asarray(src.zenith_angle_rad, dtype=float)[:, None], (n_t, n_src)),
                  **{name: np.broadcast_to(np.asarray(np.nan if values is None else values, dtype=float)[..., None],
                                           (n_t, n_src))
                     for name, values in (("azimuth", src.boresight_azimuth_rad),
                                          ("rotation", src.field_rotation_rad))},
                  "t": np.broadcast_to(np.asarray(src.t_ns, dtype=float)[:, None], (n_t, n_src))}
        fields = {name: np.asarray(values, dtype=float).reshape(n_t, n_src) for name, values in fields.items()}
        live, rates = self._rates(fields, held, n_src, self._sky_distance(src.focal_plane))
        # the usual input: sampled at the render times, its samples the held ones
        same = n_t == len(t_ns) and np.array_equal(src.t_ns, t_ns)
        index, before, carried = None, None, {}
        if not same:
            index = np.searchsorted(np.asarray(src.t_ns), t_ns, side="right") - 1
            before = index < 0
            # where a render time comes before the window's first input sample: the held sample (when it fits)
            carried = {name: np.asarray(held[name], dtype=float) for name in (*fields, "rate", "sky_rate")
                       if held is not None and name in held and np.asarray(held[name]).shape == (n_src,)} \
                if before.any() else {}
            index = np.clip(index, 0, None)

        def sampled(name: str, values, columns) -> np.ndarray:
            """Quantity ``name``'s held samples of the sources ``columns`` (render times, sources), from their input
            samples ``values()`` (input samples, sources; called only where the input has samples)."""
            if same:
                return values()
            out = values()[index] if n_t else np.full((len(t_ns), n_src), np.nan)[:, columns]
            if name in carried:
                out[before] = carried[name][columns]
            return out

        x, y = (sampled(name, lambda: fields[name], slice(None)) for name in ("x", "y"))
        keep = np.flatnonzero((np.isfinite(x) & np.isfinite(y)).any(axis=0))
        out = {"x": x[:, keep], "y": y[:, keep]}
        out.update({name: sampled(name, lambda: values[:, keep], keep) for name, values in fields.items()
                    if name not in out})
        at = np.searchsorted(live, keep)            # every source on the detector at a render time has its rates
        for name, rate in zip(("rate", "sky_rate"), rates):
            out[name] = sampled(name, lambda: rate[:, at], keep)
        boresight = None if not n_src else np.concatenate(
            [sampled(name, lambda: fields[name][:, :1], slice(0, 1)) for name in ("azimuth", "zenith", "rotation")],
            axis=1)
        if n_t:
            last = {name: values[-1].copy() for name, values in fields.items()}
            for name, rate in zip(("rate", "sky_rate"), rates):
                last[name] = np.full(n_src, np.nan)
                last[name][live] = rate[-1]
            self.held[key] = last
        return keep, out, boresight

    @staticmethod
    def _rates(fields: dict, held: dict | None, n_src: int, sky_distance) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """The apparent rate and the line of sight's rate [pixel/s] at each input sample of the sources on the
        detector at one of these samples or the held one before (their indices; (n_t, those sources) each): the
        distance [pixel] from the sample before (the held one at a window's start) over the time between them, on
        the detector (:meth:`_apparent_distance`) and in the ground frame (``sky_distance``, :meth:`_sky_distance`);
        a track's first sample takes the slowest rate of the input's other sources, NaN (still) where none has one
        (the run's first sample): a rate to the next sample would depend on whether the window holds it.
        The others' rates are NaN, as their positions give (a star field lists every star of the run, ~20 of 180
        in view in the tracked pass)."""
        n_t = len(fields["t"])
        names = ("x", "y", "t", "zenith", "azimuth", "rotation")
        before = {n: np.asarray(held[n], dtype=float) if held is not None and n in held
                  and np.asarray(held[n]).shape == (n_src,) else np.full(n_src, np.nan) for n in names}
        live = np.flatnonzero(np.isfinite(before["x"]) | np.isfinite(fields["x"]).any(axis=0)) \
            if n_t and n_src else np.zeros(0, np.int64)
        if not live.size:
            return live, (np.full((n_t, 0), np.nan), np.full((n_t, 0), np.nan))
        # the positions source by source; the time and the boresight (the input's, the same for every source) one
        # column (n + 1, 1) where the held sample before is the same for every source too, as a held input's is: the
        # same numbers element by element, broadcast in the sums (the sines and cosines once a sample, not a source)
        both = {n: np.concatenate([before[n][live][None], fields[n][:, live]]) for n in ("x", "y")}
        for n in names[2:]:
            held_n = before[n][live]
            both[n] = np.concatenate([held_n[:1][None], fields[n][:, :1]]) if same_bits(held_n, held_n[:1]) else \
                np.concatenate([held_n[None], fields[n][:, live]])
        x = both["x"]
        rates = []
        with np.errstate(invalid="ignore", divide="ignore"):
            seconds = np.diff(both["t"], axis=0) * 1e-9
            apparent = PointSourceOptics._apparent_distance(both)
            for distance in (apparent, sky_distance(both, apparent)):
                rate = distance / seconds
                # a track's first sample: the slowest rate of the input's other sources then (a star field moves
                # as one)
                first = np.isnan(rate) & np.isfinite(x[1:])
                if first.any():
                    slowest = np.where(np.isnan(rate), np.inf, rate).min(axis=1, initial=np.inf)
                    rate = np.where(first, np.where(np.isfinite(slowest), slowest, np.nan)[:, None], rate)
                rates.append(rate)
        return live, tuple(rates)

    @staticmethod
    def _apparent_distance(both: dict) -> np.ndarray:
        """How far a source moved on the detector between consecutive samples of ``both`` (n + 1, sources) [pixel]."""
        return np.hypot(np.diff(both["x"], axis=0), np.diff(both["y"], axis=0))

    @staticmethod
    def _sky_distance(focal_plane: FocalPlane):
        """How far a source's line of sight turned in the ground frame (azimuth/elevation) between consecutive samples
        of ``both`` (n + 1, sources), in pixels at the boresight [pixel] (:func:`.line_of_sight`; the chord
        ``2 asin(|u1 - u2| / 2)`` keeps a sidereal step of 1e-7 rad exact); where the boresight's azimuth is unknown,
        the distance on the detector (a stare, ``apparent``)."""
        centre = np.array([(focal_plane.width_px - 1) / 2, (focal_plane.height_px - 1) / 2])
        scale = focal_plane.pixel_scale_rad

        def distance(both: dict, apparent: np.ndarray) -> np.ndarray:
            # component by component (the sums np.linalg.norm makes of stacked vectors, in the same order)
            u = line_of_sight_at((both["x"] - centre[0]) * scale, -((both["y"] - centre[1]) * scale),
                                 both["zenith"], both["azimuth"], both["rotation"])
            length = np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
            units = [c / length for c in u]                                   # each sample's once
            step = [c[1:] - c[:-1] for c in units]
            chord = np.sqrt(step[0] * step[0] + step[1] * step[1] + step[2] * step[2])
            turned = 2.0 * np.arcsin(np.minimum(chord / 2.0, 1.0)) / scale
            azimuth = both["azimuth"]
            known = np.isfinite(azimuth[:-1]) & np.isfinite(azimuth[1:])
            return np.where(known, turned, apparent)
        return distance

    @staticmethod
    def _fresh_frames(times: np.ndarray, paths: list[str], every: np.ndarray, cadence_ns: int,
                      record: dict | None) -> tuple[np.ndarray, bool]:
        """Which frames of a stretch at render times ``times`` [ns] render (:meth:`_render_held`), and whether the
        stretch continues the stamp ``record`` held from the render time before."""
        continuing = record is not None and int(record["t_ns"]) == int(times[0]) - cadence_ns
        before = record["path"] if continuing else None
        fresh = (times // cadence_ns) % every == 0
        if paths.count(paths[0]) == len(paths):         # one path throughout: a change only at the stretch's start
            fresh[0] |= paths[0] != before
        else:
            fresh |= np.array([p != q for p, q in zip(paths, [before, *paths[:-1]])])
        return fresh, continuing

    @staticmethod
    def _render_held(imager: Imager, key: str, tr: dict, at: np.ndarray, seen: np.ndarray, paths: list[str],
                     every: np.ndarray, t_ns: np.ndarray, cadence_ns: int, record: dict | None):
        """One stretch in view of a source rendered every ``every``-th render time (:mod:`.render_interval`): render
        time ``k`` where ``k`` is a multiple of its interval, where the source was not in view at the render time
        before, or where its path changes; in between the last rendered stamp (energy fractions and placement) held.
        ``record``: the stamp held from the render time before (previous stretch or window), returned updated;
        ``tr``: the track's held samples and its placement at every render time (``placed``, :meth:`.Imager.placement`)."""
        times = t_ns[at]
        fresh, continuing = PointSourceOptics._fresh_frames(times, paths, every, cadence_ns, record)
        if fresh.all():                                 # every frame rendered: nothing held
            o, stamps, _ = imager.render(key, times * 1e-9, None, None, tr["zenith"][at], tr["range"][at], seen,
                                         paths=paths, placed=tuple(p[at] for p in tr["placed"]))
            origin = o.astype(np.int32, copy=False)
            return origin, stamps, {"path": paths[-1], "origin": origin[-1].copy(), "stamp": stamps[-1].copy(),
                                    "t_ns": int(times[-1])}
        rendered = np.flatnonzero(fresh)                # (a stretch that does not continue starts with a new path)
        origin = stamps = None
        if rendered.size:
            r = at[rendered]
            origin, stamps, _ = imager.render(
                key, times[rendered] * 1e-9, None, None, tr["zenith"][r], tr["range"][r], seen[rendered],
                paths=[paths[i] for i in rendered.tolist()], placed=tuple(p[r] for p in tr["placed"]))
            origin = origin.astype(np.int32, copy=False)
        return PointSourceOptics._held(times, fresh, continuing, record, paths, origin, stamps)

    @staticmethod
    def _held(times: np.ndarray, fresh: np.ndarray, continuing: bool, record: dict | None, paths: list[str],
              origin: np.ndarray | None, stamps: np.ndarray | None):
        """Every frame's placement and stamp of a stretch at render times ``times`` [ns] whose frames ``fresh`` were
        rendered (their ``origin`` and ``stamps``, None where none was) and the rest held: each frame's the last
        rendered at or before it, counted from the stamp ``record`` held from the render time before where the stretch
        is ``continuing``; with the record updated (:meth:`_render_held`)."""
        which = np.cumsum(fresh)
        origins, held = ([record["origin"][None]], [record["stamp"][None]]) if continuing else ([], [])
        if stamps is not None:
            origins.append(origin)
            held.append(stamps)
            record = {"path": paths[int(np.flatnonzero(fresh)[-1])]}
        if not continuing:
            which -= 1
        origin, stamps = np.concatenate(origins)[which], np.concatenate(held)[which]
        return origin, stamps, {**record, "origin": origin[-1].copy(), "stamp": stamps[-1].copy(),
                                "t_ns": int(times[-1])}

    def step(self, window: Window, sources: list[PointSources] | PointSources,
             background: SkyBackground | None = None) -> dict:
        if isinstance(sources, PointSources):
            sources = [sources]
        sources = [s for s in (sources or []) if s is not None]
        focal_plane, wavelength = self._common(sources)
        imager = self._ensure_imager(focal_plane, wavelength)
        cadence_ns = max(1, round(1e9 / self.params.render_rate_hz))
        t_ns = window.sample_times_ns(cadence_ns)
        t_s = t_ns * 1e-9
        collected = self.telescope.collecting_area_m2 * self.params.throughput      # [m^2]

        ids, names, kinds = self._named(sources)
        held, source_of, boresights, count = [], [], [], 0
        for i, src in enumerate(sources):
            keep, samples, boresight = self._held_samples(str(i), src, t_ns)
            source_of.append(count + keep)
            count += src.n_sources
            held.append(samples)
            if boresight is not None:
                boresights.append(boresight)
        # the held samples of every track on the detector at one of the render times side by side, (render times,
        # tracks) per quantity, and each track's source (its index in ids)
        columns = {name: np.concatenate([samples[name] for samples in held], axis=1) for name in held[0]}
        source_of = np.concatenate(source_of)

        sky = np.zeros(len(t_ns))
        if background is not None and len(background.t_ns):
            k = np.maximum(np.searchsorted(np.asarray(background.t_ns), t_ns, side="right") - 1, 0)
            sky = np.asarray(background.photon_flux_per_pixel, dtype=float)[k] * collected

        # the first source's zenith angle at the first render time, and the screens' frame: the boresight at the
        # run's first render time that has it (Imager.sight), the first source's that has it then
        zenith_first = float(boresights[0][0, 1]) if boresights and len(t_ns) else np.nan
        geometry = imager.ensure_geometry(zenith_first)
        if imager.frame is None and boresights and len(t_ns):
            boresight = np.stack(boresights, axis=1)                               # (T, inputs, 3)
            known = np.isfinite(boresight).all(axis=-1)
            if known.any():
                k, j = np.argwhere(known)[0]
                imager.set_frame(*boresight[k, j])
        size = geometry.stamp_size
        # a NaN flux compares false, as np.nan_to_num's 0 did (without its copies: ~70 us a window)
        visible = (np.isfinite(columns["x"]) & np.isfinite(columns["y"])
                   & (columns["flux"] > 0))                                     # (render times, tracks)
        # what the pixels see of each frame: apparent rate, collected flux, sky per pixel; and the rate of its line of
        # sight in the ground frame, which moves its footprints through the layers (render times, tracks, 4)
        seen = np.stack([columns["rate"], columns["flux"] * collected, np.broadcast_to(sky[:, None], visible.shape),
                         columns["sky_rate"]], axis=-1)
        # every frame's render interval, every track at once (1 out of view)
        every = None
        if self._intervals is not None:
            every = np.ones(visible.shape, np.int64)
            every[visible] = self._intervals.multiples(cadence_ns, seen[visible], columns["zenith"][visible])
        # every frame in view, track by track: the path choices' bins of all of them in one call (element by element,
        # the same keys as a track's alone), split at the tracks' counts
        tracks = np.flatnonzero(visible.any(axis=0))
        in_view = visible[:, tracks].T                                            # (tracks, render times)
        track_of, frame_of = np.nonzero(in_view)
        column_of = tracks[track_of]
        zenith_in_view, range_in_view, seen_in_view = (values[frame_of, column_of]
                                                       for values in (columns["zenith"], columns["range"], seen))
        bins = imager.chooser.keys(zenith_in_view, range_in_view, seen_in_view)
        ends = np.cumsum(in_view.sum(axis=1)).tolist()
        starts = [0, *ends[:-1]] if ends else []
        # the probes of every bin this window meets first, side by side on every core, before the choices take them
        # (the bins of each track's first and last frames in view)
        imager.chooser.probe_ahead(columns["zenith"], columns["range"], seen, visible,
                                   [bins[i] for i in starts] + [bins[i - 1] for i in ends])
        # every frame's stamp placement and line of sight, all tracks in view at once (Imager.placement)
        placed = imager.placement(*(columns[name][:, tracks] for name in ("x", "y", "zenith", "azimuth", "rotation")))
        # the same by track (tracks, render times, ...), with the zenith angles and ranges: a group's frames in one
        # gather each (render_together)
        by_track = tuple(np.ascontiguousarray(np.swapaxes(values, 0, 1)) for values in
                         (*placed, columns["zenith"][:, tracks], columns["range"][:, tracks]))
        every_in_view = None if every is None else every[frame_of, column_of]
        jobs = []
        for column, j in enumerate(tracks):                                       # tracks in order
            key, tr = ids[source_of[j]], {name: columns[name][:, j] for name in ("x", "y", "zenith", "range")}
            tr["placed"] = tuple(p[:, column] for p in placed)
            part = slice(starts[column], ends[column])                            # its frames in view
            mine = seen_in_view[part]
            paths = imager.prepare(key, zenith_in_view[part], range_in_view[part], mine,     # path choices, in order
                                   keys=bins[part])
            jobs.append((len(jobs), key, tr, frame_of[part], mine, paths,
                         None if every_in_view is None else every_in_view[part]))
        # a stamp slot for each source on the detector in this window only (a star field lists every star of the
        # run: 1586 in a 60 s tracked pass, ~20 at a time; zero stamps for the rest cost 31 MB a window)
        origin = np.zeros((len(t_ns), len(jobs), 2), dtype=np.int32)
        # each frame's energy fractions [1] times the frame's collected flux [photon/s], written as each source renders
        # (on the thread that renders it; the frames out of view stay zero)
        flux = np.zeros((len(t_ns), len(jobs), size, size))
        collected_flux = np.where(in_view.T, columns["flux"][:, tracks] * collected, 0.0)[:, :, None, None]

        def render(job):
            s, key, tr, idx, seen, paths, every = job
            record = self.held_stamps.get(key)
            # each stretch of consecutive render times in view; one back after more than hold_ns out of view
            # (since this window's last stretch or the render time the imager last saw it) gets new screens
            stops = ([len(idx)] if idx[-1] - idx[0] == len(idx) - 1        # one stretch (the usual window)
                     else [*(np.flatnonzero(np.diff(idx) > 1) + 1).tolist(), len(idx)])
            for first, stop in zip([0, *stops[:-1]], stops):
                at, part = idx[first:stop], slice(first, stop)
                if not imager.keeps(key, t_ns[at[0]]):
                    imager.forget([key])
                stretch_paths = paths[part]
                if every is None:
                    o, stamps, _ = imager.render(key, t_s[at], tr["x"][at], tr["y"][at], tr["zenith"][at],
                                                 tr["range"][at], seen[part], paths=stretch_paths,
                                                 placed=tuple(p[at] for p in tr["placed"]))
                else:
                    o, stamps, record = self._render_held(imager, key, tr, at, seen[part], stretch_paths,
                                                          every[part], t_ns, cadence_ns, record)
                origin[at, s] = o
                flux[at, s] = stamps * collected_flux[at, s]
                imager.seen(key, t_ns[at[-1]])
            return key, record

        def render_together(group):
            """Sources in view at the same render times ``idx`` (one stretch each) on the pupil path that render the
            same of them (every one, or the same ``fresh`` frames with the rest held, :meth:`_held`): their screens
            walked and their stamps made in one call each (:meth:`.Imager.render_many`; each source's stamps those of
            :func:`render`). ``group``: each source's job, ``fresh`` (None: every frame) and whether its stretch
            continues the stamp held from before."""
            (_, _, _, idx, *_), fresh, _ = group[0]
            at = idx if fresh is None else idx[fresh]
            span = slice(idx[0], idx[-1] + 1)           # one stretch: idx
            for (_, key, *_), _, _ in group:
                if not imager.keeps(key, t_ns[idx[0]]):
                    imager.forget([key])
            # their placements, zenith angles and ranges at the frames rendered (sources, frames, ...): job s is track s
            sources = [s for (s, *_), _, _ in group]
            rows = (sources, span) if fresh is None else np.ix_(sources, at)
            origin_of, offset, sight, zenith, range_m = (values[rows] for values in by_track)
            placed = (origin_of, offset, sight)
            stamps = imager.render_many([key for (_, key, *_), _, _ in group], t_s[at], zenith, range_m, placed)
            done = []
            for k, ((s, key, tr, _, _, paths, _), _, continuing) in enumerate(group):
                o = placed[0][k].astype(np.int32, copy=False)
                if fresh is None:
                    own = stamps[k]
                    record = self.held_stamps.get(key) if every is None else {
                        "path": "pupil_fft", "origin": o[-1].copy(), "stamp": stamps[k, -1].copy(),
                        "t_ns": int(t_ns[idx[-1]])}
                else:
                    o, own, record = self._held(t_ns[idx], fresh, continuing, self.held_stamps.get(key), paths, o,
                                                stamps[k])
                origin[span, s] = o
                np.multiply(own, collected_flux[span, s], out=flux[span, s])
                imager.seen(key, t_ns[idx[-1]])
                done.append((s, (key, record)))
            return done

        # sources in view at the same render times, one stretch each, rendering the same of them on the pupil path
        # (the usual window: the satellite and the stars that can fire a pixel, every frame or, held, the same ones)
        # go together, TOGETHER at a time
        groups, alone = {}, []
        for job in jobs:
            s, key, tr, idx, mine, paths, every_j = job
            if not (idx[-1] - idx[0] == len(idx) - 1 and paths[0] == "pupil_fft"
                    and paths.count(paths[0]) == len(paths) and imager.renders_together(paths[0])):
                alone.append(job)
                continue
            fresh, continuing = (None, False) if every_j is None else self._fresh_frames(
                t_ns[idx], paths, every_j, cadence_ns, self.held_stamps.get(key))
            if fresh is not None and fresh.all():
                fresh = None
            if fresh is not None and not fresh.any():              # every frame held: nothing to render
                alone.append(job)
                continue
            groups.setdefault((idx.tobytes(), None if fresh is None else fresh.tobytes()), []).append(
                (job, fresh, continuing))
        threads = worker_threads()
        units = [(render_together, group[k:k + TOGETHER]) for group in groups.values()
                 for k in range(0, len(group), TOGETHER)]
        units += [(lambda job: [(job[0], render(job))], job) for job in alone]
        # sources are independent (own screens, own slots of the output): render them on every core, with the
        # process's shared helper threads
        records = [record for _, record in sorted(
            (item for done in parallel_map(lambda unit: unit[0](unit[1]), units, threads) for item in done),
            key=lambda item: item[0])]
        if self._intervals is not None and len(t_ns):
            # a held stamp carries into the next window only for a source in view at this window's last render time
            self.held_stamps = {key: record for key, record in records
                                if record is not None and int(record["t_ns"]) == int(t_ns[-1])}

        # screens of the sources out of view for hold_ns at the window's last render time are dropped (a 60 s
        # pupil_fft pass sweeps 1586 stars, ~32 kB of screens each): the rule reads render times only, so windows
        # cannot change it
        if len(t_ns):
            imager.release(t_ns[-1])
        truth = truth_rows(focal_plane, t_ns, names.copy(), kinds.copy(), columns, source_of)
        return {"irradiance": Irradiance(focal_plane, wavelength, t_ns, sky, origin, flux), "truth": truth}
