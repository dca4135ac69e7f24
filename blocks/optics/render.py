"""PSF to detector pixels: stamps integrated over pixels at sub-pixel source positions.

A stamp is ``size x size`` pixels around a source at column ``x``, row ``y`` (pixel
centres at integers, :mod:`evsda.blocks.ports.core`). Its first pixel is at
``(round(x) - size//2, round(y) - size//2)`` and the source sits at the sub-pixel offset
``x - round(x)`` from the stamp's central pixel.

* :class:`PupilRenderer` integrates the far field of a sampled pupil over each pixel
  exactly (a finite Fourier series integrated term by term).
* :class:`RadialRenderer` integrates a tabulated radial PSF (analytic Airy, long
  exposure) by the midpoint rule on ``oversample x oversample`` sub-pixels. With
  sub-pixels no wider than ``lambda / 2D`` (the Nyquist interval of the band-limited
  intensity) the sum over all sub-pixels equals the PSF's integral (Poisson summation),
  so flux is conserved; within a pixel the rule's error, about
  ``0.03 (sub-pixels per lambda/2D)^-2`` of the flux, is tested against finer sampling.

Values are fractions of the power incident on the collecting area [1]; multiply by the
photon flux [photon s^-1 m^-2], the collecting area [m^2] and the throughput to get
[photon s^-1 pixel^-1].
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, cached_property

import threading

import numba
import numpy as np
import scipy.fft as sfft
from llvmlite import ir
from numba.extending import intrinsic

from . import column_fft


@dataclass(frozen=True)
class StampSampler:
    """Stamp size [pixel], pixel scale [rad] and sub-pixels per pixel along each axis."""

    size: int
    pixel_scale_rad: float
    oversample: int

    @cached_property
    def angles(self) -> np.ndarray:
        """Sub-pixel centre angles [rad] along one axis, relative to the central pixel's centre."""
        q = self.oversample
        sub = (np.arange(self.size * q) + 0.5) / q - 0.5 - self.size // 2
        return sub * self.pixel_scale_rad

    def bin(self, intensity: np.ndarray) -> np.ndarray:
        """Pixel energies [1] from intensities [sr^-1] at the sub-pixels, ``(..., Mq, Mq) -> (..., M, M)``."""
        m, q = self.size, self.oversample
        shape = intensity.shape[:-2]
        summed = intensity.reshape(*shape, m, q, m, q).sum(axis=(-3, -1))
        return summed * (self.pixel_scale_rad / q) ** 2


def oversampling_for(pixel_scale_rad: float, diameter_m: float, wavelength_m: float, per_nyquist: float = 1.0) -> int:
    """Sub-pixels per pixel so that ``per_nyquist`` of them fit in ``lambda / 2D`` (the intensity's Nyquist interval)."""
    return max(1, int(np.ceil(per_nyquist * pixel_scale_rad / (wavelength_m / (2 * diameter_m)) - 1e-9)))


def stamp_placement(x_px: np.ndarray, y_px: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Stamp origins ``(x0, y0)`` [pixel, int32] and source offsets from the central pixel [pixel].

    Returns ``origin`` of shape ``(..., 2)`` and ``offset`` of shape ``(..., 2)``, both (x, y).
    NaN positions give origin ``(0, 0)`` and offset 0 (their stamps are left empty).
    """
    xy = np.stack([np.asarray(x_px, dtype=float), np.asarray(y_px, dtype=float)], axis=-1)
    finite = np.isfinite(xy)
    centre = np.round(np.where(finite, xy, 0.0))
    origin = (centre - size // 2).astype(np.int32)
    return origin, np.where(finite, xy - centre, 0.0)


class PupilRenderer:
    """Stamps from pupil fields, integrated over the pixels exactly.

    The far field of a pupil sampled every ``delta`` is a finite Fourier series,
    ``|E(theta)|^2 = (delta^4 / lambda^2) sum_k C_k exp(-2 pi i k delta . theta / lambda)``, whose
    coefficients ``C_k = sum_m P_(m+k) P*_m`` are the pupil's autocorrelation (the OTF;
    Goodman 2005 Sec. 6.3). Each term integrates over a pixel in closed form,
    ``p^2 sinc(f_x p) sinc(f_y p) exp(-2 pi i f . theta_c)`` with ``f = k delta / lambda``, so the
    stamps are exact pixel integrals with no sub-pixel sampling. ``C`` is the inverse DFT
    of the PSF sampled by a zero-padded FFT (``L >= 2n - 1`` points, no aliasing), so the
    two steps fold into one fixed matrix ``B = A W / L`` applied to that PSF along both axes:
    ``stamp = B PSF B^T``. ``B`` is real: ``C``'s lags ``|k| <= n - 1`` lie strictly inside
    ``|k| < L / 2``, so the terms pair up as ``+-k`` into cosines (an even ``L``'s Nyquist lag
    carries no term). The source's sub-pixel offset becomes a tilt across the pupil, which keeps
    ``B`` fixed.
    """

    def __init__(self, sampler: StampSampler, n_pupil: int, delta_m: float, wavelength_m: float,
                 area_m2: float, dtype=np.complex64):
        self.sampler, self.n, self.delta, self.wavelength, self.area = sampler, n_pupil, delta_m, wavelength_m, area_m2
        self.x = (np.arange(n_pupil) - n_pupil // 2) * delta_m
        self.r2 = self.x[None, :] ** 2 + self.x[:, None] ** 2                 # r^2 [m^2] on the pupil grid (y, x)
        size = sfft.next_fast_len(2 * n_pupil)
        self.padded = size
        lags = sfft.fftfreq(size) * size                                 # FFT order
        f = lags * delta_m / wavelength_m                                # [cycles rad^-1]
        p = sampler.pixel_scale_rad
        centres = (np.arange(sampler.size) - sampler.size // 2) * p
        # C's lags are |k| <= n - 1 < L / 2: an even L's Nyquist lag -L/2 holds no term (zero weight), and the
        # sum over the symmetric lags left, p sinc(f p) cos(2 pi k (j / L - delta theta_c / lambda)), is real
        weight = np.where(np.abs(lags) < size / 2, p * np.sinc(f * p), 0.0)
        a = weight[None, :] * np.exp(-2j * np.pi * np.outer(centres, f))
        b = (a @ np.exp(2j * np.pi * np.outer(lags, np.arange(size)) / size) / size).real
        self.b = b.astype(np.float32 if dtype == np.complex64 else np.float64)
        # its transpose stored contiguous: numpy's batched matmul with a transposed (strided) right operand
        # took 2.3x longer per frame (the same products, the same bits)
        self.b_t = np.ascontiguousarray(self.b.T)
        self.dtype = dtype
        self._local = threading.local()
        # where the pupil fills the first half of an 80-point single-precision FFT exactly (the tracked pass's 40
        # samples), each frame goes from its phase to its stamp in one compiled call (:func:`_stamp_frames`: the
        # tilted phase's sine and cosine, :mod:`.column_fft`'s passes, then ``B PSF B^T`` through Numba's ``np.dot``;
        # no interpreter between the steps, no interpreter lock held) where that gives numpy's and pocketfft's bits
        # (:func:`_sincos_agree`, :meth:`_frames_agree`)
        fits = size == column_fft.LENGTH and dtype == np.complex64
        self._frames = self._columns = self._rows = False
        self._frames = fits and 2 * n_pupil == size and _sincos_agree() and self._frames_agree()
        # elsewhere (and for fields given whole, :meth:`stamps_from_field`) chunk by chunk: the compiled transforms
        # along y where they reproduce pocketfft's bits, the pupil's rows within the first half (the same passes as
        # the frames' where those agree), and along x where the pupil fills it
        self._columns = fits and 2 * n_pupil <= size and (self._frames or _compiled_columns_agree())
        self._rows = self._columns and 2 * n_pupil == size

    def _workspace(self, frames: int) -> tuple[np.ndarray, ...]:
        """This thread's buffers for a chunk of ``frames <= STAMP_CHUNK`` frames (sources render on several threads):
        the padded spectra (F, L, L), whose rows ``n:`` stay zero between chunks (or are not read), their PSFs
        (F, L, L) and ``PSF B^T`` (F, L, M)."""
        buffers = getattr(self._local, "chunk", None)
        if buffers is None:
            size, m, real, c = self.padded, self.sampler.size, self.b.dtype, STAMP_CHUNK
            buffers = self._local.chunk = (aligned_zeros((c, size, size), self.dtype),
                                           aligned_empty((c, size, size), real), aligned_empty((c, size, m), real))
            self._local.scratch = aligned_empty((4, size * size), np.float32)
        return tuple(b[:frames] for b in buffers)

    def _per_frame(self, frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """This thread's buffers for ``frames <= PHASE_FRAMES`` frames: the tilted phase's cosine and sine (F, n, n)
        and the stamps in the renderer's precision (F, M, M)."""
        buffers = getattr(self._local, "frames", None)
        if buffers is None:
            n, m, real, c = self.n, self.sampler.size, self.b.dtype, PHASE_FRAMES
            buffers = self._local.frames = (aligned_empty((c, n, n), real), aligned_empty((c, n, n), real),
                                            aligned_empty((c, m, m), real))
        return tuple(b[:frames] for b in buffers)

    def _frame_buffers(self) -> tuple[np.ndarray, ...]:
        """This thread's buffers for :func:`_stamp_frames`, one frame: the tilted phase's cosine and sine (n, n)
        float32, the rows' spectra (6400,) float32, the PSF (L, L), ``PSF B^T`` (L, M), the stamp (M, M) in the
        renderer's precision and the passes' scratch (4, L^2)."""
        buffers = getattr(self._local, "one_frame", None)
        if buffers is None:
            n, size, m, real = self.n, self.padded, self.sampler.size, self.b.dtype
            buffers = self._local.one_frame = (aligned_empty((n, n), np.float32), aligned_empty((n, n), np.float32),
                                               aligned_empty(size * size, np.float32),
                                               aligned_empty((size, size), real), aligned_empty((size, m), real),
                                               aligned_empty((m, m), real), aligned_empty((4, size * size), np.float32))
        return buffers

    def _frames_agree(self) -> bool:
        """Whether :func:`_stamp_frames` gives, on random phases, defocus and offsets (once a renderer), the bits of the
        chunked path's steps through numpy and scipy: the tilted phase (numpy's broadcast sums, transposed) rounded
        to float32, numpy's ``sin`` and ``cos``, scipy's pocketfft transforms (padded
        rows, then columns), numpy's float32 ``|.|^2`` and ``matmul`` products and the float64 scale. Its products are
        BLAS's ``sgemm`` as Numba calls it (scipy's BLAS), which must give numpy's (its own BLAS) sums."""
        rng = np.random.default_rng(3)
        frames, n, size = 5, self.n, self.padded
        amplitude_t = rng.uniform(0.0, 1.0, (1, n, n)).astype(np.float32)
        phase_t = rng.uniform(-30.0, 30.0, (frames, n, n))
        curvature, ky, kx = rng.uniform(-1e5, 1e5, (3, frames))
        x, column = self.x[None, None, :], (slice(None), None, None)
        tilted = ((((phase_t + curvature[column] * self.r2[None]) + ky[column] * x) + kx[column] * x.transpose(0, 2, 1))
                  .astype(np.float32))
        field_t = (np.cos(tilted) + 1j * np.sin(tilted)).astype(np.complex64) * amplitude_t
        grid = np.zeros((frames, size, size), np.complex64)
        grid[:, :n, :n] = field_t.transpose(0, 2, 1)
        _fft(grid[:, :n], 2)
        _fft(grid, 1)
        image = np.matmul(self.b, np.matmul(grid.real**2 + grid.imag**2, self.b_t))
        expected = np.empty((frames, self.sampler.size, self.sampler.size))
        self._scale(image, expected)
        out = np.empty_like(expected)
        try:
            within = _stamp_frames(phase_t, curvature, self.r2, ky, kx, self.x, amplitude_t, self.b, self.b_t,
                                   (self.delta**2 / self.wavelength) ** 2, float(self.area), out,
                                   *self._frame_buffers(), *column_fft.TWIDDLES)
        except Exception:                 # noqa: BLE001 -- no BLAS for Numba's np.dot: the chunked path then
            return False
        return within and bool(np.array_equal(expected.view(np.uint64), out.view(np.uint64)))

    def tilt(self, offset_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Separable pupil factors ``exp(i k theta . r)`` (F, n) along y and x moving the image by ``offset_px``."""
        theta = np.asarray(offset_px, dtype=float) * self.sampler.pixel_scale_rad
        k = 2 * np.pi / self.wavelength
        ex = np.exp(1j * k * theta[:, 0, None] * self.x[None, :]).astype(self.dtype)
        ey = np.exp(1j * k * theta[:, 1, None] * self.x[None, :]).astype(self.dtype)
        return ey, ex

    def stamps(self, amplitude: np.ndarray, phase: np.ndarray, offset_px: np.ndarray,
               curvature_rad_m2: np.ndarray | None = None) -> np.ndarray:
        """Pixel energy fractions ``(F, M, M)`` from pupil ``amplitude`` (n, n) or (F, n, n) and ``phase`` (F, n, n)
        [rad] (any strides) plus, if given, a defocus ``curvature_rad_m2 r^2`` (F,) [rad m^-2].

        The defocus and the sub-pixel offset's tilt are added to the phase before ``exp(i phase)`` (one
        complex field, no separate tilt products), written straight into the padded spectra's buffer.
        """
        phase = np.asarray(phase, dtype=float)
        amplitude, curvature, ky, kx = self._inputs(amplitude, offset_px, curvature_rad_m2, len(phase))
        out = np.empty((len(phase), self.sampler.size, self.sampler.size))
        if self._rows:
            # transposed (x, y) for the compiled row transforms: the screens' sum as it is made (no copy then) and the
            # amplitude
            phase_t = np.ascontiguousarray(phase.transpose(0, 2, 1))
            amplitude_t = _transposed(amplitude)
            # every frame from its phase to its stamp in one compiled call, unless a tilted phase is beyond the
            # compiled sine's range (or NaN): then block by block below
            if self._frames and _stamp_frames(phase_t, *self._frame_arguments(amplitude_t, curvature, ky, kx, out)):
                return out
        for block in _chunks(len(phase), PHASE_FRAMES):
            cosine, sine, image = self._per_frame(block.stop - block.start)
            # numpy's cos and sin of the tilted phase (rounded to single precision) on contiguous buffers, the
            # block's frames at once, transposed (x, y) for the compiled row transforms (in one compiled pass with
            # numpy's float32 sin and cos where they agree, :func:`tilted_sincos_transposed`); then chunk by chunk the
            # field: made as the row transforms read it, or into the FFT buffer with the padding's zeros in one pass
            if not (self._rows and _sincos_agree() and tilted_sincos_transposed(
                    phase_t[block], curvature[block], self.r2, ky[block], kx[block], self.x, cosine, sine)):
                if self._rows:
                    tilted_phase_transposed(phase_t[block], curvature[block], self.r2, ky[block], kx[block], self.x,
                                            cosine)
                else:
                    tilted_phase(phase[block], curvature[block], self.r2, ky[block], kx[block], self.x, cosine)
                np.sin(cosine, out=sine)
                np.cos(cosine, out=cosine)
            for sl in _chunks(len(image), STAMP_CHUNK):
                grid, *rest = self._workspace(sl.stop - sl.start)
                if self._rows:
                    given = amplitude_t if len(amplitude_t) == 1 else amplitude_t[block][sl]
                    column_fft.rows(given, cosine[sl], sine[sl], grid, self._local.scratch)
                else:
                    pupil_field(amplitude[None] if amplitude.ndim == 2 else amplitude[block][sl], cosine[sl],
                                sine[sl], grid)
                self._integrate(grid, *rest, image[sl], rows_done=self._rows)
            self._scale(image, out[block])
        return out

    def _inputs(self, amplitude: np.ndarray, offset_px: np.ndarray, curvature_rad_m2: np.ndarray | None,
                frames: int) -> tuple[np.ndarray, ...]:
        """:meth:`stamps`' inputs as its steps take them: the amplitude in the renderer's precision, the defocus
        curvature (F,) [rad m^-2] (zeros if None) and the offsets' tilts ``ky``, ``kx`` (F,) [rad m^-1]."""
        curvature = np.zeros(frames) if curvature_rad_m2 is None else np.asarray(curvature_rad_m2, dtype=float)
        theta = np.asarray(offset_px, dtype=float) * self.sampler.pixel_scale_rad
        k = 2 * np.pi / self.wavelength
        return amplitude.astype(self.b.dtype), curvature, k * theta[:, 1], k * theta[:, 0]

    def _frame_arguments(self, amplitude_t, curvature, ky, kx, out) -> tuple:
        """:func:`_stamp_frames`' arguments after the phase: the frames' inputs, the renderer's constants, ``out``
        (F, M, M), this thread's buffers and the twiddles."""
        return (curvature, self.r2, ky, kx, self.x, amplitude_t, self.b, self.b_t,
                (self.delta**2 / self.wavelength) ** 2, float(self.area), out, *self._frame_buffers(),
                *column_fft.TWIDDLES)

    def frame_arguments(self, amplitude: np.ndarray, offset_px: np.ndarray, curvature_rad_m2: np.ndarray,
                        out: np.ndarray) -> tuple | None:
        """:func:`_stamp_frames`' arguments after the phase for :meth:`stamps` of (F,) frames into ``out`` (F, M, M),
        for a compiled caller that makes the phases itself (:func:`.pupil_path.walk_and_stamp`); None where the
        frame path is not this renderer's or ``amplitude`` is not one (n, n) for all frames; the rest as
        :meth:`stamps`'."""
        if not self._frames or amplitude.ndim != 2:
            return None
        amplitude, curvature, ky, kx = self._inputs(amplitude, offset_px, curvature_rad_m2, len(out))
        return self._frame_arguments(_transposed(amplitude), curvature, ky, kx, out)

    def stamps_from_field(self, field: np.ndarray, offset_px: np.ndarray) -> np.ndarray:
        """Pixel energy fractions ``(F, M, M)`` from complex pupil fields (F, n, n) [incident amplitude 1]."""
        ey, ex = self.tilt(offset_px)
        out = np.empty((len(field), self.sampler.size, self.sampler.size))
        for sl in _chunks(len(field), STAMP_CHUNK):
            grid, *rest = self._workspace(sl.stop - sl.start)
            image = self._per_frame(sl.stop - sl.start)[2]
            grid[:, :self.n, :self.n] = field[sl].astype(self.dtype) * ey[sl, :, None] * ex[sl, None, :]
            grid[:, :self.n, self.n:] = 0
            self._integrate(grid, *rest, image)
            self._scale(image, out[sl])
        return out

    def _integrate(self, grid: np.ndarray, psf: np.ndarray, half: np.ndarray, image: np.ndarray,
                   rows_done: bool = False) -> None:
        """Stamps ``image`` (F, M, M), up to :meth:`_scale`'s factor, of the tilted pupil fields in
        ``grid[:, :n, :n]`` (F, L, L) (``grid[:, :n, n:]`` and ``grid[:, n:]`` zero), ``F <= STAMP_CHUNK``, through
        this thread's buffers (:meth:`_workspace`): padded FFT, ``|.|^2`` into ``psf`` (written by the compiled
        transforms along y, :func:`.column_fft.column_powers`; else ``grid[:, n:]`` is zeroed again for the next
        chunk), then ``B PSF B^T``; ``rows_done``: ``grid[:, :n]`` already holds the fields' transforms along x
        (:func:`.column_fft.rows`)."""
        n, size = self.n, self.padded
        # the zero-padded FFTs in place (the same transforms of the same values, line by line in the same order, as
        # scipy's own padding): along x on the pupil's n rows, then along y, compiled where that gives the same bits
        if not rows_done:
            _fft(grid[:, :n], 2)
        if self._columns:
            # |.|^2 of the transforms along y straight into psf (F, L, L), up to delta^4/lambda^2: grid keeps the
            # transforms along x, its rows n: zero (never written) or not read
            column_fft.column_powers(grid, psf, self._local.scratch)
        else:
            _fft(grid, 1)
            squared_modulus(grid, psf, n)
        # stamp = B PSF B^T frame by frame: every frame goes through the same fixed-size products whatever the
        # batch, so results do not depend on how frames are grouped
        np.matmul(psf, self.b_t, out=half)
        np.matmul(self.b, half, out=image)

    def _scale(self, image: np.ndarray, out: np.ndarray) -> None:
        """Pixel energy fractions [1] ``out`` (F, M, M) in double precision from :meth:`_integrate`'s ``image``."""
        np.multiply(image, (self.delta**2 / self.wavelength) ** 2, out=out, dtype=float)
        out /= self.area


#: frames rendered together: their padded spectra (16 x 84 x 84 complex64 = 0.9 MB for a 42-sample pupil) stay
#: in cache through the FFTs, ``|.|^2`` and the products, 2-2.5x faster than batches of 100 on a loaded 2-core
#: machine; every frame's stamp is the same whatever the grouping (per-line FFTs, per-frame products)
STAMP_CHUNK = 16


#: frames whose tilted phase, cosine and sine are computed together (one call each; 2 x 128 x 40 x 40 float32 =
#: 1.6 MB for a 40-sample pupil): a window's frames at 1 kHz are one block
PHASE_FRAMES = 8 * STAMP_CHUNK


#: byte alignment of the renderer's buffers: a cache line, so that the compiled passes' vector loads and stores never
#: straddle two (numpy aligns to 16 bytes only; :func:`_stamp_frames` took ~16 instead of ~12 us a PSF on such buffers)
ALIGNMENT = 64


def _transposed(amplitude: np.ndarray) -> np.ndarray:
    """A pupil amplitude (n, n) or (F, n, n) as the frame path reads it: (1 or F, n, n) transposed (x, y),
    contiguous."""
    return np.ascontiguousarray(amplitude.T[None] if amplitude.ndim == 2 else amplitude.transpose(0, 2, 1))


def aligned_empty(shape, dtype) -> np.ndarray:
    """An uninitialised C-contiguous array whose first element starts on an ``ALIGNMENT``-byte boundary (its rows
    too where their length in bytes is a multiple of it)."""
    dtype = np.dtype(dtype)
    size = int(np.prod(shape)) * dtype.itemsize
    raw = np.empty(size + ALIGNMENT, np.uint8)
    start = -raw.ctypes.data % ALIGNMENT
    return raw[start:start + size].view(dtype).reshape(shape)


def aligned_zeros(shape, dtype) -> np.ndarray:
    """:func:`aligned_empty` filled with zeros."""
    array = aligned_empty(shape, dtype)
    array.fill(0)
    return array


def _chunks(frames: int, size: int):
    return (slice(start, min(start + size, frames)) for start in range(0, frames, size))


@cache
def _pocketfft_binding():
    """scipy's own pocketfft binding, the one ``scipy.fft.fft`` calls (the same transforms without its dispatch,
    ~2 us a PSF), if this scipy has it with the call signature used here and it gives ``scipy.fft.fft``'s bits on a
    test transform (checked once a process); else None (:func:`_fft` then calls ``scipy.fft.fft``)."""
    try:                               # a private module: absent, or another signature, in some scipy
        from scipy.fft._pocketfft.pypocketfft import c2c
        values = (np.arange(48, dtype=np.float32) * 0.37 - 3.1).view(np.complex64).reshape(2, 12)
        expected = sfft.fft(values, axis=1)
        c2c(values, (1,), True, 0, values, 1)
    except Exception:                  # any failure of a private call: use the public one
        return None
    return c2c if np.array_equal(values.view(np.uint64), expected.view(np.uint64)) else None


@cache
def _compiled_columns_agree() -> bool:
    """Whether :mod:`.column_fft` gives this scipy's bits (checked once a process)."""
    return column_fft.same_as_pocketfft()


def _fft(values: np.ndarray, axis: int) -> None:
    """``values = fft(values, axis=axis)`` in place on this thread (complex, forward, unnormalised)."""
    binding = _pocketfft_binding()
    if binding is None:
        values[...] = sfft.fft(values, axis=axis, workers=1)
    else:
        binding(values, (axis,), True, 0, values, 1)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def tilted_phase(phase, curvature, r2, ky, kx, x, out):
    """``out[f, i, j] = ((phase[f, i, j] + curvature[f] r2[i, j]) + ky[f] x[i]) + kx[f] x[j]`` [rad], rounded to
    ``out``'s precision: a defocus ``c r^2`` and the tilt ``k theta . r`` of a sub-pixel offset added to the phase in
    one pass (numpy's broadcast sums, bit for bit). ``phase`` may be a strided view (the screens' transposed sum)."""
    column_fft.wide_vectors()
    frames, rows, cols = phase.shape
    for f in range(frames):
        for i in range(rows):
            along_y = ky[f] * x[i]
            target = out[f, i]
            for j in range(cols):
                target[j] = ((phase[f, i, j] + curvature[f] * r2[i, j]) + along_y) + kx[f] * x[j]


@numba.njit(cache=True, error_model="numpy", nogil=True)
def tilted_phase_transposed(phase_t, curvature, r2, ky, kx, x, out):
    """:func:`tilted_phase` on and into transposed arrays: ``out[f, j, i]`` is element ``(i, j)`` from the
    contiguous ``phase_t[f, j, i]`` (``r2`` read as ``r2[j, i]``: it is symmetric), so that every read and write runs
    along memory (vector lanes; 2.6x faster than reading the transposed view)."""
    column_fft.wide_vectors()
    for f in range(phase_t.shape[0]):
        _tilted_frame_transposed(phase_t[f], curvature[f], r2, ky[f], kx[f], x, out[f])


@numba.njit(inline="always", error_model="numpy")
def _tilted_frame_transposed(phase_t, curvature, r2, ky, kx, x, out):
    """One frame (n, n) of :func:`tilted_phase_transposed`, ``curvature``, ``ky`` and ``kx`` its scalars."""
    cols, rows = phase_t.shape
    for j in range(cols):
        along_x = kx * x[j]
        source, radius2, target = phase_t[j], r2[j], out[j]
        for i in range(rows):
            target[i] = ((source[i] + curvature * radius2[i]) + ky * x[i]) + along_x


@intrinsic
def _fused_multiply_add(typingctx, a, b, c):
    """``a b + c`` rounded once (LLVM's ``llvm.fma``) in ``a``'s floating-point type."""
    def codegen(context, builder, signature, args):
        real = context.get_value_type(signature.return_type)
        fma = builder.module.declare_intrinsic("llvm.fma", [real], ir.FunctionType(real, [real] * 3))
        return builder.call(fma, args)
    return a(a, a, a), codegen


# numpy's float32 sine and cosine (numpy 2.x ``loops_trigonometric.dispatch.cpp``, ``simd_sincos_f32``, where the
# CPU has fused multiply-adds): Cody-Waite's reduction by pi/2 in three parts, polynomials on [-pi/4, pi/4] (T.
# Myklebust's), both in single precision with every multiply-add fused (the quadrant's too, as numpy's build fuses it)
_TWO_OVER_PI = np.float32(float.fromhex("0x1.45f306p-1"))
_ROUNDING = np.float32(float.fromhex("0x1.8p23"))
_PI_OVER_2 = tuple(np.float32(float.fromhex(h)) for h in ("-0x1.921fb0p+00", "-0x1.5110b4p-22", "-0x1.846988p-48"))
_COSINE = tuple(np.float32(float.fromhex(h))
                for h in ("0x1.98e616p-16", "-0x1.6c06dcp-10", "0x1.55553cp-05", "-0x1.000000p-01", "0x1.0p0"))
_SINE = tuple(np.float32(float.fromhex(h)) for h in ("0x1.7d3bbcp-19", "-0x1.a06bbap-13", "0x1.11119ap-07",
                                                     "-0x1.555556p-03"))
#: the largest |x| [rad] whose cosine numpy reduces so (its sine's bound is larger); beyond it libm's
SINCOS_LIMIT = np.float32(71476.0625)


@numba.njit(inline="always", error_model="numpy")
def _sincos(x):
    """``(sin x, cos x)`` of a float32 ``|x| <= SINCOS_LIMIT`` [rad]: numpy's float32 ``sin`` and ``cos``, bit for
    bit where :func:`_sincos_agree`."""
    fma, zero = _fused_multiply_add, np.float32(0.0)
    quadrant = fma(x, _TWO_OVER_PI, _ROUNDING) - _ROUNDING
    r = fma(quadrant, _PI_OVER_2[0], x)
    r = fma(quadrant, _PI_OVER_2[1], r)
    r = fma(quadrant, _PI_OVER_2[2], r)
    r2 = r * r
    c = fma(_COSINE[0], r2, _COSINE[1])
    c = fma(c, r2, _COSINE[2])
    c = fma(c, r2, _COSINE[3])
    c = fma(c, r2, _COSINE[4])
    s = fma(_SINE[0], r2, _SINE[1])
    s = fma(s, r2, _SINE[2])
    s = fma(s, r2, _SINE[3])
    s = fma(s, r2, zero)
    s = fma(s, r, r)
    q = np.int32(quadrant)
    sine = s if q & 1 == 0 else c
    cosine = c if q & 1 == 0 else s
    return (zero - sine if q & 2 else sine), (zero - cosine if (q + 1) & 2 else cosine)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def tilted_sincos_transposed(phase_t, curvature, r2, ky, kx, x, cosine, sine):
    """:func:`tilted_phase_transposed` and numpy's float32 ``cos`` and ``sin`` of it, frame by frame: ``cosine``,
    ``sine`` (F, n, n) float32, C-contiguous, transposed as ``phase_t``. False (outputs unspecified) where a tilted
    phase's magnitude exceeds ``SINCOS_LIMIT`` or is NaN: the caller then takes numpy's."""
    column_fft.wide_vectors()
    within = True
    for f in range(phase_t.shape[0]):
        within &= _tilted_sincos_frame(phase_t[f], curvature[f], r2, ky[f], kx[f], x, cosine[f], sine[f])
    return within


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _tilted_sincos_frame(phase_t, curvature, r2, ky, kx, x, cosine, sine):
    """One frame (n, n) of :func:`tilted_sincos_transposed`, ``curvature``, ``ky`` and ``kx`` its scalars: whether
    every phase was within ``SINCOS_LIMIT``. Compiled once for both of its callers (not inlined: the sine's
    polynomials compiled twice cost ~0.6 s of a first run)."""
    column_fft.wide_vectors()
    # the frame's phases into ``cosine``, then their sines and cosines: loops in vector lanes over a frame in cache
    # (one loop that mixed the double-precision sums with the single-precision sine ran slower than numpy's)
    _tilted_frame_transposed(phase_t, curvature, r2, ky, kx, x, cosine)
    flat_c, flat_s = cosine.reshape(-1), sine.reshape(-1)
    within = True
    for i in range(flat_c.size):
        value = flat_c[i]
        within &= abs(value) <= SINCOS_LIMIT
        flat_s[i], flat_c[i] = _sincos(value)
    return within


@cache
def _sincos_agree() -> bool:
    """Whether :func:`_tilted_sincos_frame` (so :func:`tilted_sincos_transposed` and :func:`_stamp_frames`) gives
    numpy's float32 ``sin`` and ``cos`` bits (checked once a process on 400 000 phases, untilted: every scale of phase
    to the limit, and the neighbours of the quadrants' boundaries, where a rounding of the quadrant shows). Frame by
    frame, with the one-frame buffers' types :func:`_stamp_frames` gives it: one compiled specialisation, and
    :func:`tilted_sincos_transposed` compiled only where a block needs it; each frame into its rows of one aligned
    array, compared with numpy's at once (numpy's float32 ``sin`` and ``cos`` are element by element: the same bits
    as frame by frame, ~3 instead of ~10 ms in a run's window 0)."""
    rng = np.random.default_rng(11)
    spread = (rng.uniform(-1.0, 1.0, (6, 50_000)) * np.array([[1e-3], [1.0], [10.0], [100.0], [1e3], [7e4]])).ravel()
    boundaries = (np.arange(-400, 400) + 0.5) * (np.pi / 2)
    near = (boundaries.astype(np.float32).view(np.int32)[:, None] + np.arange(-62, 63, dtype=np.int32)).view(np.float32)
    values = np.concatenate([spread.astype(np.float32), near.ravel(), np.float32([0.0, 1e-45, -1e-45])])
    n = 40
    phase = np.zeros((-(-values.size // (n * n)), n, n))
    phase.reshape(-1)[:values.size] = values
    r2, x = np.zeros((n, n)), np.zeros(n)
    cosine, sine = aligned_empty(phase.shape, np.float32), aligned_empty(phase.shape, np.float32)
    for frame, frame_cosine, frame_sine in zip(phase, cosine, sine):
        if not _tilted_sincos_frame(frame, 0.0, r2, 0.0, 0.0, x, frame_cosine, frame_sine):
            return False
    rounded = phase.astype(np.float32)
    return (np.array_equal(sine.view(np.uint32), np.sin(rounded).view(np.uint32))
            and np.array_equal(cosine.view(np.uint32), np.cos(rounded).view(np.uint32)))


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _stamp_frames(phase_t, curvature, r2, ky, kx, x, amplitude_t, b, b_t, factor, area, out, cosine, sine, grid, psf,
                  half, image, scratch, twr, twi):
    """:meth:`PupilRenderer.stamps` frame by frame in one call: the tilted phase's float32 sine and cosine
    (:func:`tilted_sincos_transposed`'s), the field's padded FFTs and ``|.|^2`` (:func:`.column_fft.field_powers`),
    ``B PSF B^T`` (two ``sgemm`` as numpy's ``matmul`` makes them per frame) and :meth:`PupilRenderer._scale`
    (``float64(image) factor / area``), each frame's steps on its own in this thread's buffers (the frame stays in
    cache). ``phase_t`` (F, n, n) float64, ``amplitude_t`` (1 or F, n, n) float32: transposed (x, y); ``curvature``,
    ``ky``, ``kx`` (F,) as :func:`tilted_phase`'s; ``out`` (F, M, M) float64; the rest this thread's buffers
    (:meth:`PupilRenderer._frame_buffers`) and the twiddles. False (``out`` unspecified) at the first frame whose
    tilted phase exceeds ``SINCOS_LIMIT`` or is NaN: the caller then takes numpy's sine and cosine."""
    column_fft.wide_vectors()
    frames, n = phase_t.shape[0], phase_t.shape[1]
    m = image.shape[0]
    flat_psf, flat_cosine, flat_sine = psf.reshape(-1), cosine.reshape(-1), sine.reshape(-1)
    for f in range(frames):
        if not _tilted_sincos_frame(phase_t[f], curvature[f], r2, ky[f], kx[f], x, cosine, sine):
            return False
        a = amplitude_t[f if amplitude_t.shape[0] > 1 else 0]
        column_fft.field_powers(a.reshape(n * n), flat_cosine, flat_sine, grid, flat_psf, scratch, twr, twi)
        np.dot(psf, b_t, half)
        np.dot(b, half, image)
        target = out[f]
        for i in range(m):
            for j in range(m):
                target[i, j] = np.float64(image[i, j]) * factor / area
    return True


@numba.njit(cache=True, error_model="numpy", nogil=True)
def pupil_field(amplitude, cosine, sine, grid):
    """``grid[f, :n, :n] = amplitude (cosine + i sine)`` and ``grid[f, :n, n:] = 0`` for (F, n, n) ``cosine``, ``sine``
    and ``amplitude`` (1, n, n) or (F, n, n): numpy's product of the complex field with a real amplitude, bit for bit
    (an imaginary part of zero adds only signed zeros)."""
    column_fft.wide_vectors()
    frames, n = cosine.shape[0], cosine.shape[1]
    size = grid.shape[2]
    for f in range(frames):
        a = amplitude[f if amplitude.shape[0] > 1 else 0]
        for i in range(n):
            row, c, s, w = grid[f, i], cosine[f, i], sine[f, i], a[i]
            for j in range(n):
                row[j] = complex(c[j] * w[j], s[j] * w[j])
            for j in range(n, size):
                row[j] = 0


@numba.njit(cache=True, error_model="numpy", nogil=True)
def squared_modulus(spectrum, out, clear_from=-1):
    """``out = re^2 + im^2`` of a complex64 ``spectrum`` (F, L, L) in one pass (numpy's ``real**2 + imag**2``, bit for
    bit); rows ``clear_from:`` of ``spectrum`` are set to zero once read (the next padded FFT's zeros), if given."""
    column_fft.wide_vectors()
    frames, rows, cols = spectrum.shape
    for f in range(frames):
        for i in range(rows):
            row, target = spectrum[f, i], out[f, i]
            for j in range(cols):
                value = row[j]
                target[j] = value.real * value.real + value.imag * value.imag
            if 0 <= clear_from <= i:
                row[:] = 0


class RadialRenderer:
    """Stamps from a radially symmetric PSF [sr^-1] tabulated at radii [rad] (analytic Airy, long exposure)."""

    def __init__(self, sampler: StampSampler, theta_rad: np.ndarray, profile: np.ndarray):
        self.sampler, self.theta, self.profile = sampler, np.asarray(theta_rad), np.asarray(profile)

    def stamps(self, offset_px: np.ndarray) -> np.ndarray:
        """Pixel energy fractions ``(F, M, M)`` for sources at ``offset_px`` (F, 2)."""
        a = self.sampler.angles
        theta = np.asarray(offset_px, dtype=float) * self.sampler.pixel_scale_rad
        dx = a[None, None, :] - theta[:, 0, None, None]
        dy = a[None, :, None] - theta[:, 1, None, None]
        r = np.sqrt(dx * dx + dy * dy)
        intensity = np.interp(r, self.theta, self.profile, right=0.0)
        return self.sampler.bin(intensity)
