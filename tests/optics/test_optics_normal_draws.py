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


def entropies():
    """Seed sequences' entropies of 1-9 ints: small, 32-bit, 64-bit and wider, zeros (the pool's padding, more words
    than the pool: mixed in after it)."""
    rng = np.random.default_rng(2)
    cases = [[0], [5], [0, 0, 0, 0, 0], [2**32], [2**64 - 1, 3], [2**100 + 7, 1, 2**32 - 1], [1, 2, 3, 4, 5, 6, 7, 8, 9]]
    for bits in (16, 32, 63):
        for size in (1, 3, 4, 5, 8):
            cases.append([int(v) for v in rng.integers(0, 2**bits, size)])
    return cases


@pytest.mark.parametrize("entropy", entropies())
def test_seeded_state_is_numpys_seed_sequence_and_pcg64(entropy):
    state = np.empty(4, np.uint64)
    normal_draws.seeded_state(normal_draws.entropy_words(entropy), state)
    expected = np.random.PCG64(np.random.SeedSequence(entropy)).state["state"]
    assert (int(state[0]) << 64 | int(state[1]), int(state[2]) << 64 | int(state[3])) == (expected["state"],
                                                                                         expected["inc"])


def test_seeded_draws_are_a_seeded_generators():
    entropy = [3, 2**40 + 1, 0, 7, 0xFFFFFFFF]
    numpy_rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(entropy)))
    ours = normal_draws.SeededDraws(normal_draws.entropy_words(entropy))
    for _ in range(2):                                     # interleaved, as the large-scale modes draw
        assert np.array_equal(ours.random((5, 4, 2)), numpy_rng.random((5, 4, 2)))
        assert np.array_equal(ours.standard_normal((2, 20)), numpy_rng.standard_normal((2, 20)))
    assert int(ours.state[0]) << 64 | int(ours.state[1]) == numpy_rng.bit_generator.state["state"]["state"]


def test_entropy_words_refuse_negative_ints_as_numpy_does():
    assert normal_draws.entropy_words([1, -1]) is None
    with pytest.raises(ValueError):
        np.random.SeedSequence([1, -1])
