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


def package_exports(package: str):
    """A block package's names, imported on first use (PEP 562): ``(__getattr__, __dir__, __all__)``.

    ``from evsda.blocks.scene import Satellite`` imports ``evsda.blocks.scene.satellite`` only then, and
    the package's ``BLOCKS`` (its block classes in the order above) imports all of them; importing the
    package, or one of its commands or library modules, imports no block, so ``evsda`` starts without
    them (docs/speed.md, fixed costs).
    """
    import sys
    from importlib import import_module

    specs = {spec.partition(":")[2]: spec.partition(":")[0]
             for spec in BLOCKS.values() if spec.startswith(package + ".")}

    def __getattr__(name: str):
        module = sys.modules[package]
        if name == "BLOCKS":
            return [getattr(module, class_name) for class_name in specs]
        if name not in specs:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(specs[name]), name)
        setattr(module, name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(specs) | {"BLOCKS"})

    return __getattr__, __dir__, [*specs, "BLOCKS"]
