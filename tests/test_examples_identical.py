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
    "geo_sidereal.yaml": ("fb00ff3efb5c1432f2da0b0b1afa4cbe47be24142f635936e61dfc92cec5dc88",
                          "b313d4d8bf1c4e71f24865f1fa314a299b4d90597595db2014936eacc2c70f4c"),
    "iss_pass.yaml": ("fd6e8dcdee2cbf7af36759e4e36a0db33e2ee4105a68f47a196d492138e65971",
                      "d19a5188fc310088c677e052180828190b83f8548aedf7cc44d5d2489e91263d"),
    "iss_pass_burst_arbiter.yaml": ("635fc1825a6890344a5000142d81e976f58af008c566c0a3f6d4737200a96a76",
                                    "50e5895643a5e5837ae15566f8c1b9918f4a25220f040485742d76ddff9a6569"),
    "iss_pass_low_noise.yaml": ("f3e14e29d6e30eea5380efa84ebc5b10f84050c8ae7f92211489e3dd75286c51",
                                "45281451b7663bb06b5557480a1d269482637b783f34b9b64012529aff529074"),
    "limiting_magnitude_events.yaml": ("600f0cfb82eb96af30f406080a70b830a08fe415a846bfeb9a3879e758b5feed",
                                       "7743e66d386481c6c8c24d0005d370097079497c6e0fab0968ca6ce284b01aa8"),
    "limiting_magnitude_frames.yaml": ("8475b2e5ea0d83cde0be825baa49845b3d03e5ebf4b7548239d172201168cab2",
                                       "a057660e09196284d3b6c1dfa729867917fda97a693ff12b958b9af3128d3859"),
    "onsky_scan_200mm.yaml": ("cd87c9a431fa140a4b25c69e6deb33a2b516692a8f427062918cd8d107ade10e",
                              "10bf98c58130aa22c1675e3fad155dc5f07474dc67b87a0baee80073bf077f6e"),
    "onsky_stare_135mm_gen4.yaml": ("f9027f3a7dec6b11777fdde5a7e694b6d78f246c35576fbea879c4b6ba5438c4",
                                    "ef5a1f44e5c219f5b571be00c956b4115157b4b3e5d7b3c13ccb62e57eba0868"),
    "onsky_stare_135mm_vga.yaml": ("eb6f71d456f43a8fd94bbc402e78663336eee53ede803fc3f5a25f88a3b0b598",
                                   "3e97ecdf060d37196787b0c1164b60f9d7c0efaae58adbb3334b0ab06d40598d"),
    "onsky_stare_85mm_hvga.yaml": ("6f299a4c7ea606876543586516fee02094f3a93917f0a9435fe9c3bc00d55b1b",
                                   "61adcd555d79764fd2bd4f4c581707e81fbc102c95a9caeda53c3bf31375ac23"),
    "onsky_stare_85mm_vga.yaml": ("6da30d0949f25621b904c238b369a7f10f21683819168ad1265a924e2a022ff2",
                                  "7743e66d386481c6c8c24d0005d370097079497c6e0fab0968ca6ce284b01aa8"),
    "scan_star_streaks.yaml": ("9aa9050e855dc81496db3ddba000a4c8641a5bbde40aa5965fc663978e0b3aa3",
                               "469cddec6618af7efd88f8562a3e7d5b947c0fceff7ab603d7d2ccc1ea3c1cf5"),
    "scene_pass.yaml": ("edb56c2b63484c3ab742a99cfe5fcb978144de9981bdf3b7b12415e13000c83c",
                        "8566a623e4547ddc0cf27b03d8061786147086d9af05342e5483c66e56aa559f"),
    "sl-16-rb.yaml": ("e194a79f47ed1aaa11431506dd983e8462f949e5f136d44ae4e1ad5c8c60fdff",
                      "ff7ff331d346c26c0169a5aa663c4c59e31eb6ba8e17e075d1327c474e4f8b83"),
    "space_based.yaml": ("fb3f6782908e18865e676fffbe19ce75e30608e8005fe0d077978f07b5f026e2",
                         "bccce637d4122891c76e6dd6b8abdb7431aa33139513e8945f0ebef8d98d23f1"),
    "starlink_field.yaml": ("70342b7bd44f406042c66ca1c21bf45c751dc2553b6873aad081f6d40321c5cd",
                            "7065a742593d86dbb92422709ffe17a67e739a4bb631707b2e6d519ee2bcd839"),
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
