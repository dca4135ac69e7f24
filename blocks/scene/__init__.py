"""Scene blocks: orbits, observers, pointing, field of view, visibility, radiometry, stars and sky (paper Sec. 2.1)."""

from evsda.blocks.catalog import package_exports

__getattr__, __dir__, __all__ = package_exports(__name__)   # blocks imported on first use
