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
    "geo_sidereal.yaml": ("6e0729d7e7e8f11ed663c2d88cd44fb4a0e1b61a5cd63edbe803a78e90fb0c8d",
                          "0cd0a38fde06b168687960ab298791d8dfe3766efe6ba71756751f656d87ab3d"),
    "iss_pass.yaml": ("6f1b90c5a5032a4849aff00c840ae257810825c3240fc0457792fb36f3f6828a",
                      "2a3f7ca6efbbf7bcae33423ca46fecc785dad6f62f4e7cf99d1add19f9539b2b"),
    "iss_pass_burst_arbiter.yaml": ("2c430d50df3f48c1f1978313808f7d5341bc31b57d4227fe47a585b1170486d4",
                                    "40351b83c4884527de6109e08ce5dace35592b8f5065dc1d8adf28f545c05aa1"),
    "iss_pass_low_noise.yaml": ("b5bcc7fc9cd1d0ab940e23e742dfac4f8e3c74d2b1925a2d534689551fd9f1a7",
                                "c178aee0708a5b97a1096e00cf88eb6a5ea972762ecbe4013fb99a4754a951b7"),
    "limiting_magnitude_events.yaml": ("77266e03c988f90f1d93c3a91aa286aca4479699a44b3aa9ec6ee096c9fba264",
                                       "b7a472ccb33d8f35ebaafbff73668807b15aa9ca10fccd13ff9b1e050b2a0c92"),
    "limiting_magnitude_frames.yaml": ("8a810ad5f32c40330bc0b71c32657147d0b239992adb2acb679c4589bdd7a18b",
                                       "a057660e09196284d3b6c1dfa729867917fda97a693ff12b958b9af3128d3859"),
    "onsky_scan_200mm.yaml": ("e8aeb33a02cabe2007291e1af3454fbb19248de0a75de3a666c1237cd3d25a17",
                              "9c1e7bcf4389ead4f680865c71e44b0d2331aeebcc3a4f36a2ab256c4e38ded4"),
    "onsky_stare_135mm_gen4.yaml": ("cf60fea777b08a22944243f244110d1fe9d8e19af3f606d5696284a512d5d36f",
                                    "2f46353956ea3cb1c6eb77e7ea32d6b944f035e4f722bc4485c5c50229bb6e59"),
    "onsky_stare_135mm_vga.yaml": ("48648f8a9b0a6decfa9c79fd80f02aaf415d0f7238a8353f81aea39240ad2499",
                                   "d8fea9b57b3f67254399519ae0cb31d51155298a0274a0dd54822049b41f05f5"),
    "onsky_stare_85mm_hvga.yaml": ("3a45668f1cb0b4dbe848b26cf3fa40717d7351c47d40986fdc6ad803d6024d89",
                                   "9a88b0827c94240b0d6f27be899605ab0f69370960a3d39cd7a075f385ba83b0"),
    "onsky_stare_85mm_vga.yaml": ("095a4a6a44f5bd766495b2d0f313d633a505d878587667a46b9c232dc359297f",
                                  "b7a472ccb33d8f35ebaafbff73668807b15aa9ca10fccd13ff9b1e050b2a0c92"),
    "scan_star_streaks.yaml": ("d88945922a1d57dd279bab1d1645987a212f2f115d022311115add2adf2e58df",
                               "469cddec6618af7efd88f8562a3e7d5b947c0fceff7ab603d7d2ccc1ea3c1cf5"),
    "scene_pass.yaml": ("edb56c2b63484c3ab742a99cfe5fcb978144de9981bdf3b7b12415e13000c83c",
                        "8566a623e4547ddc0cf27b03d8061786147086d9af05342e5483c66e56aa559f"),
    "sl-16-rb.yaml": ("324d45e663b3f9ddd5973039cf83553f2b26eee7046aa81ffab4fd11824b3507",
                      "e9cb282b8adca70523f25bd65c968465a60b604a769a5696a82db41edf1f776a"),
    "space_based.yaml": ("2b8fce249566ee4763483c832eb8a3d155f13a9e0cdbb3d8bd7873af4ac56485",
                         "e40a382309d466f1c75d3e079904a8872de6c360ec225ad120ba66dd6acc9ca0"),
    "starlink_field.yaml": ("814b53701ff8f7d125ea92213252422d2f938eb0892ebc1eaeaf3014c15a18b8",
                            "e48f7c9c1dfa921e1314ebdc136a6b08254dd26207d26ed67b0b23725d66c8bd"),
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
