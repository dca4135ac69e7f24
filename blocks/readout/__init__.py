"""Readout blocks (paper Sec. 2.5 and 3): arbiters, the frame-sensor baseline, metrics."""

from .arbiters import ColumnBurstArbiter, IdealReadout, RowScanArbiter
from .frame_sensor import FrameSensor
from .metrics import EventMetrics
from .object_metrics import ObjectMetrics
from .photometry import FramePhotometry

BLOCKS: list = [IdealReadout, RowScanArbiter, ColumnBurstArbiter, EventMetrics, ObjectMetrics, FrameSensor,
                FramePhotometry]
