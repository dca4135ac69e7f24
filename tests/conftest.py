"""Test-session settings shared by every stage."""

import pytest
from threadpoolctl import threadpool_limits


@pytest.fixture(autouse=True, scope="session")
def one_blas_thread():
    """One BLAS thread, as the `evsda` command uses: the blocks' many small products run faster."""
    with threadpool_limits(limits=1, user_api="blas"):
        yield
