"""readout blocks."""

BLOCKS: list = []
