"""Pixel blocks: photoreceptor, dark current, low-pass, comparator, noise, refractory (paper Sec. 2.3-2.5)."""

from evsda.blocks.catalog import package_exports

__getattr__, __dir__, __all__ = package_exports(__name__)   # blocks imported on first use
