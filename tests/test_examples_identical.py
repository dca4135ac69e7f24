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
             "limiting_magnitude_scene.yaml": "limiting_magnitude_events.yaml"}

# scene: (digest of its resolved graph, SHA-256 of its run store); written by running this file
EXPECTED: dict[str, tuple[str, str]] = {
    "geo_sidereal.yaml": ("3a20fb45f735dffd0beae639bda9debb1d46fe714f004c83c66909ee98e949cf",
                          "eaa053be4850201506867cc9c06f63448a3dd542136b30348f66aa167c31c532"),
    "iss_pass.yaml": ("9dc0224b409bac9e058bf80125f459713350dd160999bf165839f1fea94f3490",
                      "60b7838df90ed5978ca79b1f5043520fd2e8ce82379a251218ba1fca16f00ef8"),
    "iss_pass_burst_arbiter.yaml": ("dd499e370664d42c40e1b4e4ea15723444069b65cf4c1a918d3b97c125083438",
                                    "3b3e74a06d05b6b2814051a101ee7003cccec96a9f6795ac3d49f3557831d460"),
    "iss_pass_low_noise.yaml": ("2069e028adb1d58e6e8c2bbfc19be93224c05b5a7b2536c2155251b0934eed02",
                                "7845da4a2ed0b30b3d262eef00431326fbf161c614a080dc98cf5c2f8b32b7e3"),
    "limiting_magnitude_events.yaml": ("8a2b90917545ead9823423de44a588851175243ccf287abe7c8170f815d82d01",
                                       "c414c70f1b45dcf49e6da0335ce3b7d120cef128fe198137b021810a274eb700"),
    "limiting_magnitude_frames.yaml": ("8475b2e5ea0d83cde0be825baa49845b3d03e5ebf4b7548239d172201168cab2",
                                       "a057660e09196284d3b6c1dfa729867917fda97a693ff12b958b9af3128d3859"),
    "onsky_scan_200mm.yaml": ("aeb8ed773d0617a4d724510486a241471a21eec569eccd54be7e3bb778011d53",
                              "60ae5bca579d1377592557d8862fbb8b8a39678de7e3fb0e51a1706860cbcb34"),
    "scan_star_streaks.yaml": ("b9e7b88abbf097153c5ab6f457b3b1ebec6f87a10adb53ec20da2595ff43cc5d",
                               "6a7d1b3e64817fcd025f45c43d5614c88554f7f9d2694a859fd09c07b07bb8c1"),
    "scene_pass.yaml": ("edb56c2b63484c3ab742a99cfe5fcb978144de9981bdf3b7b12415e13000c83c",
                        "8566a623e4547ddc0cf27b03d8061786147086d9af05342e5483c66e56aa559f"),
    "sl-16-rb.yaml": ("b146c0ffb9b0b2d2a7117ba3e98d5ce33ae79e9deb56b571ff41f670109c7175",
                      "eb2fdc840b6229e577fde4d741e2f6a0d30b2646ee5c974044740064417a4221"),
    "space_based.yaml": ("fe6ff0e8bdea8a6ce8f2bec92df7d8733f8600d956cac8e24919e1047cdfe2a3",
                         "59b193b1214f59f9ce324d45b90aae0804ca0dcaf202f18440873f3bc932e1ec"),
    "starlink_field.yaml": ("67af36f2dd6983192985a12aa7e33bdcf0665d13e22a90e4e9643c760a4ec23b",
                            "690b1efe4ab5536661a1a1e240d9590c080323b17f1ad10c87cfb4432e9b7b51"),
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
