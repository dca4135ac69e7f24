"""A turbulent layer's phase screen under frozen flow: a square window onto an unbounded screen.

The window holds the ``n x n`` cubic B-spline coefficients, spaced ``delta`` [m], of a screen
drawn for ``r0 = 1 m`` (multiply by ``r0^(-5/6)`` for a layer of Fried parameter ``r0``): the
spline through them takes the statistics of von Karman's screen of the shorter outer scale ``L1``
on the grid (:mod:`.autoregressive`), and the scales beyond it are random Fourier modes added to
the coefficients where a frame reads them (:mod:`.large_scales`): together, von Karman's of ``L0``.
Its first sample sits at the absolute index ``origin`` (row, column) of the unbounded screen, so a footprint
is addressed in absolute screen coordinates ``[delta]`` that do not depend on when the
window moved. When a footprint would leave the window the screen is

* ``"extend"``: continued on that side by conditional draws (:mod:`.autoregressive`),
  one column (or row) at a time, dropping as many on the opposite side, just until the
  footprint fits; or
* ``"regenerate"``: replaced by a fresh, independent screen centred on the footprint
  (the paper's Sec. 2.2 revisit). Modal (Zernike) screens live in :mod:`.modal_screen`.

A fresh window of up to ``SELF_START_SAMPLES`` is made by the same conditional draws, from
a few exactly drawn columns (the Cholesky factor of their covariance) and ``BURN_IN``
windows of columns before its own, so a walk has no seam between differently made screens
(an FFT screen twice a 24-sample window, cut to it, joined its first conditional columns
with a structure function 10-16 % high: benchmarks/screen_statistics.py). Wider windows (the
reference path's) are cut from an FFT screen twice as wide, whose samples are prefiltered
by Unser's inverse filter (Eq. 10) truncated at ``|k| <= PREFILTER_HALF_WIDTH``.

Each (re)generated screen draws from its own generator seeded by ``(seed, epoch,
regeneration count)``, where the epoch counts revisit periods (``floor(t / revisit)``),
so the screen's values at an absolute position depend only on the sequence of
footprints, never on how a run is cut into windows. ``state()`` / ``set_state()``
round-trip it, generator included.

Values between samples are cubic B-spline interpolants (Unser 1999, IEEE Signal
Process. Mag. 16(6), 22): unlike bilinear weights they do not smooth the screen by an
amount that changes with the sub-sample position (which would modulate the PSD at the
rate the screen crosses samples). Every draw makes coefficients directly (no prefilter).
:meth:`LayerScreen.accumulate` walks a whole batch of footprints in a few compiled calls
(:mod:`.screen_kernels`): it plans the extensions, makes every coefficient of the walk on
one canvas and reads each frame with separable 4-tap weights; :func:`accumulate_layers` walks every
layer of a line of sight so, in one plan and one walk for all (the same values, bit for bit).
"""

from __future__ import annotations

import threading
from functools import lru_cache

import numpy as np

from .autoregressive import FULL_COLUMNS, extension_operator, first_columns, stencil_width
from .fft_screens import fft_spline_corners
from .large_scales import PHASOR_SLOTS, SEED_WORD, STRIDE, LargeScales, split_outer_scale
from .normal_draws import _TABLES, _UNSCALED, SeededDraws, entropy_words, same_as_numpy, standard_normal
from .screen_kernels import (MARGIN, RIGHT, extend_in_stages, plan_layers, read_spans,
                             sample_grids_transposed, walk_segments)

#: most conditional columns made on one canvas before it is read and started afresh (bounds its memory)
CANVAS_STEPS = 2048
#: windows of columns drawn before a fresh window's own: their first few are conditioned on a partial stencil [1]
BURN_IN = 1
#: widest window made by conditional draws when fresh (a 128-sample one costs ~20 ms) [samples]
SELF_START_SAMPLES = 128
#: where a window cut from an FFT screen starts in it, along each axis (where a prefilter truncated at 16 samples
#: each side put it until the filter moved to the Fourier domain: the same screens, within ~1e-10) [samples]
PREFILTER_HALF_WIDTH = 16
# a walk's output when it reads nothing; packed arrays when no run draws noise or has large-scale modes
_NO_OUTPUT = np.zeros((0, 1, 1))
_EMPTY = np.zeros(0)
_NO_OPERATOR = ((_EMPTY, _EMPTY, np.zeros(0, np.int64), np.zeros(0, np.int64)), np.zeros((0, 4), np.int64))
_NO_MODES = ((_EMPTY, _EMPTY, _EMPTY, _EMPTY), np.zeros((0, 4), np.int64))
#: most sets of operators kept packed for :func:`walk_layers` (a few per source)
PACKED_SETS = 512


def _generator(seed: tuple[int, ...], epoch: int, word: int) -> np.random.Generator:
    """The random generator of a screen's draws addressed by its ``seed``, ``epoch`` and ``word`` (the regeneration
    count within the epoch, or :data:`.large_scales.SEED_WORD` for its large-scale modes)."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([*seed, epoch & 0xFFFFFFFF, word])))


def _seeded_entropy(seed_words: np.ndarray | None, epoch: int, word: int) -> np.ndarray | None:
    """:func:`_generator`'s entropy as SeedSequence's 32-bit words (:func:`.normal_draws.entropy_words`), from the
    seed's (``seed_words``), where the compiled draws are NumPy's (:func:`.normal_draws.same_as_numpy`) and the seed
    has words; None otherwise (NumPy's generator draws)."""
    if seed_words is None or not same_as_numpy():
        return None
    tail = entropy_words((epoch & 0xFFFFFFFF, word))
    return np.concatenate((seed_words, tail))


_WORD = 2**64 - 1


def _words(state: dict) -> np.ndarray:
    """A PCG64 ``bit_generator.state`` as the four words the compiled draws take: state high, low, increment high,
    low (:mod:`.normal_draws`)."""
    pcg = state["state"]
    return np.array([pcg["state"] >> 64, pcg["state"] & _WORD, pcg["inc"] >> 64, pcg["inc"] & _WORD], np.uint64)


def _state(words: np.ndarray, spare: tuple[int, int]) -> dict:
    """:func:`_words` back to a PCG64 ``bit_generator.state``, with its ``(has_uint32, uinteger)`` (``spare``)."""
    high, low, inc_high, inc_low = (int(w) for w in words)
    return {"bit_generator": "PCG64", "state": {"state": (high << 64) | low, "inc": (inc_high << 64) | inc_low},
            "has_uint32": spare[0], "uinteger": spare[1]}


# the compiled draws' tables (unused where NumPy draws: same_as_numpy() is False)
_ZIGGURAT = _TABLES if _TABLES is not None else (np.zeros(256, np.uint64), np.zeros(256), np.zeros(256))
_FIRST_STATE = np.random.PCG64(0).state


@lru_cache(maxsize=8)
def _fresh_stages(n: int, width: int) -> tuple[tuple[int, np.ndarray, np.ndarray, np.ndarray], ...]:
    """A fresh ``n``-row canvas ``width`` columns wide, grown right from its ``FULL_COLUMNS`` exact columns one
    conditional column at a time, in stages of one stencil each (it gains a column at 4, 8, 16, ...): each stage's
    first column, and its steps' window positions (rows, columns) and sides for
    :func:`.screen_kernels.extend_columns`."""
    stages, made = [], FULL_COLUMNS
    while made < width:
        stop = made + 1
        while stop < width and stencil_width(min(stop, n)) == stencil_width(min(made, n)):
            stop += 1
        steps = np.arange(made, stop, dtype=np.int64)
        stages.append((made, np.zeros_like(steps), steps - n, np.full(steps.shape, RIGHT, np.int8)))  # int8: the walks' sides
        made = stop
    return tuple(stages)


@lru_cache(maxsize=16)
def _fresh_plan(n: int, width: int, delta: float, L1: float) -> tuple:
    """:func:`_fresh_stages` with each stage's operator, packed for :func:`.screen_kernels.extend_in_stages`:
    the stages' bounds, their steps' rows, columns and sides concatenated, the operators' ``A``, ``B`` and stencils
    packed and where each stage's start (``operator_at`` (stages, 4), its stencil's length last)."""
    stages = _fresh_stages(n, width)
    operators = tuple(extension_operator(n, 1, delta, L1, min(made, n)) for made, *_ in stages)
    (a, b, stencil_rows, stencil_back), at = _packed(operators, lambda o: (o.A, o.B, o.stencil_rows, o.stencil_cols))
    lengths = np.array([[len(o.stencil_rows)] for o in operators], np.int64)
    bounds = np.cumsum([0] + [len(tops) for _, tops, _, _ in stages]).astype(np.int64)
    tops, lefts, sides = (np.concatenate([stage[i] for stage in stages]) for i in (1, 2, 3))
    return bounds, tops, lefts, sides, a, b, stencil_rows, stencil_back, np.hstack([at[:, :3], lengths])


class LayerScreen:
    """Frozen-flow phase screen of one layer seen by one source (phase for ``r0 = 1 m``)."""

    def __init__(self, n: int, delta: float, seed: tuple[int, ...], *, L0: float = 25.0, update: str = "extend",
                 keep_twin: bool = False):
        if update == "extend" and not np.isfinite(L0):
            raise ValueError("extending a screen needs a finite outer scale L0")
        self.n, self.delta, self.seed = int(n), float(delta), tuple(int(s) for s in seed)
        self.L0, self.update = float(L0), update
        # the conditional draws make von Karman's screen of outer scale L1 <= L0, the rest are large-scale modes;
        # windows wider than SELF_START_SAMPLES keep L0: cut from FFT screens with subharmonics, their stencil
        # reaching back 127 columns and more (the reference path's: a modes' sum over their whole window per read)
        self.L1 = split_outer_scale(self.n, self.delta, self.L0) if self.n <= SELF_START_SAMPLES else self.L0
        self._large: tuple[int, LargeScales] | None = None     # (epoch, its modes)
        self._operator = None      # the one-column conditional draw (:mod:`.autoregressive`), made at first use
        self.coefficients: np.ndarray | None = None   # B-spline coefficients of the window [rad, r0 = 1 m]
        self.origin = np.zeros(2, dtype=np.int64)
        self.epoch = -1            # revisit period the screen belongs to
        self.n_regenerations = 0   # regenerations within the epoch (footprint ran off, or jumped far)
        # the screen's generator between walks: PCG64's words (its draws are made in the compiled walk) and the
        # state's other fields, (has_uint32, uinteger), which normal draws leave as they are
        self._words, self._spare = _words(_FIRST_STATE), (0, 0)
        self._seed_words = entropy_words(self.seed)       # SeedSequence's words of the seed (None: negative)
        # with keep_twin, the other (imaginary) half of the last FFT draw, for twin(): (samples, origin, epoch, count)
        self.keep_twin, self._twin = bool(keep_twin), None

    # -- creation -------------------------------------------------------------------------------
    def regenerate(self, centre: np.ndarray, epoch: int) -> None:
        """A fresh screen whose window is centred on absolute position ``centre`` (row, col) [delta]."""
        if epoch == self.epoch:
            self.n_regenerations += 1
        else:
            self.epoch, self.n_regenerations = int(epoch), 0
        self.origin = np.floor(np.asarray(centre, dtype=float)).astype(np.int64) - self.n // 2
        entropy = _seeded_entropy(self._seed_words, self.epoch, self.n_regenerations)
        draws = self.n * (self.n + BURN_IN * self.n)
        if entropy is not None and self.n <= SELF_START_SAMPLES:
            # seeded and drawn compiled: NumPy's generator's numbers and state (:func:`_generator`)
            seeded = SeededDraws(entropy)
            self.coefficients = self._fresh(seeded.standard_normal(draws))
            self._words, self._spare = seeded.state, (0, 0)     # a fresh PCG64 holds no spare 32-bit word
            return
        rng = _generator(self.seed, self.epoch, self.n_regenerations)
        self.coefficients = (self._fresh(standard_normal(rng, draws)) if self.n <= SELF_START_SAMPLES
                             else self._cut_from_fft(rng))
        self._set_generator(rng)

    def _set_generator(self, rng: np.random.Generator) -> None:
        state = rng.bit_generator.state
        self._words, self._spare = _words(state), (state["has_uint32"], state["uinteger"])

    def _generator_now(self) -> np.random.Generator:
        """A NumPy generator in the screen's present state (for draws made outside the compiled walk)."""
        rng = np.random.Generator(np.random.PCG64(0))
        rng.bit_generator.state = _state(self._words, self._spare)
        return rng

    def _cut_from_fft(self, rng: np.random.Generator) -> np.ndarray:
        """B-spline coefficients of a window cut from an FFT screen twice as wide (cf. Johansson & Gavel 1994: the
        low orders kept; :func:`.fft_spline_corners`). The draw's other screen, its imaginary half, is kept for
        :meth:`twin` when the screen was made with ``keep_twin``."""
        n, first = self.n, PREFILTER_HALF_WIDTH
        cut = fft_spline_corners(rng, max(2 * n, n + 2 * first), n, first, self.delta, 1.0, self.L1)
        if self.keep_twin:
            self._twin = (np.ascontiguousarray(cut.imag), self.origin.copy(), self.epoch, self.n_regenerations)
        return np.ascontiguousarray(cut.real)

    def twin(self, seed: tuple[int, ...]) -> LayerScreen | None:
        """A screen of the same window made from the imaginary half of this screen's FFT draw (made with
        ``keep_twin``; None otherwise, or once the window has moved): independent of this one and of the same
        statistics, as the real and imaginary parts of one complex Gaussian FFT screen are (Lane, Glindemann &
        Dainty 1992), for no draw or transform of its own. ``seed`` seeds its own later draws."""
        if self._twin is None:
            return None
        coefficients, origin, epoch, count = self._twin
        if not np.array_equal(origin, self.origin) or epoch != self.epoch or count != self.n_regenerations:
            return None
        twin = LayerScreen(self.n, self.delta, seed, L0=self.L0, update=self.update)
        twin.epoch, twin.n_regenerations, twin.origin = epoch, count, origin.copy()
        entropy = _seeded_entropy(twin._seed_words, epoch, count)
        if entropy is None:
            twin._set_generator(_generator(twin.seed, epoch, count))
        else:
            twin._words = SeededDraws(entropy).state            # a fresh PCG64's state, spare (0, 0)
        twin.coefficients = coefficients
        return twin

    def _fresh(self, noise: np.ndarray) -> np.ndarray:
        """B-spline coefficients of a window made by conditional draws from a few exact columns, from ``n (n +
        BURN_IN n)`` standard normal draws (``noise``: the exact columns' first, then each conditional column's n, in
        order; one draw of the screen's generator)."""
        n = self.n
        width = n + BURN_IN * n
        canvas = np.empty((n, width))
        # the first columns exactly, then one conditional column at a time, each on the stencil the columns
        # made so far allow (the operators change where the stencil gains a column: 4, 8, 16, ...); the window
        # keeps the last n
        canvas[:, :FULL_COLUMNS] = (first_columns(n, self.delta, self.L1)
                                    @ noise[:FULL_COLUMNS * n]).reshape(FULL_COLUMNS, n).T
        bounds, tops, lefts, sides, a, b, stencil_rows, stencil_back, operator_at = _fresh_plan(n, width, self.delta,
                                                                                              self.L1)
        extend_in_stages(canvas, bounds, tops, lefts, sides, a, b, stencil_rows, stencil_back, operator_at,
                         noise[n * FULL_COLUMNS:], n)
        return np.ascontiguousarray(canvas[:, width - n:])

    # -- keeping footprints inside ------------------------------------------------------------
    def usable(self, low: np.ndarray, high: np.ndarray) -> np.ndarray | bool:
        """Whether boxes ``low .. high`` (absolute row, col) [delta], shape (2,) or (F, 2), lie in the usable part."""
        low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
        if self.coefficients is None:
            return np.zeros(low.shape[:-1], dtype=bool) if low.ndim > 1 else False
        lo = self.origin + MARGIN
        hi = self.origin + self.n - 1 - MARGIN
        inside = np.all(low >= lo, axis=-1) & np.all(high <= hi, axis=-1)
        return inside if low.ndim > 1 else bool(inside)

    def cover(self, low: np.ndarray, high: np.ndarray, epoch: int = 0) -> None:
        """Make the window hold the box ``low .. high`` [delta] of revisit period ``epoch``.

        Extends or regenerates as configured; a footprint farther than 1.5 window widths from
        the window is regenerated in any case (the screen there is practically independent).
        """
        low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
        self.walk(np.array([[low[0], high[0]]]), np.array([[low[1], high[1]]]), np.array([epoch], dtype=np.int64))

    def walk(self, rows: np.ndarray, cols: np.ndarray, epochs: np.ndarray, reads: tuple | None = None) -> None:
        """Keep each frame's footprint, from its grid's first to last ``rows`` (F, ny) and ``cols`` (F, nx) [delta], of
        epoch ``epochs[f]`` inside the window in turn (:func:`walk_layers` with this screen alone).

        With ``reads = (weight, out_t)`` (:meth:`accumulate`) each frame's grid is read from a canvas holding its
        window at its turn; coefficients are made once, in order, whatever the batching.
        """
        walk_layers([self], rows[None], cols[None], epochs, None if reads is None else (reads[0][None], reads[1]))

    def _large_scales(self) -> LargeScales:
        """The present epoch's large-scale modes (:mod:`.large_scales`), drawn from their own generator seeded by
        ``(seed, epoch)``."""
        if self._large is None or self._large[0] != self.epoch:
            entropy = _seeded_entropy(self._seed_words, self.epoch, SEED_WORD)
            draws = _generator(self.seed, self.epoch, SEED_WORD) if entropy is None else SeededDraws(entropy)
            self._large = (self.epoch, LargeScales(draws, self.delta, self.L0, self.L1))
        return self._large[1]

    def _with_large_scales(self, coefficients: np.ndarray, top: int, left: int, rows: np.ndarray,
                           cols: np.ndarray) -> tuple[np.ndarray, int, int]:
        """``coefficients`` (first sample at absolute (``top``, ``left``)) with the present epoch's large-scale modes
        (:mod:`.large_scales`; drawn from their own generator seeded by ``(seed, epoch)``) added where the frames'
        grids ``rows`` (F, ny), ``cols`` (F, nx) [samples] read them (an array defined there only), with ``top`` and
        ``left``, so the reads' arithmetic is unchanged."""
        if self.L1 == self.L0:
            return coefficients, top, left
        # in each row, the columns from the first to the last any frame reads there (a diagonal walk reads a band)
        height, width = coefficients.shape
        first, stop = np.empty(height, np.int64), np.empty(height, np.int64)
        read_spans(rows, cols, top, left, height, width, first, stop)
        return self._large_scales().added(coefficients, top, left, first, stop), top, left

    def spline_coefficients(self) -> np.ndarray:
        """The window's B-spline coefficients [rad, r0 = 1 m] with the large-scale modes: the screen the reads see."""
        n = self.n
        return self._with_large_scales(self.coefficients, int(self.origin[0]), int(self.origin[1]),
                                       self.origin[0] + np.array([[1.0, n - 3]]),
                                       self.origin[1] + np.array([[1.0, n - 3]]))[0]

    # -- sampling ---------------------------------------------------------------------------------
    def accumulate(self, rows: np.ndarray, cols: np.ndarray, epochs: np.ndarray, weight: np.ndarray,
                   out_t: np.ndarray) -> None:
        """Walk the footprints of separable grids ``rows`` (F, ny), ``cols`` (F, nx) [delta] and add ``weight[f]`` times
        the phase [rad, for r0 = 1 m] to ``out_t`` (F, nx, ny), each frame read when the window holds it.

        ``out_t`` is the phase transposed (``out_t[f, j, i]`` at ``rows[f, i]``, ``cols[f, j]``): the
        compiled read then runs along its contiguous rows; each value is :meth:`sample`'s, bit for bit.
        """
        accumulate_layers([self], rows[None], cols[None], epochs, np.asarray(weight)[None], out_t)

    def sample(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Phase [rad, for r0 = 1 m] on separable grids of the present window: ``rows`` (F, ny), ``cols`` (F, nx) [delta].

        Returns ``(F, ny, nx)``. The points must lie in the usable part of the window and be
        increasing along each axis.
        """
        rows = np.ascontiguousarray(np.atleast_2d(rows), dtype=float)
        cols = np.ascontiguousarray(np.atleast_2d(cols), dtype=float)
        out_t = np.zeros((rows.shape[0], cols.shape[1], rows.shape[1]))
        coefficients, top, left = self._with_large_scales(self.coefficients, int(self.origin[0]), int(self.origin[1]),
                                                          rows, cols)
        if not sample_grids_transposed(np.ascontiguousarray(coefficients), top, left, rows, cols,
                                       np.ones(rows.shape[0]), 0, rows.shape[0], out_t, False):
            raise ValueError("screen sampled outside its window")
        return out_t.transpose(0, 2, 1)

    # -- checkpoint -------------------------------------------------------------------------------
    def state(self) -> dict:
        return {"coefficients": self.coefficients, "origin": self.origin.copy(), "epoch": self.epoch,
                "n_regenerations": self.n_regenerations, "rng": _state(self._words, self._spare)}

    def set_state(self, state: dict) -> None:
        coefficients = state.get("coefficients")
        self.coefficients = None if coefficients is None else np.asarray(coefficients, dtype=float)
        self.origin = np.asarray(state["origin"], dtype=np.int64)
        self.epoch = int(state["epoch"])
        self.n_regenerations = int(state["n_regenerations"])
        rng = np.random.Generator(np.random.PCG64(0))
        rng.bit_generator.state = state["rng"]
        self._set_generator(rng)


# -- walking several screens --------------------------------------------------------------------------
_packed_sets: dict[tuple[int, ...], tuple] = {}


def _packed(objects: tuple, arrays_of) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
    """Each kind of array ``arrays_of(o)`` of the objects concatenated flat, and where each object's start
    (len(objects), kinds). Kept by the objects' identities, with the objects (an identity is not reused while its
    entry lives): the operators and the modes' tables, fixed once made, are packed once, not at every walk."""
    key = tuple(map(id, objects))
    entry = _packed_sets.get(key)
    if entry is None:
        parts = [arrays_of(o) for o in objects]
        flat = tuple(np.concatenate([p[i].ravel() for p in parts]) for i in range(len(parts[0])))
        at = np.cumsum([[0] * len(parts[0])] + [[x.size for x in p] for p in parts[:-1]], axis=0)
        if len(_packed_sets) >= PACKED_SETS:
            _packed_sets.clear()
        entry = _packed_sets[key] = (objects, flat, at)
    return entry[1], entry[2]


class ModesPool:
    """Every walked screen's large-scale modes' tables (:class:`.large_scales.LargeScales`' ``low``, ``amplitudes``,
    ``frequencies``; then ``phasors``, the cosines and sines at whole strides that the walks keep: 2 axes of
    :data:`.large_scales.PHASOR_SLOTS` slots of 1 + 2 K values, NaN when packed), each packed once into growing flat
    arrays when first walked: a walk passes their rows, not a concatenation of its own (held sources are walked
    together in changing sets, so the sets of modes seldom repeat). Kept by the modes' identities, with the modes (an identity is not reused while its entry lives); started
    afresh, between walks, past ``limit`` values of ``low``."""

    def __init__(self, limit: int = 1 << 21):
        self.limit = int(limit)
        self.clear()

    def clear(self) -> None:
        # low, amplitudes, frequencies, phasors
        self.tables = (np.empty(1 << 12), np.empty(1 << 8), np.empty(1 << 8), np.empty(1 << 12))
        self.used = [0, 0, 0, 0]
        self._rows: dict[int, tuple[LargeScales, list[int]]] = {}

    def make_room(self) -> None:
        """Start afresh if past the limit (call between walks: rows handed out before stay valid until then)."""
        if self.used[0] > self.limit:
            self.clear()

    def row(self, modes: LargeScales) -> list[int]:
        """Where ``modes``' ``low``, ``amplitudes``, ``frequencies`` and their ``phasors`` cache start in ``tables``
        (packed when first asked)."""
        entry = self._rows.get(id(modes))
        if entry is None:
            at = []
            grown = list(self.tables)
            empty = np.full(2 * PHASOR_SLOTS * (1 + 2 * len(modes.a)), np.nan)
            for kind, part in enumerate((modes.low, modes.amplitudes, modes.frequencies, empty)):
                start, stop = self.used[kind], self.used[kind] + part.size
                if stop > grown[kind].size:
                    bigger = np.empty(max(2 * grown[kind].size, stop))
                    bigger[:start] = grown[kind][:start]
                    grown[kind] = bigger
                grown[kind][start:stop] = part.ravel()
                at.append(start)
                self.used[kind] = stop
            self.tables = tuple(grown)
            entry = self._rows[id(modes)] = (modes, at)
        return entry[1]


_threads = threading.local()


def _modes_pool() -> ModesPool:
    """This thread's :class:`ModesPool` (one a thread: a pool changes between a walk's rows and its compiled call)."""
    pool = getattr(_threads, "modes", None)
    if pool is None:
        pool = _threads.modes = ModesPool()
    return pool


def accumulate_layers(screens: list[LayerScreen], rows: np.ndarray, cols: np.ndarray, epochs: np.ndarray,
                      weight: np.ndarray, out_t: np.ndarray, fresh: bool = False,
                      outputs: np.ndarray | None = None, then: tuple | None = None):
    """:meth:`LayerScreen.accumulate` of each screen ``l`` in turn on its grids ``rows[l]`` (F, ny), ``cols[l]`` (F, nx)
    [delta] with ``weight[l]`` (F,) into one ``out_t`` (F, nx, ny): the same sums in the same order, bit for bit, in
    two compiled calls for all (:func:`walk_layers`). With ``fresh``, ``out_t`` is written as if it held zeros (it
    may be uninitialised: no zeroing pass over it). With ``outputs`` (L,), several lines of sight at once: ``out_t``
    is (S, F, nx, ny) and screen ``l`` adds to ``out_t[outputs[l]]`` (each output's sums, in the screens' order,
    those of its screens walked alone). ``then``: :func:`walk_layers`' (its result returned)."""
    return walk_layers(screens, np.ascontiguousarray(rows, dtype=float), np.ascontiguousarray(cols, dtype=float),
                       np.ascontiguousarray(epochs, dtype=np.int64), (np.ascontiguousarray(weight, dtype=float), out_t),
                       fresh, outputs, then)


def walk_layers(screens: list[LayerScreen], rows: np.ndarray, cols: np.ndarray, epochs: np.ndarray,
                reads: tuple | None = None, fresh: bool = False, outputs: np.ndarray | None = None,
                then: tuple | None = None):
    """:meth:`LayerScreen.walk` of each screen ``l`` on ``rows[l]``, ``cols[l]`` (contiguous (L, F, .)) in turn.

    :func:`.screen_kernels.plan_layers` plans every walk from integers (regenerations, extensions, canvases); the
    regenerations are made in the walks' order; then :func:`.screen_kernels.walk_segments` draws each run's
    conditional noise from its screen's generator (one draw a run; NumPy's, where the compiled draws are not
    NumPy's: :func:`.normal_draws.same_as_numpy`), makes and reads every canvas (``reads = (weight (L, F), out_t)``),
    the large-scale modes added where frames read them (with ``fresh``, the first layer's reads written into
    ``out_t`` as if it held zeros). Each screen's draws, values and reads are those of its own walk: the screens
    share only the calls. ``outputs``: :func:`accumulate_layers`' (``out_t`` (S, F, nx, ny), each output's first
    layer written with ``fresh``).

    ``then = (kernel, arguments)``: ``kernel(*walk_segments' arguments, *arguments)`` is called instead, a compiled
    caller of :func:`.screen_kernels.walk_segments` that does more in the same call (:func:`.pupil_path.walk_and_stamp`)
    and returns the first segment that read outside its canvas (-1: none) and a result, which this returns (None
    when nothing was walked, or without ``then``).
    """
    weight, out_t = reads if reads is not None else (np.zeros((len(screens), 0)), _NO_OUTPUT)
    if outputs is None:                             # one output: out_t (F, nx, ny)
        out_t, outputs = out_t[None], np.zeros(len(screens), np.int64)
    reading = weight.shape[1] > 0
    failed, sides, before, centre, op_epoch, op_at, frame_ops, edges, segments = plan_layers(
        rows, cols, epochs, np.array([s.n for s in screens], np.int64), MARGIN,
        np.array([s.update == "regenerate" for s in screens]), np.array([s.origin for s in screens], np.int64),
        np.array([s.epoch for s in screens], np.int64), np.array([s.coefficients is not None for s in screens]),
        CANVAS_STEPS)
    if failed >= 0:
        r, c = rows[failed], cols[failed]
        span = np.max(np.stack([r[:, -1] - r[:, 0], c[:, -1] - c[:, 0]], axis=-1), axis=0)
        raise ValueError(f"a footprint of {span} samples does not fit a {screens[failed].n}-sample screen")
    # each run of canvases (segment): the regeneration before it, its window, generator, operator and modes, in order
    layout, windows, origins, states, operators, modes, last = [], [], [], [], [], [], {}
    compiled = same_as_numpy()
    pool = _modes_pool()
    pool.make_room()
    noises = []                 # NumPy's draws, where the compiled ones are not NumPy's
    window_at = noise_at = 0
    edges_at, layers_at = edges.tolist(), op_at.tolist()
    for layer, e0, e1, as_is, renew in segments.tolist():
        screen = screens[layer]
        if renew >= 0:
            op = layers_at[layer] + renew
            screen.regenerate(centre[op], int(op_epoch[op]))
            last.pop(layer, None)                                   # the window and generator are the fresh ones
        n = screen.n
        count = n * (edges_at[e1 - 1] - edges_at[e0])
        if screen.coefficients is None or (not count and not reading):
            continue                                                # nothing to make or read
        operator, stencil = -1, 0
        if count:
            if not compiled:
                rng = screen._generator_now()
                noises.append(rng.standard_normal(count))
                screen._set_generator(rng)
            if screen._operator is None:
                screen._operator = extension_operator(n, 1, screen.delta, screen.L1, n)
            operator, stencil = len(operators), len(screen._operator.stencil_rows)
            operators.append(screen._operator)
        k, mode = 0, -1                                             # the large-scale modes
        if reading and screen.L1 != screen.L0:
            large = screen._large_scales()
            k = len(large.a)
            mode = len(modes) if k else -1
            modes.append(pool.row(large))
        last[layer] = len(layout)
        windows.append(screen.coefficients.ravel())
        origins.append(screen.origin)
        states.append(screen._words)
        layout.append([layer, n, e0, e1, as_is, layers_at[layer], layers_at[layer + 1], window_at, noise_at,
                       noise_at + count, operator, stencil, k, mode])
        window_at, noise_at = window_at + n * n, noise_at + count
    # each output's first layer walked (the first layer of its runs, in order) writes its reads with fresh; an
    # output none reads is zero then
    assign = np.zeros(len(screens), np.bool_)
    if fresh and reading:
        first = {}
        for row in layout:
            first.setdefault(int(outputs[row[0]]), row[0])
        assign[list(first.values())] = True
        if len(first) < len(out_t):
            for k in range(len(out_t)):
                if k not in first:
                    out_t[k] = 0.0
    elif fresh and not layout:
        out_t[...] = 0.0
    if not layout:
        return None
    rows_of, layout = layout, np.array(layout, np.int64)
    (a, b, stencil_rows, stencil_back), operator_at = (
        _packed(tuple(operators), lambda o: (o.A, o.B, o.stencil_rows, o.stencil_cols)) if operators
        else _NO_OPERATOR)
    (low, amplitudes, frequencies, phasors), mode_at = ((pool.tables, np.array(modes, np.int64)) if modes
                                                         else _NO_MODES)
    windows, origins, states = np.concatenate(windows), np.array(origins, np.int64), np.array(states, np.uint64)
    noise = np.concatenate(noises) if noises else np.empty(noise_at)
    arguments = (layout, windows, origins, sides, before, edges, noise, states, compiled, _UNSCALED, *_ZIGGURAT, a, b,
                 stencil_rows, stencil_back, operator_at, frame_ops, rows, cols, weight, out_t, outputs, assign, low,
                 amplitudes, frequencies, mode_at, STRIDE, phasors, PHASOR_SLOTS)
    bad, result = (walk_segments(*arguments), None) if then is None else then[0](*arguments, *then[1])
    for layer, s in last.items():
        n, at = rows_of[s][1], rows_of[s][7]
        screens[layer].coefficients = windows[at:at + n * n].reshape(n, n)
        screens[layer].origin = origins[s]
        screens[layer]._words = states[s]
    if bad >= 0:
        raise ValueError("screen sampled outside its window")
    return result
