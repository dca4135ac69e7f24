"""The pixel block's compile tasks and warm-up scene, compiled ahead in a second process when a run starts with an empty
Numba cache."""

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from evsda.blocks.pixel import warm_up
from evsda.blocks.pixel.params import DvsPixelParams

MAIN_JOB = Path(__file__).parents[2] / "examples" / "iss_pass.yaml"

#: in a fresh interpreter: the warm-up scene with the main job's pixel parameters, then the main job; the compiled
#: pixel loops' argument types (Numba signatures) that the run added to the scene's
SCENE_THEN_RUN = """
import json, sys
from evsda.blocks.pixel import DvsPixel, warm_up
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

def signatures():
    return {f"{name}.{key}": set(map(str, value.signatures)) for name, module in list(sys.modules.items())
            if name.startswith("evsda.blocks.pixel.") for key, value in vars(module).items()
            if getattr(value, "signatures", None) and getattr(value, "__module__", None) == name}

graph = load_graph(sys.argv[1])
pixel, = [block for block in graph.blocks.values() if isinstance(block, DvsPixel)]
warm_up.run_small_scene(pixel.params.model_dump(mode="json"))
scene = signatures()
run_graph(graph)
print(json.dumps({"scene": sorted(scene), "new": {name: sorted(types - scene.get(name, set()))
                                                  for name, types in signatures().items() if types - scene.get(name, set())}}))
"""


#: in a fresh interpreter: the compile tasks (loaded where the cache holds them), then the warm-up scene; the compiled
#: pixel loops' argument types that the scene added to the tasks'
TASKS_THEN_SCENE = """
import json, sys, tempfile
from evsda.blocks.pixel import warm_up
from evsda.graph import compile_ahead

def signatures():
    return {f"{name}.{key}": set(map(str, value.signatures)) for name, module in list(sys.modules.items())
            if name.startswith("evsda.blocks.pixel.") for key, value in vars(module).items()
            if getattr(value, "signatures", None) and getattr(value, "__module__", None) == name}

with tempfile.TemporaryDirectory() as claims:
    compile_ahead.compile_claimed(warm_up.TASKS, claims, range(len(warm_up.TASKS)))
tasks = signatures()
warm_up.run_small_scene({})
print(json.dumps({"tasks": sorted(tasks), "new": {name: sorted(types - tasks.get(name, set()))
                                                  for name, types in signatures().items() if types - tasks.get(name, set())}}))
"""


def test_the_tasks_compile_every_loop_the_scene_calls():
    """The compile tasks cover the scene's calls: after them the scene compiles no pixel loop for other types."""
    env = {**os.environ, "EVSDA_COMPILE_AHEAD": "off"}
    out = subprocess.run([sys.executable, "-c", TASKS_THEN_SCENE], env=env, capture_output=True, text=True, check=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert {f"{function.replace(':', '.')}" for function, _ in warm_up.TASKS} <= set(result["tasks"])
    assert result["new"] == {}


def test_the_scene_fires_and_calls_a_compiled_loop_of_every_module_it_names():
    assert warm_up.run_small_scene(DvsPixelParams().model_dump(mode="json")) > 0     # the streaking spot fires
    for name in warm_up.MODULES:
        compiled = [value for value in vars(importlib.import_module(name)).values()
                    if getattr(value, "_cache", None) is not None and value.signatures
                    and value.targetoptions.get("inline") != "always" and value.__module__ == name]
        assert compiled, f"{name} has no loop the scene called"


@pytest.mark.slow
def test_after_the_scene_the_main_job_needs_no_other_pixel_compile():
    """Every compiled pixel loop the main job calls, it calls with argument types the scene called it with: a cache
    the scene filled holds every pixel loop the run needs (the run then compiles none of them)."""
    env = {**os.environ, "EVSDA_COMPILE_AHEAD": "off", "EVSDA_CACHE": "off"}
    out = subprocess.run([sys.executable, "-c", SCENE_THEN_RUN, str(MAIN_JOB)], env=env, capture_output=True,
                         text=True, check=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert "evsda.blocks.pixel.pixel_loop.start_pixels" in result["scene"]
    assert result["new"] == {}
