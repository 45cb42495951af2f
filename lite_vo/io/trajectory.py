"""Trajectory files in TUM format: ``timestamp tx ty tz qx qy qz qw`` (T_world_cam), ``#`` comments.

Imports numpy, ``lite_vo.geometry`` and the io helpers only.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import pose_from_tum, tum_from_pose
from ._text import check_increasing, read_lines
from .outputs import write_file_atomic
from .types import Trajectory

TUM_HEADER = "timestamp tx ty tz qx qy qz qw"


def parse_tum_rows(path: Path, what: str = "trajectory file") -> tuple[np.ndarray, np.ndarray]:
    """(timestamps (N,), rows (N, 7) ``tx ty tz qx qy qz qw``) of a TUM pose file."""
    ts, rows, numbers = [], [], []
    for n, s in read_lines(path, what):
        f = s.replace(",", " ").split()
        if len(f) != 8:
            raise InputError(f"{path} line {n}: expected 8 fields ({TUM_HEADER}), got {len(f)}")
        try:
            vals = [float(x) for x in f]
        except ValueError:
            bad = next(x for x in f if not _is_float(x))
            raise InputError(f"{path} line {n}: {bad!r} is not a number") from None
        if not np.all(np.isfinite(vals)):
            raise InputError(f"{path} line {n}: pose contains NaN or infinite values")
        q = np.asarray(vals[4:8])
        if np.linalg.norm(q) < 1e-6:
            raise InputError(f"{path} line {n}: quaternion qx qy qz qw has zero length")
        ts.append(vals[0])
        rows.append(vals[1:8])
        numbers.append(n)
    t = np.asarray(ts, dtype=np.float64)
    check_increasing(path, t, numbers)
    return t, np.asarray(rows, dtype=np.float64).reshape(-1, 7)


def _is_float(x: str) -> bool:
    try:
        float(x)
        return True
    except ValueError:
        return False


def read_trajectory(path: str | os.PathLike, what: str = "trajectory file") -> Trajectory:
    """Read a TUM trajectory file (``timestamp tx ty tz qx qy qz qw`` per line, T_world_cam);
    ``what`` names the file in error messages (e.g. "ground truth file")."""
    path = Path(path)
    t, rows = parse_tum_rows(path, what)
    if len(t) == 0:
        raise InputError(f"{path}: {what} contains no poses")
    return Trajectory(t, pose_from_tum(rows))


def write_trajectory(path: str | os.PathLike, traj: Trajectory, comment: str | None = None) -> None:
    """Write ``traj`` in TUM format (header comment line, then one pose per line)."""
    path = Path(path)
    rows = tum_from_pose(traj.poses) if len(traj) else np.zeros((0, 7))
    lines = [f"# {TUM_HEADER}"]
    if comment:
        lines += ["# " + c for c in str(comment).splitlines()]
    for t, r in zip(traj.timestamps, rows):
        lines.append(f"{t:.6f} {r[0]:.9g} {r[1]:.9g} {r[2]:.9g} {r[3]:.9f} {r[4]:.9f} {r[5]:.9f} {r[6]:.9f}")
    write_file_atomic(path, "\n".join(lines) + "\n")
