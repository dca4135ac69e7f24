"""SciPy's array-API layer imported lean (evsda.graph.scipy_imports): the same functions and capabilities, fewer
imports."""

import json
import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent("""
    import json, sys
    from evsda.graph import scipy_imports
    lean = scipy_imports.lean_array_api()
    import numpy as np
    import scipy.constants, scipy.fft, scipy.linalg, scipy.special
    from scipy._lib import _array_api
    from scipy._lib.array_api_compat import numpy as clone
    x = np.linspace(0.1, 7.0, 257)
    values = [scipy.special.j0(x), scipy.special.j1(x), scipy.special.erf(x), scipy.special.gammaln(x),
              scipy.special.kv(5 / 6, x), np.abs(scipy.fft.fft(x)), scipy.linalg.cholesky(np.eye(3) * 2.0).ravel()]
    capabilities = {getattr(f, "__name__", repr(f)): repr(sorted(c.items()))
                    for f, c in _array_api.xp_capabilities_table.items()}
    print(json.dumps({
        "lean": lean,
        "imported": sorted(m for m in sys.modules if m in ("numpy.f2py", "numpy.testing", "numpy.ma", "numpy.char")),
        "values": [v.tobytes().hex() for v in values] + [repr(scipy.constants.k)],
        "capabilities": capabilities,
        "clone": sorted(set(dir(clone)) - {f"{n}" for n in scipy_imports.LEFT_OUT}),
        "numpy_all": sorted(np.__all__),
        "j0_doc_has_table": "Array API Standard Support" in (scipy.special.j0.__doc__ or ""),
    }))
""")


def imported(**env) -> dict:
    """SCRIPT in a fresh interpreter."""
    environ = {name: value for name, value in os.environ.items() if name != "EVSDA_LEAN_SCIPY"}
    environ.update(env)
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=environ, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.splitlines()[-1])


def test_scipy_imported_lean_has_the_same_functions_values_and_capabilities():
    lean, full = imported(), imported(EVSDA_LEAN_SCIPY="off")
    if not lean["lean"]:
        pytest.skip("not a SciPy / NumPy version the lean import was checked on")
    assert not full["lean"]
    assert lean["imported"] == [] and full["imported"] == ["numpy.char", "numpy.f2py", "numpy.ma", "numpy.testing"]
    assert lean["values"] == full["values"]
    assert lean["capabilities"] == full["capabilities"] and len(lean["capabilities"]) > 90
    assert lean["clone"] == full["clone"]                  # the clone lacks only the submodules left out
    assert lean["numpy_all"] == full["numpy_all"]          # NumPy's own namespace as it was
    assert full["j0_doc_has_table"] and not lean["j0_doc_has_table"]


def test_the_lean_import_waits_for_scipy_and_leaves_an_imported_scipy_alone():
    script = textwrap.dedent("""
        import json, sys
        from evsda.graph import scipy_imports
        first = scipy_imports.lean_array_api()
        waiting = "scipy" not in sys.modules and any(isinstance(f, scipy_imports._LeanArrayApi) for f in sys.meta_path)
        import scipy.fft
        done = not any(isinstance(f, scipy_imports._LeanArrayApi) for f in sys.meta_path)
        print(json.dumps([first, waiting, done, scipy_imports.lean_array_api()]))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    first, waiting, done, again = json.loads(out.stdout.splitlines()[-1])
    if not first:
        pytest.skip("not a SciPy / NumPy version the lean import was checked on")
    assert waiting and done and not again


def test_installed_version_reads_what_importlib_metadata_reads():
    from importlib.metadata import version

    from evsda.graph.scipy_imports import installed_version

    for name in ("scipy", "numpy", "numba", "pydantic", "evsda"):
        assert installed_version(name) == version(name)
    assert installed_version("no-such-distribution-here") is None
