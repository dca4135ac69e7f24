"""Which stars can a preset's pixel see at all? The contrast condition of a static star, from the pixel equations.

A star adds a photocurrent ``I_s`` to a pixel that already carries the sky's ``I_sky`` and
its dark current ``I_dark``; the photoreceptor, logarithmic down to its dark current, sees the
contrast ``ln(1 + I_s / (I_sky + I_dark))`` (Eq. 12-15), and the pixel fires once that reaches
its threshold ``theta`` (Eq. 17). This prints, for each sensor preset behind a lens of
``--aperture-m`` and ``--focal-m`` under a sky of ``--sky-mag`` mag/arcsec^2, the contrast of
stars of V 6-12 (B - V 0.66, in the preset detector's spectral response) with ``--psf-fraction`` of
their light in the brightest pixel, the faintest
V that reaches ``theta``, and the dark current that would let ``--target-v`` reach it. It
ignores the bandwidth (a static star, e.g. under sidereal tracking), optics losses and
turbulence: an upper bound on what the simulation can detect.

    python examples/pixel_faint_limit.py [--aperture-m 0.06] [--focal-m 0.1] [--sky-mag 19.5] [--target-v 12]
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import constants

from evsda.blocks.pixel.model import PixelModel
from evsda.blocks.scene import spectra
from evsda.blocks.scene.radiometry import V_BAND
from evsda.graph.graphfile import load_graph

PRESETS = ("prophesee_gen4", "prophesee_gen3_vga", "davis346", "dvs128", "cooled_bsi")
WAVELENGTH_M = 550e-9
RAD_TO_ARCSEC = 180 / np.pi * 3600


def star_and_sky(name: str, aperture_m: float, focal_m: float, sky_mag: float, psf_fraction: float) -> dict:
    """A preset's pixel behind the lens: its parameters, pitch, and electrons per second from dark, sky and V = 0."""
    graph = load_graph(f"library:sensors/{name}.yaml", overrides={"camera.focal_length_m": focal_m})
    pitch = graph.nodes["camera"].block.params.pixel_pitch_m
    response = graph.nodes["camera"].block.focal_plane.spectral_response
    params = graph.nodes["pixel"].block.params
    model = PixelModel(params, pitch**2, WAVELENGTH_M)
    zero = V_BAND.zero_point_photon_flux * np.pi * (aperture_m / 2) ** 2      # V = 0 through the aperture [photon/s]
    pixel_arcsec = pitch / focal_m * RAD_TO_ARCSEC
    qe = params.quantum_efficiency
    # photons of the detector's response over V's (1 for a V-band preset): a sunlight-coloured sky, a field star
    sky_band, star_band = spectra.sun_band_factor(response), float(spectra.star_band_factor(response, spectra.FIELD_STAR_B_V))
    return {"params": params, "pitch_m": pitch, "pixel_arcsec": pixel_arcsec,
            "dark_e": model.dark_current_A / constants.e,
            "sky_e": zero * 10 ** (-0.4 * sky_mag) * pixel_arcsec**2 * qe * sky_band,
            "star0_e": zero * psf_fraction * qe * star_band}                      # a V = 0 star in its brightest pixel


def contrast(pixel: dict, v_mag) -> np.ndarray:
    """Log contrast ``ln(1 + I_s / (I_sky + I_dark))`` of a star of ``v_mag`` (Eq. 12-15) [1]."""
    star = pixel["star0_e"] * 10 ** (-0.4 * np.asarray(v_mag, dtype=float))
    return np.log1p(star / (pixel["sky_e"] + pixel["dark_e"]))


def faintest_v(pixel: dict) -> float:
    """The V at which the contrast equals ``threshold_on``: ``I_s = (e^theta - 1)(I_sky + I_dark)``."""
    needed = np.expm1(pixel["params"].threshold_on) * (pixel["sky_e"] + pixel["dark_e"])
    return float(-2.5 * np.log10(needed / pixel["star0_e"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--aperture-m", type=float, default=0.06)
    parser.add_argument("--focal-m", type=float, default=0.1)
    parser.add_argument("--sky-mag", type=float, default=19.5, help="sky surface brightness [V mag arcsec^-2]")
    parser.add_argument("--psf-fraction", type=float, default=0.5, help="share of a star's light in its brightest pixel")
    parser.add_argument("--target-v", type=float, default=12.0)
    args = parser.parse_args()
    mags = np.arange(6, 13)
    print(f"aperture {args.aperture_m * 100:g} cm, focal length {args.focal_m * 1000:g} mm, sky {args.sky_mag} "
          f"mag/arcsec^2, {args.psf_fraction:g} of the PSF in one pixel; contrast ln(1 + I_s/(I_sky + I_dark)):")
    print(f"{'preset':<20} {'pixel':>7} {'I_dark':>9} {'I_sky':>8} " + " ".join(f"{'V' + str(m):>6}" for m in mags)
          + f" {'limit':>6} {'I_dark for V' + format(args.target_v, 'g'):>16}")
    for name in PRESETS:
        pixel = star_and_sky(name, args.aperture_m, args.focal_m, args.sky_mag, args.psf_fraction)
        theta = pixel["params"].threshold_on
        dark_needed = pixel["star0_e"] * 10 ** (-0.4 * args.target_v) / np.expm1(theta) - pixel["sky_e"]
        needed = f"{dark_needed:.3g} e-/s" if dark_needed > 0 else "sky too bright"
        print(f"{name:<20} {pixel['pixel_arcsec']:6.1f}\" {pixel['dark_e']:7.3g}/s {pixel['sky_e']:6.3g}/s "
              + " ".join(f"{c:6.3f}" for c in contrast(pixel, mags)) + f" {faintest_v(pixel):6.2f} {needed:>16}")
    print("(electrons per second; theta = each preset's threshold_on; I_dark at the preset's temperature)")


if __name__ == "__main__":
    main()
