"""Photodiode dark current versus temperature (paper Eq. 15, in its Arrhenius form).

The paper prints Eq. 15 as ``ln I_dark = constant - E_a A_pix / (k T^4)``, citing the
measurements of Nozaki & Delbruck (2017, IEEE TED 64(8):3239) and calling it "the linear
relationship [of ln I_dark] with the reciprocal temperature". The printed right-hand side
is not dimensionless (``E_a / kT`` is; ``A_pix / T^3`` is not) and is not linear in 1/T,
so it cannot be what was fitted. What a plot of ``ln I_dark`` against ``1/T`` with slope
``-E_a/k`` describes is the Arrhenius law

    I_dark(T) = J_dark(T_ref) A_pix exp[-(E_a / k) (1/T - 1/T_ref)]

in which the pixel area enters where it belongs, through the area-proportional dark
current density ``J_dark``. That is the form used here. The activation energy sets how
fast cooling pays off: the dark current halves every
``Delta T_1/2 ~ ln 2 k T^2 / E_a`` kelvin near ``T``. The default ``E_a = 0.56 eV`` is half
the silicon band gap, the activation energy of depletion-region (generation) dark current
that dominates silicon photodiodes near room temperature (Widenhorn et al. 2001,
J. Appl. Phys. 89:8179; diffusion current, dominant when hot, has ``E_a ~ E_g = 1.12 eV``);
it halves the dark current for ~10 K of cooling at 300 K. The paper takes ``E_a`` from Nozaki &
Delbruck's measurements without quoting it (their figures could not be consulted for this
code); fit ``E_a`` and ``J_dark`` to the sensor at hand for quantitative work.

In the paper's model temperature acts only through ``I_dark``: it dilutes the contrast of a
faint source (``ln(1 + I_s / I_dark)``), sets the shot-noise level of a dark pixel through
``I/I_max`` in Eq. 20, and, with the proportional cutoff law, the dark bandwidth. The
junction leak of Eq. 18 is temperature-independent (paper Sec. 2.4).
"""

from __future__ import annotations

import numpy as np

# exact by definition of the SI since 2019 (BIPM, The International System of Units, 9th ed., Table 1): written out,
# not read from scipy.constants, whose CODATA tables cost ~7 ms of every run's start (the same floats)
BOLTZMANN_J_PER_K = 1.380649e-23                   # k [J K^-1]
ELEMENTARY_CHARGE_C = 1.602176634e-19              # e [C]
BOLTZMANN_EV_PER_K = BOLTZMANN_J_PER_K / ELEMENTARY_CHARGE_C     # k [eV K^-1]


def dark_current_A(temperature_K, density_A_m2: float, pixel_area_m2: float,
                   reference_temperature_K: float, activation_energy_eV: float):
    """Dark current of one pixel at ``temperature_K`` (Arrhenius form of paper Eq. 15) [A]."""
    t = np.asarray(temperature_K, dtype=float)
    arrhenius = np.exp(-activation_energy_eV / BOLTZMANN_EV_PER_K * (1.0 / t - 1.0 / reference_temperature_K))
    return density_A_m2 * pixel_area_m2 * arrhenius


def halving_cooling_K(temperature_K: float, activation_energy_eV: float) -> float:
    """Cooling that halves the dark current near ``temperature_K``: ``ln 2 k T^2 / E_a`` [K]."""
    return float(np.log(2.0) * BOLTZMANN_EV_PER_K * temperature_K**2 / activation_energy_eV)
