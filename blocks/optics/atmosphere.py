"""Layered turbulent atmospheres: Cn^2 profiles, layer Fried parameters, winds and scintillation.

A profile is a set of thin layers, each with its turbulence integral ``J = Cn^2 dh``
[m^(1/3)], altitude above the observer [m] and wind. For a wavelength ``lambda`` and a
zenith angle ``zeta`` (plane-parallel atmosphere, ``sec zeta`` air mass):

* layer Fried parameter (Fried 1966; Hardy 1998, *Adaptive Optics for Astronomical
  Telescopes*, Eq. 3.40):  ``r0_i = (0.423 k^2 sec(zeta) J_i)^(-3/5)``, ``k = 2 pi / lambda``,
  and for the whole path ``r0 = (sum_i r0_i^(-5/3))^(-3/5)``;
* isoplanatic angle (Fried 1982, Hardy Eq. 3.61):
  ``theta0 = (2.914 k^2 sec(zeta)^(8/3) sum_i J_i h_i^(5/3))^(-3/5)``;
* aperture-averaged scintillation index in the weak-fluctuation regime (Tatarskii 1971;
  Roddier 1981, Progress in Optics XIX, Eq. 3.21 with the aperture filter of Sec. 3.3)::

      sigma_I^2 = 16 pi^2 k^2 sec(zeta) sum_i J_i int kappa dkappa 0.033 kappa^(-11/3)
                  sin^2(kappa^2 z_i (1 - z_i/R) / 2k) [2 J1(x)/x]^2,  x = kappa D (1 - z_i/R) / 2

  with ``z_i = h_i sec(zeta)`` and a point source at range ``R``; it tends to the Rytov
  variance ``2.25 k^(7/6) sec^(11/6) sum J h^(5/6)`` for small apertures (Andrews &
  Phillips 2005, *Laser Beam Propagation through Random Media*, Eq. 12.38) and to
  ``17.34 D^(-7/3) sec^3 sum J h^2`` for large ones (Dravins et al. 1997, PASP 109, 173, Eq. 10).

Profiles: Hufnagel-Valley (Hufnagel 1974; Valley 1980, Appl. Opt. 19, 574; the HV5/7
model has ``A = 1.7e-14`` and ``v_rms = 21 m/s`` and gives ``r0 = 5 cm`` and
``theta0 = 7 urad`` at 0.5 um), with the Bufton wind model (Bufton 1973, Appl. Opt. 12,
1785), or a user table (CSV, see :func:`read_profile_table`).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.special import j1

from evsda.graph.files import read_text

#: Kolmogorov refractive-index spectrum coefficient, Phi_n = 0.033 Cn^2 kappa^(-11/3) (Tatarskii 1971) [1]
PHI_N_COEFFICIENT = 0.033


def hufnagel_valley_cn2(h: np.ndarray, v_rms: float = 21.0, A: float = 1.7e-14) -> np.ndarray:
    """Hufnagel-Valley ``Cn^2(h)`` [m^(-2/3)] at altitude ``h`` [m] (Valley 1980; HV5/7 by default)."""
    h = np.asarray(h, dtype=float)
    return (0.00594 * (v_rms / 27.0) ** 2 * (1e-5 * h) ** 10 * np.exp(-h / 1000.0)
            + 2.7e-16 * np.exp(-h / 1500.0) + A * np.exp(-h / 100.0))


def bufton_wind(h: np.ndarray, ground_wind: float = 5.0) -> np.ndarray:
    """Bufton wind speed [m/s] at altitude ``h`` [m]: ``v_g + 30 exp(-((h - 9400)/4800)^2)`` (Bufton 1973)."""
    h = np.asarray(h, dtype=float)
    return ground_wind + 30.0 * np.exp(-(((h - 9400.0) / 4800.0) ** 2))


@dataclass(frozen=True)
class Layer:
    """One thin turbulent layer."""

    altitude_m: float            # height above the observer [m]
    cn2_dh: float                # turbulence integral J = Cn^2 dh [m^(1/3)]
    wind_speed_m_s: float        # [m/s]
    # direction the air moves toward, from the focal plane's +x (columns) toward +y at the run's first render time
    # (the screens' frame, fixed to the ground: Imager.sight) [rad]
    wind_direction_rad: float

    @property
    def wind_m_s(self) -> np.ndarray:
        """Wind vector (x, y) [m/s] in the screens' frame (the focal plane's axes at the first render time)."""
        return self.wind_speed_m_s * np.array([np.cos(self.wind_direction_rad), np.sin(self.wind_direction_rad)])


@dataclass(frozen=True)
class Atmosphere:
    """A stack of thin layers and the outer scale ``L0`` [m] of their turbulence."""

    layers: tuple[Layer, ...]
    L0: float = 25.0
    #: for equivalent layers (:mod:`.equivalent_layers`), each layer's members in the full profile (their ``J``
    #: weigh within the group only, so a profile scaled after it was compressed keeps them); None: layers as given
    members: tuple[tuple[Layer, ...], ...] | None = None

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def hufnagel_valley(cls, n_layers: int = 4, v_rms: float = 21.0, A: float = 1.7e-14,
                        ground_wind: float = 5.0, wind_direction_rad: float = 0.0, L0: float = 25.0,
                        top_m: float = 30e3) -> "Atmosphere":
        """HV profile lumped into ``n_layers`` layers, preserving ``r0`` and ``theta0`` exactly.

        Bin edges are 0 and ``300 m * 100^(i/(n-1))`` up to ``top_m``; each layer carries the
        bin's ``int Cn^2 dh`` at the altitude ``(int Cn^2 h^(5/3) dh / int Cn^2 dh)^(3/5)``.
        """
        from scipy.integrate import quad       # here: scipy.integrate costs 0.4 s to import, tables never need it

        if n_layers == 1:
            edges = np.array([0.0, top_m])
        else:
            edges = np.r_[0.0, 300.0 * (top_m / 300.0) ** (np.arange(n_layers) / (n_layers - 1))]
        layers = []
        for lo, hi in zip(edges[:-1], edges[1:]):
            j = quad(lambda h: hufnagel_valley_cn2(h, v_rms, A), lo, hi, limit=200, points=[100.0, 1000.0, 10e3])[0]
            jh = quad(lambda h: hufnagel_valley_cn2(h, v_rms, A) * h ** (5 / 3), lo, hi, limit=200,
                      points=[100.0, 1000.0, 10e3])[0]
            altitude = (jh / j) ** (3 / 5)
            layers.append(Layer(altitude, j, float(bufton_wind(altitude, ground_wind)), wind_direction_rad))
        return cls(tuple(layers), L0)

    @classmethod
    def from_table(cls, path: str | Path, L0: float = 25.0) -> "Atmosphere":
        return cls(read_profile_table(path), L0)

    def scaled_to_r0(self, r0_m: float, wavelength_m: float = 500e-9) -> "Atmosphere":
        """The same profile with all ``J`` scaled so that ``r0`` at zenith and ``wavelength_m`` is ``r0_m``."""
        factor = (self.r0(wavelength_m, 0.0) / r0_m) ** (5 / 3)
        return replace(self, layers=tuple(replace(layer, cn2_dh=layer.cn2_dh * factor) for layer in self.layers))

    # -- integrated quantities ------------------------------------------------------------------
    @property
    def total_cn2_dh(self) -> float:
        return float(sum(layer.cn2_dh for layer in self.layers))

    def layer_r0(self, wavelength_m: float, zenith_rad: float) -> np.ndarray:
        """Fried parameter of each layer [m] (Hardy 1998 Eq. 3.40)."""
        k = 2 * np.pi / wavelength_m
        j = np.array([layer.cn2_dh for layer in self.layers])
        with np.errstate(divide="ignore"):
            return (0.423 * k**2 / np.cos(zenith_rad) * j) ** (-3 / 5)

    def r0(self, wavelength_m: float, zenith_rad: float) -> float:
        """Fried parameter of the whole path [m]."""
        k = 2 * np.pi / wavelength_m
        return float((0.423 * k**2 / np.cos(zenith_rad) * self.total_cn2_dh) ** (-3 / 5))

    def isoplanatic_angle(self, wavelength_m: float, zenith_rad: float) -> float:
        """``theta0`` [rad] (Fried 1982; Hardy 1998 Eq. 3.61)."""
        k = 2 * np.pi / wavelength_m
        moment = sum(layer.cn2_dh * layer.altitude_m ** (5 / 3) for layer in self.layers)
        return float((2.914 * k**2 / np.cos(zenith_rad) ** (8 / 3) * moment) ** (-3 / 5))

    def scintillation_index(self, diameter_m: float, wavelength_m: float, zenith_rad: float,
                            source_range_m: float = np.inf) -> float:
        """Aperture-averaged intensity variance ``sigma_I^2`` [1], weak fluctuations (module docstring)."""
        k = 2 * np.pi / wavelength_m
        airmass = 1.0 / np.cos(zenith_rad)
        total = 0.0
        for layer in self.layers:
            z = layer.altitude_m * airmass
            if z <= 0.0 or layer.cn2_dh <= 0.0:
                continue
            shrink = 1.0 - z / source_range_m if np.isfinite(source_range_m) else 1.0
            fresnel = z * shrink / (2 * k)
            radius = diameter_m * shrink / 2

            value = _scintillation_integral(fresnel, radius)
            total += layer.cn2_dh * value
        return float(16 * np.pi**2 * k**2 * airmass * PHI_N_COEFFICIENT * total)


def _scintillation_integral(fresnel: float, radius: float) -> float:
    """``int kappa^(-8/3) sin^2(kappa^2 fresnel) [2 J1(kappa radius)/(kappa radius)]^2 dkappa`` [m^(5/3)].

    Trapezoidal rule in ``ln kappa``; where ``kappa^2 fresnel > 40`` the sine squared is
    replaced by its mean 1/2 (its oscillations are then far finer than the integrand's scale).
    """
    scale = 1.0 / np.sqrt(fresnel)
    kappa = np.geomspace(1e-4, 1e4, 20001) * scale
    phase = kappa**2 * fresnel
    oscillation = np.where(phase < 40.0, np.sin(np.minimum(phase, 40.0)) ** 2, 0.5)
    x = kappa * radius
    with np.errstate(invalid="ignore", divide="ignore"):
        aperture = np.where(x < 1e-6, 1.0, (2 * j1(x) / x) ** 2)
    integrand = kappa ** (-5 / 3) * oscillation * aperture          # extra kappa from d kappa = kappa d ln kappa
    return float(np.trapezoid(integrand, np.log(kappa)))


def read_profile_table(path: str | Path) -> tuple[Layer, ...]:
    """Layers from a CSV with columns ``altitude_m, cn2_dh_m13, wind_speed_m_s, wind_direction_deg``.

    Lines starting with ``#`` are comments. ``cn2_dh_m13`` is ``Cn^2 dh`` [m^(1/3)]; the wind
    direction is measured from the focal plane's +x axis toward +y at the run's first render time (the
    screens' frame, fixed to the ground: :meth:`.Imager.sight`) [deg].
    """
    path = Path(path)
    text = read_text(path, "Cn2 profile table")        # a regular UTF-8 file (a FIFO would block)
    rows = [(number, line) for number, line in enumerate(text.splitlines(keepends=True), start=1)
            if line.strip() and not line.lstrip().startswith("#")]
    reader = csv.DictReader([line for _, line in rows])
    expected = {"altitude_m", "cn2_dh_m13", "wind_speed_m_s", "wind_direction_deg"}
    if reader.fieldnames is None or not expected <= {str(name).strip() for name in reader.fieldnames}:
        # the header is not quoted back: the file may be anything its user can read
        raise ValueError(f"{path}: expected the columns {sorted(expected)} on the first line that is not a comment")
    layers = []
    for (number, _), row in zip(rows[1:], reader):
        try:
            row = {str(key).strip(): value for key, value in row.items()}
            layer = Layer(float(row["altitude_m"]), float(row["cn2_dh_m13"]), float(row["wind_speed_m_s"]),
                          np.deg2rad(float(row["wind_direction_deg"])))
        except (TypeError, ValueError):
            raise ValueError(f"{path}: line {number}: expected four numbers") from None
        values = (layer.altitude_m, layer.cn2_dh, layer.wind_speed_m_s, layer.wind_direction_rad)
        if not all(np.isfinite(v) for v in values):
            raise ValueError(f"{path}: line {number}: the values must be finite")
        if layer.altitude_m < 0 or layer.cn2_dh < 0 or layer.wind_speed_m_s < 0:
            raise ValueError(f"{path}: line {number}: negative altitude, Cn2 dh or wind speed")
        layers.append(layer)
    if not layers:
        raise ValueError(f"{path}: no layers")
    return tuple(layers)
