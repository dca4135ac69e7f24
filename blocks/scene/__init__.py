"""scene blocks."""

BLOCKS: list = []
