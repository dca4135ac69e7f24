"""Event images: the paper's Fig. 6 (ON events green, OFF red, accumulated over a time
span) as a PNG, and an animation of events over time as a GIF.

Both stream over event chunks (dicts of numpy arrays sorted by ``t_readout_ns``, as
:meth:`RunStore.iter_events` yields them) and select events by their readout time
``t_a``, the time the sensor reports. Memory holds count images, never the events.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from evsda.graph import NS_PER_S

Chunk = dict[str, np.ndarray]


def _in_span(chunks: Iterable[Chunk], start_ns: int | None, stop_ns: int | None) -> Iterator[Chunk]:
    for chunk in chunks:
        t = np.asarray(chunk["t_readout_ns"])
        lo = 0 if start_ns is None else int(np.searchsorted(t, start_ns, side="left"))
        hi = t.size if stop_ns is None else int(np.searchsorted(t, stop_ns, side="left"))
        if hi > lo:
            yield {name: np.asarray(value)[lo:hi] for name, value in chunk.items()}


def accumulate(chunks: Iterable[Chunk], width: int, height: int, start_ns: int | None = None,
               stop_ns: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """ON and OFF event counts per pixel, ``(height, width)`` int64 each, over ``[start_ns, stop_ns)``."""
    on = np.zeros(width * height, np.int64)
    off = np.zeros(width * height, np.int64)
    for chunk in _in_span(chunks, start_ns, stop_ns):
        index = np.asarray(chunk["y"], np.int64) * width + np.asarray(chunk["x"], np.int64)
        positive = np.asarray(chunk["p"]) > 0
        on += np.bincount(index[positive], minlength=on.size)
        off += np.bincount(index[~positive], minlength=off.size)
    return on.reshape(height, width), off.reshape(height, width)


def event_rgb(on: np.ndarray, off: np.ndarray, scale: float | None = None) -> np.ndarray:
    """RGB image in [0, 1]: OFF counts in red, ON counts in green, on black (paper Fig. 6).

    Counts map through a square root up to ``scale`` (by default the 99.5th percentile of
    the non-zero counts), so that a single event stays visible next to a bright track.
    """
    if scale is None:
        counts = np.concatenate([on[on > 0], off[off > 0]])
        scale = float(np.percentile(counts, 99.5)) if counts.size else 1.0
    scale = max(scale, 1.0)
    rgb = np.zeros((*on.shape, 3))
    rgb[..., 0] = np.sqrt(np.minimum(off / scale, 1.0))
    rgb[..., 1] = np.sqrt(np.minimum(on / scale, 1.0))
    return rgb


#: margins of a native-resolution figure around the image [pixel at 100 dpi]: left, right, bottom, top
NATIVE_MARGINS_PX = (70, 20, 50, 40)


def _figure(width: int, height: int, scale: float | None = None, dpi: float = 100):
    """Figure, axes and image artist for a ``width`` x ``height`` sensor (built without pyplot: no backend
    is selected and nothing stays registered). With ``scale`` the image area is exactly ``scale`` output
    pixels per sensor pixel (native resolution at 1), labels in fixed margins around it; without, the
    figure is 8 inches wide."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    if scale is None:
        size = 8.0
        fig = Figure(figsize=(size, size * height / width + 0.9), dpi=dpi)
        ax = fig.add_subplot()
    else:
        left, right, bottom, top = (m * dpi / 100 for m in NATIVE_MARGINS_PX)
        w_px, h_px = width * scale, height * scale
        fig_w, fig_h = w_px + left + right, h_px + bottom + top
        fig = Figure(figsize=(fig_w / dpi, fig_h / dpi), dpi=dpi)
        ax = fig.add_axes((left / fig_w, bottom / fig_h, w_px / fig_w, h_px / fig_h))
    ax.set_xlabel("column x [pixel]")
    ax.set_ylabel("row y [pixel]")
    ax.legend(handles=[Patch(color=(0, 1, 0), label="ON"), Patch(color=(1, 0, 0), label="OFF")],
              **_legend_place(scale))
    image = ax.imshow(np.zeros((height, width, 3)), origin="upper", interpolation="nearest",
                      extent=(-0.5, width - 0.5, height - 0.5, -0.5), resample=False)
    if scale is None:
        fig.tight_layout()
    return fig, ax, image


def _legend_place(scale: float | None) -> dict:
    """Inside the image's upper right corner, or at native resolution above it (no sensor pixel hidden)."""
    if scale is None:
        return {"loc": "upper right", "framealpha": 0.6}
    return {"loc": "lower right", "bbox_to_anchor": (1.0, 1.0), "ncol": 4, "fontsize": 7, "frameon": False,
            "borderaxespad": 0.1}


def draw_truth(ax, truth: dict[str, np.ndarray], start_ns: int | None = None, stop_ns: int | None = None,
               scale: float | None = None) -> int:
    """Draw each source's true path in ``[start_ns, stop_ns)`` from the store's truth (satellites cyan,
    labelled; stars yellow); returns the number of paths drawn."""
    from evsda.blocks.ports import SourceKind

    t = truth["t_ns"]
    span = (t >= (start_ns if start_ns is not None else t.min(initial=0))) & \
        (t < (stop_ns if stop_ns is not None else t.max(initial=0) + 1))
    drawn = 0
    for source_id in dict.fromkeys(truth["source_id"][span].tolist()):
        mine = span & (truth["source_id"] == source_id)
        satellite = truth["kind"][mine][0] == SourceKind.SATELLITE
        ax.plot(truth["x_px"][mine], truth["y_px"][mine], color="cyan" if satellite else "yellow",
                lw=0.8 if satellite else 0.5, alpha=0.9, label=f"{source_id} (truth)" if satellite else None)
        drawn += 1
    if drawn:
        handles = [h for h in ax.get_legend().legend_handles] + ax.get_legend_handles_labels()[0]
        ax.legend(handles=handles, **{"fontsize": 8, **_legend_place(scale)})
    return drawn


def event_figure(on: np.ndarray, off: np.ndarray, title: str = "", truth: dict[str, np.ndarray] | None = None,
                 start_ns: int | None = None, stop_ns: int | None = None, scale: float | None = None,
                 dpi: float = 100):
    """The event image of ON and OFF counts (paper Fig. 6, :func:`accumulate`) as a Figure, with the true
    paths in ``[start_ns, stop_ns)`` on top when ``truth`` (:meth:`RunStore.read_truth`) is given;
    ``scale`` output pixels per sensor pixel (see :func:`_figure`)."""
    height, width = on.shape
    fig, ax, image = _figure(width, height, scale, dpi)
    image.set_data(event_rgb(on, off))
    ax.set_title(title or f"{int(on.sum())} ON, {int(off.sum())} OFF events", fontsize=9,
                 loc="center" if scale is None else "left")
    if truth:
        draw_truth(ax, truth, start_ns, stop_ns, scale)
        ax.set_xlim(-0.5, width - 0.5)
        ax.set_ylim(height - 0.5, -0.5)
    return fig


def render_png(chunks: Iterable[Chunk], path, width: int, height: int, start_ns: int | None = None,
               stop_ns: int | None = None, title: str = "", truth: dict[str, np.ndarray] | None = None,
               scale: float | None = None, dpi: float = 100) -> tuple[int, int]:
    """Write the accumulated event image (:func:`event_figure`) to ``path``; returns (ON, OFF) event counts."""
    on, off = accumulate(chunks, width, height, start_ns, stop_ns)
    event_figure(on, off, title, truth, start_ns, stop_ns, scale, dpi).savefig(path, dpi=dpi)
    return int(on.sum()), int(off.sum())


def render_gif(chunks: Iterable[Chunk], path, width: int, height: int, start_ns: int, stop_ns: int,
               n_frames: int = 100, fps: float = 10.0) -> int:
    """Write an animation of ``n_frames`` equal time slices of ``[start_ns, stop_ns)`` to ``path``
    (GIF through matplotlib's PillowWriter); returns the number of frames.

    Each frame shows the events recorded in its slice; the colour scale is fixed over the
    animation by the first frame with events, so brightness compares between frames.
    """
    from matplotlib.animation import PillowWriter

    if stop_ns <= start_ns or n_frames < 1:
        raise ValueError("render_gif needs stop_ns > start_ns and at least one frame")
    edges = start_ns + (np.arange(n_frames + 1, dtype=np.int64) * (stop_ns - start_ns)) // n_frames
    fig, ax, image = _figure(width, height)
    writer = PillowWriter(fps=fps)
    on = np.zeros(width * height, np.int64)
    off = np.zeros(width * height, np.int64)
    frame, scale = 0, None

    def flush():
        nonlocal scale, on, off
        if scale is None and (on.any() or off.any()):
            counts = np.concatenate([on[on > 0], off[off > 0]])
            scale = float(np.percentile(counts, 99.5))
        image.set_data(event_rgb(on.reshape(height, width), off.reshape(height, width), scale or 1.0))
        ax.set_title(f"t = {edges[frame] / NS_PER_S:.6f} s to {edges[frame + 1] / NS_PER_S:.6f} s")
        writer.grab_frame()
        on[:] = 0
        off[:] = 0

    with writer.saving(fig, str(path), dpi=100):
        for chunk in _in_span(chunks, start_ns, stop_ns):
            t = np.asarray(chunk["t_readout_ns"])
            index = np.asarray(chunk["y"], np.int64) * width + np.asarray(chunk["x"], np.int64)
            positive = np.asarray(chunk["p"]) > 0
            bounds = np.searchsorted(t, edges[frame + 1:], side="left")
            lo = 0
            for hi in bounds:
                sel = slice(lo, hi)
                on += np.bincount(index[sel][positive[sel]], minlength=on.size)
                off += np.bincount(index[sel][~positive[sel]], minlength=off.size)
                lo = hi
                if hi == t.size:
                    break
                flush()
                frame += 1
        while frame < n_frames:
            flush()
            frame += 1
    return n_frames
