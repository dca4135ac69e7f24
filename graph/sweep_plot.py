"""``evsda sweep-plot``: a metric of a sweep against one or two swept parameters, failed points marked.

* One parameter (``x``): the metric against it, one line per combination of the other swept
  parameters when they take few values (a grid), else points; failed points are red crosses on
  the axis at their parameter value.
* Two parameters (``x`` and ``y``): the points in the (x, y) plane coloured by the metric, with a
  colour bar; failed points are red crosses.

Axes whose values are all positive and span more than two decades are logarithmic. Built on
:class:`matplotlib.figure.Figure` (no pyplot): the backend of a notebook is never switched.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .errors import UserError, clip
from .store import RunStore, is_run_store
from .sweep import FIXED_COLUMNS, TAIL_COLUMNS, read_results

#: most lines drawn for the combinations of the other swept parameters; more become points
MAX_LINES = 8


def swept_parameters(table) -> list[str]:
    """The swept parameters of a results table: the columns between ``status`` and ``wall_s``."""
    columns = list(table.columns)
    return columns[columns.index(FIXED_COLUMNS[-1]) + 1: columns.index(TAIL_COLUMNS[0])]


def metric_unit(table, metric: str) -> str:
    """The unit of ``metric`` as the first finished point's store records it ('' if unknown)."""
    for row in table[table.status != "failed"].itertuples():
        if is_run_store(row.store):
            return RunStore.open(row.store).metric_units.get(metric, "")
    return ""


def _log_scale(values: np.ndarray) -> bool:
    finite = values[np.isfinite(values)]
    return finite.size > 1 and bool(np.all(finite > 0)) and finite.max() / finite.min() > 100


def _numeric(table, column: str) -> np.ndarray:
    values = np.asarray(table[column])
    try:
        return values.astype(float)
    except (TypeError, ValueError):
        raise UserError(f"parameter {column} has values that are not numbers; sweep-plot draws numeric "
                        f"parameters only") from None


def _x_parameter(parameters: list[str], x: str | None, y: str | None) -> str:
    """The x axis (the only swept parameter when not given), after checking that ``x`` and ``y`` are swept."""
    if x is None:
        if len(parameters) != 1:
            raise UserError(f"the sweep varies {', '.join(parameters)}; choose the x axis with --x")
        x = parameters[0]
    for name in filter(None, (x, y)):
        if name not in parameters:
            raise UserError(f"{clip(name)} is not a swept parameter; the sweep varies {', '.join(parameters)}")
    return x


def _check_metric(table, metric: str, parameters: list[str]) -> None:
    not_metrics = (*FIXED_COLUMNS, *TAIL_COLUMNS, *parameters)
    if metric not in table.columns or metric in not_metrics:
        metrics = [c for c in table.columns if c not in not_metrics]
        raise UserError(f"{clip(metric)} is not a metric of this sweep; its metrics: {', '.join(metrics) or 'none'}")


def _group_name(others: list[str], key) -> str:
    """``"b = 2, c = red"``: the values of the other swept parameters that one line holds."""
    key = key if isinstance(key, tuple) else (key,)
    return ", ".join(f"{p} = {v:g}" if isinstance(v, float) else f"{p} = {v}" for p, v in zip(others, key))


def _plot_groups(axes, good, x: str, metric: str, others: list[str]) -> None:
    """One line per combination of ``others`` (at most :data:`MAX_LINES`, with a legend), else points."""
    groups = good.groupby(others, dropna=False) if others else [((), good)]
    n_groups = good[others].drop_duplicates().shape[0] if others else 1
    for key, group in groups:
        group = group.sort_values(x)
        values = group[metric].astype(float)
        if n_groups <= MAX_LINES:
            axes.plot(group[x].astype(float), values, "o-", label=_group_name(others, key) or None)
        else:
            axes.plot(group[x].astype(float), values, "o", color="C0", ms=3)
    if n_groups <= MAX_LINES and others:
        axes.legend(fontsize="small")


def _plot_against_x(axes, table, xs, x: str, metric: str, parameters: list[str], label: str) -> None:
    """The metric against ``x``; failed points as red crosses on the x axis."""
    failed = table.status == "failed"
    good = table[~failed]
    _plot_groups(axes, good, x, metric, [p for p in parameters if p != x])
    if failed.any():
        axes.plot(xs[failed.to_numpy()], np.zeros(int(failed.sum())), "x", color="red", ms=9, mew=2,
                  transform=axes.get_xaxis_transform(), clip_on=False,
                  label=f"failed ({int(failed.sum())})")
        axes.legend(fontsize="small")
    axes.set_ylabel(label)
    if _log_scale(good[metric].astype(float).to_numpy()):
        axes.set_yscale("log")


def _plot_plane(figure, axes, table, xs, y: str, metric: str, label: str) -> None:
    """The (x, y) points coloured by the metric, with a colour bar; failed points as red crosses."""
    failed = table.status == "failed"
    ys = _numeric(table, y)
    ok = ~failed.to_numpy()
    points = axes.scatter(xs[ok], ys[ok], c=table[~failed][metric].astype(float), cmap="viridis", s=40)
    figure.colorbar(points, ax=axes, label=label)
    if failed.any():
        axes.plot(xs[~ok], ys[~ok], "x", color="red", ms=9, mew=2, label=f"failed ({int(failed.sum())})")
        axes.legend(fontsize="small")
    axes.set_ylabel(y)
    if _log_scale(ys):
        axes.set_yscale("log")


def plot_sweep(table, metric: str, x: str | None = None, y: str | None = None, unit: str | None = None):
    """The Figure of ``metric`` against ``x`` (and ``y``) from a sweep's results table (a DataFrame)."""
    from matplotlib.figure import Figure

    parameters = swept_parameters(table)
    x = _x_parameter(parameters, x, y)
    _check_metric(table, metric, parameters)
    unit = metric_unit(table, metric) if unit is None else unit
    label = f"{metric} [{unit}]" if unit and unit != "1" else metric
    figure = Figure(figsize=(7, 4.5), layout="constrained")
    axes = figure.add_subplot()
    xs = _numeric(table, x)
    if y is None:
        _plot_against_x(axes, table, xs, x, metric, parameters, label)
    else:
        _plot_plane(figure, axes, table, xs, y, metric, label)
    axes.set_xlabel(x)
    if _log_scale(xs):
        axes.set_xscale("log")
    failed = table.status == "failed"
    done = int((~failed).sum())
    axes.set_title(f"{metric}: {done} points" + (f", {int(failed.sum())} failed" if failed.any() else ""),
                   fontsize="medium")
    return figure


def sweep_plot(sweep_dir: str | Path, metric: str, output: str | Path, x: str | None = None,
               y: str | None = None, dpi: float = 120):
    """Draw :func:`plot_sweep` from the results in ``sweep_dir`` into the PNG ``output``; returns the Figure."""
    if not math.isfinite(dpi) or dpi <= 0:
        raise UserError(f"--dpi must be a positive number, got {dpi}")
    figure = plot_sweep(read_results(sweep_dir), metric, x, y)
    figure.savefig(output, dpi=dpi)
    return figure
