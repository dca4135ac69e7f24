"""A walk and its stamps in one compiled call (pupil_path.walk_and_stamp) against the walk's phases stamped after it."""

import numpy as np
import pytest

from evsda.blocks.optics import PointSourceOptics, pupil_path
from evsda.blocks.optics.atmosphere import Atmosphere
from evsda.blocks.optics.imaging import Imager
from evsda.blocks.optics.telescope import Telescope
from evsda.blocks.ports import FocalPlane

# the tracked pass's pupil: 40 samples, 80-point transforms, the renderer's frame path
FOCAL_PLANE = FocalPlane(640, 480, 4.86e-6, 0.4)
WAVELENGTH = 568.3e-9


def imager() -> Imager:
    made = Imager(Telescope(0.2, 0.4), FOCAL_PLANE, WAVELENGTH, Atmosphere.hufnagel_valley(3),
                  PointSourceOptics.Params(psf_path="pupil_fft", focus="infinity"), seed=(5,))
    made.ensure_geometry(0.6)
    return made


def walked_then_stamped(imager: Imager, sources, t, zenith, range_m, placed) -> np.ndarray:
    """The stamps as two calls make them: every source's phases walked, then stamped."""
    pupil, renderer = imager.pupil, imager.pupil_renderer
    count, frames = zenith.shape
    phase = pupil._phases(sources, t, imager.epochs_of(t), placed[2], zenith, range_m)
    stamps = renderer.stamps(imager.pupil_amplitude, phase.reshape(count * frames, *phase.shape[2:]),
                             placed[1].reshape(count * frames, 2), imager.defocus_curvature(range_m.reshape(-1)))
    return stamps.reshape(count, frames, *stamps.shape[1:])


@pytest.mark.parametrize("beyond", [False, True])
def test_sources_walked_and_stamped_in_one_call_get_the_stamps_of_two_calls(beyond, monkeypatch):
    # three sources (a satellite at finite range: defocus) over two windows, the screens carried on; with ``beyond``
    # one frame's tilt is past the compiled sine's range, so the call's stamps come from PupilRenderer.stamps instead
    calls = []
    kernel = pupil_path.walk_and_stamp

    def counted(*arguments):
        bad, stamped = kernel(*arguments)
        calls.append(stamped)
        return bad, stamped

    fused, alone = imager(), imager()
    assert fused.pupil_renderer._frames and fused.renders_together("pupil_fft")
    rng = np.random.default_rng(8)
    sources, frames = ["sat", "star a", "star b"], 30
    for window in range(2):
        t = 0.001 * (np.arange(frames) + window * frames)
        x = rng.uniform(100, 500, (len(sources), 1)) + 0.3 * np.arange(frames)
        y = rng.uniform(100, 400, (len(sources), 1)) - 0.2 * np.arange(frames)
        zenith = 0.6 + rng.uniform(0, 1e-3, (len(sources), frames))
        range_m = np.array([[4e5], [np.inf], [np.inf]]) * np.ones(frames)
        placed = fused.placement(x, y, zenith)
        if beyond:
            placed[1][1, 7] = (3e4, 0.0)
        monkeypatch.setattr(pupil_path, "walk_and_stamp", counted)
        together = fused.render_many(sources, t, zenith, range_m, placed)
        monkeypatch.undo()
        expected = walked_then_stamped(alone, sources, t, zenith, range_m, placed)
        assert together.tobytes() == expected.tobytes()
    assert calls == [not beyond] * 2
