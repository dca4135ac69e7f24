"""Detection on a sensor's output without ground truth, its scoring against the truth, and the
limiting-magnitude study: injected sources, the event detector, the frame detector, scoring."""

from .event_detector import EventDetector
from .frame_detector import FrameDetector
from .injected import InjectedSources
from .scoring import DetectionScoring

BLOCKS: list = [InjectedSources, EventDetector, FrameDetector, DetectionScoring]
