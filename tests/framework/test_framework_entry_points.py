"""The installed distributions' entry points read once a process (evsda.graph.entry_points): the same answers as
Python's function, read again when the installed packages change."""

import json
import os
import subprocess
import sys
import textwrap
from importlib import metadata

import pytest

SCRIPT = textwrap.dedent("""
    import json, sys
    from importlib import metadata
    python_s = metadata.entry_points
    import evsda.graph
    import pydantic.plugin._loader, networkx.utils.backends

    def listed(points):
        return [[p.name, p.value, p.group, p.dist.name] for p in points]

    def answers(entry_points):
        groups = entry_points()
        return {"groups": {name: listed(points) for name, points in groups.items()},
                "blocks": listed(entry_points(group="evsda.blocks")),
                "one": listed(entry_points(group="evsda.blocks", name=sorted(groups["evsda.blocks"].names)[0])),
                "none": listed(entry_points(group="no such group"))}

    print(json.dumps({"cached": type(metadata.entry_points).__name__ != "function",
                      "taken": pydantic.plugin._loader.entry_points is metadata.entry_points
                               and networkx.utils.backends.entry_points is metadata.entry_points,
                      "python": answers(python_s), "ours": answers(metadata.entry_points),
                      "again": answers(metadata.entry_points)}))
""")

needs_311 = pytest.mark.skipif(not hasattr(metadata, "SelectableGroups"),
                               reason="checked on Python 3.11's entry_points (SelectableGroups)")


def run_script(**env) -> dict:
    environ = {name: value for name, value in os.environ.items() if name != "EVSDA_ENTRY_POINTS_CACHE"}
    environ.update(env)
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=environ, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


@needs_311
def test_the_same_entry_points_as_python_reads():
    found = run_script()
    assert found["cached"] and found["taken"]
    assert found["ours"] == found["python"] == found["again"]
    assert found["python"]["blocks"] and len(found["python"]["one"]) == 1 and not found["python"]["none"]


def test_switched_off_leaves_python_s_function():
    found = run_script(EVSDA_ENTRY_POINTS_CACHE="off")
    assert not found["cached"]
    assert found["ours"] == found["python"]


@needs_311
def test_a_package_installed_meanwhile_is_seen(tmp_path, monkeypatch):
    from evsda.graph import entry_points

    monkeypatch.syspath_prepend(str(tmp_path))
    reader = entry_points._ReadOnce(getattr(metadata.entry_points, "original", metadata.entry_points))
    assert not reader(group="evsda.test.late")
    info = tmp_path / "late_plugin-1.0.dist-info"          # installed into a folder already on the path
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: late-plugin\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[evsda.test.late]\nlate = late_plugin:Block\n")
    assert [(p.name, p.value) for p in reader(group="evsda.test.late")] == [("late", "late_plugin:Block")]
