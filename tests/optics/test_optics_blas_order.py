"""The stamps' products in OpenBLAS's order (blocks/optics/blas_order.py) against numpy's ``matmul``."""

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from evsda.blocks.optics import blas_order, render
from evsda.blocks.optics.render import PupilRenderer, StampSampler
from evsda.blocks.optics.telescope import Telescope


def _renderer() -> PupilRenderer:
    """The tracked pass's pupil renderer: 40 samples padded to 80, 7 x 7 stamps."""
    return PupilRenderer(StampSampler(7, 12.15e-6, 9), 40, 0.2 / 38, 568.3e-9, Telescope(0.2, 0.4).collecting_area_m2)


def test_the_order_is_taken_only_where_it_gives_numpys_products():
    # products() is bit for bit numpy's matmul wherever the check holds, on the renderer's own B and PSFs it has not
    # seen; the check refuses products in any other order (here float64 sums rounded once, nearly always within
    # an ulp of numpy's); a renderer takes the order exactly where the check holds
    renderer = _renderer()
    b = renderer.b
    if not blas_order.same_as_numpy(b):
        # where numpy's BLAS is OpenBLAS's AVX-512 build (its SkylakeX kernels) the order must be found
        assert not any(info["internal_api"] == "openblas" and info["architecture"] == "SkylakeX"
                       and "numpy" in info["filepath"] for info in threadpool_info()), "OpenBLAS's order not reproduced"
        pytest.skip("numpy's BLAS sums in another order here: the renderer keeps BLAS's products")
    assert renderer._blas_order
    rng = np.random.default_rng(5)
    half_t, image = np.zeros(blas_order.HALF_T_SIZE, np.float32), np.zeros(blas_order.IMAGE_SIZE, np.float32)
    for scale in (1e-4, 1.0, 3e5):
        psf = (scale * rng.exponential(1.0, (blas_order.LENGTH, blas_order.LENGTH))).astype(np.float32)
        blas_order.products(psf.reshape(-1), b.reshape(-1), half_t, image)
        half = np.matmul(psf, renderer.b_t)
        np.testing.assert_array_equal(half_t[:7 * 80].reshape(7, 80).T.view(np.uint32), half.view(np.uint32))
        np.testing.assert_array_equal(image.reshape(7, 16)[:, :7].view(np.uint32),
                                      np.matmul(b, half).view(np.uint32))

    def rounded_once(x, y):
        return np.matmul(x.astype(np.float64), y.astype(np.float64)).astype(np.float32)

    assert not blas_order.same_as_numpy(b, matmul=rounded_once)
    assert not blas_order.same_as_numpy(b.astype(np.float64))


def test_stamps_are_the_same_with_the_products_in_blas_order_or_through_blas(monkeypatch):
    # the frame path (phase to stamp in one compiled call) with the products in OpenBLAS's order against the same
    # path through BLAS's sgemm and against the chunked path (numpy's matmul): the same bits; a renderer whose check
    # fails takes BLAS's products
    n = 40
    renderer = _renderer()
    amplitude = Telescope(0.2, 0.4).pupil(n, 0.2 / 38)
    rng = np.random.default_rng(8)
    phase = 4.0 * rng.standard_normal((37, n, n))
    offsets = rng.uniform(-0.5, 0.5, (len(phase), 2))
    curvature = rng.uniform(0, 1e5, len(phase))
    ordered = renderer.stamps(amplitude, phase, offsets, curvature)
    monkeypatch.setattr(blas_order, "same_as_numpy", lambda b: False)
    through_blas = _renderer()
    assert not through_blas._blas_order and through_blas._frames == renderer._frames
    np.testing.assert_array_equal(through_blas.stamps(amplitude, phase, offsets, curvature).view(np.uint64),
                                  ordered.view(np.uint64))
    through_blas._frames = False
    np.testing.assert_array_equal(through_blas.stamps(amplitude, phase, offsets, curvature).view(np.uint64),
                                  ordered.view(np.uint64))
    assert render._sincos_agree() == renderer._frames
