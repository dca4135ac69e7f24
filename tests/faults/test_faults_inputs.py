"""Bad and hostile inputs: special files, wrong encodings, oversized and alias-bomb YAML, files that are
not what the graph says, non-finite numbers, paths out of the library. Each is one line (exit 2) naming
the file and what was expected, never its contents, and never a hang."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest
from faultkit import GRAPH, cli

SECRET = "hunter2-s3cr3t"


def graph_text(extra_blocks: str = "", include: str = "") -> str:
    text = GRAPH.format(duration_s=0.05, sleep_s=0.0)
    if include:
        text += f"include:\n  - {{file: {include}, as: sub}}\n"
    return text.replace("blocks:\n", f"blocks:\n{extra_blocks}")


def only_line(capsys, *args) -> str:
    status, lines = cli(capsys, "validate", *args)
    assert status == 2 and len(lines) == 1, lines
    assert SECRET not in lines[0]
    return lines[0]


def test_special_files_are_refused_before_they_are_opened(capsys, tmp_path):
    fifo = tmp_path / "pipe.yaml"
    os.mkfifo(fifo)
    (tmp_path / "main.yaml").write_text(graph_text(include=str(fifo)))
    assert only_line(capsys, tmp_path / "main.yaml").endswith("pipe.yaml: expected a graph file, found a FIFO (named pipe)")
    assert only_line(capsys, fifo).endswith("expected a graph file, found a FIFO (named pipe)")
    assert only_line(capsys, "/dev/zero").endswith("expected a graph file, found a character device")
    assert only_line(capsys, tmp_path).endswith("expected a graph file, found a folder")
    tle = graph_text(f"  sat: {{type: tle_source, params: {{tle_file: {fifo}}}}}\n")
    (tmp_path / "tle.yaml").write_text(tle)
    assert "parameter 'tle_file'" in only_line(capsys, tmp_path / "tle.yaml")


def test_a_fifo_include_does_not_hang_the_command(evsda, tmp_path):
    os.mkfifo(tmp_path / "pipe.yaml")
    (tmp_path / "main.yaml").write_text(graph_text(include="pipe.yaml"))
    proc = evsda("validate", tmp_path / "main.yaml", timeout=30)       # a hang fails with TimeoutExpired
    assert proc.returncode == 2 and "found a FIFO" in proc.stderr and len(proc.stderr.splitlines()) == 1


@pytest.mark.parametrize("content,expected", [
    (b"evsda: 1\nname: caf\xe9\n", "line 2: the graph file is not UTF-8 text"),
    (b"evsda: 1\n\x00\x01\x02binary", "the graph file is binary, not text"),
    (b"# " + b"x" * (1 << 20) + b"\n", "the graph file is 1.0 MiB, more than the 1.0 MiB a graph file may have"),
    (b"evsda: 1\nblocks: [\n" * 1 + b"[" * 50_000, "values are nested too deeply"),
    (b"- just\n- a list\n", "not an evsda graph file"),
])
def test_unreadable_graph_files_are_one_line(capsys, tmp_path, content, expected):
    path = tmp_path / "g.yaml"
    path.write_bytes(content)
    assert expected in only_line(capsys, path)


def test_file_contents_never_reach_a_message(capsys, tmp_path):
    env = tmp_path / "secrets.env"
    env.write_text(f"API_TOKEN={SECRET}\nDB_PASSWORD={SECRET}\n")
    (tmp_path / "tle.yaml").write_text(graph_text(f"  sat: {{type: tle_source, params: {{tle_file: {env}}}}}\n"))
    assert "no two-line element set found" in only_line(capsys, tmp_path / "tle.yaml")
    mapping = tmp_path / "settings.yaml"
    mapping.write_text(f"api_token: {SECRET}\npassword: {SECRET}\n")
    (tmp_path / "inc.yaml").write_text(graph_text(include=str(mapping)))
    assert "settings.yaml: not an evsda graph file" in only_line(capsys, tmp_path / "inc.yaml")
    (tmp_path / "inc2.yaml").write_text(graph_text(include=str(env)))
    assert "secrets.env: not an evsda graph file" in only_line(capsys, tmp_path / "inc2.yaml")


@pytest.mark.parametrize("params,expected", [
    ("{{type: satellite_catalog, params: {{catalog_file: {f}}}}}", "no two-line element set found"),
    ("{{type: satellite_catalog, params: {{catalog_file: 'library:tle/iss.tle', properties_file: {f}}}}}",
     "a properties file is a CSV file whose header (line 1) names a NORAD_CAT_ID column"),
    ("{{type: satellite, params: {{shape: facets, facet_model_file: {f}}}}}", "not a facet model file"),
])
@pytest.mark.parametrize("content", [f"API_TOKEN={SECRET}\nDB_PASSWORD={SECRET}\n", f"api_token: {SECRET}\n",
                                     f"NORAD,{SECRET}\n1,2\n"])
def test_data_files_of_scene_blocks_never_reach_a_message(capsys, tmp_path, params, expected, content):
    """A catalogue, a properties file or a facet model that is some other file is named, never quoted."""
    secrets = tmp_path / "secrets.txt"
    secrets.write_text(content)
    (tmp_path / "g.yaml").write_text(graph_text("  data: " + params.format(f=secrets) + "\n"))
    status, lines = cli(capsys, "validate", tmp_path / "g.yaml")     # (its inputs are left unconnected)
    assert status == 2 and expected in lines[0] and str(secrets) in lines[0], lines
    assert not any(SECRET in line for line in lines)


def test_values_quoted_in_errors_are_cut(capsys, tmp_path):
    (tmp_path / "g.yaml").write_text(graph_text().replace("{type: test_ramp}",
                                                          "{type: test_ramp, params: {noise: '" + "9" * 5000 + "'}}"))
    line = only_line(capsys, tmp_path / "g.yaml")
    assert "parameter 'noise'" in line and len(line) < 300


def test_library_paths_cannot_leave_the_library(capsys, tmp_path):
    (tmp_path / "inc.yaml").write_text(graph_text(include="'library:../../../../etc/passwd'"))
    assert "must name a file inside the bundled library" in only_line(capsys, tmp_path / "inc.yaml")
    tle = graph_text("  sat: {type: tle_source, params: {tle_file: 'library:../graph/cli.py'}}\n")
    (tmp_path / "tle.yaml").write_text(tle)
    assert "must name a file inside the bundled library" in only_line(capsys, tmp_path / "tle.yaml")


@pytest.mark.parametrize("setting,name", [("--set", "ramp.slope_per_s=.inf"), ("--set", "run.duration_s=.inf"),
                                          ("--set", "spikes.latency_s=.nan")])
def test_non_finite_numbers_are_refused_by_validate(capsys, tmp_path, setting, name):
    (tmp_path / "g.yaml").write_text(graph_text())
    assert "finite number" in only_line(capsys, tmp_path / "g.yaml", setting, name)


def _alias_bomb(levels: int = 9, width: int = 9) -> str:
    lines = ["a0: &a0 [" + ", ".join(["lol"] * width) + "]"]
    for k in range(1, levels):
        lines.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * width) + "]")
    return "\n".join(lines) + "\n"


def test_an_alias_bomb_is_refused_under_a_memory_cap(env, tmp_path):
    """9^9 = 387 million values from 0.6 kB of YAML: refused before it is built, in a process limited to 600 MiB."""
    bomb = _alias_bomb()
    text = bomb + graph_text().replace("{type: test_ramp}", "{type: test_ramp, params: {noise: *a8}}")
    (tmp_path / "bomb.yaml").write_text(text)
    cap = 600 << 20
    proc = subprocess.run([sys.executable, "-m", "evsda.graph.cli", "validate", str(tmp_path / "bomb.yaml")], env=env,
                          capture_output=True, text=True, timeout=60,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (cap, cap)))
    assert proc.returncode == 2 and len(proc.stderr.splitlines()) == 1, proc.stderr
    assert "aliases expand to more than 100000 values" in proc.stderr


def test_sizes_are_estimated_and_refused_before_allocating(capsys):
    """A 65 535 x 65 535 sensor (4.3 G pixels, ~1.7 TB of pixel state) and 400 million windows are refused
    by validate, naming the estimate, the limit and the flag that raises it; the flag does raise it."""
    scene = Path(__file__).parents[2] / "examples" / "iss_pass.yaml"
    huge = ["--set", "sensor/camera.width_px=65535", "--set", "sensor/camera.height_px=65535"]
    line = only_line(capsys, scene, *huge)
    assert "a sensor of 4.295e+09 pixels is more than the limit of 3.355e+07" in line and "--limit pixels=" in line
    line = only_line(capsys, scene, *huge, "--limit", "pixels=5e9")
    assert "would hold about 1.6e+03 GiB per window (most in 'sensor/pixel')" in line
    line = only_line(capsys, scene, "--set", "run.window_s=1e-8")
    assert "4e+08 windows (duration_s / window_s) is more than the limit of 1e+07" in line
    assert cli(capsys, "validate", scene, "--set", "run.window_s=1e-8", "--limit", "windows=1e9")[0] == 0
    assert "expected NAME=VALUE" in only_line(capsys, scene, "--limit", "memory=1")


def test_the_python_api_is_as_strict_as_the_command_line(tmp_path):
    from evsda.blocks.ports import FocalPlane
    from evsda.blocks.readout import RowScanArbiter
    from evsda.graph import InputError, ParameterError, RunInfo, Window
    from evsda.graph.graphfile import load_graph
    from evsda.graph.limits import Limits

    arbiter = RowScanArbiter(seed=1)
    arbiter.setup(RunInfo())
    with pytest.raises(InputError, match="missing its required input 'events'"):
        arbiter.step(Window(0, 0, 1000))
    with pytest.raises(InputError, match="input 'events' expects TriggeredEvents"):
        arbiter.step(Window(0, 0, 1000), events=FocalPlane(4, 4, 1e-5, 1.0))
    with pytest.raises(InputError, match="needs a Window first"):
        arbiter.step((0, 1000), events=None)
    with pytest.raises(ParameterError, match="seed must be a non-negative integer"):
        RowScanArbiter(seed=-3)
    with pytest.raises(ParameterError, match="finite number"):
        RowScanArbiter(clock_hz=float("inf"))
    with pytest.raises(InputError, match="stops .* before it starts"):
        Window.from_seconds(1.0, 0.5)
    (tmp_path / "g.yaml").write_text(graph_text())
    with pytest.raises(Exception, match="windows .* more than the limit of 3"):
        load_graph(tmp_path / "g.yaml", limits=Limits(windows=3))


def test_a_blocks_warning_is_one_line_without_the_code_that_raised_it(capsys, tmp_path):
    """A catalogue entry skipped with on_bad_entry: skip is named in one ``evsda: warning:`` line (Python's
    default format added the source file and a line of evsda's code)."""
    from evsda import library

    lines = library.resolve("library:tle/iss.tle").read_text().splitlines()[:3]
    broken = lines[2][:-1] + str((int(lines[2][-1]) + 1) % 10)                  # a wrong checksum
    (tmp_path / "two.tle").write_text("\n".join([*lines, "ISS AGAIN", lines[1], broken]) + "\n")
    block = "  data: {type: satellite_catalog, params: {catalog_file: two.tle, on_bad_entry: skip}}\n"
    (tmp_path / "g.yaml").write_text(graph_text(block))
    status, lines = cli(capsys, "validate", tmp_path / "g.yaml")
    warned = [line for line in lines if not line.startswith("evsda: error:")]    # (inputs left unconnected)
    assert len(warned) == 1 and not any(".py:" in line or "self." in line for line in lines), lines
    assert warned[0].startswith(f"evsda: warning: satellite_catalog 'data' catalog_file {tmp_path / 'two.tle'}: "
                               f"skipped 1 malformed entries (line 4: line 6 fails its checksum")
