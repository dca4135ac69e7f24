"""Pixel blocks: photoreceptor, dark current, low-pass, comparator, noise, refractory (paper Sec. 2.3-2.5)."""

from .block import DvsPixel

BLOCKS: list = [DvsPixel]
