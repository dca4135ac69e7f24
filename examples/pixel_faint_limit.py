"""Which stars can a preset's pixel see at all? The contrast condition of a static star, from the pixel equations.

A star adds a photocurrent ``I_s`` to a pixel that already carries the sky's ``I_sky`` and
its dark current ``I_dark``; the photoreceptor, logarithmic down to its dark current, sees the
contrast ``ln(1 + I_s / (I_sky + I_dark))`` (Eq. 12-15), and the pixel fires once that reaches
its threshold ``theta`` (Eq. 17). This prints, for each sensor preset behind a lens of
``--aperture-m`` and ``--focal-m`` under a sky of ``--sky-mag`` mag/arcsec^2, the contrast of
stars of V 6-12 with ``--psf-fraction`` of their light in the brightest pixel, the faintest
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
from evsda.blocks.scene.radiometry import V_BAND
from evsda.graph.graphfile import load_graph

PRESETS = ("prophesee_gen4", "prophesee_gen3_vga", "davis346", "dvs128", "cooled_bsi")
WAVELENGTH_M = 550e-9
RAD_TO_ARCSEC = 180 / np.pi * 3600


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--aperture-m", type=float, default=0.06)
    parser.add_argument("--focal-m", type=float, default=0.1)
    parser.add_argument("--sky-mag", type=float, default=19.5, help="sky surface brightness [V mag arcsec^-2]")
    parser.add_argument("--psf-fraction", type=float, default=0.5, help="share of a star's light in its brightest pixel")
    parser.add_argument("--target-v", type=float, default=12.0)
    args = parser.parse_args()
    area_m2 = np.pi * (args.aperture_m / 2) ** 2
    zero = V_BAND.zero_point_photon_flux * area_m2                     # V = 0 through the aperture [photon/s]
    mags = np.arange(6, 13)
    print(f"aperture {args.aperture_m * 100:g} cm, focal length {args.focal_m * 1000:g} mm, sky {args.sky_mag} "
          f"mag/arcsec^2, {args.psf_fraction:g} of the PSF in one pixel; contrast ln(1 + I_s/(I_sky + I_dark)):")
    print(f"{'preset':<20} {'pixel':>7} {'I_dark':>9} {'I_sky':>8} " + " ".join(f"{'V' + str(m):>6}" for m in mags)
          + f" {'limit':>6} {'I_dark for V' + format(args.target_v, 'g'):>16}")
    for name in PRESETS:
        graph = load_graph(f"library:sensors/{name}.yaml", overrides={"camera.focal_length_m": args.focal_m})
        pitch = graph.nodes["camera"].block.params.pixel_pitch_m
        params = graph.nodes["pixel"].block.params
        model = PixelModel(params, pitch**2, WAVELENGTH_M)
        qe = params.quantum_efficiency
        pixel_arcsec = pitch / args.focal_m * RAD_TO_ARCSEC
        sky_e = zero * 10 ** (-0.4 * args.sky_mag) * pixel_arcsec**2 * qe
        dark_e = model.dark_current_A / constants.e
        star_e = zero * 10 ** (-0.4 * mags) * args.psf_fraction * qe
        contrast = np.log1p(star_e / (sky_e + dark_e))
        theta = params.threshold_on
        # faintest V with contrast >= theta: I_s = (e^theta - 1)(I_sky + I_dark)
        limit = -2.5 * np.log10((np.expm1(theta) * (sky_e + dark_e)) / (zero * args.psf_fraction * qe))
        target_e = zero * 10 ** (-0.4 * args.target_v) * args.psf_fraction * qe
        dark_needed = target_e / np.expm1(theta) - sky_e
        needed = f"{dark_needed:.3g} e-/s" if dark_needed > 0 else "sky too bright"
        print(f"{name:<20} {pixel_arcsec:6.1f}\" {dark_e:7.3g}/s {sky_e:6.3g}/s "
              + " ".join(f"{c:6.3f}" for c in contrast) + f" {limit:6.2f} {needed:>16}")
    print("(electrons per second; theta = each preset's threshold_on; I_dark at the preset's temperature)")


if __name__ == "__main__":
    main()
