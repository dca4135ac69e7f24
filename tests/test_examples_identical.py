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
    "geo_sidereal.yaml": ("b51ad058e84dea196c875331a29dc6b2f30612ab9dbafe445491f4ced1371afc",
                          "c404a80b35e0f462abdbc64e73da982fb420e9fe5e97a45cab58b41a13b39577"),
    "iss_pass.yaml": ("2a1720633cc49445cb7d79655427301a97a165de0a4645223e576b36b318deb0",
                      "39044329c6ce0a5cf9e01702678957603345e74c03b119d446e1a35aa57af97c"),
    "iss_pass_burst_arbiter.yaml": ("201f8cfd7892b71a249514bbc8b97c33de4f0233d49e560429033f9acf9167dc",
                                    "2d3c1afafb7a00686465ddac10d91f02e949233676e02c7ef2a2021ab007bbd6"),
    "iss_pass_low_noise.yaml": ("6ab0c9f9aa7d37d0a698e27c5cfb6922064203b30d3d92074ebf7916d73419e1",
                                "60e9db6c43c68505d5f8da87ddbd0768366fa94613c9432ce8dd7374e5e7c8d7"),
    "limiting_magnitude_events.yaml": ("9e9355efadf8974e338b8b906d68fa38d4837cdac1c67fb42a4c79ffa1afabce",
                                       "216c1e3a28373810cbd2c65fa6b32534e4484753bf73f82f606641c1b6cb99ef"),
    "limiting_magnitude_frames.yaml": ("8a810ad5f32c40330bc0b71c32657147d0b239992adb2acb679c4589bdd7a18b",
                                       "a057660e09196284d3b6c1dfa729867917fda97a693ff12b958b9af3128d3859"),
    "onsky_scan_200mm.yaml": ("458722bb00182bad3bdadfd28476f30fbd2ca1ae5d40b18df00772cc4cc099ba",
                              "d404900df7adf51926acaab935cea530b72e1644a5398b95e2d9576ffe18b8d9"),
    "onsky_stare_135mm_gen4.yaml": ("a099c7ff2085473d9764e194b25d1d4e126ee3bfc6e6f27b4386e9952ea26116",
                                    "76e2dca29b30412e14b5f56155ef7c11614dd62f7b253796ba29838b4aeabdbd"),
    "onsky_stare_135mm_vga.yaml": ("d662762595d75ab972e8da1a4d9c832bdd9473dc4126ea712abe1e4388a03c65",
                                   "3dc7bce59720a3ca701637a2176a2f601cd03bc7dc4539398697b3d47975422d"),
    "onsky_stare_85mm_hvga.yaml": ("6c46bee1d6ab9afba14a0dfff6359c3bbd7a0541a5d658ac1bac520b277f61d9",
                                   "04f63bfafe86c9cb4653fa58ebec3b44578408eec3606b4f35b2218a0975b4fe"),
    "onsky_stare_85mm_vga.yaml": ("4e91cee252dd84c6f315c27e17fc3693c13fd83d29669fa0f55ecb9fa50fc439",
                                  "216c1e3a28373810cbd2c65fa6b32534e4484753bf73f82f606641c1b6cb99ef"),
    "scan_star_streaks.yaml": ("fa1673320e5fddd9cd2968c7bdb1bd1cdefbb9f49e1ee9e9fb9432402f441e79",
                               "469cddec6618af7efd88f8562a3e7d5b947c0fceff7ab603d7d2ccc1ea3c1cf5"),
    "scene_pass.yaml": ("edb56c2b63484c3ab742a99cfe5fcb978144de9981bdf3b7b12415e13000c83c",
                        "8566a623e4547ddc0cf27b03d8061786147086d9af05342e5483c66e56aa559f"),
    "sl-16-rb.yaml": ("a7981c5c3c69007cc36700c788f6f29b0dbe602094d35b2bb97c633373e4d0e3",
                      "d45b5c715f26d5f0faed24924032e2b215f41121d824dd4461b63df5a6b2b99d"),
    "space_based.yaml": ("62c358a97e63cf3173bf2aaf92d934f004bd702b332ffea165a5a397b54bdd4e",
                         "fb94591790f8d01c1723900ece100abd177ecb348e2e442256abdc79d55ab9d0"),
    "starlink_field.yaml": ("4744564c929f0fbf744de131d151fafd1545bf90ecc82bdfec48244b3c7edc77",
                            "c25776f197ac6902b2dc792b1768a651b1d62bf0ef6424483d00e79d56b39a56"),
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
