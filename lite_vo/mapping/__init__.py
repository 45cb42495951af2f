"""Semi-dense per-pixel inverse-depth filter (numba kernels + depth map + Mapper).

Public API: :class:`Mapper`, :class:`MapFrame`, :class:`MappingStats`, :func:`depth_accuracy`,
:class:`MappingConfig`. Kernels live in ``_kernels.py`` (``warmup()`` compiles them).
Imports: numpy, numba, ``lite_vo.camera``/``geometry``/``errors``; never tracking, system or ar_demo.
"""
from .config import MappingConfig
from .mapper import MapFrame, Mapper, MappingStats, depth_accuracy, image_gradients

__all__ = ["MappingConfig", "MapFrame", "Mapper", "MappingStats", "depth_accuracy", "image_gradients"]
