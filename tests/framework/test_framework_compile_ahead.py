"""Compiling ahead (evsda.graph.compile_ahead): a child process fills the Numba cache that this process then loads."""

import json
import os
import subprocess
import sys
import textwrap

import pytest

MODULE = textwrap.dedent("""
    import os, signal
    import numba

    @numba.njit(cache=True)
    def twice(x):
        return 2 * x

    def warm(n):
        twice(n)

    def fail(n):
        raise RuntimeError("the warm-up broke")

    def killed(n):
        os.kill(os.getpid(), signal.SIGKILL)
""")

PARENT = textwrap.dedent("""
    import json, sys
    import ahead_kernels
    from evsda.graph import compile_ahead
    ahead = compile_ahead.start(sys.argv[1], ("ahead_kernels",), 3)
    ahead.wait()
    value = ahead_kernels.twice(4)
    stats = ahead_kernels.twice.stats
    print(json.dumps({"started": ahead.started, "value": value, "loaded": sum(stats.cache_hits.values()),
                      "compiled": sum(stats.cache_misses.values())}))
""")


def parent(tmp_path, target="ahead_kernels:warm", **env) -> dict:
    """Run PARENT in a fresh interpreter with the kernels' module on its path and its own Numba cache folder; what
    it printed, and that it printed nothing else."""
    environ = {name: value for name, value in os.environ.items() if name != "EVSDA_COMPILE_AHEAD"}
    environ.update(NUMBA_CACHE_DIR=str(tmp_path / "numba"), EVSDA_THREADS="2",
                   PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    environ.update(env)
    out = subprocess.run([sys.executable, "-c", PARENT, target], env=environ, capture_output=True, text=True,
                         check=True)
    assert out.stderr == "" and len(out.stdout.splitlines()) == 1
    return json.loads(out.stdout)


@pytest.fixture
def kernels(tmp_path):
    (tmp_path / "ahead_kernels.py").write_text(MODULE)
    return tmp_path


def test_the_child_compiles_and_this_process_loads_then_no_child_once_cached(kernels):
    first = parent(kernels)
    assert first == {"started": True, "value": 8, "loaded": 1, "compiled": 0}
    again = parent(kernels)
    assert again == {"started": False, "value": 8, "loaded": 1, "compiled": 0}


@pytest.mark.parametrize("env", [{"EVSDA_THREADS": "1"}, {"EVSDA_COMPILE_AHEAD": "off"}])
def test_one_thread_or_switched_off_compiles_here(kernels, env):
    assert parent(kernels, **env) == {"started": False, "value": 8, "loaded": 0, "compiled": 1}


@pytest.mark.parametrize("target", ["ahead_kernels:fail", "ahead_kernels:killed"])
def test_a_child_that_fails_or_is_killed_costs_only_its_time(kernels, target):
    assert parent(kernels, target) == {"started": True, "value": 8, "loaded": 0, "compiled": 1}
