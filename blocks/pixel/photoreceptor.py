"""Photoreceptor: photon flux to photocurrent to the lin-log response (paper Eq. 12-14).

Unit convention
---------------
The paper (and v2e, from which it inherits Eqs. 14, 16 and 20) works with currents on a
dimensionless "digital number" scale: the lin-log knee at 5, ``I_max = ln 255 = 5.54``.
evsda keeps the physics in amperes and makes that scale explicit: every current that
enters Eqs. 14, 16 and 20 is the *normalised current*

    x = (I_p + I_dark) / I_ref

where ``I_ref`` (``reference_current_A``) is a stated reference current: one unit of the
paper's scale. With the defaults (knee 5, ``I_max = ln 255``, ``I_ref`` = 1 fA) the paper's
behaviour is reproduced exactly on that scale; changing ``I_ref`` moves the knee and the
saturation of the noise model in amperes without touching the log-domain thresholds.

Where the knee sits
-------------------
A DVS photoreceptor (the adaptive logarithmic photoreceptor of Delbruck & Mead 1994, the
front end of every sensor since Lichtsteiner et al. 2008) responds to the logarithm of the
total current through its photodiode, ``ln(I_p + I_dark)``, down to the dark current: the
dark current is itself the floor, and a source adds contrast ``ln(1 + I_s/I_dark)``, linear in
``I_s`` for faint sources without any knee. The paper's knee at ``5 I_ref`` (1 fA scale) sits
above the dark current of the small pixels of modern sensors (0.24 fA for a 4.86 um pixel at
1 nA/cm^2), where it makes the response linear with a fixed slope that cooling cannot
improve. ``knee_at_dark_current`` (set by every sensor preset) uses the logarithm for every
current when the dark current is positive; the linear piece then only serves a pixel with no
dark current at all (paper Fig. 5a).
"""

from __future__ import annotations

import numpy as np

from .dark_current import ELEMENTARY_CHARGE_C      # q [C]

# exact by definition of the SI since 2019 (BIPM, The International System of Units, 9th ed., Table 1)
PLANCK_J_S = 6.62607015e-34              # h [J s]
SPEED_OF_LIGHT_M_S = 299792458.0         # c [m s^-1]


def photon_energy_J(wavelength_m: float) -> float:
    """Energy of one photon, ``h c / lambda`` [J]."""
    return PLANCK_J_S * SPEED_OF_LIGHT_M_S / wavelength_m


def optical_power_W(photon_flux, wavelength_m: float):
    """Optical power carried by ``photon_flux`` [photon s^-1] at ``wavelength_m`` [W]."""
    return np.asarray(photon_flux, dtype=float) * photon_energy_J(wavelength_m)


def responsivity_A_per_W(quantum_efficiency: float, wavelength_m: float) -> float:
    """Paper Eq. 12: ``R = eta q / (h f) = eta q lambda / (h c)`` [A W^-1].

    The paper's shortcut ``eta lambda / 1.23985`` (lambda in micrometres) is the same
    expression with ``h c / q = 1.23985 um V``.
    """
    return quantum_efficiency * ELEMENTARY_CHARGE_C * wavelength_m / (PLANCK_J_S * SPEED_OF_LIGHT_M_S)


def photocurrent_A(power_W, responsivity: float):
    """Paper Eq. 13: ``I_p = R Phi`` [A] for an optical power ``Phi`` [W]."""
    return responsivity * np.asarray(power_W, dtype=float)


def log_response(x):
    """Eq. 14 without the linear piece: ``Y = ln x`` for a normalised current ``x > 0`` [1]."""
    return np.log(np.asarray(x, dtype=float))


def lin_log(x, knee: float = 5.0):
    """Paper Eq. 14: the photoreceptor's log response, linearised below ``knee`` [1].

    ``x`` is the normalised current (see the module docstring). Below the knee the
    response is the straight line ``x ln(knee) / knee``, which meets ``ln x`` at
    ``x = knee``: the paper prints the condition as ``I_p < ln 5`` but the slope
    ``ln(5)/5`` only makes the two pieces meet at ``I_p = 5``, which is v2e's
    ``lin_log`` (knee 20 there). The line keeps a current decaying to zero from
    producing an unbounded train of OFF events (paper Fig. 5a).
    """
    x = np.asarray(x, dtype=float)
    linear = x * (np.log(knee) / knee)
    with np.errstate(divide="ignore"):
        log = np.log(np.maximum(x, knee))
    return np.where(x < knee, linear, log)
