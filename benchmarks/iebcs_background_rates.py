"""Background rates in IEBCS's measured noise histograms, and the presets' parasitic leak fitted to them (prints both).

IEBCS (Joubert, Marcireau, Ralph, Jolley, van Schaik & Cohen 2021, "Event camera simulator improvements via
characterized parameters", Front. Neurosci. 15:702765; github neuromorphicsystems/IEBCS) ships per-pixel noise
histograms measured on a real sensor, which the repository does not name: ``data/noise_{pos,neg}_{0.1lux,161lux,
3klux}.npy``, 50 x 50 pixels x 72 bins. Each is the cumulative histogram of the instantaneous rate of a pixel's
events (one over the interval to its previous event of that polarity) on the bins 1-9 x 10^k Hz, k = -3..4 (IEBCS's
``dvs_sensor.py`` draws its noise intervals from them; the 72nd column is unused). A pixel's count is its last
cumulative value, and its intervals add up to the time it was recording, so the files give absolute rates:

* events over pixels x the recording, taken as the longest per-pixel span (a pixel's span misses the time before its
  first event and after its last, so it is a lower bound of the recording and this rate an upper bound of the truth
  by that margin);
* the mean over pixels of count / own span (biased high for pixels with few events: their span is short).

Eq. 19's parasitic leak (``parasitic_rate_per_lux_hz``) is the rise of the ON rate with light: fitted to the two lit
recordings with the first estimator, ``(ON(3 klx) - ON(161 lx)) / (3000 - 161) lx``, lux taken as on the chip (the
files do not say). The presets carry it (docs/pixel.md, "Sensor presets"). The data are not bundled:

    python benchmarks/iebcs_background_rates.py PATH/TO/IEBCS/data
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

#: IEBCS's histogram bins [Hz]: 1-9 x 10^k, k = -3..4 (72 values; the files' last column is unused)
BIN_HZ = np.concatenate([np.arange(1, 10) * 10.0**k for k in range(-3, 5)])[:71]
#: the recordings' illuminance [lx]
RECORDINGS = {"0.1lux": 0.1, "161lux": 161.0, "3klux": 3000.0}


def pixel_counts_and_spans(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Events per pixel and the time their intervals add up to [s], from one cumulative histogram file."""
    cumulative = np.load(path).reshape(-1, 72)[:, :71]
    per_bin = np.diff(cumulative, axis=1, prepend=0.0)
    return per_bin.sum(axis=1), (per_bin / BIN_HZ).sum(axis=1)


def rates(data: Path) -> dict[str, dict[str, tuple[float, float]]]:
    """{recording: {polarity: (events over pixels x longest span, mean of per-pixel rates)}} [Hz per pixel]."""
    out = {}
    for name in RECORDINGS:
        counts = {pol: pixel_counts_and_spans(data / f"noise_{pol}_{name}.npy") for pol in ("pos", "neg")}
        recording_s = max(span.max() for _, span in counts.values())
        out[name] = {}
        for pol, (n, span) in counts.items():
            per_pixel = np.divide(n, span, out=np.zeros_like(n), where=span > 0)
            out[name][pol] = (n.sum() / n.size / recording_s, per_pixel.mean())
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="IEBCS's data directory (holds noise_pos_161lux.npy etc.)")
    measured = rates(parser.parse_args().data)
    print(f"{'recording':>10} {'pol':>4} {'events/(pixels x recording)':>28} {'mean of pixel rates':>20}  [Hz per pixel]")
    for name, by_pol in measured.items():
        for pol, (total, mean) in by_pol.items():
            print(f"{name:>10} {'ON' if pol == 'pos' else 'OFF':>4} {total:28.4f} {mean:20.4f}")
    for k, label in ((0, "events/(pixels x recording)"), (1, "mean of pixel rates")):
        lo, hi = measured["161lux"]["pos"][k], measured["3klux"]["pos"][k]
        slope = (hi - lo) / (RECORDINGS["3klux"] - RECORDINGS["161lux"])
        print(f"parasitic leak from the ON rise 161 lx -> 3 klx ({label}): {slope:.3g} Hz/lx, intercept {lo - 161 * slope:.4f} Hz")


if __name__ == "__main__":
    main()
