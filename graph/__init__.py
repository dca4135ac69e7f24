"""evsda's block framework: blocks, typed ports, graph files, executor, run stores, CLI.

This package knows nothing about physics; the blocks live in :mod:`evsda.blocks`.
"""

from importlib.metadata import PackageNotFoundError, version

from .entry_points import cache_entry_points

cache_entry_points()                # before pydantic (imported with .block) takes importlib's function

from .block import NS_PER_S, Block, RunInfo, Window, block_rng, parse_epoch
from .errors import GraphError, InputError, ParameterError, Problem, SceneError, StoreError, UserError
from .limits import Footprint, Limits
from .params import BlockParams
from .ports import Input, Output, PortValue
from .registry import register

try:
    __version__ = version("evsda")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = [
    "NS_PER_S", "Block", "BlockParams", "Footprint", "GraphError", "Limits", "Input", "InputError", "Output", "ParameterError",
    "PortValue", "Problem", "RunInfo", "SceneError", "StoreError", "UserError", "Window", "block_rng",
    "parse_epoch", "register", "__version__",
]
