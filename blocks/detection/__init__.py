"""Detection on a sensor's output without ground truth, its scoring against the truth, and the
limiting-magnitude study: injected sources, the event detector, the frame detector, scoring."""

from evsda.blocks.catalog import package_exports

__getattr__, __dir__, __all__ = package_exports(__name__)   # blocks imported on first use
