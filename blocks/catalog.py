"""Every built-in block, registered through the ``evsda.blocks`` entry point.

Type names to ``"module:Class"``: the registry (:mod:`evsda.graph.registry`) imports a block's
module only when a graph or a command asks for that type, so loading a graph imports only the
block packages it names.
"""

BLOCKS = {
    # scene (paper Sec. 2.1)
    "tle_source": "evsda.blocks.scene.sources:TleSource",
    "ground_site": "evsda.blocks.scene.sources:GroundSite",
    "space_observer": "evsda.blocks.scene.sources:SpaceObserver",
    "camera": "evsda.blocks.scene.sources:Camera",
    "pointing": "evsda.blocks.scene.sources:PointingLaw",
    "satellite": "evsda.blocks.scene.satellite:Satellite",
    "satellite_catalog": "evsda.blocks.scene.satellite_catalog:SatelliteCatalog",
    "star_field": "evsda.blocks.scene.stars:StarField",
    "sky_background": "evsda.blocks.scene.sky:SkyBackgroundBlock",
    # optics (Sec. 2.2)
    "optics": "evsda.blocks.optics.block:PointSourceOptics",
    # pixels (Sec. 2.3-2.5)
    "dvs_pixel": "evsda.blocks.pixel.block:DvsPixel",
    # readout (Sec. 2.5, 3)
    "ideal_readout": "evsda.blocks.readout.arbiters:IdealReadout",
    "row_scan_arbiter": "evsda.blocks.readout.arbiters:RowScanArbiter",
    "column_burst_arbiter": "evsda.blocks.readout.arbiters:ColumnBurstArbiter",
    "event_metrics": "evsda.blocks.readout.metrics:EventMetrics",
    "object_metrics": "evsda.blocks.readout.object_metrics:ObjectMetrics",
    "frame_sensor": "evsda.blocks.readout.frame_sensor:FrameSensor",
    "frame_photometry": "evsda.blocks.readout.photometry:FramePhotometry",
    # detection
    "injected_sources": "evsda.blocks.detection.injected:InjectedSources",
    "event_detector": "evsda.blocks.detection.event_detector:EventDetector",
    "frame_detector": "evsda.blocks.detection.frame_detector:FrameDetector",
    "detection_scoring": "evsda.blocks.detection.scoring:DetectionScoring",
}
