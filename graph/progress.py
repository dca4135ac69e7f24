"""A progress bar for long runs (tqdm), shown only after a run has taken a second or two."""

from __future__ import annotations

from tqdm import tqdm

SHOW_AFTER_S = 1.5


def progress_bar(total: int, initial: int = 0, enabled: bool = True, desc: str = "") -> tqdm:
    """A window counter on stderr that appears once the run has lasted ``SHOW_AFTER_S``."""
    return tqdm(total=total, initial=initial, disable=not enabled, delay=SHOW_AFTER_S, desc=desc,
                unit="window", leave=False, dynamic_ncols=True)
