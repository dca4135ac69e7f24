"""The pixel circuit's response to a constant photon flux: everything Eqs. 12-20 derive from the input.

Both implementations of the block share this: given the photon flux on each pixel it
returns the lin-log target ``Y`` (Eq. 12-15), the low-pass gain (Eq. 16), the parasitic
leak rate (Eq. 19) and the shot-noise probability per step (Eq. 20).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np

from . import dark_current, lowpass, noise, photoreceptor
from .params import DvsPixelParams
from .refractory import refractory_steps


#: a sensor's fluxes are driven once per distinct value when there are more than ``_FEW_FROM`` and fewer than one
#: distinct value per ``_FEW_SHARE`` pixels (:meth:`PixelModel.distinct_drive`)
_FEW_FROM, _FEW_SHARE = 65536, 16
_FEW_SAMPLE = 8                       # one value in this many tells the many distinct fluxes (:func:`_many_distinct`)


class Drive(NamedTuple):
    """Per-pixel quantities set by a constant input flux."""

    y: np.ndarray            # lin-log target of the photoreceptor, Eq. 14 [1]
    eps: np.ndarray          # low-pass gain per step, Eq. 16 [1]
    log_a: np.ndarray        # ln(1 - eps) [1]
    parasitic_hz: np.ndarray # parasitic leak-event rate, Eq. 19 [Hz]
    shot_p: np.ndarray       # shot-noise probability per step and polarity, Eq. 20 [1]


@dataclass(frozen=True)
class PixelModel:
    """Eqs. 12-21 with the parameters of one sensor, its pixel area and the band's wavelength."""

    params: DvsPixelParams
    pixel_area_m2: float
    wavelength_m: float

    @cached_property
    def dt_ns(self) -> int:
        return max(1, round(self.params.time_step_s * 1e9))

    @cached_property
    def dt_s(self) -> float:
        return self.dt_ns * 1e-9

    @cached_property
    def responsivity_A_per_W(self) -> float:
        return photoreceptor.responsivity_A_per_W(self.params.quantum_efficiency, self.wavelength_m)

    @cached_property
    def dark_current_A(self) -> float:
        p = self.params
        return float(dark_current.dark_current_A(p.temperature_K, p.dark_current_density_A_m2, self.pixel_area_m2,
                                                 p.dark_reference_temperature_K, p.dark_activation_energy_eV))

    @cached_property
    def _log_to_dark(self) -> bool:
        """Eq. 14 logarithmic for every current (``knee_at_dark_current`` with a positive dark current)."""
        return self.params.knee_at_dark_current and self.dark_current_A > 0

    @cached_property
    def shot_noise_floor(self) -> float:
        """The lin-log level at which Eq. 20 gives ``R_n``: 0 (the paper), or a dark pixel's ``ln x_dark`` [1].

        With the photoreceptor logarithmic down to its dark current a pixel never sees
        ``I = 0``; the dark pixel is the bottom of Eq. 20's scale, so ``R_n`` is the rate of a
        dark pixel, the measured background activity a preset cites.
        """
        if not self._log_to_dark:
            return 0.0
        return float(np.log(self.dark_current_A / self.params.reference_current_A))

    @cached_property
    def parasitic_max_hz(self) -> float:
        """Largest parasitic leak rate a pixel can emit beside its junction leak: one event per refractory period [Hz]."""
        return max(1.0 / (self.refractory_steps * self.dt_s) - self.params.leak_rate_hz, 0.0)

    @cached_property
    def refractory_steps(self) -> int:
        return refractory_steps(round(self.params.refractory_period_s * 1e9), self.dt_ns)

    @cached_property
    def shot_p_max(self) -> float:
        """Largest shot-noise probability per step and polarity over all inputs (Eq. 20) [1]."""
        p = self.params
        return p.shot_noise_rate_hz * max(1.0, p.shot_noise_intensity_factor) * self.dt_s

    def normalised_current(self, photon_flux) -> np.ndarray:
        """``x = (I_p + I_dark) / I_ref`` for a photon flux [photon s^-1] (Eqs. 12, 13, 15) [1]."""
        power = photoreceptor.optical_power_W(photon_flux, self.wavelength_m)
        current = photoreceptor.photocurrent_A(power, self.responsivity_A_per_W) + self.dark_current_A
        return current / self.params.reference_current_A

    def drive(self, photon_flux, distinct: bool = False) -> Drive:
        """Everything a constant ``photon_flux`` [photon s^-1 per pixel] sets in the circuit.

        A whole sensor under a uniform background holds few distinct values: those are
        evaluated once each (unless the caller knows them ``distinct``, as for video frames).
        """
        flux = np.asarray(photon_flux, dtype=float)
        if not distinct and flux.ndim == 1:
            values, drive, inverse = self.distinct_drive(flux)
            return drive if values is flux else Drive(*(v[inverse] for v in drive))
        return self._drive(flux)

    def distinct_drive(self, photon_flux: np.ndarray) -> tuple[np.ndarray, Drive, np.ndarray]:
        """``(values, drive, inverse)``: :meth:`drive` of a 1-d ``photon_flux`` as the drive of the fluxes
        ``values`` and each pixel's entry ``inverse`` in them (``drive(photon_flux).y`` is ``drive.y[inverse]``, the
        same bits): the distinct fluxes where they are few, else ``photon_flux`` itself (as a contiguous array) and
        every pixel its own entry."""
        flux = np.ascontiguousarray(photon_flux, dtype=float)
        if flux.size > _FEW_FROM and not _many_distinct(flux):
            values, inverse = distinct_values(flux)
            if values.size < flux.size // _FEW_SHARE:
                return values, self._drive(values), inverse
        return flux, self._drive(flux), np.arange(flux.size)

    def _drive(self, flux: np.ndarray) -> Drive:
        p = self.params
        x = self.normalised_current(flux)
        if self._log_to_dark:
            y = photoreceptor.log_response(x)
        else:
            y = photoreceptor.lin_log(x, p.linear_knee)
        if p.cutoff_max_hz > 0:
            f3db = lowpass.cutoff_hz(x, y, p.cutoff_max_hz, p.cutoff_model, p.cutoff_saturation, p.cutoff_exponent)
        else:
            f3db = np.full_like(y, np.inf)
        eps = lowpass.filter_gain(f3db, self.dt_s)
        power = photoreceptor.optical_power_W(flux, self.wavelength_m)
        lux = noise.illuminance_lux(power, self.pixel_area_m2, p.luminous_efficacy_lm_per_W)
        parasitic = noise.parasitic_rate_hz(lux, p.parasitic_rate_per_lux_hz, self.parasitic_max_hz)
        shot = noise.shot_noise_rate_hz(y, p.shot_noise_rate_hz, p.shot_noise_intensity_factor,
                                        p.log_current_max, self.shot_noise_floor) * self.dt_s
        return Drive(y, eps, lowpass.log_retention(eps), parasitic, shot)


def _many_distinct(flux: np.ndarray) -> bool:
    """Whether every ``_FEW_SAMPLE``-th value of ``flux`` alone already holds at least one distinct value per
    ``_FEW_SHARE`` pixels of the whole, so that the whole does too (a subset has no more distinct values than the
    whole) and :meth:`PixelModel.distinct_drive` would drive every pixel on its own. A noisy frame's values all
    differ: the sort of every pixel (5.5 ms of a 346 x 260 sensor's start) is then left out, for one of an eighth
    of them; a uniform background with stamps has few values other than the first and is not sorted here."""
    subset = flux[::_FEW_SAMPLE]
    enough = flux.size // _FEW_SHARE
    return np.count_nonzero(subset != subset[0]) >= enough and _distinct_count(subset) >= enough


def _distinct_count(values: np.ndarray) -> int:
    """``np.unique(values).size`` of a 1-d float array (NaNs one value, -0.0 and 0.0 one): its sort and a comparison
    of neighbours, as ``np.unique`` makes it, without ``np.unique``'s first call importing ``numpy.ma`` (~10 ms of
    the start, holding the interpreter lock)."""
    ordered = np.sort(values)
    numbers = ordered[~np.isnan(ordered)]                # NaNs sort last
    return int(numbers.size > 0) + np.count_nonzero(numbers[1:] != numbers[:-1]) + int(numbers.size < ordered.size)


def distinct_values(flux: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(flux, return_inverse=True)`` of a 1-d array, the same arrays; where all but a few values
    equal the first (a uniform background and the stamps' pixels) only those few are sorted (a sort of every
    pixel of a 1280 x 720 sensor took ~40 ms at the pixels' start), by ``np.unique``'s own sort and neighbour mask.
    Nonzero finite values are equal only when their bits are, so the distinct values are the same; zeros and
    non-finite values take ``np.unique``."""
    first = flux[0]
    other = flux != first
    rest = flux[other]
    if rest.size < flux.size // 16 and first != 0.0 and np.isfinite(first) and np.all(np.isfinite(rest)) \
            and not np.any(rest == 0.0):
        ordered = np.sort(np.append(rest, first))        # np.unique's sort and mask, without its numpy.ma import
        values = ordered[np.concatenate(([True], ordered[1:] != ordered[:-1]))]
        inverse = np.full(flux.size, np.searchsorted(values, first), np.intp)
        inverse[other] = np.searchsorted(values, rest)
        return values, inverse
    return np.unique(flux, return_inverse=True)
