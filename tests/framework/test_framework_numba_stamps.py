"""Numba's cache stamped by a package's sources (evsda.graph.numba_stamps): a change to any file of the package
compiles its cached functions again, an unchanged package loads them."""

import ast
import importlib
import os
import pathlib
import textwrap

import pytest

from evsda.graph import numba_stamps

CALLEE = textwrap.dedent("""
    import numba

    @numba.njit                            # not cached: compiled into its callers' code
    def scaled(x):
        return 2.0 * x
""")

CONSTANTS = "OFFSET = 1.0\n"

CALLER = textwrap.dedent("""
    import numba

    from .callee import scaled
    from .constants import OFFSET

    @numba.njit(cache=True)
    def caller(x):
        return scaled(x) + OFFSET
""")

SCRIPT = textwrap.dedent("""
    import json
    from evsda.graph import numba_stamps
    numba_stamps.stamp_packages("stamped_pkg")     # before Numba is imported, as evsda.blocks does
    from stamped_pkg.caller import caller
    value = caller(1.0)
    print(json.dumps({"value": value, "stamped": numba_stamps.stamped(),
                      "loaded": sum(caller.stats.cache_hits.values()), "compiled": sum(caller.stats.cache_misses.values())}))
""")


def package(tmp_path) -> pathlib.Path:
    """A small package: a cached caller whose code holds a function and a constant of two other files."""
    folder = tmp_path / "stamped_pkg"
    folder.mkdir()
    for name, text in (("__init__", ""), ("callee", CALLEE), ("constants", CONSTANTS), ("caller", CALLER)):
        (folder / f"{name}.py").write_text(text)
    return folder


def test_an_unchanged_package_loads_from_the_cache(fresh_numba, tmp_path):
    run = fresh_numba(SCRIPT, "EVSDA_PACKAGE_STAMPS")
    package(tmp_path)
    first, second = run(), run()
    assert first["stamped"] and second["stamped"]
    assert (first["compiled"], first["loaded"]) == (1, 0)
    assert (second["compiled"], second["loaded"]) == (0, 1)
    assert first["value"] == second["value"] == 3.0


@pytest.mark.parametrize(("name", "old", "new", "value"), [("callee", "2.0 * x", "3.0 * x", 4.0),
                                                            ("constants", "1.0", "5.0", 7.0)])
def test_a_change_to_another_file_of_the_package_compiles_the_caller_again(fresh_numba, tmp_path, name, old, new,
                                                                           value):
    run = fresh_numba(SCRIPT, "EVSDA_PACKAGE_STAMPS")
    folder = package(tmp_path)
    assert run()["value"] == 3.0
    source = folder / f"{name}.py"
    source.write_text(source.read_text().replace(old, new))
    changed = run()
    assert (changed["compiled"], changed["loaded"], changed["value"]) == (1, 0, value)
    assert run()["loaded"] == 1                           # and loaded from the cache after that


def test_switched_off_numbas_stamps_keep_the_old_code(fresh_numba, tmp_path):
    """Numba's own stamp (the hazard this module takes away): the callee's change is not seen."""
    run = fresh_numba(SCRIPT, "EVSDA_PACKAGE_STAMPS")
    folder = package(tmp_path)
    assert run(EVSDA_PACKAGE_STAMPS="off")["value"] == 3.0
    callee = folder / "callee.py"
    callee.write_text(callee.read_text().replace("2.0 * x", "3.0 * x"))
    stale = run(EVSDA_PACKAGE_STAMPS="off")
    assert not stale["stamped"] and stale["loaded"] == 1 and stale["value"] == 3.0


def test_folder_digest_follows_every_python_file(tmp_path):
    folder = package(tmp_path)
    digest = numba_stamps.folder_digest(str(folder))
    assert numba_stamps.folder_digest(str(folder)) == digest
    (folder / "notes.txt").write_text("not a source")
    assert numba_stamps.folder_digest(str(folder)) == digest
    (folder / "constants.py").write_text("OFFSET = 1.5\n")                 # the same size: the bytes are read again
    assert numba_stamps.folder_digest(str(folder)) != digest
    (folder / "constants.py").write_text(CONSTANTS)
    assert numba_stamps.folder_digest(str(folder)) == digest               # bytes, not times
    (folder / "extra.py").write_text("")
    assert numba_stamps.folder_digest(str(folder)) != digest


def test_evsdas_cached_functions_are_stamped_by_their_package():
    from evsda.blocks.pixel import deferred

    if os.environ.get("EVSDA_PACKAGE_STAMPS", "").lower() in ("off", "0", "no", "false"):
        pytest.skip("EVSDA_PACKAGE_STAMPS is off")
    locator = deferred.take_and_run._cache._impl.locator
    assert isinstance(locator, numba_stamps.PackageStamped)
    assert locator.get_source_stamp() == ("package", numba_stamps.folder_digest(os.path.dirname(deferred.__file__)))


BLOCKS = pathlib.Path(importlib.import_module("evsda.blocks").__file__).parent


def compiled_folders() -> list[pathlib.Path]:
    """evsda's folders that hold a module with a cached compiled function."""
    return sorted({path.parent for path in BLOCKS.rglob("*.py") if "cache=True" in path.read_text()})


def imported_from_elsewhere(path: pathlib.Path, module: str) -> set[str]:
    """The global names that ``module`` (at ``path``) imports from evsda modules outside its own folder."""
    names = set()
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update((alias.asname or alias.name).split(".")[0] for alias in node.names
                         if alias.name.split(".")[0] == "evsda")
        elif isinstance(node, ast.ImportFrom):
            source = importlib.util.resolve_name("." * node.level + (node.module or ""), package) if node.level else node.module
            if source.split(".")[0] != "evsda":
                continue
            origin = importlib.util.find_spec(source).origin
            if pathlib.Path(origin).parent != path.parent:
                names.update(alias.asname or alias.name for alias in node.names)
    return names


def global_names(code) -> set[str]:
    """The names that ``code`` and the functions defined in it read."""
    names = set(code.co_names)
    for constant in code.co_consts:
        if hasattr(constant, "co_names"):
            names |= global_names(constant)
    return names


@pytest.mark.parametrize("folder", compiled_folders(), ids=lambda folder: folder.name)
def test_compiled_code_reads_only_its_own_folder(folder):
    """The stamp covers the function's folder: no compiled function (nor intrinsic) reads a name that its module
    imports from another folder of evsda."""
    for path in sorted(folder.glob("*.py")):
        relative = path.relative_to(BLOCKS.parent).with_suffix("")
        module_name = "evsda." + ".".join(part for part in relative.parts if part != "__init__")
        elsewhere = imported_from_elsewhere(path, module_name)
        if not elsewhere:
            continue
        module = importlib.import_module(module_name)
        for value in vars(module).values():
            function = getattr(value, "py_func", None) or getattr(value, "_defn", None)
            if function is not None and getattr(function, "__module__", None) == module_name:
                assert not global_names(function.__code__) & elsewhere, (module_name, function.__qualname__)


def test_a_module_import_reads_its_folder_once(tmp_path):
    """The functions of one module's import share a reading of the folder; a reload (a new spec) reads it again."""
    folder = package(tmp_path)
    spec, reloaded = object(), object()
    digest = numba_stamps._import_digest(str(folder), spec)
    (folder / "constants.py").write_text("OFFSET = 1.5\n")
    assert numba_stamps._import_digest(str(folder), spec) == digest
    assert numba_stamps._import_digest(str(folder), reloaded) == numba_stamps.folder_digest(str(folder)) != digest


CHECKED = textwrap.dedent("""
    import numba

    @numba.njit(cache=True)
    def first(x):
        return x + 1.0

    @numba.njit(cache=True)
    def second(x):
        return x + 2.0

    @numba.njit(cache=True)
    def third(x):
        return first(x) * second(x)
""")


def test_a_modules_cache_folder_is_checked_once(tmp_path, monkeypatch):
    """Numba's check that the cache folder can be written runs for a file's first function only; every function is
    located (folder and stamp) as Numba's own locator would, and still checks where it saves."""
    from numba.core import caching

    if not numba_stamps.stamped():
        pytest.skip("Numba's own stamps (EVSDA_PACKAGE_STAMPS off, or another Numba)")
    folder = tmp_path / "checked_pkg"
    folder.mkdir()
    (folder / "__init__.py").write_text("")
    (folder / "kernels.py").write_text(CHECKED)
    checks = []
    numbas_check = caching._CacheLocator.ensure_cache_path
    monkeypatch.setattr(caching._CacheLocator, "ensure_cache_path", lambda self: checks.append(self) or numbas_check(self))
    monkeypatch.syspath_prepend(str(tmp_path))
    numba_stamps.stamp_packages("checked_pkg")
    kernels = importlib.import_module("checked_pkg.kernels")
    functions = (kernels.first, kernels.second, kernels.third)
    assert len(checks) == 1
    checks.clear()
    for function in functions:
        locator = function._cache._impl.locator
        numbas = caching.InTreeCacheLocator.from_function(function.py_func, str(folder / "kernels.py"))
        assert isinstance(locator, numba_stamps.PackageStamped)
        assert locator.get_cache_path() == numbas.get_cache_path() == str(folder / "__pycache__")
        assert locator.get_disambiguator() == numbas.get_disambiguator()
    checks.clear()
    assert kernels.third(1.0) == 6.0 and len(checks) == 3           # the saves (three functions) check again
