"""Optics: point sources through a turbulent atmosphere and a telescope onto the pixels (paper Sec. 2.2, Eq. 3-11).

Library modules (usable without a graph): :mod:`.zernike`, :mod:`.karhunen_loeve`,
:mod:`.kolmogorov`, :mod:`.fft_screens`, :mod:`.autoregressive`, :mod:`.layer_screen`,
:mod:`.atmosphere`, :mod:`.propagation`, :mod:`.sampling`, :mod:`.telescope`, :mod:`.psf`,
:mod:`.render`, :mod:`.sizing`, :mod:`.paths`, :mod:`.analytic_path`, :mod:`.pupil_path`,
:mod:`.reference_path`, :mod:`.imaging`. The block is :class:`.block.PointSourceOptics`.
"""

from evsda.blocks.catalog import package_exports

__getattr__, __dir__, __all__ = package_exports(__name__)   # blocks imported on first use
