"""The base class of every sequence reader (folders, EuRoC, video, live camera, ROS bags).

Imports numpy, ``lite_vo.camera`` and the io data types only, so every reader module can derive from
it without importing another reader.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator, Optional

from ..camera import Camera
from .types import Accelerometer, Frame, Trajectory


class Sequence:
    """Base class: ``name``, ``camera`` (native, with distortion), ``has_depth``, ``groundtruth``,
    ``accelerometer``, ``len()``, iteration yielding :class:`Frame` (images read lazily).

    A frame that cannot be read (unreadable, truncated, missing or wrong-size file, a video frame
    that does not decode) is yielded with ``image=None`` and ``error="<file>: <reason>"``; the
    iteration goes on. ``calib_source`` names where the calibration came from."""

    kind = "sequence"

    def __init__(self, name: str, camera: Camera, path: Optional[Path] = None, calib_source: str = ""):
        self.name = name
        self.camera = camera
        self.path = path
        self.calib_source = calib_source
        self.has_depth = False
        self.groundtruth: Optional[Trajectory] = None
        self.accelerometer: Optional[Accelerometer] = None
        self.depth_scale: Optional[float] = None

    def __len__(self) -> int:  # pragma: no cover - overridden
        raise TypeError(f"{self.kind} sequence has no length")

    def __iter__(self) -> Iterator[Frame]:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:
        """Release resources (video files, cameras); file sequences hold none."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self) -> str:
        try:
            n = f"{len(self)} frames"
        except TypeError:
            n = "live"
        extras = [x for x, on in (("depth", self.has_depth), ("groundtruth", self.groundtruth is not None),
                                  ("accelerometer", self.accelerometer is not None)) if on]
        return (f"<{type(self).__name__} {self.name!r}: {n}, camera {self.camera.describe()}"
                f"{', ' + ', '.join(extras) if extras else ''}>")
