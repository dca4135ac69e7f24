"""Test-session settings shared by every stage."""

import os

import pytest
from threadpoolctl import threadpool_limits


@pytest.fixture(autouse=True, scope="session")
def one_blas_thread():
    """One BLAS thread, as the `evsda` command uses: the blocks' many small products run faster."""
    with threadpool_limits(limits=1, user_api="blas"):
        yield


@pytest.fixture(autouse=True, scope="session")
def no_user_cache(tmp_path_factory):
    """Results kept across runs (evsda.graph.result_cache) never come from or go to the user's cache, and are off:
    a test that computes a thing twice (with 1 and 2 threads, resumed or not) computes it twice. The tests of
    the cache switch it on in this session's own folder (tests/optics/test_optics_probe_cache.py)."""
    saved = {name: os.environ.get(name) for name in ("EVSDA_CACHE", "EVSDA_CACHE_DIR")}
    os.environ["EVSDA_CACHE"] = "off"
    os.environ["EVSDA_CACHE_DIR"] = str(tmp_path_factory.mktemp("evsda-cache"))
    yield
    for name, value in saved.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
