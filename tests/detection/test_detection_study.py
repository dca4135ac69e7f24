"""The limiting-magnitude study end to end on a small case of the example designs (events and the frame
baseline), its resumption, and its bad-input messages."""

import csv
import shutil
from pathlib import Path

import pytest
import yaml

from evsda.graph.cli import main

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
FILES = ("limiting_magnitude_events.yaml", "limiting_magnitude_frames.yaml", "limiting_magnitude_scene.yaml",
         "limiting_magnitude_cmos.yaml")
SMALL = ["--set", "sensor/camera.width_px=48", "--set", "sensor/camera.height_px=48", "--set",
         "scene/inject.n_sources=4", "--set", "scene/inject.rate_arcsec_s=150", "--set", "run.duration_s=1.0"]


@pytest.fixture
def designs(tmp_path):
    """The example designs, with the event detector's look shortened to fit a 1 s run (sources at 4 px/s)."""
    for name in FILES:
        shutil.copy(EXAMPLES / name, tmp_path / name)
    path = tmp_path / "limiting_magnitude_events.yaml"
    graph = yaml.safe_load(path.read_text())
    graph["blocks"]["detector"]["params"].update(look_s=0.5, max_rate_px_s=5.0)
    path.write_text(yaml.safe_dump(graph, sort_keys=False))
    return tmp_path / FILES[0], tmp_path / FILES[1]


def test_event_and_frame_study_end_to_end_and_resumed(designs, tmp_path, capsys):
    events, frames = designs
    out = tmp_path / "study"
    args = ["limiting-magnitude", str(events), str(frames), "--magnitudes", "0,14", "-o", str(out), *SMALL]
    assert main(args) == 0
    printed = capsys.readouterr().out
    rows = list(csv.DictReader(open(out / "limiting_magnitude.csv")))
    by = {(r["kind"], float(r["magnitude"])): r for r in rows}
    # a V 0 source is found in every look by both designs, a V 14 one by neither (the design's limit is ~V 5-8)
    for kind in ("events", "frames"):
        assert int(by[(kind, 0.0)]["opportunities"]) > 0
        assert by[(kind, 0.0)]["p_d"] == "1.0000" and by[(kind, 14.0)]["p_d"] == "0.0000"
    assert (out / "limiting_magnitude.png").stat().st_size > 10_000
    summary = (out / "summary.txt").read_text()
    assert "limiting_magnitude_events.yaml" in summary and "limiting_magnitude_frames.yaml" in summary
    assert "m50 (analytic)" in printed and "P_d falls from 1 to 0 between V 0 and 14" in printed
    # the same study again: every point is found complete, nothing is recomputed
    stores = sorted(out.glob("*/point_*.zarr"))
    stamps = [p.stat().st_mtime_ns for p in stores]
    assert main([*args, "--no-analytic"]) == 0
    assert capsys.readouterr().out.count("already complete") == 4
    assert [p.stat().st_mtime_ns for p in stores] == stamps


def test_bad_ladders_and_designs_are_one_message(designs, tmp_path, capsys):
    events, _ = designs
    assert main(["limiting-magnitude", str(events), "--magnitudes", "9:8:1", "-o", str(tmp_path / "o")]) == 2
    assert "expected START:STOP:STEP" in capsys.readouterr().err
    plain = tmp_path / "plain.yaml"
    graph = yaml.safe_load(events.read_text())
    del graph["blocks"]["score"]
    graph["connections"] = [c for c in graph["connections"] if not c["to"].startswith("score.")]
    plain.write_text(yaml.safe_dump(graph, sort_keys=False))
    assert main(["limiting-magnitude", str(plain), "--magnitudes", "8,9", "-o", str(tmp_path / "o")]) == 2
    assert "needs a scoring block" in capsys.readouterr().err


def test_a_psf_far_smaller_than_a_pixel_is_refused(designs, tmp_path, capsys):
    """A 5 mm focal length puts 619 arcsec on a pixel of the 61 mm lens (lambda/D 1.9 arcsec at the Gen3 silicon
    response's 568 nm)."""
    events, _ = designs
    code = main(["run", str(events), "-o", str(tmp_path / "run"), "--set", "sensor/camera.focal_length_m=0.005",
                 *SMALL])
    assert code == 2
    err = capsys.readouterr().err
    assert "far smaller than a pixel" in err and "1.93 arcsec" in err and "Traceback" not in err


def test_a_star_field_ladder_beyond_its_stars_is_refused(designs, tmp_path, capsys):
    events, _ = designs
    scene_path = tmp_path / "limiting_magnitude_scene.yaml"
    scene = yaml.safe_load(scene_path.read_text())
    del scene["blocks"]["inject"]
    scene["blocks"]["stars"] = {"type": "star_field", "params": {"faint_limit_mag": 12.0}}
    scene["connections"] = [c for c in scene["connections"] if not c["from"].startswith("inject.")] + [
        {"from": "site.observer", "to": "stars.observer"}, {"from": "pointing.pointing", "to": "stars.pointing"},
        {"from": "stars.sources", "to": "telescope.sources"}]
    scene["expose"] = {"inputs": {"focal_plane": "stars.focal_plane", "sky_focal_plane": "sky.focal_plane"},
                       "outputs": {"irradiance": "telescope.irradiance", "sources": "stars.sources"}}
    scene_path.write_text(yaml.safe_dump(scene, sort_keys=False))
    assert main(["limiting-magnitude", str(events), "--magnitudes", "10:13:1", "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "holds stars from V -1.5" in err and "to V 12" in err and "13" in err


def test_a_motion_no_pixel_can_follow_is_refused(designs, tmp_path, capsys):
    """500 deg/s (49 500 px/s) on the 85 mm lens: a pixel sees a V 7 source for 0.02 ms, its photoreceptor's time
    constant is ~1 ms even under the source's light (the Gen3 preset's measured square-root bandwidth, 3 kHz at 56 lx
    on the pixel). Refused before any rung runs, saying why."""
    events, _ = designs
    fast = ["--set", "scene/inject.rate_arcsec_s=1800000", "--set", "scene/inject.cadence_s=0.00001", "--set",
            "detector.max_rate_px_s=50000", "--set", "detector.look_s=0.0002"]
    out = tmp_path / "o"
    assert main(["limiting-magnitude", str(events), "--magnitudes", "7,8", "-o", str(out), *SMALL, *fast]) == 2
    err = capsys.readouterr().err
    assert "no pixel can respond to this motion" in err and "crosses a pixel in 0.0202 ms" in err
    assert not list(out.glob("*/point_*.zarr"))
    # the detector must search the sources' rate
    assert main(["limiting-magnitude", str(events), "--magnitudes", "6,7", "-o", str(out), *SMALL,
                 "--set", "scene/inject.rate_arcsec_s=1800", "--set", "scene/inject.cadence_s=0.01"]) == 2
    assert "the injected sources move 49.5 pixel/s but the detector 'detector' searches 0 to 5" in capsys.readouterr().err
