"""Star field: apparent places against Skyfield, sidereal drift, star counts, windows and resume."""

from datetime import timedelta
from types import SimpleNamespace

import numpy as np
import pytest
from skyfield.api import Star
from skyfield.framelib import galactic_frame

from evsda import library
from evsda.blocks.ports import FocalPlane
from evsda.blocks.ports.scene import Pointing
from evsda.blocks.scene import projection
from evsda.blocks.scene.catalog import load_hipparcos
from evsda.blocks.scene.ephemeris import skyfield_time, timescale
from evsda.blocks.scene.starcounts import integrated_counts_per_deg2
from evsda.blocks.scene.stars import StarField
from evsda.graph import RunInfo, Window

NS = 10**9


def field(fov_deg: float) -> FocalPlane:
    pitch = 4.86e-6
    return FocalPlane(1280, 720, pitch, 1280 * pitch / (2 * np.tan(np.radians(fov_deg) / 2)))


def started(block, epoch, duration_s=10.0, window_s=1.0, seed=1):
    block.setup(RunInfo(epoch=epoch, duration_ns=int(duration_s * NS), window_ns=int(window_s * NS), seed=seed))
    return block


def test_positions_match_skyfield_at_every_sample(graz, pass_start):
    fp = field(6.0)
    pointing = Pointing(mode="stare", azimuth_deg=343.75, elevation_deg=40.57, roll_deg=10)
    block = started(StarField(faint_limit_mag=9.0), pass_start)
    window = Window(0, 0, 2 * NS, pass_start)
    out = block.step(window, observer=graz, pointing=pointing, focal_plane=fp)["sources"]
    stars = block._stars
    assert len(stars) > 10
    picks = np.arange(0, len(out.t_ns), 97)
    catalog_epoch = timescale().J(stars.epoch_jyear)
    star = Star(ra_hours=stars.ra_deg / 15, dec_degrees=stars.dec_deg, ra_mas_per_year=stars.pm_ra_mas_yr,
                dec_mas_per_year=stars.pm_dec_mas_yr, parallax_mas=stars.parallax_mas, epoch=catalog_epoch)
    observer = block._observer.skyfield_observer()
    for k in picks:
        t_ns = out.t_ns[k : k + 1]
        direction = observer.at(skyfield_time(pass_start, t_ns)[0]).observe(star).apparent().xyz.m.T
        b, r, u = (np.repeat(a, len(stars), axis=0) for a in block._pointing.frame(t_ns))
        x, y = projection.project(direction / np.linalg.norm(direction, axis=1, keepdims=True), b, r, u, fp)
        seen = np.isfinite(out.x_px[k])
        assert np.abs(out.x_px[k, seen] - x[seen]).max() < 1e-3 and np.abs(out.y_px[k, seen] - y[seen]).max() < 1e-3


def test_staring_field_drifts_at_the_sidereal_rate(graz, gen4, pass_start):
    """Stars cross a stare at 15.041 arcsec/s * cos(dec) (Earth's rotation relative to the stars)."""
    block = started(StarField(faint_limit_mag=11.0), pass_start)
    pointing = Pointing(mode="stare", azimuth_deg=180.0, elevation_deg=40.0)    # on the meridian, south
    out = block.step(Window(0, 0, 10 * NS, pass_start), observer=graz, pointing=pointing, focal_plane=gen4)["sources"]
    seen = np.isfinite(out.x_px[0]) & np.isfinite(out.x_px[-1])
    assert seen.sum() >= 2
    speed_arcsec_s = np.hypot(out.x_px[-1, seen] - out.x_px[0, seen], out.y_px[-1, seen] - out.y_px[0, seen]) \
        / ((out.t_ns[-1] - out.t_ns[0]) / NS) * np.degrees(gen4.pixel_scale_rad) * 3600
    dec = np.radians(40.0 + graz.latitude_deg - 90.0)                   # declination on the meridian
    assert speed_arcsec_s == pytest.approx(np.full(seen.sum(), 15.041 * np.cos(dec)), rel=2e-3)


def test_sidereal_pointing_holds_a_star_at_the_centre(graz, gen4, pass_start):
    capella = load_hipparcos(str(library.path("stars/hip_main.dat.gz")))
    capella = capella.select(capella.name == "HIP 24608")
    star = Star(ra_hours=capella.ra_deg[0] / 15, dec_degrees=capella.dec_deg[0], ra_mas_per_year=capella.pm_ra_mas_yr[0],
                dec_mas_per_year=capella.pm_dec_mas_yr[0], parallax_mas=capella.parallax_mas[0],
                epoch=timescale().J(capella.epoch_jyear))
    earth = __import__("evsda.blocks.scene.ephemeris", fromlist=["planets"]).planets()["earth"]
    ra, dec, _ = earth.at(skyfield_time(pass_start, np.zeros(1))[0]).observe(star).radec()   # ICRS at the date
    block = started(StarField(faint_limit_mag=6.5), pass_start)
    pointing = Pointing(mode="sidereal", ra_deg=ra._degrees, dec_deg=dec.degrees)
    out = block.step(Window(0, 0, 10 * NS, pass_start), observer=graz, pointing=pointing, focal_plane=gen4)["sources"]
    i = list(out.source_id).index("HIP 24608")
    assert np.abs(out.x_px[:, i] - 639.5).max() < 0.05 and np.abs(out.y_px[:, i] - 359.5).max() < 0.05
    assert out.magnitude[0, i] == pytest.approx(0.08 + 0.2 * 1.2, abs=0.3)   # Capella V = 0.08, extinction at X~1-2


def test_bahcall_soneira_counts_against_hipparcos():
    """Integrated counts V < 6 over |b| >= 20 deg: the model against the catalogue (15% per the authors)."""
    catalog = load_hipparcos(str(library.path("stars/hip_main.dat.gz")))
    galactic = catalog.unit_vectors() @ galactic_frame.rotation_at(None).T
    b = np.degrees(np.arcsin(galactic[:, 2]))
    observed = np.sum((np.abs(b) >= 20) & (catalog.vmag < 6.0))
    rng = np.random.default_rng(0)
    v = rng.normal(size=(20000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    gb = np.degrees(np.arcsin(v[:, 2]))
    gl = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    high = np.abs(gb) >= 20
    model = np.mean([integrated_counts_per_deg2(6.0, l, b_) for l, b_ in zip(gl[high], gb[high])])
    assert model * 41252.96 * high.mean() == pytest.approx(observed, rel=0.15)


def test_faint_stars_follow_the_counts(graz, pass_start):
    fp = field(3.0)
    block = started(StarField(faint_limit_mag=13.0, catalog_limit_mag=6.5), pass_start, duration_s=1.0)
    pointing = Pointing(mode="stare", azimuth_deg=90.0, elevation_deg=60.0)
    out = block.step(Window(0, 0, NS // 10, pass_start), observer=graz, pointing=pointing, focal_plane=fp)["sources"]
    synthetic = np.char.startswith(out.source_id.astype(str), "BS ")
    on = np.isfinite(out.x_px[0]) & synthetic
    b_dir = block._pointing.frame(np.zeros(1))[0][0]
    g = galactic_frame.rotation_at(None) @ b_dir
    l, b = np.degrees(np.arctan2(g[1], g[0])), np.degrees(np.arcsin(g[2]))
    half_w, half_h = projection.half_extent_rad(fp)
    area = 4 * half_w * half_h * np.degrees(1) ** 2                      # tangent-plane area, deg^2
    expected = area * (integrated_counts_per_deg2(13.0, l, b) - integrated_counts_per_deg2(6.5, l, b))
    assert abs(on.sum() - expected) < 4 * np.sqrt(expected)
    mags = out.magnitude[0, on]
    assert np.mean(mags > 12.0) > 0.4                                     # counts rise steeply to the faint end


def test_windows_and_resume_give_identical_output(graz, gen4, quickstart_pointing, pass_start):
    scene = dict(observer=graz, pointing=quickstart_pointing, focal_plane=gen4)
    whole = started(StarField(faint_limit_mag=14.0, name="stars"), pass_start, 1.0, 1.0)
    reference = whole.step(Window(0, 0, NS, pass_start), **scene)["sources"]
    first = started(StarField(faint_limit_mag=14.0, name="stars"), pass_start, 1.0, 0.1)
    parts = [first.step(w, **scene)["sources"] for w in list(first.run.windows())[:4]]
    state = first.get_state()
    resumed = started(StarField(faint_limit_mag=14.0, name="stars"), pass_start, 1.0, 0.1)
    resumed.set_state(state)
    parts += [resumed.step(w, **scene)["sources"] for w in list(resumed.run.windows())[4:]]
    assert reference.n_sources > 10
    for name in ("t_ns", "x_px", "y_px", "photon_flux"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(reference, name))
    np.testing.assert_array_equal(parts[-1].source_id, reference.source_id)


def test_the_kept_knot_interval_gives_each_window_its_own_asks(graz, gen4, quickstart_pointing, pass_start):
    """The places at a window's knot and their change to the next are kept from the window before (the same
    arrays, layout included); windows inside one knot interval and across two give the bytes a block that asks
    the knot grid afresh every window gives."""
    scene = dict(observer=graz, pointing=quickstart_pointing, focal_plane=gen4)
    kept, afresh = (started(StarField(faint_limit_mag=11.0, knot_step_s=0.25, name="stars"), pass_start, 0.6, 0.1)
                    for _ in range(2))
    for window in kept.run.windows():                      # windows 2 and 4 cross the knots at 0.25 s and 0.5 s
        a = kept.step(window, **scene)["sources"]
        afresh._interval_kept = None
        b = afresh.step(window, **scene)["sources"]
        for name in ("x_px", "y_px", "photon_flux", "magnitude"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), (window.index, name)
    assert np.isfinite(a.x_px).any()


def test_a_star_catalogue_with_a_field_that_is_no_number_is_one_clear_error(tmp_path):
    """A record with a non-numeric magnitude was a ValueError traceback in the first window of a run."""
    from evsda.blocks.scene.catalog import load_hipparcos
    from evsda.graph import ParameterError

    bad = tmp_path / "hip.dat"
    bad.write_text("H|1| |00 00 00.22|+01 05 20.4| 9.10| |H|0.00091185|1.08901332| |3.54|-5.20|-1.88|\n"
                   "H|2| |00 00 00.91|-19 29 55.8| abc| |G|0.00379737|-19.49883745| |21.90|181.21|-0.93|\n")
    with pytest.raises(ParameterError, match=r"hip\.dat: line 2: field H5 \(Vmag\) is not a number"):
        load_hipparcos(str(bad))
    bad.write_text(bad.read_text().replace(" abc", " 9.27"))
    stars = load_hipparcos(str(bad))
    assert list(stars.vmag) == [9.10, 9.27] and list(stars.parallax_mas) == [3.54, 21.90]


CATALOGUE_FIELDS = ("name", "vmag", "ra_deg", "dec_deg", "pm_ra_mas_yr", "pm_dec_mas_yr", "parallax_mas", "b_v")


def _both_readings(path, monkeypatch):
    """The catalogue read column by column (where the fixed layout allows) and line by line."""
    from evsda.blocks.scene import catalog

    fast = catalog.load_hipparcos.__wrapped__(str(path))
    with monkeypatch.context() as patch:
        patch.setattr(catalog, "_fixed_layout", lambda data: None)
        slow = catalog.load_hipparcos.__wrapped__(str(path))
    return fast, slow


def test_the_catalogue_read_column_by_column_is_the_line_by_line_reading(tmp_path, monkeypatch):
    """The fixed-layout reader gives the line-by-line reader's arrays bit for bit, blank fields included, and
    leaves lines it cannot read by columns to it."""
    import gzip

    from evsda.blocks.scene import catalog

    fast, slow = _both_readings(library.path("stars/hip_main.dat.gz"), monkeypatch)
    assert len(fast) == 9928          # 9 933 lines, 5 without an astrometric solution
    for name in CATALOGUE_FIELDS:
        a, b = getattr(fast, name), getattr(slow, name)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name

    lines = gzip.decompress(library.path("stars/hip_main.dat.gz").read_bytes()).split(b"\n")[:40]
    ends = [i for i, c in enumerate(lines[0]) if c == ord("|")]

    def blanked(line: bytes, field: int) -> bytes:
        start = ends[field - 1] + 1
        return line[:start] + b" " * (ends[field] - start) + line[ends[field]:]

    lines[3] = blanked(blanked(lines[3], 11), 37)       # no parallax, no B-V
    lines[5] = blanked(lines[5], 8)                     # no RA: skipped
    edited = tmp_path / "hip.dat"
    edited.write_bytes(b"\n".join(lines) + b"\n")
    assert catalog._fixed_layout(edited.read_bytes()) is not None
    fast, slow = _both_readings(edited, monkeypatch)
    assert len(fast) == 39 and fast.parallax_mas[3] == 0 and np.isnan(fast.b_v[3])
    for name in CATALOGUE_FIELDS:
        assert getattr(fast, name).tobytes() == getattr(slow, name).tobytes(), name
    text = b"\n".join(lines) + b"\n"
    for change in (b"|\t6.53|", b"| 6|53|", b"| 6.5x|"):   # a control character, a separator more, no number
        variant = text.replace(b"| 6.53|", change, 1)
        assert len(variant) == len(text) and catalog._fixed_layout(variant) is None, change


def test_plain_decimals_are_read_as_pythons_float_reads_them():
    """``catalog._decimals`` reads a column of fixed-width texts with NumPy: where it reads a row, the bits are
    ``float``'s (signed zeros, points first or last, 15 digits); what it leaves (blanks, exponents, underscores,
    signs or blanks inside, two points, 16 digits, other characters) ``float`` may read or refuse."""
    import random

    from evsda.blocks.scene import catalog

    rng = random.Random(13)
    texts = [b" -0.00", b"+0.0", b"5.", b".5", b"123456789012345", b"1234567890.12345", b"0.000000000000001",
             b"1234567890123456", b"1e3", b"1_0", b"- 1", b"1 2", b"1.2.3", b"+-1", b"1-", b".", b"-", b"", b"nan",
             b"\t1"]
    for _ in range(20_000):
        digits = "".join(rng.choice("0123456789") for _ in range(rng.randint(0, 16)))
        cut = rng.randint(0, len(digits))
        body = rng.choice(["", "-", "+"]) + digits[:cut] + rng.choice(["", "."]) + digits[cut:]
        texts.append((" " * rng.randint(0, 3) + body + " " * rng.randint(0, 2)).encode())
    texts += ["".join(rng.choice("0123456789 .-+e_x") for _ in range(rng.randint(1, 12))).encode()
              for _ in range(5_000)]
    width = max(map(len, texts))
    field = np.frombuffer(b"".join(t.rjust(width) if k % 2 else t.ljust(width) for k, t in enumerate(texts)),
                          np.uint8).reshape(-1, width)
    values, read = catalog._decimals(field)
    for text, value, was_read in zip(texts, values.tolist(), read.tolist()):
        plain = text.strip(b" ")
        plain = plain[1:] if plain[:1] in (b"+", b"-") else plain
        expected = (0 < sum(c in b"0123456789" for c in plain) <= 15 and plain.count(b".") <= 1
                    and not plain.strip(b"0123456789."))
        assert was_read == expected, text
        if was_read:
            assert np.float64(value).tobytes() == np.float64(float(text)).tobytes(), text
    assert read.sum() > 15_000


def test_a_window_in_one_knot_interval_interpolates_as_one_across_two():
    """The photometry between knots: a window inside one knot interval (its rows at once) gives each sample the
    bytes the general loop (one knot interval after the other) gives it."""
    rng = np.random.default_rng(3)
    knots = {k: (None, rng.uniform(1e3, 1e6, 7), rng.uniform(2, 12, 7)) for k in (4, 5, 6)}
    field = SimpleNamespace(_stars=np.zeros(7))
    k_one, w_one = np.full(40, 5), rng.uniform(0, 1, 40)
    k_two, w_two = np.append(k_one, 4), np.append(w_one, 0.5)          # the same samples and one before them
    for member in (1, 2):
        one = StarField._between_knots(field, k_one, w_one, knots.__getitem__, member)
        two = StarField._between_knots(field, k_two, w_two, knots.__getitem__, member)
        assert one.tobytes() == two[:40].tobytes()
