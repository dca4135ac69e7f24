"""Every built-in block, registered through the ``evsda.blocks`` entry point."""

from evsda.blocks.detection import BLOCKS as DETECTION
from evsda.blocks.optics import BLOCKS as OPTICS
from evsda.blocks.pixel import BLOCKS as PIXEL
from evsda.blocks.readout import BLOCKS as READOUT
from evsda.blocks.scene import BLOCKS as SCENE

BLOCKS = [*SCENE, *OPTICS, *PIXEL, *READOUT, *DETECTION]
