"""The photoreceptor's intensity-dependent low-pass filter (paper Eq. 16).

A DVS photoreceptor has a bandwidth that grows with the photodiode current up to a
maximum set by its amplifier, about 3 kHz for the DVS128 (Lichtsteiner, Posch &
Delbruck 2008, IEEE JSSC 43(2):566). The paper discretises the one-pole filter with
the backward-Euler (always stable) gain

    eps = 2 pi dt f_3dB / (2 pi dt f_3dB + 1),     L <- (1 - eps) L + eps Y

applied, as in v2e, to the lin-log value ``Y`` of Eq. 14 (the photoreceptor output is a
voltage proportional to the log current; its bandwidth limit acts on that voltage).

Three cutoff laws:

* ``paper`` -- Eq. 16 as printed, ``f_3dB = (Y + 3) / 5.616 f_max`` with ``Y`` the lin-log
  input (the constants are v2e's ``(DN + 20) / 275`` carried to log units: ln 20 = 3.0,
  ln 275 = 5.616), capped at ``f_max``, the maximum the paper states. It varies only by a
  factor ~2 from dark to bright.
* ``proportional`` -- v2e's law in physical form: ``f_3dB = f_max min(1, x / x_sat)`` with
  ``x`` the normalised total (photo + dark) current. The bandwidth then falls in proportion
  to the current in the dark, so cooling, by lowering the dark current, also lowers the
  dark-pixel bandwidth.
* ``power`` -- ``f_3dB = f_max min(1, (x / x_sat)^n)``. The DVS128's measured bandwidth curves
  (Lichtsteiner et al. 2008, "fast" biases: events per cycle of a sinusoidal stimulus at 0, -1,
  -2, -3 decades of light) fall to zero at ~2.5-3 kHz, ~2 kHz, ~700 Hz and ~200 Hz: 3.2x per
  decade of light, ``n = 0.5``. That is the second-order photoreceptor of Graca & Delbruck 2021
  (the photodiode node's pole goes as the photocurrent, the amplifier's as its bias current;
  their geometric mean sets the cutoff while the two are apart); the resonant peaking of the
  second-order response is left out of this one-pole filter.

Two forms of the filter (``lowpass_form``):

* ``small_signal`` -- Eq. 16 as printed: the one-pole filter on ``L`` itself.
* ``large_signal`` -- the same filter on ``w = e^-L`` towards ``e^-Y``. The first-order
  logarithmic photoreceptor (Delbruck & Mead 1994, "Analog VLSI phototransduction by
  continuous-time, adaptive, logarithmic photoreceptor circuits"; Liu, Kramer, Indiveri,
  Delbruck & Douglas 2002, *Analog VLSI: Circuits and Principles*, ch. 13) charges its node
  ``V`` (in units of ``U_T / kappa``) with the photocurrent and discharges it through the
  feedback transistor's subthreshold current: ``C dV/dt = I - I_0 e^V``. With ``u = ln(I/I_0)``
  and ``a = I / C`` this is ``dV/dt = a (1 - e^(V - u))``, and in ``w = e^-V`` it is linear:
  ``dw/dt = -a (w - e^-u)``, a one-pole low-pass whose rate is the input current's, the cutoff
  law above. Near equilibrium (``|V - u|`` small) it is the small-signal form; on a large
  falling step ``V`` starts falling at ``(I_before - I)/C``, the speed of the current the node
  carried, not of the current it now gets (the first OFF event of a light turned off comes at
  about the bright speed, as NIST measure); on a large rising step it rises at most at ``a``
  per unit ``V`` (slew), slower than the small-signal form's ``a (u - V)``. Discretised with
  the same backward-Euler gain: ``w <- (1 - eps) w + eps e^-Y``.
"""

from __future__ import annotations

import numpy as np

PAPER_OFFSET = 3.0        # Eq. 16 "+3" (ln 20 of v2e's DN offset) [1]
PAPER_SCALE = 5.616       # Eq. 16 "/5.616" (ln 275 of v2e's DN normaliser) [1]


def cutoff_hz(x, y, max_hz: float, model: str = "paper", saturation: float = 275.0, exponent: float = 1.0):
    """3 dB cutoff of the photoreceptor (paper Eq. 16) [Hz].

    ``x`` is the normalised current and ``y = lin_log(x)``; ``saturation`` is the
    normalised current at which the ``proportional`` and ``power`` laws reach ``max_hz``;
    ``exponent`` is the ``power`` law's.
    """
    if model == "paper":
        f = (np.asarray(y, dtype=float) + PAPER_OFFSET) / PAPER_SCALE * max_hz
    elif model == "proportional":
        f = np.asarray(x, dtype=float) / saturation * max_hz
    elif model == "power":
        f = np.power(np.asarray(x, dtype=float) / saturation, exponent) * max_hz
    else:
        raise ValueError(f"unknown cutoff model {model!r}; expected 'paper', 'proportional' or 'power'")
    return np.clip(f, 0.0, max_hz)


def filter_gain(cutoff, dt_s: float):
    """Backward-Euler gain ``eps`` of paper Eq. 16 for a step ``dt_s`` [1].

    A cutoff of ``inf`` (no filter) gives ``eps = 1``: the output follows the input.
    """
    w = 2.0 * np.pi * dt_s * np.asarray(cutoff, dtype=float)
    with np.errstate(invalid="ignore"):
        eps = w / (w + 1.0)
    return np.where(np.isinf(w), 1.0, eps)


def log_retention(eps):
    """``ln(1 - eps)``: after ``j`` steps at constant input ``L - Y`` is multiplied by ``exp(j ln(1 - eps))``."""
    eps = np.asarray(eps, dtype=float)
    with np.errstate(divide="ignore"):
        return np.log1p(-eps)


def large_signal_step(filtered, y, eps):
    """One backward-Euler step of the large-signal filter: ``e^-L <- (1 - eps) e^-L + eps e^-Y`` [1].

    Written relative to the target, ``L - Y <- -ln(eps + (1 - eps) e^(Y - L))``, so that ``e^-L``
    neither overflows nor underflows (``Y - L`` is clipped to +-700: a step of e^700 is no current).
    """
    filtered, y, eps = (np.asarray(v, dtype=float) for v in (filtered, y, eps))
    return y - np.log(eps + (1.0 - eps) * np.exp(np.clip(y - filtered, -700.0, 700.0)))
