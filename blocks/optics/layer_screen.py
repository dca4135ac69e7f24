"""A turbulent layer's phase screen under frozen flow: a square window onto an unbounded screen.

The window holds ``n x n`` samples spaced ``delta`` [m] of a screen drawn for ``r0 = 1 m``
(multiply by ``r0^(-5/6)`` for a layer of Fried parameter ``r0``). Its first sample sits
at the absolute index ``origin`` (row, column) of the unbounded screen, so a footprint
is addressed in absolute screen coordinates ``[delta]`` that do not depend on when the
window moved. When a footprint would leave the window the screen is

* ``"extend"``: continued on that side by conditional draws (:mod:`.autoregressive`),
  dropping as many samples on the opposite side; or
* ``"regenerate"``: replaced by a fresh, independent screen centred on the footprint
  (the paper's Sec. 2.2 revisit). Modal (Zernike) screens live in :mod:`.modal_screen`.

Each (re)generated screen draws from its own generator seeded by ``(seed, epoch,
regeneration count)``, where the epoch counts revisit periods (``floor(t / revisit)``),
so the screen's values at an absolute position depend only on the sequence of
footprints, never on how a run is cut into windows. ``state()`` / ``set_state()``
round-trip it, generator included.

Values between samples are cubic B-spline interpolants (Unser 1999, IEEE Signal
Process. Mag. 16(6), 22): unlike bilinear weights they do not smooth the screen by an
amount that changes with the sub-sample position (which would modulate the PSD at the
rate the screen crosses samples).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.ndimage import spline_filter

from .autoregressive import extension_operator
from .fft_screens import fft_phase_screens

#: samples kept between a footprint and the window's edge (cubic spline support and prefilter edge effects)
MARGIN = 6


class LayerScreen:
    """Frozen-flow phase screen of one layer seen by one source (phase for ``r0 = 1 m``)."""

    def __init__(self, n: int, delta: float, seed: tuple[int, ...], *, L0: float = 25.0, update: str = "extend"):
        if update == "extend" and not np.isfinite(L0):
            raise ValueError("extending a screen needs a finite outer scale L0")
        self.n, self.delta, self.seed = int(n), float(delta), tuple(int(s) for s in seed)
        self.L0, self.update = float(L0), update
        self.values: np.ndarray | None = None
        self.origin = np.zeros(2, dtype=np.int64)
        self.epoch = -1            # revisit period the screen belongs to
        self.n_regenerations = 0   # regenerations within the epoch (footprint ran off, or jumped far)
        self._rng = np.random.Generator(np.random.PCG64(0))
        self._coefficients: np.ndarray | None = None

    # -- creation -------------------------------------------------------------------------------
    def regenerate(self, centre: np.ndarray, epoch: int) -> None:
        """A fresh screen whose window is centred on absolute position ``centre`` (row, col) [delta]."""
        if epoch == self.epoch:
            self.n_regenerations += 1
        else:
            self.epoch, self.n_regenerations = int(epoch), 0
        self._rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(
            [*self.seed, self.epoch & 0xFFFFFFFF, self.n_regenerations])))
        rng = self._rng
        self.origin = np.floor(np.asarray(centre, dtype=float)).astype(np.int64) - self.n // 2
        # a screen twice the window, cut down, keeps the low orders (cf. Johansson & Gavel 1994)
        full, _ = fft_phase_screens(rng, 2 * self.n, self.delta, 1.0, self.L0)
        self.values = np.ascontiguousarray(full[: self.n, : self.n])
        self._coefficients = None

    # -- keeping footprints inside ------------------------------------------------------------
    def usable(self, low: np.ndarray, high: np.ndarray) -> np.ndarray | bool:
        """Whether boxes ``low .. high`` (absolute row, col) [delta], shape (2,) or (F, 2), lie in the usable part."""
        low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
        if self.values is None:
            return np.zeros(low.shape[:-1], dtype=bool) if low.ndim > 1 else False
        lo = self.origin + MARGIN
        hi = self.origin + self.n - 1 - MARGIN
        inside = np.all(low >= lo, axis=-1) & np.all(high <= hi, axis=-1)
        return inside if low.ndim > 1 else bool(inside)

    def cover(self, low: np.ndarray, high: np.ndarray, epoch: int = 0) -> None:
        """Make the window hold the box ``low .. high`` [delta] of revisit period ``epoch``.

        Extends or regenerates as configured; a footprint farther than a window width from
        the window is regenerated in any case (the screen there is practically independent).
        """
        low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
        if high[0] - low[0] > self.n - 1 - 2 * MARGIN or high[1] - low[1] > self.n - 1 - 2 * MARGIN:
            raise ValueError(f"a footprint of {high - low} samples does not fit a {self.n}-sample screen")
        centre = 0.5 * (low + high)
        if self.values is None or epoch != self.epoch:
            self.regenerate(centre, epoch)
        if self.usable(low, high):
            return
        far = np.any(np.abs(centre - (self.origin + self.n / 2)) > 1.5 * self.n)
        if self.update == "regenerate" or far:
            self.regenerate(centre, epoch)
            return
        k = self.block_columns
        # extend toward the footprint until it fits, then on while its trailing side still fits,
        # so that it lands at the trailing edge with the most room to travel
        for axis, forward, backward in ((1, "right", "left"), (0, "down", "up")):
            lo = self.origin[axis] + MARGIN
            hi = self.origin[axis] + self.n - 1 - MARGIN
            if high[axis] > hi:
                while high[axis] > self.origin[axis] + self.n - 1 - MARGIN or \
                        low[axis] - k >= self.origin[axis] + MARGIN + k:
                    self._extend(forward, k)
            elif low[axis] < lo:
                while low[axis] < self.origin[axis] + MARGIN or \
                        high[axis] + k <= self.origin[axis] + self.n - 1 - MARGIN - k:
                    self._extend(backward, k)

    @property
    def block_columns(self) -> int:
        """Columns added per conditional draw: about 500 new values, at most a quarter of the window."""
        return max(1, min(self.n // 4, 512 // self.n))

    def _extend(self, side: str, k: int) -> None:
        operator = extension_operator(self.n, k, self.delta, self.L0, self.n)
        noise = self._rng.standard_normal(self.n * k)
        # view the screen so that the side to grow is on the right
        view = {"right": lambda a: a, "left": lambda a: a[:, ::-1],
                "down": lambda a: a.T, "up": lambda a: a[::-1, :].T}[side]
        unview = {"right": lambda a: a, "left": lambda a: a[:, ::-1],
                  "down": lambda a: a.T, "up": lambda a: a.T[::-1, :]}[side]
        oriented = view(self.values)
        block = operator.extend_right(oriented, noise)
        grown = np.concatenate([oriented[:, k:], block], axis=1)
        self.values = np.ascontiguousarray(unview(grown))
        step = {"right": (0, k), "left": (0, -k), "down": (k, 0), "up": (-k, 0)}[side]
        self.origin = self.origin + np.array(step, dtype=np.int64)
        self._coefficients = None

    # -- sampling ---------------------------------------------------------------------------------
    def sample(self, rows: np.ndarray, cols: np.ndarray, span: int | None = None) -> np.ndarray:
        """Phase [rad, for r0 = 1 m] on separable grids: ``rows`` (F, ny), ``cols`` (F, nx) absolute [delta].

        Returns ``(F, ny, nx)``. The points must lie in the usable part of the window and be
        increasing along each axis. ``span`` fixes the width [samples] of the coefficient patch
        each frame reads (at least the grid's extent plus 4); with it, a frame's result does not
        depend on the other frames of the batch (bit for bit).
        """
        if self._coefficients is None:
            self._coefficients = spline_filter(self.values, order=3, mode="mirror")
        iy, wy = _bspline_taps(np.asarray(rows, dtype=float) - self.origin[0], self.n)
        ix, wx = _bspline_taps(np.asarray(cols, dtype=float) - self.origin[1], self.n)
        # each frame needs one rectangular patch of coefficients: gather them all, then two small products
        top, left = iy[:, 0, 0], ix[:, 0, 0]
        height = int((iy[:, -1, -1] - top).max()) + 1
        width = int((ix[:, -1, -1] - left).max()) + 1
        if span is not None:
            if span < max(height, width):
                raise ValueError(f"sampling grids span {max(height, width)} samples, more than span={span}")
            height = width = min(int(span), self.n)
        top = np.minimum(top, self.n - height)
        left = np.minimum(left, self.n - width)
        patches = sliding_window_view(self._coefficients, (height, width))[top, left]
        matrix_y = _scatter(iy - top[:, None, None], wy, height)
        matrix_x = _scatter(ix - left[:, None, None], wx, width)
        return matrix_y @ patches @ np.swapaxes(matrix_x, -1, -2)

    # -- checkpoint -------------------------------------------------------------------------------
    def state(self) -> dict:
        return {"values": self.values, "origin": self.origin.copy(), "epoch": self.epoch,
                "n_regenerations": self.n_regenerations, "rng": self._rng.bit_generator.state}

    def set_state(self, state: dict) -> None:
        values = state.get("values")
        self.values = None if values is None else np.asarray(values, dtype=float)
        self.origin = np.asarray(state["origin"], dtype=np.int64)
        self.epoch = int(state["epoch"])
        self.n_regenerations = int(state["n_regenerations"])
        self._rng = np.random.Generator(np.random.PCG64(0))
        self._rng.bit_generator.state = state["rng"]
        self._coefficients = None


def _scatter(index: np.ndarray, weights: np.ndarray, width: int) -> np.ndarray:
    """Dense (F, m, width) matrices with ``weights`` (F, m, 4) placed at columns ``index`` (F, m, 4)."""
    out = np.zeros((*index.shape[:2], width))
    np.put_along_axis(out, index, weights, axis=-1)
    return out


def _bspline_taps(u: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (..., m, 4) and weights (..., m, 4) of the cubic B-spline at positions ``u`` (..., m) [samples]."""
    base = np.floor(u)
    t = u - base
    t2, t3 = t * t, t * t * t
    weights = np.stack([(1 - t) ** 3 / 6, (3 * t3 - 6 * t2 + 4) / 6, (-3 * t3 + 3 * t2 + 3 * t + 1) / 6, t3 / 6],
                       axis=-1)
    index = base.astype(np.int64)[..., None] + np.arange(-1, 3)
    if index.min() < 0 or index.max() >= n:
        raise ValueError("screen sampled outside its window")
    return index, weights
