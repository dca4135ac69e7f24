"""The vocabulary of port types: every value that flows between evsda blocks.

``core`` holds the contracts between pipeline stages; stage-specific types live in
their own modules and are re-exported here.
"""

from .core import (
    EventCause,
    Events,
    FocalPlane,
    Frame,
    Irradiance,
    Metrics,
    PointSources,
    SkyBackground,
    SourceKind,
    SpectralResponse,
    TriggeredEvents,
    Truth,
    add_stamp,
)
from .detection import Detections
from .scene import Observer, Orbit, Pointing

__all__ = [
    "EventCause", "Events", "FocalPlane", "SpectralResponse", "Frame", "Irradiance", "Metrics", "PointSources",
    "SkyBackground", "SourceKind", "TriggeredEvents", "Truth", "add_stamp",
    "Observer", "Orbit", "Pointing", "Detections",
]
