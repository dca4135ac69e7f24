"""pixel blocks."""

BLOCKS: list = []
