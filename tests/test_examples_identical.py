"""Every example scene (``examples/*.yaml``) records the same bytes as when its hash was written down.

A guard for changes that must not change behaviour (issue 16: the framework's redesign): each example
runs in a short, small version (:data:`SHORT`) into a run store, and a SHA-256 of everything the store
records (events, products, truth, metrics; not timings or versions) is compared with :data:`EXPECTED`.

Each expected hash is recorded with the digest of the resolved graph it came from. When a scene itself
changes (a preset's numbers, a block's default, an example's parameters), its graph digest changes and the
test skips that scene, saying so: the hashes guard the code, not the scenes. The same graph recording
different bytes fails.

Regenerate (only after a change that alters physics on purpose, and say so in its commit message)::

    OPENBLAS_NUM_THREADS=1 python tests/test_examples_identical.py

which prints the new EXPECTED table to paste below. To compare two commits side by side instead (every
example at both, array by array)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/old_scenes_identical.py OLD_COMMIT NEW_COMMIT
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"


def _small(prefix: str, width_px: int, height_px: int, pitch_m: float, shrink: int = 4) -> dict:
    """Overrides of ``<prefix>camera`` that keep the field with ``1/shrink`` of the pixels per side."""
    return {f"{prefix}camera.width_px": width_px // shrink, f"{prefix}camera.height_px": height_px // shrink,
            f"{prefix}camera.pixel_pitch_m": shrink * pitch_m}


GEN4 = (1280, 720, 4.86e-6)
VGA = (640, 480, 15.0e-6)
ISS_RUN = {"run.start": "2023-03-20T19:18:39.4Z", "run.duration_s": 0.2}
LIMITING = {"run.duration_s": 1.0, "run.window_s": 0.5, "scene/inject.n_sources": 4}

#: the overrides that make each example short and small (a fraction of a second, a few thousand pixels)
SHORT: dict[str, dict] = {
    "geo_sidereal.yaml": {**_small("sensor/", *GEN4), "run.start": "2013-03-24T09:40:01.5Z", "run.duration_s": 0.1,
                          "stars.faint_limit_mag": 11.0},
    "iss_pass.yaml": {**_small("sensor/", *GEN4), **ISS_RUN, "stars.faint_limit_mag": 9.0},
    "iss_pass_burst_arbiter.yaml": {**_small("scene/sensor/", *GEN4), **ISS_RUN, "scene/stars.faint_limit_mag": 9.0},
    "iss_pass_low_noise.yaml": {**_small("scene/sensor/", *GEN4), **ISS_RUN, "scene/stars.faint_limit_mag": 9.0},
    "limiting_magnitude_events.yaml": {**LIMITING, "sensor/camera.width_px": 64, "sensor/camera.height_px": 64,
                                       "detector.look_s": 0.5},
    "limiting_magnitude_frames.yaml": {**LIMITING, "sensor/camera.width_px": 64, "sensor/camera.height_px": 64,
                                       "sensor/frames.frame_rate_hz": 2.0, "sensor/frames.exposure_s": 0.5},
    "onsky_scan_200mm.yaml": {"run.duration_s": 0.5, "sensor/camera.width_px": 64, "sensor/camera.height_px": 64,
                              "inject.n_sources": 4},
    "onsky_stare_85mm_hvga.yaml": {**LIMITING, "sensor/camera.width_px": 64, "sensor/camera.height_px": 64,
                                   "detector.look_s": 0.5},
    "onsky_stare_85mm_vga.yaml": {**LIMITING, "sensor/camera.width_px": 64, "sensor/camera.height_px": 64,
                                  "detector.look_s": 0.5},
    "onsky_stare_135mm_gen4.yaml": {**LIMITING, "sensor/camera.width_px": 64, "sensor/camera.height_px": 64,
                                    "detector.look_s": 0.5},
    "onsky_stare_135mm_vga.yaml": {**LIMITING, "sensor/camera.width_px": 64, "sensor/camera.height_px": 64,
                                   "detector.look_s": 0.5},
    "scan_star_streaks.yaml": {**_small("sensor/", *GEN4), "run.duration_s": 0.1, "stars.faint_limit_mag": 9.0},
    "scene_pass.yaml": {"run.start": "2023-03-20T19:19:59.8Z", "run.duration_s": 0.2, "camera.width_px": 320,
                        "camera.height_px": 180, "camera.pixel_pitch_m": 1.944e-5, "stars.faint_limit_mag": 10.0},
    "sl-16-rb.yaml": {**_small("sensor/", *VGA), "run.duration_s": 0.2, "stars.faint_limit_mag": 8.0},
    "space_based.yaml": {**_small("sensor/", *VGA), "run.duration_s": 0.1},
    "starlink_field.yaml": {**_small("sensor/", *GEN4), "run.duration_s": 0.1},
}

#: sub-graphs that cannot run on their own (no run section, or inputs left to the including graph): each runs
#: inside the scenes that include it
SUBGRAPHS = {"limiting_magnitude_cmos.yaml": "limiting_magnitude_frames.yaml",
             "limiting_magnitude_scene.yaml": "limiting_magnitude_events.yaml",
             "onsky_stare_scene.yaml": "onsky_stare_85mm_vga.yaml",
             "onsky_stare_135mm_scene.yaml": "onsky_stare_135mm_vga.yaml"}

# scene: (digest of its resolved graph, SHA-256 of its run store); written by running this file
EXPECTED: dict[str, tuple[str, str]] = {
    "geo_sidereal.yaml": ("146b367fbac877b339632afe4154564f0a36cc00bf84f6309ebdda1b52abe42f",
                          "51bcfc5403071576d15c90ba5026eab0eb42ab07d7034348b3526a8742b5d3c3"),
    "iss_pass.yaml": ("bc3f3de73f747ceb28c3055aa6be8fa7f712797d6e3b77669df90081b57166d9",
                      "aa968610f8ecde1761c7618ffe0f55b2b210e39f8503432fdf09906fb493ff16"),
    "iss_pass_burst_arbiter.yaml": ("91a479a15d7b956fce25a9e23c467988dd946b4ce637734fc5edb33014805d7f",
                                    "af97d4391af624aed17ce815fe76c1324df6b5c7bfeb9f0192f85f1d1f43b29f"),
    "iss_pass_low_noise.yaml": ("dca7fdaeea2d1a24be50fce153a2742abba0370f08d809025537d97be251954e",
                                "bb1fa1840b7a99838dea9dcd1d683f43b097561e06e3a63b1c6afd44da594ec4"),
    "limiting_magnitude_events.yaml": ("e4ee5fcad88d12ddb7212a0d2d1bbaa891864f7484c4f7e38156b85b93b5d448",
                                       "fbed813bf6dfff62c5dfb68f486669fac4012192372230a433959e80ed688040"),
    "limiting_magnitude_frames.yaml": ("ea5833ff2f8356f43cec57c2de426978013386761331ac006b295309ea09be9e",
                                       "d42e74e96216e91a95a1701eab06bedbd0f584769f5cec34b55fdb9c50894b8d"),
    "onsky_scan_200mm.yaml": ("2d5bd45d160a0c3c23c7e74773431846f1c278258ae80942604c3d669955d775",
                              "7ae5dd51029eda0c216c14580efd51c9cbcd77d55e39307d04ceff3e5eac9d86"),
    "onsky_stare_135mm_gen4.yaml": ("0ff50c6cc9b5197375e631be05aca21aabda21811df2e9575a86095798596c83",
                                    "4b1451f362ef992ad80ac9472b61efb4eeb75b2d7ce3d77f7ccadec3dc4c9b5a"),
    "onsky_stare_135mm_vga.yaml": ("badc306d80ea70414c2737b0ef70afb60acee0899950deaea0828a9eb849c473",
                                   "6c387beca36272c0d031b8adde8d0b1514166cb4e7cab4833c838b836b67f6fd"),
    "onsky_stare_85mm_hvga.yaml": ("209058a7d9e73404b0230659627cc0dbd7551abc183127edc9c21c16020df284",
                                   "2e51b209fa9ee369a1da3cae159c715e499189ae4af2b1b0693b370f2ccb8d36"),
    "onsky_stare_85mm_vga.yaml": ("cae300631a345317c583c3657bcd19b36ffe894f9388e64aae706c0d2afc1245",
                                  "fbed813bf6dfff62c5dfb68f486669fac4012192372230a433959e80ed688040"),
    "scan_star_streaks.yaml": ("ca3e1c1429a183f1a1d33f5815d32bde1375bc13485c6ae2c78503f202208e6e",
                               "a6e8f113b6e918319e27d7c47834525c37e53757ece3585cf378f937ff2250b7"),
    "scene_pass.yaml": ("204b892e0f874da5e5a95683a31dec8cd507fe8351e7a3239c5b2e030f4723d4",
                        "0f5e5b13133b52f6eceedf1e4f5a4c436345348222278f056c456fae58dabbea"),
    "sl-16-rb.yaml": ("7efd4cd7d4d33c8464d25daf5066c60cd0fbbf701bac8c7eafe9d59bfc4a3036",
                      "4ef046293a1c411b365679aa2ee428856bc2197a751987bf77342e24bcbdbb77"),
    "space_based.yaml": ("8289ba9bf8d15b2fdcaacc303f9073e1518f84c4caa54a50925e89e86acdd074",
                         "83c90ed7e1aa4fe2b11742e6c97e3a4182a6b74887738d9448c84448433ae474"),
    "starlink_field.yaml": ("f4821f71887a5f98fd81733528785cb5caf0c76939b4bc57bb272e2227e18312",
                            "70c104d594ed530831cce1fd2107a6dbddd849887d1ec6b1a1856b2c6bda83ac"),
}


def graph_digest(graph) -> str:
    """The resolved graph's digest, with this checkout's path left out (file parameters are absolute)."""
    text = json.dumps(graph.to_dict(), sort_keys=True).replace(str(REPO), "<repo>")
    return hashlib.sha256(text.encode()).hexdigest()


def store_digest(path: Path) -> str:
    """SHA-256 of every array a run store records (events, products, truth, metrics) and of the metric
    values and the events' focal plane; checkpoints, timings and versions left out."""
    import zarr

    group = zarr.open_group(path, mode="r")
    digest = hashlib.sha256()
    for key in sorted(k for k in _array_keys(group) if not k.startswith("checkpoint")):
        data = np.asarray(group[key][...])
        digest.update(f"{key} {data.dtype} {data.shape}\n".encode())
        digest.update("\0".join(map(str, data.ravel().tolist())).encode() if data.dtype.kind in "OTU"
                      else data.tobytes())
    for key in ("metrics", "events"):
        if key in group:
            digest.update(json.dumps(dict(group[key].attrs), sort_keys=True, default=str).encode())
    return digest.hexdigest()


def _array_keys(group, prefix: str = ""):
    yield from (prefix + name for name in group.array_keys())
    for name, sub in group.groups():
        yield from _array_keys(sub, f"{prefix}{name}/")


def run_example(scene: str, out: Path, examples: Path = EXAMPLES) -> tuple[str, str]:
    """(graph digest, store digest) of the short version of ``<examples>/<scene>``."""
    from evsda.graph.executor import run_graph
    from evsda.graph.graphfile import load_graph

    graph = load_graph(examples / scene, dict(SHORT[scene]))
    run_graph(graph, out, progress=False)
    return graph_digest(graph), store_digest(out)


def test_every_example_runs_here_or_inside_another():
    assert sorted([*SHORT, *SUBGRAPHS]) == sorted(p.name for p in EXAMPLES.glob("*.yaml"))
    for sub, scene in SUBGRAPHS.items():
        assert sub in (EXAMPLES / scene).read_text()


@pytest.mark.parametrize("scene", sorted(SHORT))
def test_example_records_the_expected_bytes(scene, tmp_path):
    if scene not in EXPECTED:
        pytest.fail(f"no expected hash for {scene}; run `python tests/test_examples_identical.py`")
    expected_graph, expected_store = EXPECTED[scene]
    graph, store = run_example(scene, tmp_path / "run.zarr")
    if graph != expected_graph:
        pytest.skip(f"{scene} itself changed since its hash was recorded (parameters, presets or defaults); "
                    f"regenerate with `python tests/test_examples_identical.py`")
    assert store == expected_store, f"{scene}: same graph, different recorded bytes"


if __name__ == "__main__":
    import tempfile

    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"), tempfile.TemporaryDirectory() as tmp:
        print("EXPECTED: dict[str, tuple[str, str]] = {")
        for name in sorted(SHORT):
            graph, store = run_example(name, Path(tmp) / name.replace(".yaml", ".zarr"))
            print(f'    "{name}": ("{graph}",\n{" " * (len(name) + 9)}"{store}"),', flush=True)
        print("}")
