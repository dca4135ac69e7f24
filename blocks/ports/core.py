"""Port types shared between pipeline stages (the contracts between scene, optics, pixel and readout).

Conventions used by every type here:

* Times are integer nanoseconds since the run's start epoch (``int64``).
* Focal-plane coordinates are in pixels: ``x`` is the column, ``y`` the row; the
  centre of pixel ``(col, row)`` is at ``(x, y) = (col, row)``, so a pixel covers
  ``[col - 0.5, col + 0.5)``. The boresight is at ``((width - 1) / 2, (height - 1) / 2)``.
* A value sampled at times ``t_ns`` holds from each sample until the next one
  (sample and hold); the last sample holds until the end of the window.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from evsda.graph.ports import EVENT_STREAM, METRICS, TRUTH, PortValue


@dataclass(frozen=True, eq=False)
class SpectralResponse(PortValue):
    """Which photons a detector counts: its quantum efficiency's shape against wavelength.

    ``detector = "V"``: the Johnson V band as the response (Bessell 1990, peak 1), i.e. a detector that counts
    V-band photons, evsda's model where a preset has no spectral curve. ``"silicon"``: a silicon photodiode
    collecting the carriers made within ``silicon_depth_m`` of its surface, ``1 - exp(-alpha d)`` with
    silicon's absorption (Green 2008; :mod:`evsda.blocks.scene.spectra`), 1 at 550 nm: the pixel's
    ``quantum_efficiency`` is the QE there (times the fill factor). ``filter``: ``"V"`` puts a V filter in front.
    """

    unit = "1"
    detector: str = "V"
    silicon_depth_m: float = 0.0
    filter: str = "none"

    @property
    def is_v_band(self) -> bool:
        """The detector counts V-band photons (no spectral curve): fluxes are the V band's."""
        return self.detector == "V" and self.filter == "none"


@dataclass(frozen=True, eq=False)
class FocalPlane(PortValue):
    """Detector geometry behind the telescope: pixel grid, pitch and focal length, and the detector's
    spectral response (which photons the scene counts for it)."""

    unit = "pixel"
    width_px: int
    height_px: int
    pixel_pitch_m: float
    focal_length_m: float
    spectral_response: SpectralResponse = SpectralResponse()

    @property
    def pixel_scale_rad(self) -> float:
        """Angle subtended by one pixel at the boresight [rad] (pitch / focal length)."""
        return self.pixel_pitch_m / self.focal_length_m

    @property
    def shape(self) -> tuple[int, int]:
        """``(height_px, width_px)``: the numpy shape of a full frame."""
        return (self.height_px, self.width_px)

    @property
    def pixel_area_m2(self) -> float:
        return self.pixel_pitch_m**2


class SourceKind(enum.IntEnum):
    SATELLITE = 0
    STAR = 1


@dataclass(frozen=True, eq=False)
class PointSources(PortValue):
    """Unresolved sources on the focal plane and their flux at the aperture versus time.

    Arrays are ``[n_t, n_src]``; positions are ``NaN`` while a source is outside the
    field of view, below the horizon or otherwise not observable. The boresight's azimuth
    and the field rotation place each source's line of sight in the ground frame (the optics'
    layer footprints, :meth:`evsda.blocks.optics.imaging.Imager.sight`); without them the
    optics takes the sources as seen from a staring mount.
    """

    unit = "photon s^-1 m^-2"
    focal_plane: FocalPlane
    wavelength_m: float                      # effective wavelength of the band [m]
    t_ns: np.ndarray                         # int64 [n_t] sample times
    source_id: np.ndarray                    # str [n_src] e.g. NORAD number or HIP id
    kind: np.ndarray                         # int8 [n_src] SourceKind
    x_px: np.ndarray                         # float64 [n_t, n_src] column coordinate [pixel]
    y_px: np.ndarray                         # float64 [n_t, n_src] row coordinate [pixel]
    photon_flux: np.ndarray                  # float64 [n_t, n_src] at the aperture, after the atmosphere [photon s^-1 m^-2]
    magnitude: np.ndarray                    # float64 [n_t, n_src] apparent magnitude in the band [mag]
    range_m: np.ndarray                      # float64 [n_t, n_src] observer-source distance [m] (inf for stars)
    zenith_angle_rad: np.ndarray             # float64 [n_t] boresight zenith angle [rad]; NaN above the atmosphere (space observer)
    #: float64 [n_t] boresight azimuth, from north through east [rad]; NaN from space (None: unknown)
    boresight_azimuth_rad: np.ndarray | None = None
    #: float64 [n_t] the image's up axis turned from the local elevation direction at the boresight towards
    #: increasing azimuth [rad]: the roll for azimuth/elevation pointings; NaN from space (None: unknown)
    field_rotation_rad: np.ndarray | None = None

    @property
    def n_sources(self) -> int:
        return int(self.source_id.shape[0])

    @classmethod
    def empty(cls, focal_plane: FocalPlane, wavelength_m: float, t_ns: np.ndarray) -> "PointSources":
        n_t = len(t_ns)
        nan = np.full((n_t, 0), np.nan)
        return cls(focal_plane, wavelength_m, np.asarray(t_ns, np.int64), np.array([], dtype=str),
                   np.array([], dtype=np.int8), nan, nan.copy(), np.zeros((n_t, 0)), nan.copy(), nan.copy(),
                   np.full(n_t, np.nan))


@dataclass(frozen=True, eq=False)
class Truth(PortValue):
    """The true state of point sources at the optics' render times: one row per rendered sample.

    A row is a source on the detector (finite position) at a render time, as the optics drew
    it (sample and hold of :class:`PointSources`); ``source_index`` indexes the per-source
    ``source_id`` and ``kind``. Rows are sorted by time, then source. The run store keeps
    every window's rows in its ``truth`` group (see :mod:`evsda.graph.store`).
    """

    unit = "pixel"
    record = TRUTH
    #: per column: unit and meaning, written as the stored arrays' attributes
    COLUMNS: ClassVar[dict[str, tuple[str, str]]] = {
        "t_ns": ("ns", "render time since the run's start epoch"),
        "source_index": ("1", "the row's source: its index along the source dimension (source_id, kind)"),
        "x_px": ("pixel", "column coordinate of the source (pixel centres at integers)"),
        "y_px": ("pixel", "row coordinate of the source (pixel centres at integers)"),
        "magnitude": ("mag", "apparent magnitude in the band"),
        "photon_flux": ("photon s^-1 m^-2", "photon flux at the aperture, after the atmosphere"),
        "range_m": ("m", "observer-source distance (inf for stars)"),
    }
    focal_plane: FocalPlane
    source_id: np.ndarray                    # str [n_src] e.g. NORAD number or HIP id
    kind: np.ndarray                         # int8 [n_src] SourceKind
    t_ns: np.ndarray                         # int64 [n] render time
    source_index: np.ndarray                 # int32 [n] index into source_id
    x_px: np.ndarray                         # float32 [n] column [pixel]
    y_px: np.ndarray                         # float32 [n] row [pixel]
    magnitude: np.ndarray                    # float32 [n] [mag]
    photon_flux: np.ndarray                  # float32 [n] [photon s^-1 m^-2]
    range_m: np.ndarray                      # float32 [n] [m]

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def table(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, dict]]:
        """``(per-source columns, per-row columns, attributes of each column)`` as the run store keeps them:
        rows refer to sources by the ``source_index`` column; attributes hold ``units`` and ``long_name``
        (CF ``flag_values`` / ``flag_meanings`` for ``kind``)."""
        sources = {"source_id": np.asarray(self.source_id, dtype=str), "kind": np.asarray(self.kind, np.int8)}
        rows = {name: np.asarray(getattr(self, name)) for name in self.COLUMNS}
        attrs = {name: {"units": unit, "long_name": meaning} for name, (unit, meaning) in self.COLUMNS.items()}
        attrs["source_id"] = {"long_name": "source identifier: NORAD number of a satellite, "
                                           "HIP n or BS n (drawn from star counts) of a star"}
        attrs["kind"] = {"long_name": "kind of source", "flag_values": [int(k) for k in SourceKind],
                         "flag_meanings": " ".join(k.name.lower() for k in SourceKind)}
        return sources, rows, attrs


@dataclass(frozen=True, eq=False)
class SkyBackground(PortValue):
    """Diffuse sky brightness collected by one pixel's solid angle, per unit aperture area."""

    unit = "photon s^-1 m^-2 pixel^-1"
    t_ns: np.ndarray                         # int64 [n_t]
    photon_flux_per_pixel: np.ndarray        # float64 [n_t] [photon s^-1 m^-2 pixel^-1]


@dataclass(frozen=True, eq=False)
class Irradiance(PortValue):
    """Photon flux reaching each detector pixel: a uniform background plus stamps around sources.

    The full-frame flux at sample ``k`` is ``background[k]`` everywhere plus, for
    every stamp ``s``, ``stamp_flux[k, s]`` added at rows ``y0 .. y0+h`` and columns
    ``x0 .. x0+w`` where ``(x0, y0) = stamp_origin[k, s]`` (stamps may overlap each
    other and the sensor edge; parts outside the sensor are discarded).
    """

    unit = "photon s^-1 pixel^-1"
    focal_plane: FocalPlane
    wavelength_m: float                      # effective wavelength [m] (photon energy h c / wavelength)
    t_ns: np.ndarray                         # int64 [n_t] sample times (sample and hold)
    background: np.ndarray                   # float64 [n_t] uniform flux on every pixel [photon s^-1 pixel^-1]
    stamp_origin: np.ndarray                 # int32 [n_t, n_stamps, 2] (x0 column, y0 row) of each stamp's first pixel
    stamp_flux: np.ndarray                   # float64 [n_t, n_stamps, h, w] flux added to the background [photon s^-1 pixel^-1]

    @property
    def n_stamps(self) -> int:
        return int(self.stamp_flux.shape[1])

    def frame(self, k: int) -> np.ndarray:
        """The dense ``(height, width)`` photon-flux image at sample ``k`` [photon s^-1 pixel^-1]."""
        height, width = self.focal_plane.shape
        image = np.full((height, width), float(self.background[k]))
        for s in range(self.n_stamps):
            add_stamp(image, self.stamp_flux[k, s], *self.stamp_origin[k, s])
        return image


def add_stamp(image: np.ndarray, stamp: np.ndarray, x0: int, y0: int) -> None:
    """Add ``stamp`` into ``image`` with its first pixel at column ``x0``, row ``y0``, clipped to the image."""
    height, width = image.shape
    h, w = stamp.shape
    r0, r1 = max(y0, 0), min(y0 + h, height)
    c0, c1 = max(x0, 0), min(x0 + w, width)
    if r0 < r1 and c0 < c1:
        image[r0:r1, c0:c1] += stamp[r0 - y0 : r1 - y0, c0 - x0 : c1 - x0]


class EventCause(enum.IntEnum):
    """Why a pixel fired: the simulator's ground truth for each event."""

    SIGNAL = 0      # a change of photocurrent crossed the threshold (Eq. 17)
    LEAK = 1        # junction leak (Eq. 18)
    PARASITIC = 2   # parasitic photocurrent (Eq. 19)
    SHOT = 3        # shot noise (Eq. 20)


@dataclass(frozen=True, eq=False)
class TriggeredEvents(PortValue):
    """Events as the pixels trigger them, before the arbiter (sorted by ``t_ns``, then row, then column)."""

    unit = "event"
    focal_plane: FocalPlane
    t_ns: np.ndarray                         # int64 [n] trigger time
    x: np.ndarray                            # uint16 [n] column
    y: np.ndarray                            # uint16 [n] row
    p: np.ndarray                            # int8 [n] polarity, +1 ON / -1 OFF
    cause: np.ndarray                        # uint8 [n] EventCause
    n_loss: int = 0                          # events the pixels could not emit in this window (Eq. 17's owed events taken back, noise while blind)
    counts_by_cause: tuple[int, ...] = field(default=(0, 0, 0, 0))  # triggered events per EventCause in this window

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @classmethod
    def empty(cls, focal_plane: FocalPlane) -> "TriggeredEvents":
        return cls(focal_plane, np.zeros(0, np.int64), np.zeros(0, np.uint16), np.zeros(0, np.uint16),
                   np.zeros(0, np.int8), np.zeros(0, np.uint8))


@dataclass(frozen=True, eq=False)
class Events(PortValue):
    """Events as recorded by the readout: the paper's Eq. 22 record ``{t_a, x, y, p, t_t}``.

    Sorted by readout time ``t_readout_ns``. A run store records them as its event stream (``events/``):
    one array per column with the dtype and CF attributes below, the focal plane once as attributes.
    """

    unit = "event"
    record = EVENT_STREAM
    stream_columns = {
        "t_trigger_ns": (np.dtype(np.int64), {"units": "ns",
                                              "long_name": "trigger time since start_epoch (t_t, paper Eq. 22)"}),
        "t_readout_ns": (np.dtype(np.int64), {"units": "ns",
                                              "long_name": "readout time since start_epoch (t_a, paper Eq. 22)"}),
        "x": (np.dtype(np.uint16), {"units": "pixel", "long_name": "column"}),
        "y": (np.dtype(np.uint16), {"units": "pixel", "long_name": "row"}),
        "p": (np.dtype(np.int8), {"units": "1", "long_name": "polarity", "flag_values": [-1, 1],
                                  "flag_meanings": "OFF ON"}),
        "cause": (np.dtype(np.uint8), {"units": "1", "long_name": "why the pixel fired (simulation truth)",
                                       "flag_values": [int(c) for c in EventCause],
                                       "flag_meanings": " ".join(c.name.lower() for c in EventCause)}),
    }
    stream_geometry = "focal_plane"
    focal_plane: FocalPlane
    t_trigger_ns: np.ndarray                 # int64 [n] t_t, when the pixel fired
    t_readout_ns: np.ndarray                 # int64 [n] t_a, when the arbiter recorded it
    x: np.ndarray                            # uint16 [n] column
    y: np.ndarray                            # uint16 [n] row
    p: np.ndarray                            # int8 [n] polarity, +1 ON / -1 OFF
    cause: np.ndarray                        # uint8 [n] EventCause (simulation truth)
    n_dropped: int = 0                       # triggered events the readout dropped in this window

    def __len__(self) -> int:
        return int(self.t_readout_ns.shape[0])


@dataclass(frozen=True, eq=False)
class Frame(PortValue):
    """Frames of a conventional (CMOS/CCD) sensor."""

    unit = "DN"
    focal_plane: FocalPlane
    t_start_ns: np.ndarray                   # int64 [n_frames] exposure start
    exposure_ns: int                         # exposure time [ns]
    image: np.ndarray                        # uint16 [n_frames, height, width] digital numbers [DN]


@dataclass(frozen=True, eq=False)
class Metrics(PortValue):
    """Named scalar figures of a run (paper Section 3), with their units."""

    unit = "mixed"
    record = METRICS
    values: dict = field(default_factory=dict)   # name -> number
    units: dict = field(default_factory=dict)    # name -> unit string

    def figures(self) -> tuple[dict, dict]:
        return self.values, self.units
