"""Scene blocks: orbits, observers, pointing, field of view, visibility, radiometry, stars and sky (paper Sec. 2.1)."""

from .satellite import Satellite
from .satellite_catalog import SatelliteCatalog
from .sky import SkyBackgroundBlock
from .sources import Camera, GroundSite, PointingLaw, SpaceObserver, TleSource
from .stars import StarField

BLOCKS: list = [TleSource, GroundSite, SpaceObserver, Camera, PointingLaw, Satellite, SatelliteCatalog, StarField,
                SkyBackgroundBlock]
