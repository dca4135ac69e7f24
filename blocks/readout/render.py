"""Event images: the paper's Fig. 6 (ON events green, OFF red, accumulated over a time
span) as a PNG, and an animation of events over time as a GIF.

Both stream over event chunks (dicts of numpy arrays sorted by ``t_readout_ns``, as
:meth:`RunStore.iter_events` yields them) and select events by their readout time
``t_a``, the time the sensor reports. Memory holds count images, never the events.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

Chunk = dict[str, np.ndarray]
NS_PER_S = 1_000_000_000


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


def _figure(width: int, height: int):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    size = 8.0
    fig, ax = plt.subplots(figsize=(size, size * height / width + 0.9), dpi=100)
    ax.set_xlabel("column x [pixel]")
    ax.set_ylabel("row y [pixel]")
    ax.legend(handles=[Patch(color=(0, 1, 0), label="ON"), Patch(color=(1, 0, 0), label="OFF")],
              loc="upper right", framealpha=0.6)
    image = ax.imshow(np.zeros((height, width, 3)), origin="upper", interpolation="nearest",
                      extent=(-0.5, width - 0.5, height - 0.5, -0.5))
    fig.tight_layout()
    return fig, ax, image


def render_png(chunks: Iterable[Chunk], path, width: int, height: int, start_ns: int | None = None,
               stop_ns: int | None = None, title: str = "") -> tuple[int, int]:
    """Write the accumulated event image (paper Fig. 6) to ``path``; returns (ON, OFF) event counts."""
    import matplotlib.pyplot as plt

    on, off = accumulate(chunks, width, height, start_ns, stop_ns)
    fig, ax, image = _figure(width, height)
    image.set_data(event_rgb(on, off))
    ax.set_title(title or f"{int(on.sum())} ON, {int(off.sum())} OFF events")
    fig.savefig(path)
    plt.close(fig)
    return int(on.sum()), int(off.sum())


def render_gif(chunks: Iterable[Chunk], path, width: int, height: int, start_ns: int, stop_ns: int,
               n_frames: int = 100, fps: float = 10.0) -> int:
    """Write an animation of ``n_frames`` equal time slices of ``[start_ns, stop_ns)`` to ``path``
    (GIF through matplotlib's PillowWriter); returns the number of frames.

    Each frame shows the events recorded in its slice; the colour scale is fixed over the
    animation by the first frame with events, so brightness compares between frames.
    """
    import matplotlib.pyplot as plt
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
    plt.close(fig)
    return n_frames
