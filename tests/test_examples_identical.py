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
    "geo_sidereal.yaml": ("d938c74ec4aa4315ac4999691faa2e9676ee77e23712d63da74d35a618e18f7b",
                          "65ed485fdda33a2a2ffe9f9730c5250f9f5e2ce77e835fd3c601da487732491b"),
    "iss_pass.yaml": ("2ed3b1ab41ce9e7f907e81a91b4e88d8bfd61e3391bd6c3f6482fcd3320ccb80",
                      "16bbe224b4288c9fb1891b66e6f5ce5b0d9c43b21db0ec7f1e610bfb1ff15d43"),
    "iss_pass_burst_arbiter.yaml": ("eb78d49376cdf441280cf65a0106d796e382ddfe0600cfdccbe95be24dee06a8",
                                    "e4b8dfa31979a5f90f8408bd261b204a95ba658d0d6f39abbc3c4aed717cbfd5"),
    "iss_pass_low_noise.yaml": ("7b5a95d7785d3362020b04eb5215474da0261fdf4fdbe8772c977bb849f1cc44",
                                "4ab459f34058812b257ce6aca5e899bac1eb9be90829ee48b8ec811e76c7fc06"),
    "limiting_magnitude_events.yaml": ("9ce2925f849fce449ff9117f0fa1a9d7a2001240ba7f24233f9c2aa87ba3f378",
                                       "9af1199ed294cd3c00e20905a02d86d616b657836110fce30599a449c936e365"),
    "limiting_magnitude_frames.yaml": ("8a810ad5f32c40330bc0b71c32657147d0b239992adb2acb679c4589bdd7a18b",
                                       "a057660e09196284d3b6c1dfa729867917fda97a693ff12b958b9af3128d3859"),
    "onsky_scan_200mm.yaml": ("84ccf1545e83f1d8ecef69047dd243807200a06ce96c174a16315c88bec8e6df",
                              "34c73d16f30688187572225ff496c7c8725f66dc3628cc8d3637fb55e4dacc6f"),
    "onsky_stare_135mm_gen4.yaml": ("ee2cf9e6737189880a760bb08cd15298ff7bf8f456c3bbde9db6daff010c1626",
                                    "533506ede61047f6424e6c9a1106f6c55927a4a47f220442636ac91d59af573c"),
    "onsky_stare_135mm_vga.yaml": ("3f303666b72112886b54fa8a54f6f18669eec339045fe0782598f5b43981bde6",
                                   "4d2d93f535805b30dcd738e66657bf76bb75e5d5e202d003d259caedbab9d8e2"),
    "onsky_stare_85mm_hvga.yaml": ("dd1dd4de8918f1ed5432dce77a4f73044619f7b3585982f3388b837a8b2ad3ac",
                                   "bcde93be506719faa42569cebf5ff368a6258057fda692a759587b10a8a6a703"),
    "onsky_stare_85mm_vga.yaml": ("54dd1bb03de615077a0588e5f15d19818bdbb6aa56ce024428bdc8907ac17b08",
                                  "9af1199ed294cd3c00e20905a02d86d616b657836110fce30599a449c936e365"),
    "scan_star_streaks.yaml": ("aa790aeeb21865f975e5f33cd371b3f1c6f023a970b0a7f7ba1c1a566c57874b",
                               "08ffadf382db59320ff10215980bd47bf6de05aff72f966e22dcca1f39e4a21d"),
    "scene_pass.yaml": ("edb56c2b63484c3ab742a99cfe5fcb978144de9981bdf3b7b12415e13000c83c",
                        "f3bb221d1faf2810212c01ba974e99480673b56a56ee2258385d0311e5ccdcd2"),
    "sl-16-rb.yaml": ("c79a6f8a654beefce6fa5ac82093175616f18197325c25a9cc2d6ad32ae45c32",
                      "9a7b63c5d4bfb1ec60f46aeebc76feeb22cf95d6d28db5ffe9a1bfd14f3f84a6"),
    "space_based.yaml": ("86d6ade4c0fb6414b995ad9abb7d57d060150162508163c09aec2f2984c036ce",
                         "bcc6c7901a7004a975d9655bf7933f0166bad75aa479140ef0c10e3e80ee0e3b"),
    "starlink_field.yaml": ("da189ba663badbed92145d04e1d916bdde1a32d5f4cbc372593fb13956a5e76c",
                            "a73e309e2949f4a87cc52545bd871729a8a9d334a42660ad5ec253cbba7f68c5"),
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
