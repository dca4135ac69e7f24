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

#: scenes also run with every source rendered at every render time (the optics' ``source_intervals: false``): that
#: switch keeps the bytes the scene recorded before per-source render intervals were the default (issue 13)
BASE_RATE: dict[str, dict] = {"iss_pass.yaml": {"telescope/optics.source_intervals": False}}

# scene: (digest of its resolved graph, SHA-256 of its run store); written by running this file
EXPECTED: dict[str, tuple[str, str]] = {
    "geo_sidereal.yaml": ("08d51ac77d464bd89ed0710032d0887d86657389036450269a82ad50b7c908b5",
                          "51bcfc5403071576d15c90ba5026eab0eb42ab07d7034348b3526a8742b5d3c3"),
    "iss_pass.yaml": ("6a206dd4f655c266db661af6264db0d775fc463e40365bdd6041361cee171707",
                      "e0753f96519e81d0fb4f467c946ba1c7a127a3f2a94ed1eaa965431ff557be5d"),
    "iss_pass_burst_arbiter.yaml": ("34c282e0c74823d181e75f0d5aa450855f563d8ea87dfdaeed342b6e090c390b",
                                    "af97d4391af624aed17ce815fe76c1324df6b5c7bfeb9f0192f85f1d1f43b29f"),
    "iss_pass_low_noise.yaml": ("49cee81bceca6669a16830a46b409bfccaf04b71ec8be83ce48944cbea7f344c",
                                "bb1fa1840b7a99838dea9dcd1d683f43b097561e06e3a63b1c6afd44da594ec4"),
    "limiting_magnitude_events.yaml": ("dd7c1b9395f1d098c3ceff01e6b67c299338da3494582d1277a1043587c72155",
                                       "2693b5a4e32f3dd1ffa9de52fbc65c5027c1a17a583085a01752cdfd36b72de6"),
    "limiting_magnitude_frames.yaml": ("db0092e55e7b96b961855fca33227cfe77127e8fe5551c1d7ed1bee4c20ffd57",
                                       "70674ad5cfd0b99f19690ec65cd1c0cc1cdd013b99e795e0570d7f0a6ba6efcf"),
    "onsky_scan_200mm.yaml": ("97aef17e0cec598172c71979227b39f094cf83e57797eb8cc7706046fcfa71b6",
                              "e9a664c3fa9858ae9786d7026b3c8166058f1528d73e61e238f3f814f2a9d0ca"),
    "onsky_stare_135mm_gen4.yaml": ("6912d21407f5b1b924c03d102735d3a918e4b7f2cf0919f71bd8f31b80189916",
                                    "e624584c3df30fef3ef4e6027108c809f913d8a8c2127b028fb434fdfba081d8"),
    "onsky_stare_135mm_vga.yaml": ("0ed75c8e498f63bd71a88cda50a0ab24fc8303934156b3c645ce00f88a6f4c50",
                                   "74afe0a7e2ecaa8f4e663e78494eeb0597d3955aa5d024910158517c5507b42f"),
    "onsky_stare_85mm_hvga.yaml": ("4fd92ccaea73739202cb4953bcbaaf3f54cdd17675fe87bce83f8dbb3f61c5e6",
                                   "440b5219d65b391f20676b3482db5b15906a336e71bd944040596af3019816e9"),
    "onsky_stare_85mm_vga.yaml": ("f453cefde6533f4f3c57ee38591e3fbae59d0b818572abf6f60e68fde47f721b",
                                  "2693b5a4e32f3dd1ffa9de52fbc65c5027c1a17a583085a01752cdfd36b72de6"),
    "scan_star_streaks.yaml": ("6b29e6f069451f2b3c509014dd119cf60e62c461a4796f0b68494cfe3ee06a68",
                               "a6e8f113b6e918319e27d7c47834525c37e53757ece3585cf378f937ff2250b7"),
    "scene_pass.yaml": ("204b892e0f874da5e5a95683a31dec8cd507fe8351e7a3239c5b2e030f4723d4",
                        "0f5e5b13133b52f6eceedf1e4f5a4c436345348222278f056c456fae58dabbea"),
    "sl-16-rb.yaml": ("c82aa8155222233bcbc66e139dfc70b1e963632665dda5fd25f9ee1b4bbee42d",
                      "4ef046293a1c411b365679aa2ee428856bc2197a751987bf77342e24bcbdbb77"),
    "space_based.yaml": ("861aac0382218120b61ae4a8b6b45c964ff75a72d43422df668f5caac54cf2a2",
                         "1cd736c2174ffd3f6ef305aed912be6bec6c9314c7077291e2dea39b68fb9ccc"),
    "starlink_field.yaml": ("0a0735ef824c0d17d4e8354da1f4cd62a9925934d4e7a1db663da8abd242b36e",
                            "70c104d594ed530831cce1fd2107a6dbddd849887d1ec6b1a1856b2c6bda83ac"),
}

#: the scenes of BASE_RATE with the switch off (the store digest they recorded before the render intervals)
EXPECTED_BASE_RATE: dict[str, tuple[str, str]] = {
    "iss_pass.yaml": ("f65fce2cbe3bb423406b423849bbdbc334e43bf149de7ab7a513cee108b9ab50",
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
