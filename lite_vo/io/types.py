"""Plain data types of sequences: :class:`Frame`, :class:`Trajectory`, :class:`Accelerometer`.

Imports numpy and ``lite_vo.geometry`` only.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One frame of a sequence as recorded.

    ``image``: uint8 (H, W) grey at the native resolution (distorted, as recorded), or None for a
    bad frame; ``depth``: float32 (H, W) metres, 0 = invalid, or None when the sequence has no
    depth for it; ``color``: the BGR uint8 (H, W, 3) image as decoded when the source is colour
    (``image`` is its grey version: for image files the decoder's own, a JPEG's luma plane), None
    for grey sources; ``error``: None, or for a frame
    that could not be read (unreadable, truncated, missing or wrong-size file) a one-line
    ``"<file>: <reason>"`` (then ``image``, ``depth`` and ``color`` are None). Readers yield bad
    frames instead of stopping, so the caller decides how many it tolerates. ``depth_reader``: when
    the frame was read with deferred depth (:meth:`FileSequence.frame` ``defer_depth=True``),
    ``depth`` is None and calling this reads it (``InputError`` naming the file if it cannot).
    ``color_reader``: when the frame was read with deferred colour (``defer_color=True``), ``color``
    is None and calling this decodes it (the BGR image, or None for a grey file); ``color_reader(r)``
    with ``r`` 2, 4 or 8 may return it at 1/r of the size instead (JPEGs decode faster so).
    """
    index: int
    timestamp: float
    image: Optional[np.ndarray]
    depth: Optional[np.ndarray] = None
    color: Optional[np.ndarray] = None
    error: Optional[str] = None
    depth_reader: Optional[Callable[[], np.ndarray]] = None
    color_reader: Optional[Callable[..., Optional[np.ndarray]]] = None

    @property
    def ok(self) -> bool:
        """True when the frame was read (``error`` is None)."""
        return self.error is None


class Trajectory:
    """Timestamped poses ``T_world_cam``: ``timestamps`` (N,) seconds, strictly increasing,
    ``poses`` (N, 4, 4) float64 (also available as ``poses_T_world_cam``).

    Gaps are allowed (lost frames are simply absent). Raises ValueError on inconsistent arrays,
    non-increasing timestamps or non-finite values (readers turn that into InputError with a file).
    """

    __slots__ = ("timestamps", "poses")

    def __init__(self, timestamps, poses_T_world_cam):
        t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
        p = np.asarray(poses_T_world_cam, dtype=np.float64)
        if p.ndim != 3 or p.shape[1:] != (4, 4) or len(p) != len(t):
            raise ValueError(f"expected timestamps (N,) and poses (N, 4, 4), got {t.shape} and {p.shape}")
        if not np.all(np.isfinite(t)) or not np.all(np.isfinite(p)):
            raise ValueError("trajectory contains NaN or infinite values")
        if len(t) > 1 and np.any(np.diff(t) <= 0):
            raise ValueError("trajectory timestamps must be strictly increasing")
        t.setflags(write=False)
        p.setflags(write=False)
        self.timestamps = t
        self.poses = p

    @property
    def poses_T_world_cam(self) -> np.ndarray:
        return self.poses

    @property
    def positions_xyz(self) -> np.ndarray:
        """Camera centres in the world (N, 3)."""
        return self.poses[:, :3, 3]

    def __len__(self) -> int:
        return len(self.timestamps)

    def __repr__(self) -> str:
        if len(self) == 0:
            return "Trajectory(empty)"
        return (f"Trajectory({len(self)} poses, t={self.timestamps[0]:.3f}..{self.timestamps[-1]:.3f} s, "
                f"path {self.path_length():.3f})")

    def __getitem__(self, idx) -> "Trajectory":
        """Sub-trajectory by slice, index array or boolean mask."""
        if isinstance(idx, (int, np.integer)):
            idx = [int(idx)]
        return Trajectory(self.timestamps[idx], self.poses[idx])

    def path_length(self) -> float:
        """Sum of distances between consecutive camera centres."""
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.positions_xyz, axis=0), axis=1).sum())

    def nearest(self, timestamp: float, max_dt: float = np.inf) -> Optional[int]:
        """Index of the pose whose timestamp is nearest ``timestamp`` (None if none within max_dt)."""
        if len(self) == 0:
            return None
        j = int(np.searchsorted(self.timestamps, timestamp))
        cands = [c for c in (j - 1, j) if 0 <= c < len(self)]
        best = min(cands, key=lambda c: abs(self.timestamps[c] - timestamp))
        return best if abs(self.timestamps[best] - timestamp) <= max_dt else None

    def pose_at(self, timestamp: float, max_gap: float = 0.1) -> Optional[np.ndarray]:
        """Pose (4, 4) at ``timestamp`` interpolated between the two neighbouring poses (linear
        translation, geodesic rotation); None outside the trajectory or when the neighbours are
        more than ``max_gap`` seconds apart. An exact timestamp returns that pose."""
        from ..geometry import exp_so3, log_so3
        t = self.timestamps
        if len(t) == 0 or timestamp < t[0] or timestamp > t[-1]:
            return None
        j = int(np.searchsorted(t, timestamp))
        if t[j] == timestamp:
            return self.poses[j].copy()
        i = j - 1
        if t[j] - t[i] > max_gap:
            return None
        a = (timestamp - t[i]) / (t[j] - t[i])
        T0, T1 = self.poses[i], self.poses[j]
        out = np.eye(4)
        out[:3, :3] = T0[:3, :3] @ exp_so3(a * log_so3(T0[:3, :3].T @ T1[:3, :3]))
        out[:3, 3] = (1 - a) * T0[:3, 3] + a * T1[:3, 3]
        return out


class Accelerometer:
    """Accelerometer samples: ``timestamps`` (N,) s, strictly increasing; ``acc_xyz`` (N, 3) m/s^2,
    specific force in the CAMERA frame (at rest it points away from the ground: ``|a| ~ 9.81``)."""

    __slots__ = ("timestamps", "acc_xyz")

    def __init__(self, timestamps, acc_xyz):
        t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
        a = np.asarray(acc_xyz, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != 3 or len(a) != len(t):
            raise ValueError(f"expected timestamps (N,) and acc_xyz (N, 3), got {t.shape} and {a.shape}")
        if not np.all(np.isfinite(t)) or not np.all(np.isfinite(a)):
            raise ValueError("accelerometer data contains NaN or infinite values")
        if len(t) > 1 and np.any(np.diff(t) <= 0):
            raise ValueError("accelerometer timestamps must be strictly increasing")
        t.setflags(write=False)
        a.setflags(write=False)
        self.timestamps = t
        self.acc_xyz = a

    def __len__(self) -> int:
        return len(self.timestamps)

    def __repr__(self) -> str:
        return f"Accelerometer({len(self)} samples)"

    def at(self, timestamp: float) -> np.ndarray:
        """Linearly interpolated sample (3,) at ``timestamp`` (clamped to the recorded range)."""
        if len(self) == 0:
            raise ValueError("no accelerometer samples")
        return np.array([np.interp(timestamp, self.timestamps, self.acc_xyz[:, k]) for k in range(3)])

    def mean_between(self, t0: float, t1: float) -> Optional[np.ndarray]:
        """Mean sample (3,) over ``t0 <= t <= t1`` (a simple low-pass), or None if there is none."""
        m = (self.timestamps >= t0) & (self.timestamps <= t1)
        if not m.any():
            return None
        return self.acc_xyz[m].mean(axis=0)
