"""Fresnel propagation of a point source through turbulence: paper Eq. 3-4 (Schmidt 2010, ch. 8-9).

Grids are ``N x N`` with the optical axis at index ``N // 2``; coordinates are
``(index - N // 2) * delta`` [m]. Fields are complex amplitudes whose squared modulus
is an irradiance in arbitrary but consistent units; the constant phase
``exp(i k dz)`` of each step is dropped (at GEO ``dz / lambda ~ 7e13`` cycles, beyond
float64 anyway, and it never affects an intensity).

**Precision.** Quadratic phases are evaluated from coefficients that never involve
differences of nearly equal numbers: the scaled angular-spectrum method's source and
observation chirps ``(1 - m_1)/dz_1`` and ``(m_n - 1)/(m_n dz_n)`` are rewritten exactly
as ``(delta_1 - delta_n) / (Z delta_1)`` and ``-(delta_1 - delta_n)/(Z delta_n)``, and the
point source's own curvature and the final collimation are merged into them
analytically, so a 36 000 km propagation keeps its phases to float64 precision.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from functools import lru_cache

import numba
import numpy as np
import scipy.fft as sfft
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic
from scipy.special import erf, fresnel


def grid_coordinates(n: int, delta: float) -> np.ndarray:
    """1-D coordinates ``(i - n//2) delta`` [m] of an ``n``-point axis."""
    return (np.arange(n) - n // 2) * delta


def chirp(coefficient: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``exp(i pi coefficient (x^2 + y^2))`` [1] for a coefficient in m^-2, separably (exact in float64)."""
    return np.outer(np.exp(1j * np.pi * coefficient * y**2), np.exp(1j * np.pi * coefficient * x**2))


def point_source_field(n: int, delta1: float, wavelength: float, distance: float, roi_diameter: float,
                       centre: tuple[float, float] = (0.0, 0.0), curvature: bool = True) -> np.ndarray:
    """Point-source field on the source plane, paper Eq. 3 in Schmidt's form (Schmidt 2010 Listing 9.5).

    ``U1 = exp(-i pi r1^2 / (lambda dz)) / D1^2 sinc((x1-xc)/D1) sinc((y1-yc)/D1) exp(-(|r1-rc|/4 D1)^2)``
    with ``D1 = lambda dz / D_roi``: a band-limited point whose vacuum Fresnel image is a
    uniform spherical wave over a ``D_roi``-wide region of the observation plane (the
    Gaussian window, Schmidt's, softens its edges). The paper's ``D`` is ``D_roi`` and its
    ``Phi`` an overall scale (we return unit scale: the observed field is ``~1/(lambda dz)``).

    ``centre`` = ``(xc, yc)`` [m] offsets the source. Its observed region stays centred on
    the axis and its wavefront carries the tilt ``-rc / dz`` of an off-axis source; the
    extra ``exp(i k rc^2/2dz) exp(-i k rc.r1/dz)`` factors printed in Eq. 3 would move the
    illuminated region to ``-rc`` instead, off a grid that only holds the aperture.

    With ``curvature=False`` the leading chirp is left out, for :func:`propagate` to apply
    it exactly as ``source_curvature=-distance``.
    """
    d1 = wavelength * distance / roi_diameter
    x = grid_coordinates(n, delta1)
    gx = np.sinc((x - centre[0]) / d1) * np.exp(-(((x - centre[0]) / (4 * d1)) ** 2)) / d1
    gy = np.sinc((x - centre[1]) / d1) * np.exp(-(((x - centre[1]) / (4 * d1)) ** 2)) / d1
    field = np.outer(gy, gx).astype(complex)
    if curvature:
        field *= chirp(-1.0 / (wavelength * distance), x, x)
    return field


def point_source_vacuum_field(x2: np.ndarray, y2: np.ndarray, wavelength: float, distance: float,
                              roi_diameter: float, collimated: bool = False) -> np.ndarray:
    """Exact Fresnel-diffracted field of :func:`point_source_field` (on axis) at (``x2``, ``y2``) [m].

    The source is separable, ``g(x) g(y)`` with ``g = sinc(x/D1) exp(-x^2/16 D1^2) / D1``, and
    its chirp cancels the Fresnel kernel's, so ``U2 = exp(i pi r2^2/(lambda dz)) / (i lambda dz)
    G(x2/lambda dz) G(y2/lambda dz)`` with ``G`` the Fourier transform of ``g``: a rectangle
    convolved with a Gaussian, ``G = [erf(4 pi x2/D_roi + 2 pi) - erf(4 pi x2/D_roi - 2 pi)] / 2``
    (Goodman 2005, *Introduction to Fourier Optics*, Eq. 4-17). ``collimated`` drops the
    spherical phase (the final factor of paper Eq. 4).
    """
    x2, y2 = np.asarray(x2, dtype=float), np.asarray(y2, dtype=float)

    def g(u):
        s = 4 * np.pi * u / roi_diameter
        return 0.5 * (erf(s + 2 * np.pi) - erf(s - 2 * np.pi))

    field = g(x2) * g(y2) / (1j * wavelength * distance)
    if not collimated:
        field = field * np.exp(1j * np.pi * (x2**2 + y2**2) / (wavelength * distance))
    return field


def square_aperture_vacuum_field(x2: np.ndarray, y2: np.ndarray, width: float, wavelength: float,
                                 distance: float) -> np.ndarray:
    """Fresnel diffraction of a unit plane wave by a ``width``-wide square (Goodman 2005 Eq. 4-53; Schmidt Eq. 1.60).

    The constant phase ``exp(i k dz)`` is dropped, as in :func:`propagate`.
    """
    scale = np.sqrt(2.0 / (wavelength * distance))

    def edge(u):
        s1, c1 = fresnel(-scale * (width / 2 + u))
        s2, c2 = fresnel(scale * (width / 2 - u))
        return (c2 - c1) + 1j * (s2 - s1)

    return edge(np.asarray(x2, dtype=float)) * edge(np.asarray(y2, dtype=float)) / (2j)


@lru_cache(maxsize=4)
def absorbing_boundary(n: int) -> np.ndarray:
    """Super-Gaussian window ``exp(-(r / 0.47 N)^16)`` [1] (Schmidt 2010 Listing 9.1); read-only, kept per ``n``."""
    i = np.arange(n) - n // 2
    r2 = i[:, None] ** 2 + i[None, :] ** 2
    window = np.exp(-((r2 / (0.47 * n) ** 2) ** 8))
    window.setflags(write=False)
    return window


@lru_cache(maxsize=4)
def _absorber_fft_order(n: int) -> np.ndarray:
    """:func:`absorbing_boundary` in the FFT's order (``ifftshift``), read-only."""
    window = sfft.ifftshift(absorbing_boundary(n))
    window.setflags(write=False)
    return window


def plane_spacings(delta1: float, deltan: float, z: Sequence[float]) -> np.ndarray:
    """Grid spacing [m] at the source and at each plane ``z``: linear in z (Schmidt 2010 Listing 9.1)."""
    z = np.r_[0.0, np.asarray(z, dtype=float)]
    alpha = z / z[-1]
    return (1 - alpha) * delta1 + alpha * deltan


def propagate(source: np.ndarray, wavelength: float, delta1: float, deltan: float, z: Sequence[float],
              screens: Mapping[int, np.ndarray] | None = None, source_curvature: float = np.inf,
              collimate: float = np.inf, absorber: bool = True, workers: int = -1,
              start: tuple[int, np.ndarray] | None = None, stop: int | None = None,
              window: int | None = None) -> np.ndarray:
    """Multi-plane angular-spectrum propagation, paper Eq. 4 (Schmidt 2010 Listing 9.1).

    ``source`` is sampled every ``delta1`` [m]; ``z`` [m] are the positions of the planes
    after the source (the last is the observation plane, sampled every ``deltan``).
    ``screens[i]`` is the phase [rad] applied at plane ``i`` (1-based; plane 0 is the
    source), sampled on that plane's grid (:func:`plane_spacings`).

    ``source_curvature`` ``R`` [m] multiplies the source by ``exp(i pi r^2 / (lambda R))``
    (``R = -Z`` for the point source of :func:`point_source_field` built without its chirp);
    ``collimate`` ``R_c`` [m] multiplies the result by ``exp(-i pi r^2 / (lambda R_c))``
    (the last factor of Eq. 4, ``R_c = Z`` for a point source). Both are merged exactly
    into the method's own chirps (module docstring).

    ``stop = k`` (``k >= 1``) returns the field on plane ``k`` before its screen and absorber, in the FFT's order
    (``ifftshift``'s); ``start = (k, u)`` goes on from such a field ``u`` made with the same arguments (``source``
    is then read only for its size): the same numbers as the whole (:func:`propagate_point_source`).

    ``window = w`` returns only the observation plane's centred ``w x w`` (rows and columns ``n // 2 - w // 2`` on):
    the same numbers as that part of the whole, for less (:func:`_observed_window`; without a screen on the
    observation plane).
    """
    n = source.shape[0]
    z = np.asarray(z, dtype=float)
    total = z[-1]
    delta = plane_spacings(delta1, deltan, z)
    steps = np.diff(np.r_[0.0, z])
    screens = screens or {}
    index = np.arange(n) - n // 2
    fused = fused_steps_agree()
    if start is None:
        # source plane: Q1 of Eq. 4 merged with the source curvature
        x1 = index * delta1
        coefficient = (delta1 - deltan) / (wavelength * total * delta1) + _inverse(source_curvature) / wavelength
        u = source * chirp(coefficient, x1, x1)
        if 0 in screens:
            u = _times(_phasor(screens[0]), u)
        # between the source and the observation plane the field is kept in the FFT's order (``ifftshift``): the
        # products below are element by element, so the screens and the absorber are put in that order instead of
        # the field being shifted back and forth at every step
        u = _padded(sfft.ifftshift(u))
        first = 0
    else:
        first, u = start
        if fused or first not in screens:           # the steps below work in place: not on the given field
            u = _padded(u)
    sg = _absorber_fft_order(n) if absorber else None
    transfer = _transfer_functions(n, float(wavelength), tuple(delta.tolist()), tuple(steps.tolist()),
                                   16 * n * n * len(steps) <= TRANSFER_CACHE_BYTES)
    for i, h in enumerate(transfer):
        if i + 1 < first:                           # in the field started from
            continue
        divide = i + 1 > first and i + 1 != stop
        if i + 1 > first:
            # Q2 of Eq. 4 on the frequencies of plane i
            u = sfft.fft2(u, workers=workers, overwrite_x=True)
            _times_rows(u, h)
            if window is not None and i + 1 == len(steps) and stop is None and i + 1 not in screens:
                return _observed_window(u, window, delta[i + 1] / delta[i], sg,
                                        _observation_coefficient(delta1, deltan, wavelength, total, collimate),
                                        deltan, workers)
            u = sfft.ifft2(u, workers=workers, overwrite_x=True)
            if not divide:
                u /= delta[i + 1] / delta[i]
                return np.ascontiguousarray(u)
        if fused:                                   # the division, the screen and the absorber in one pass
            _step(u, divide, delta[i + 1] / delta[i], *_screen_parts(screens.get(i + 1)),
                  _NO_ABSORBER if sg is None else sg, sg is not None)
            continue
        if divide:
            u /= delta[i + 1] / delta[i]
        if i + 1 in screens:
            u = _times(_phasor(screens[i + 1], shifted=True), u)
        if sg is not None:
            u *= sg
    # observation plane: Q3 of Eq. 4 merged with the collimation
    xn = index * deltan
    coefficient = _observation_coefficient(delta1, deltan, wavelength, total, collimate)
    field = _times(chirp(coefficient, xn, xn), sfft.fftshift(u))
    if window is None:
        return field
    corner = n // 2 - window // 2
    return field[corner:corner + window, corner:corner + window]


#: complex samples by which the propagation's field rows are longer than the field (:func:`_padded`)
ROW_PADDING = 4


def _padded(u: np.ndarray) -> np.ndarray:
    """A copy of the field ``u`` (n, m) as the first ``m`` columns of rows :data:`ROW_PADDING` samples longer: the
    same numbers, but an ``n = 256`` field's rows are no longer 4 KiB apart, so the columns' transforms (which read
    one sample a row) do not map every row to the same cache sets (~30 % less time for that pass; a transform's
    numbers do not depend on its input's strides). The padding is zero (:func:`_times_rows` multiplies it)."""
    rows = np.empty((u.shape[0], u.shape[1] + ROW_PADDING), dtype=complex)
    rows[:, u.shape[1]:] = 0.0
    out = rows[:, :u.shape[1]]
    out[...] = u
    return out


def _whole_rows(u: np.ndarray) -> np.ndarray | None:
    """The C-ordered array whose first columns ``u`` is (:func:`_padded`), or None where ``u`` is not such a view."""
    rows = u.base
    if (rows is None or rows.ndim != 2 or not rows.flags.c_contiguous or rows.shape[0] != u.shape[0]
            or u.strides != rows.strides or u.ctypes.data != rows.ctypes.data):
        return None
    return rows


def _times_rows(u: np.ndarray, h: np.ndarray) -> None:
    """``u *= h`` where both are views of padded rows of one length (:func:`_padded`, :func:`_transfer_functions`):
    the product over the whole rows, one contiguous pass (NumPy's loop over the views' rows took ~3x longer: 0.30
    against 0.09-0.11 ms for 256 x 256), the padding's zeros times zeros; the same product element by element, whose
    bits :func:`whole_rows_agree` checks once a process. Else ``u *= h``."""
    rows, factor = _whole_rows(u), _whole_rows(h)
    if rows is not None and factor is not None and rows.shape == factor.shape and whole_rows_agree():
        np.multiply(rows, factor, out=rows)
    else:
        u *= h


def _inverse_size(size: int) -> float:
    """``1 / size`` as pocketfft's ``norm_fct`` makes its scale: in long double, then rounded to double."""
    return float(np.longdouble(1) / np.longdouble(size))


def _observation_coefficient(delta1: float, deltan: float, wavelength: float, total: float,
                             collimate: float) -> float:
    """Q3 of Eq. 4 merged with the collimation: the observation plane's chirp coefficient [m^-2] (:func:`chirp`)."""
    return -(delta1 - deltan) / (wavelength * total * deltan) - _inverse(collimate) / wavelength


def _observed_window(spectrum: np.ndarray, window: int, ratio: float, absorber: np.ndarray | None,
                     coefficient: float, deltan: float, workers: int) -> np.ndarray:
    """The last step of :func:`propagate` from its ``spectrum`` (the last transform times its Q2, FFT order; it is
    overwritten) to the observation plane's centred ``window x window`` [rows, columns ``n // 2 - window // 2`` on],
    with the same numbers as the whole field's: ``ifft2`` is pocketfft's inverse transform of the columns, their
    values then times ``1 / n^2`` (:func:`_inverse_size`), then the rows' transform, each line alone (test), so only
    the window's rows take the second pass; the division by the spacings' ratio, the absorber
    (NumPy's products, which :func:`_step` matches: :func:`fused_steps_agree`) and Q3 of Eq. 4 (``coefficient``,
    :func:`_observation_coefficient`) are element by element, on the window only."""
    n = spectrum.shape[0]
    corner = n // 2 - window // 2
    lines = (np.arange(corner, corner + window) - n // 2) % n          # the window's rows and columns, FFT order
    columns = sfft.ifft(spectrum, axis=0, norm="forward", workers=workers, overwrite_x=True)   # unscaled
    rows = columns[lines]
    rows.view(np.float64)[...] *= _inverse_size(n * n)                # pocketfft's scale: both parts, times 1 / n^2
    u = sfft.ifft(rows, axis=1, norm="forward", workers=workers, overwrite_x=True)[:, lines]
    u /= ratio
    if absorber is not None:
        u *= absorber[np.ix_(lines, lines)]
    xw = (np.arange(corner, corner + window) - n // 2) * deltan
    return _times(chirp(coefficient, xw, xw), u)


def propagate_point_source(n: int, delta1: float, deltan: float, wavelength: float, distance: float,
                           roi_diameter: float, z: Sequence[float], screens: Mapping[int, np.ndarray],
                           collimate: float = np.inf, workers: int = -1, window: int | None = None) -> np.ndarray:
    """:func:`propagate` of :func:`point_source_field` (``curvature=False``, merged as ``source_curvature=-distance``)
    through ``screens``, with the absorber: the same numbers, with the steps before the first screen made once
    (``window``: only the centred ``window x window``, as :func:`propagate`).

    Those steps, the source plane and the vacuum up to the first screened plane, read nothing but the grid and
    the source (every frame of a path probe's bin shares them: ~5 ms of a 256-point grid's ~22): they are kept
    for the last two grids, under the transfer functions' rule (:data:`TRANSFER_CACHE_BYTES`)."""
    z = tuple(float(v) for v in z)
    first = min(screens, default=0)
    keep = 16 * n * n * len(z) <= TRANSFER_CACHE_BYTES
    arguments = (n, float(delta1), float(deltan), float(wavelength), float(distance), float(roi_diameter), z)
    if first < 1 or not keep:
        return propagate(_point_source(*arguments[:6]), wavelength, delta1, deltan, z, screens,
                         source_curvature=-distance, collimate=collimate, workers=workers, window=window)
    head = _vacuum_head(*arguments, first, workers)
    return propagate(head, wavelength, delta1, deltan, z, screens, source_curvature=-distance, collimate=collimate,
                     workers=workers, start=(first, head), window=window)


def _point_source(n: int, delta1: float, deltan: float, wavelength: float, distance: float,
                  roi_diameter: float) -> np.ndarray:
    return point_source_field(n, delta1, wavelength, distance, roi_diameter, curvature=False)


@lru_cache(maxsize=2)
def _vacuum_head(n: int, delta1: float, deltan: float, wavelength: float, distance: float, roi_diameter: float,
                 z: tuple[float, ...], first: int, workers: int) -> np.ndarray:
    """:func:`propagate_point_source`'s field on plane ``first`` before its screen (FFT order), read-only."""
    head = propagate(_point_source(n, delta1, deltan, wavelength, distance, roi_diameter), wavelength, delta1,
                     deltan, z, source_curvature=-distance, workers=workers, stop=first)
    head.setflags(write=False)
    return head


def _times(factor: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``factor * u`` written into ``factor`` (a temporary), in that order: NumPy's complex product is not
    commutative to the last bit, and this is the order in which its elision of temporaries computed
    ``u * np.exp(...)`` before (the same numbers)."""
    return np.multiply(factor, u, out=factor)


#: the transfer functions of the last two propagation plans are kept when they hold at most this many bytes
#: (every reference frame of a path probe's bin shares its grid) [bytes]
TRANSFER_CACHE_BYTES = 32 * 2**20


def _transfer_functions(n: int, wavelength: float, delta: tuple[float, ...], steps: tuple[float, ...],
                        keep: bool) -> Iterable[np.ndarray]:
    """Each step's Q2 of Eq. 4, ``exp(-i pi lambda dz f^2 / m)`` on the frequencies of its first plane, (n, n) in the
    FFT's order: with ``keep``, all of them, kept for the next calls (:data:`TRANSFER_CACHE_BYTES`); else made one
    at a time."""
    return _kept_transfer_functions(n, wavelength, delta, steps) if keep else _each_transfer_function(
        n, wavelength, delta, steps)


def _each_transfer_function(n: int, wavelength: float, delta: tuple[float, ...],
                            steps: tuple[float, ...]) -> Iterator[np.ndarray]:
    """Each step's Q2 (:func:`_transfer_functions`), read-only, in rows as long as the field's (:func:`_padded`, the
    padding zero: :func:`_times_rows`)."""
    delta = np.array(delta)                     # NumPy scalars below, as in the plan's own arithmetic
    for i, dz in enumerate(np.array(steps)):
        q2_axis = np.exp(-1j * np.pi * wavelength * dz / (delta[i] * delta[i + 1]) * sfft.fftfreq(n) ** 2)
        h = _padded(np.outer(q2_axis, q2_axis))
        h.base.setflags(write=False)
        h.setflags(write=False)
        yield h


@lru_cache(maxsize=2)
def _kept_transfer_functions(n: int, wavelength: float, delta: tuple[float, ...],
                             steps: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    return tuple(_each_transfer_function(n, wavelength, delta, steps))


def _phasor(phase: np.ndarray, shifted: bool = False) -> np.ndarray:
    """``exp(i phase)`` [1] from the sine and cosine of the phase rounded to single precision (NumPy's vectorised
    float32 ones: 10x faster than in double precision), scaled to unit modulus in double precision so that the
    propagation keeps its energy exactly: a phase error of ``|phase| x 6e-8`` rad (4e-6 rad at 60 rad), far below
    the screens' own (the pupil path rounds its phase to single precision too). ``shifted``: in the FFT's order
    (``ifftshift``'s), as the propagation keeps its field."""
    rounded = phase.astype(np.float32)
    out = np.empty(phase.shape, dtype=complex)
    _unit_phasors(np.cos(rounded), np.sin(rounded), phase.shape[0] // 2 if shifted else 0, out)
    return out


def _screen_parts(phase: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """The float32 cosine and sine of a screen's phase (NumPy's, as :func:`_phasor` takes them), ``ifftshift``'s
    shift, and whether there is a screen, for :func:`_step` (C-ordered whatever the screen's layout: one compiled
    signature)."""
    if phase is None:
        return _NO_SCREEN, _NO_SCREEN, 0, False
    rounded = np.ascontiguousarray(phase, dtype=np.float32)
    return np.cos(rounded), np.sin(rounded), phase.shape[0] // 2, True


@intrinsic
def _fma(typingctx, a, b, c):
    """``a b + c`` rounded once (LLVM's ``llvm.fma.f64``), as NumPy's vectorised complex product rounds its parts."""
    def codegen(context, builder, signature, args):
        double = ir.DoubleType()
        fma = builder.module.declare_intrinsic("llvm.fma", [double], ir.FunctionType(double, [double] * 3))
        return builder.call(fma, args)
    return types.float64(types.float64, types.float64, types.float64), codegen


@numba.njit(cache=True, nogil=True)
def _step(u, divide, ratio, cos, sin, shift, screened, absorber, absorbed):
    """One pass over the field ``u`` (FFT order) for what :func:`propagate` does after a step's transforms, with
    NumPy's roundings: ``u /= ratio`` (NumPy's complex division by ``ratio + 0i``: times ``1 / ratio``, Smith's
    form), then with ``screened`` ``u = phasor * u`` (:func:`_phasor`'s unit phasor of ``cos`` and ``sin`` at
    ``ifftshift``'s ``shift``, :func:`_unit_phasors`; NumPy's complex product ``(a_r b_r - a_i b_i, a_r b_i + a_i
    b_r)`` with one rounding per fused multiply-add), then with ``absorbed`` ``u *= absorber`` (a product with
    ``absorber + 0i``). :func:`fused_steps_agree` checks the bits against NumPy's steps once per process."""
    n = u.shape[0]
    ratio_i = 0.0
    rat = ratio_i / ratio
    scale = 1.0 / (ratio + ratio_i * rat)
    for i in range(n):
        row = (i + shift) % n
        for j in range(n):
            ur = u[i, j].real
            ui = u[i, j].imag
            if divide:
                ur, ui = (ur + ui * rat) * scale, (ui - ur * rat) * scale
            if screened:
                column = j + shift if j + shift < n else j + shift - n
                c = np.float64(cos[row, column])
                s = np.float64(sin[row, column])
                modulus = np.sqrt(c * c + s * s)
                pr = c / modulus
                pi = s / modulus
                ur, ui = _fma(pr, ur, -(pi * ui)), _fma(pr, ui, pi * ur)
            if absorbed:
                a = absorber[i, j]
                ur, ui = _fma(ur, a, -(ui * 0.0)), _fma(ur, 0.0, ui * a)
            u[i, j] = complex(ur, ui)


_NO_SCREEN = np.empty((0, 0), np.float32)
_NO_ABSORBER = np.empty((0, 0))
_NO_ABSORBER.setflags(write=False)            # the absorber's type: read-only (one compiled signature)


@lru_cache(maxsize=1)
def fused_steps_agree(n: int = 33) -> bool:
    """Whether :func:`_step` gives NumPy's steps' numbers bit for bit here (NumPy's complex product uses fused
    multiply-adds where the machine has them): checked once per process on a random field, screen and absorber
    of an odd size, each step alone and together; :func:`propagate` makes its steps with NumPy where not."""
    rng = np.random.default_rng(20251126)
    field = rng.normal(0.0, 1.0, (n, n)) + 1j * rng.normal(0.0, 1.0, (n, n))
    phase = rng.normal(0.0, 30.0, (n, n))
    absorber = np.fft.ifftshift(absorbing_boundary(n)).copy()
    absorber.setflags(write=False)
    ratio = 1.0 + rng.uniform()
    # the phasor as _unit_phasors makes it, in NumPy (tests/optics: the same numbers)
    cos, sin, shift, _ = _screen_parts(phase)
    c, s = np.fft.ifftshift(cos).astype(float), np.fft.ifftshift(sin).astype(float)
    modulus = np.sqrt(np.square(c) + np.square(s))
    phasor = c / modulus + 1j * (s / modulus)
    for divide, screened, absorbed in ((True, False, False), (False, True, False), (False, False, True),
                                       (True, True, True)):
        expected = field.copy()
        if divide:
            expected /= ratio
        if screened:
            expected = np.multiply(phasor, expected, out=phasor.copy())
        if absorbed:
            expected *= absorber
        got = _padded(field)                       # the field's layout in propagate: one compiled signature
        try:
            _step(got, divide, ratio, cos if screened else _NO_SCREEN, sin if screened else _NO_SCREEN,
                  shift if screened else 0, screened, absorber if absorbed else _NO_ABSORBER, absorbed)
        except Exception:                          # pragma: no cover - a Numba that cannot compile it: NumPy's steps
            return False
        if not np.array_equal(got.view(np.uint64), expected.view(np.uint64)):
            return False
    return True


@lru_cache(maxsize=1)
def whole_rows_agree(n: int = 33) -> bool:
    """Whether NumPy's complex product over whole padded rows (:func:`_times_rows`) gives its product over the rows'
    first columns bit for bit here (the loops for contiguous and strided arrays are NumPy's to choose): checked once
    a process on a random field and factor of an odd size."""
    rng = np.random.default_rng(20261127)
    field = rng.normal(0.0, 1.0, (n, n)) + 1j * rng.normal(0.0, 1.0, (n, n))
    factor = np.exp(1j * rng.uniform(-np.pi, np.pi, (n, n)))
    expected, got, rows = _padded(field), _padded(field), _padded(factor)
    expected *= rows
    np.multiply(got.base, rows.base, out=got.base)
    return bool(np.array_equal(got.view(np.uint64), expected.view(np.uint64)))


@numba.njit(cache=True, nogil=True)
def _unit_phasors(cos, sin, shift, out):
    """``out[i, j] = (c + i s) / sqrt(c^2 + s^2)`` in double precision from the float32 ``cos`` and ``sin`` at
    ``((i + shift) % n, (j + shift) % n)`` (``shift = n // 2``: ``ifftshift``'s order), each step rounded as numpy's
    ``square``, ``+=``, ``sqrt`` and ``/=`` round it (no fused multiply-add): the same numbers, in one pass."""
    n = cos.shape[0]
    for i in range(n):
        row = (i + shift) % n
        for j in range(n):
            column = j + shift if j + shift < n else j + shift - n
            c = np.float64(cos[row, column])
            s = np.float64(sin[row, column])
            modulus = np.sqrt(c * c + s * s)
            out[i, j] = complex(c / modulus, s / modulus)


def _inverse(radius: float) -> float:
    return 0.0 if np.isinf(radius) else 1.0 / radius
