"""Readout blocks (paper Sec. 2.5 and 3): arbiters, the frame-sensor baseline, metrics."""

from .arbiters import ColumnBurstArbiter, IdealReadout, RowScanArbiter
from .metrics import EventMetrics

BLOCKS: list = [IdealReadout, RowScanArbiter, ColumnBurstArbiter, EventMetrics]
