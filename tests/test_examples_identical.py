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

#: scenes also run with every source rendered at every render time (the optics' ``source_intervals: false``) and on
#: every layer of the profile (``equivalent_layers: null``): those switches keep the bytes the scene recorded before
#: per-source render intervals and equivalent layers were the defaults (issue 13)
BASE_RATE: dict[str, dict] = {"iss_pass.yaml": {"telescope/optics.source_intervals": False,
                                              "telescope/optics.equivalent_layers": None}}   # every layer, as then

# scene: (digest of its resolved graph, SHA-256 of its run store); written by running this file
EXPECTED: dict[str, tuple[str, str]] = {
    "geo_sidereal.yaml": ("dd8d6bd571252acbc56328bf987136fe36ae1e359209d2df3d044df445c4ab72",
                          "90cad39ef6054625233f332f654829941a3d684e470c3bd9fc00f915a26a7788"),
    "iss_pass.yaml": ("52ac9a8df4992717e7f23450536dd177f01bd3846873911af14daff91dc225d8",
                      "888fbef1a26d49cc5183feea0e06b279fcba01c6f49b2514097b4d6a7cbcf2e0"),
    "iss_pass_burst_arbiter.yaml": ("9b975a6fbdcbd38f9216b357a8e831947cc7c728f38e0f894bc29fb77a312022",
                                    "291142ebc42c8253acb5aa770d09c9df8e7a2111ad736676ea1600926fb2b66a"),
    "iss_pass_low_noise.yaml": ("8934dba1a54ffd56cdd0075b0c8294502461df625d74fb18250a5d3f01eb0172",
                                "f3a1d17cf2b6563d5098c8240e2a5b4e33f128c40e78f52fb785c235246043c2"),
    "limiting_magnitude_events.yaml": ("c0c09bb1e39aacc6bb1e02a2207c12b5d4acc4e77ad6471c06513cfedf0a7e43",
                                       "2693b5a4e32f3dd1ffa9de52fbc65c5027c1a17a583085a01752cdfd36b72de6"),
    "limiting_magnitude_frames.yaml": ("3de011de5d8aac32d08b69b34edf5eab8482b85e27ea4964345899202e9cabd8",
                                       "70674ad5cfd0b99f19690ec65cd1c0cc1cdd013b99e795e0570d7f0a6ba6efcf"),
    "onsky_scan_200mm.yaml": ("c5d9618ecffcb7b1e03dda0909af37bf9c46de87c128a881366cbd91d3c210ab",
                              "e9a664c3fa9858ae9786d7026b3c8166058f1528d73e61e238f3f814f2a9d0ca"),
    "onsky_stare_135mm_gen4.yaml": ("a8bed5bfc088fafdb6dc22cd02f592c6b7a31b18b46ce617c76faa4c514373f9",
                                    "e624584c3df30fef3ef4e6027108c809f913d8a8c2127b028fb434fdfba081d8"),
    "onsky_stare_135mm_vga.yaml": ("cb8f8fe865856b632ffb1bb35fbf75f4020a33dc60cb1a53d1f62b103287ab64",
                                   "74afe0a7e2ecaa8f4e663e78494eeb0597d3955aa5d024910158517c5507b42f"),
    "onsky_stare_85mm_hvga.yaml": ("465aace8b2ad7c778b4f9a3ab5eac70dbf392d96983efdc47bc8202d0a1bdff4",
                                   "440b5219d65b391f20676b3482db5b15906a336e71bd944040596af3019816e9"),
    "onsky_stare_85mm_vga.yaml": ("4fa75087b5aca5a62aef09ec97f5842679f3e107bf222846d2c8a318ce8a1404",
                                  "2693b5a4e32f3dd1ffa9de52fbc65c5027c1a17a583085a01752cdfd36b72de6"),
    "scan_star_streaks.yaml": ("03f660ff9007d607750a7c19f1f2ef1db317800d68b71dd7e0e95899df49b274",
                               "a6e8f113b6e918319e27d7c47834525c37e53757ece3585cf378f937ff2250b7"),
    "scene_pass.yaml": ("204b892e0f874da5e5a95683a31dec8cd507fe8351e7a3239c5b2e030f4723d4",
                        "0f5e5b13133b52f6eceedf1e4f5a4c436345348222278f056c456fae58dabbea"),
    "sl-16-rb.yaml": ("9e402ca719d0fc8360984ec9384e9534914bcde536280766997a579aa3c2716f",
                      "ee2173da373fa8a18707cea8fb22b3d4a507b430d9faa0e190202b1ebe2b21ed"),
    "space_based.yaml": ("801bdaee5f395e03d0a616b8fc352d306614372f9283f4cbdc6630ad37f62614",
                         "1cd736c2174ffd3f6ef305aed912be6bec6c9314c7077291e2dea39b68fb9ccc"),
    "starlink_field.yaml": ("3fc9080c9a9f8df83ed0f25d37be70d39458b2e469a9625de710515f3ff12289",
                            "70c104d594ed530831cce1fd2107a6dbddd849887d1ec6b1a1856b2c6bda83ac"),
}

#: the scenes of BASE_RATE with the switch off (the store digest they recorded before the render intervals)
EXPECTED_BASE_RATE: dict[str, tuple[str, str]] = {
    "iss_pass.yaml": ("1fc1b20665066feb1cbcfcc73220475cd40bc500df6cff431ee41b2b7ba3fddc",
                      "aa968610f8ecde1761c7618ffe0f55b2b210e39f8503432fdf09906fb493ff16"),
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


def run_example(scene: str, out: Path, examples: Path = EXAMPLES, more: dict | None = None) -> tuple[str, str]:
    """(graph digest, store digest) of the short version of ``<examples>/<scene>`` (``more``: more overrides)."""
    from evsda.graph.executor import run_graph
    from evsda.graph.graphfile import load_graph

    graph = load_graph(examples / scene, {**SHORT[scene], **(more or {})})
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


@pytest.mark.parametrize("scene", sorted(BASE_RATE))
def test_example_at_the_base_rate_records_the_bytes_from_before_render_intervals(scene, tmp_path):
    expected_graph, expected_store = EXPECTED_BASE_RATE[scene]
    graph, store = run_example(scene, tmp_path / "run.zarr", more=BASE_RATE[scene])
    if graph != expected_graph:
        pytest.skip(f"{scene} itself changed since its hash was recorded; regenerate with "
                    f"`python tests/test_examples_identical.py`")
    assert store == expected_store, f"{scene} with every source at the base rate: same graph, different bytes"
    assert store != EXPECTED[scene][1], f"{scene}: the render intervals change nothing here; pick another scene"


if __name__ == "__main__":
    import tempfile

    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"), tempfile.TemporaryDirectory() as tmp:
        print("EXPECTED: dict[str, tuple[str, str]] = {")
        for name in sorted(SHORT):
            graph, store = run_example(name, Path(tmp) / name.replace(".yaml", ".zarr"))
            print(f'    "{name}": ("{graph}",\n{" " * (len(name) + 9)}"{store}"),', flush=True)
        print("}")
        print("EXPECTED_BASE_RATE: dict[str, tuple[str, str]] = {")
        for name in sorted(BASE_RATE):
            graph, store = run_example(name, Path(tmp) / name.replace(".yaml", "_base.zarr"), more=BASE_RATE[name])
            print(f'    "{name}": ("{graph}",\n{" " * (len(name) + 9)}"{store}"),', flush=True)
        print("}")
