"""lite_vo: semi-dense direct visual odometry (Schoeps, Engel, Cremers, ISMAR 2014) in Python.

Public API (imported lazily so ``import lite_vo`` stays cheap and compiles no kernels):

* :func:`open_sequence` - read TUM, EuRoC, image-folder, video and live-camera sequences
* :func:`load_profile` - a validated :class:`VOConfig` from a shipped profile or TOML file
* :class:`Session` - the frame driver: a whole sequence through the VO into :class:`OutputSink` objects
* :class:`VisualOdometry` - ``process(image, timestamp) -> FrameResult``, ``depth_map()``

The core never imports ``ar_demo``, pybullet, trimesh or moderngl.
"""
from __future__ import annotations

import logging
import os

__version__ = "0.1.0"

# numba's parallel kernels run on GNU OpenMP (Linux), whose idle worker threads keep spinning for a
# while after every parallel region: on ICL (`phone`, sync) that burned about 2 ms of CPU per frame that
# the frame reader, the depth evaluation and everything else on the machine could use (CPU 9.6 -> 7.7 ms,
# wall 5.2 -> 4.8 ms per frame, medians of six interleaved runs against GNU's default of 300000). A
# shorter spin unless the user set one; it has to be in the environment before OpenMP starts (the
# first parallel kernel).
os.environ.setdefault("GOMP_SPINCOUNT", "30000")

logging.getLogger(__name__).addHandler(logging.NullHandler())

_LAZY = {
    "open_sequence": ("lite_vo.io", "open_sequence"),
    "load_profile": ("lite_vo.config", "load_profile"),
    "VOConfig": ("lite_vo.config", "VOConfig"),
    "VisualOdometry": ("lite_vo.system", "VisualOdometry"),
    "FrameResult": ("lite_vo.system", "FrameResult"),
    "OutputSink": ("lite_vo.session", "OutputSink"),
    "Session": ("lite_vo.session", "Session"),
    "PublishedMap": ("lite_vo.system", "PublishedMap"),
    "LiteVOError": ("lite_vo.errors", "LiteVOError"),
}

__all__ = sorted(_LAZY) + ["__version__"]


def __getattr__(name: str):
    if name in _LAZY:
        import importlib
        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'lite_vo' has no attribute {name!r}")
