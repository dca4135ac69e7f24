"""Readout blocks (paper Sec. 2.5 and 3): arbiters, the frame-sensor baseline, metrics."""

from evsda.blocks.catalog import package_exports

__getattr__, __dir__, __all__ = package_exports(__name__)   # blocks imported on first use
