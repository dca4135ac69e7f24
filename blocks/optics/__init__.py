"""optics blocks."""

BLOCKS: list = []
