"""Every plot command takes the same output options (issue 14.7): ``-o/--output FILE`` with the format
from the extension, ``--dpi`` and ``--overwrite``; an existing file, an extension matplotlib cannot
write and a resolution out of range are one line with exit 2, checked before any work (so the
positional inputs below need not exist)."""

from __future__ import annotations

import pytest

from evsda.graph.cli import main

#: each plot command and the positional arguments it needs (never read: the output is checked first)
PLOTS = {
    "plot-lightcurve": ["missing.zarr"],
    "plot-rate": ["missing.zarr"],
    "plot-spacetime": ["missing.zarr"],
    "plot-psf": ["missing.yaml"],
    "plot-pass": ["missing.yaml"],
    "plot-screen": [],
    "plot-propagation": [],
    "sweep-plot": ["missing_sweep", "some_metric"],
}


def run(capsys, *args) -> tuple[int, list[str]]:
    capsys.readouterr()
    status = main([str(a) for a in args])
    return status, [line for line in capsys.readouterr().err.splitlines() if line.strip()]


@pytest.mark.parametrize("command", PLOTS)
def test_every_plot_command_refuses_an_existing_file_a_bad_format_and_dpi(capsys, tmp_path, command):
    existing = tmp_path / "existing.png"
    existing.write_bytes(b"keep me")
    status, lines = run(capsys, command, *PLOTS[command], "-o", existing, "--dpi", "80")
    assert status == 2 and lines == [f"evsda: error: {existing} already exists; pass --overwrite to replace it"]
    assert existing.read_bytes() == b"keep me"
    status, lines = run(capsys, command, *PLOTS[command], "--output", tmp_path / "figure.foo")
    assert status == 2 and len(lines) == 1 and "cannot write a figure as .foo" in lines[0] and "svg" in lines[0]
    status, lines = run(capsys, command, *PLOTS[command], "-o", tmp_path / "figure.pdf", "--dpi", "0")
    assert status == 2 and lines == ["evsda: error: --dpi must be between 10 and 2400, got 0"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing.png"]


def test_overwrite_and_dpi_reach_the_saved_figure(capsys, tmp_path):
    """plot-screen (the quickest plot) replaces a file only with --overwrite, at the --dpi asked, in the
    format of the extension."""
    from PIL import Image

    output = tmp_path / "screen.png"
    output.write_bytes(b"keep me")
    args = ["plot-screen", "--samples", "32", "--modes", "5", "--show", "2,4"]
    assert run(capsys, *args, "-o", output, "--overwrite", "--dpi", "50")[0] == 0
    small = Image.open(output).size
    assert run(capsys, *args, "-o", output, "--overwrite", "--dpi", "100")[0] == 0
    assert Image.open(output).size == (2 * small[0], 2 * small[1])
    assert run(capsys, *args, "-o", tmp_path / "screen.svg")[0] == 0
    assert (tmp_path / "screen.svg").read_text().lstrip().startswith("<?xml")


@pytest.mark.parametrize("args,expected", [
    (["plot-spacetime", "missing.zarr", "--start-s", "nan"], "--start-s must be a finite time in seconds"),
    (["plot-spacetime", "missing.zarr", "--stop-s", "1e300"], "--stop-s must be a finite time in seconds"),
    (["plot-psf", "missing.yaml", "--time-s", "nan"], "--time-s must be a finite time in seconds"),
    (["plot-psf", "missing.yaml", "--time-s=-1e300"], "--time-s must be a finite time in seconds"),
    (["render", "missing.zarr", "--gif", "out.gif", "--frames", "100000000"], "--frames must be at most 10000"),
])
def test_times_and_frame_counts_out_of_range_are_one_line(capsys, tmp_path, monkeypatch, args, expected):
    """NaN or 1e300 seconds overflowed the nanosecond clock (a traceback); 10^8 GIF frames never ended.
    Checked before any work, so the inputs named need not exist."""
    monkeypatch.chdir(tmp_path)
    status, lines = run(capsys, *args, *([] if args[0] == "render" else ["-o", "out.png"]))
    assert status == 2 and len(lines) == 1 and expected in lines[0], lines


def test_quiet_leaves_out_the_summary_line(capsys, tmp_path):
    """``-q`` (before or after the command) is "only errors and warnings": the line saying what was written
    goes too (it did not for export, render and the plot commands)."""
    args = ["plot-screen", "--samples", "16", "--modes", "3", "--show", "2"]
    for quiet, name in (([], "a.png"), (["-q"], "b.png")):
        capsys.readouterr()
        assert main([*quiet, *args, "-o", str(tmp_path / name)]) == 0
        assert (capsys.readouterr().out != "") == (not quiet)
    assert main([*args, "-q", "-o", str(tmp_path / "c.png")]) == 0 and capsys.readouterr().out == ""
