"""evsda's physics blocks, one sub-package per stage of the paper's pipeline.

* :mod:`evsda.blocks.scene` — orbits, observers, pointing, visibility, radiometry, stars, sky (Sec. 2.1, Eq. 1-2)
* :mod:`evsda.blocks.optics` — source field, propagation, turbulence, PSF, focal-plane rendering (Sec. 2.2, Eq. 3-11)
* :mod:`evsda.blocks.pixel` — photoreceptor, comparator, noise, refractory period (Sec. 2.3-2.5, Eq. 12-21)
* :mod:`evsda.blocks.readout` — arbiters, frame-sensor baseline, metrics, images (Sec. 2.5 and 3, Eq. 22)
"""

from evsda.graph.numba_stamps import stamp_packages

stamp_packages("evsda")       # Numba's cache of each package's compiled code stamped by all the package's sources
