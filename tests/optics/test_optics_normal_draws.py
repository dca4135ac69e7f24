"""The compiled normal draws (blocks/optics/normal_draws.py) against NumPy's own Generator: the same bits and the
same state after, over enough draws to take the ziggurat's wedge and tail branches many times."""

import numpy as np
import pytest

from evsda.blocks.optics import normal_draws
from evsda.blocks.optics.fft_screens import fft_phase_screens


def generators(seed):
    make = lambda: np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, 7, 1])))  # noqa: E731
    return make(), make()


def test_compiled_draws_run_here():
    assert normal_draws.same_as_numpy()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_standard_normal_is_numpys_bit_for_bit(seed):
    numpy_rng, ours = generators(seed)
    expected = numpy_rng.standard_normal(1_000_003)          # ~250 tail draws (|z| > 3.654), ~10 000 from wedges
    drawn = normal_draws.standard_normal(ours, 1_000_003)
    assert np.sum(np.abs(expected) > normal_draws.ziggurat_nor_r) > 100
    assert np.array_equal(drawn.view(np.uint64), expected.view(np.uint64))
    assert ours.bit_generator.state == numpy_rng.bit_generator.state
    assert np.array_equal(ours.standard_normal(5), numpy_rng.standard_normal(5))   # the stream goes on alike


def test_scaled_pair_is_the_products_of_numpys_draws():
    numpy_rng, ours = generators(3)
    amplitude = np.random.default_rng(0).uniform(0.1, 10.0, (37, 41))
    draws = numpy_rng.standard_normal((2, *amplitude.shape))
    out = normal_draws.scaled_pair(ours, amplitude)
    assert np.array_equal(out.real, draws[0] * amplitude) and np.array_equal(out.imag, draws[1] * amplitude)
    assert ours.bit_generator.state == numpy_rng.bit_generator.state


def test_other_generators_get_numpys_draws():
    ours = np.random.Generator(np.random.Philox(5))
    expected = np.random.Generator(np.random.Philox(5)).standard_normal(1000)
    assert np.array_equal(normal_draws.standard_normal(ours, 1000), expected)


def test_fft_screens_unchanged_by_the_compiled_draws(monkeypatch):
    """The screens from the compiled draws are those from NumPy's (the check switched off: NumPy draws)."""
    a = fft_phase_screens(np.random.default_rng(11), 64, 0.01, 0.1, 20.0)
    monkeypatch.setattr(normal_draws, "_compiled_here", lambda rng: False)
    b = fft_phase_screens(np.random.default_rng(11), 64, 0.01, 0.1, 20.0)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
