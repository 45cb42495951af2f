"""Direct SE(3) tracking against the semi-dense inverse-depth map (numba kernels + Tracker).

Public API: :class:`TrackingReference` (immutable per-level point arrays built once per map update),
:class:`Tracker` (coarse-to-fine iteratively re-weighted Levenberg-Marquardt), :class:`TrackingResult`.
Imports numpy, numba, :mod:`lite_vo.image`, :mod:`lite_vo.camera`, :mod:`lite_vo.geometry` only.
"""
from .config import TrackingConfig
from .depth_images import depth_image_idepth, depth_image_mask
from .reference import ReferenceLevel, TrackingReference
from .tracker import Tracker, TrackingResult

__all__ = ["depth_image_mask", "depth_image_idepth", "TrackingConfig", "TrackingReference", "ReferenceLevel", "Tracker", "TrackingResult"]
