"""Trajectory files in TUM format: ``timestamp tx ty tz qx qy qz qw`` (T_world_cam), ``#`` comments.

Imports numpy, ``lite_vo.geometry`` and the io helpers only.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import pose_from_tum, tum_from_pose
from ._text import check_increasing, parse_table, read_lines
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


# ------------------------------------------------------------------------------------------------
# KITTI and EuRoC trajectories (read for ``lite-vo eval``; KITTI written on request)
# ------------------------------------------------------------------------------------------------

TRAJECTORY_FORMATS = ("tum", "kitti", "euroc")
KITTI_LAYOUT = "r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz"
KITTI_FPS = 10.0   # KITTI odometry's camera rate: frame timestamps when nothing better is known


def trajectory_format(path: str | os.PathLike, what: str = "trajectory file") -> str:
    """``"tum"``, ``"kitti"`` or ``"euroc"``, from the content of the first pose line (and header):

    * EuRoC CSV (``state_groundtruth_estimate0/data.csv``): comma-separated, >= 8 columns, a header
      naming ``p_RS_R_x`` or an integer nanosecond timestamp first;
    * KITTI: 12 numbers (a 3x4 pose matrix, no timestamp);
    * TUM: 8 fields ``timestamp tx ty tz qx qy qz qw`` (spaces or commas)."""
    path = Path(path)
    lines = read_lines(path, what)
    if not lines:
        raise InputError(f"{path}: {what} contains no poses")
    try:
        head = path.read_text(encoding="utf-8-sig", errors="replace")[:4096]
    except OSError as err:  # read_lines read it a moment ago
        raise InputError(f"{path}: cannot read ({err.strerror or err})") from None
    n, s = lines[0]
    if "," in s:
        f = [x.strip() for x in s.split(",")]
        if len(f) >= 8 and ("p_RS_R_x" in head or (f[0].isdigit() and len(f[0]) >= 15)):
            return "euroc"
        if len(f) == 8:
            return "tum"
    else:
        f = s.split()
        if len(f) == 12:
            return "kitti"
        if len(f) == 8:
            return "tum"
    raise InputError(f"{path} line {n}: {len(f)} fields: not a TUM ({TUM_HEADER}), KITTI (12 numbers: "
                     f"{KITTI_LAYOUT}) or EuRoC CSV (timestamp [ns], p_RS_R_x .. q_RS_z) trajectory")


def read_kitti_poses(path: str | os.PathLike, what: str = "KITTI trajectory file") -> np.ndarray:
    """Poses (N, 4, 4) of a KITTI file: one row-major 3x4 matrix ``T_world_cam`` per line."""
    path = Path(path)
    rows = []
    for n, s in read_lines(path, what):
        f = s.split()
        if len(f) != 12:
            raise InputError(f"{path} line {n}: expected 12 numbers ({KITTI_LAYOUT}), got {len(f)} fields")
        try:
            vals = np.array([float(x) for x in f])
        except ValueError:
            bad = next(x for x in f if not _is_float(x))
            raise InputError(f"{path} line {n}: {bad!r} is not a number") from None
        if not np.all(np.isfinite(vals)):
            raise InputError(f"{path} line {n}: pose contains NaN or infinite values")
        T = np.eye(4)
        T[:3, :] = vals.reshape(3, 4)
        R = T[:3, :3]
        off = float(np.abs(R @ R.T - np.eye(3)).max())
        if off > 1e-2 or np.linalg.det(R) <= 0:
            raise InputError(f"{path} line {n}: the 3x3 part is not a rotation (max |R R^T - I| = {off:.3g}, "
                             f"det {np.linalg.det(R):.3g})")
        rows.append(T)
    if not rows:
        raise InputError(f"{path}: {what} contains no poses")
    return np.asarray(rows)


def read_kitti_times(path: Path, count: int) -> np.ndarray:
    """Timestamps of KITTI's ``times.txt`` (one per line, seconds), ``count`` of them."""
    arr, numbers = parse_table(path, 1, 1, what="times file", layout="timestamp")
    if len(arr) != count:
        raise InputError(f"{path}: has {len(arr)} timestamps for the {count} poses of the KITTI file beside it")
    check_increasing(path, arr[:, 0], numbers)
    return arr[:, 0].copy()


def read_euroc_groundtruth(path: str | os.PathLike, what: str = "ground truth file",
                           T_body_cam: np.ndarray | None = None) -> tuple[Trajectory, str]:
    """(trajectory, note) of an EuRoC ``state_groundtruth_estimate0/data.csv`` (ns timestamps,
    ``p_RS_R_xyz``, ``q_RS_wxyz``, further columns ignored).

    The poses are converted to the camera (``T_world_cam = T_world_S T_BS^-1 T_BC``) with
    ``T_body_cam`` when given, else inside a ``mav0`` folder with ``../../cam0/sensor.yaml`` (as the
    sequence reader does); otherwise they stay the poses of the ground-truth sensor (the body), which
    the note says."""
    from ..geometry import make_pose, rotmat_from_quat_xyzw
    from .calib_formats import read_sensor_transform
    path = Path(path)
    arr, numbers = parse_table(path, 8, None, sep=",", what=what,
                               layout="timestamp [ns], p_RS_R_x, p_RS_R_y, p_RS_R_z, q_RS_w, q_RS_x, q_RS_y, q_RS_z")
    if len(arr) == 0:
        raise InputError(f"{path}: {what} contains no poses")
    t = arr[:, 0] / 1e9
    check_increasing(path, t, numbers)
    q_wxyz = arr[:, 4:8]
    bad = np.nonzero(np.linalg.norm(q_wxyz, axis=1) < 1e-6)[0]
    if len(bad):
        raise InputError(f"{path} line {numbers[bad[0]]}: quaternion q_RS_w .. q_RS_z has zero length")
    T_world_S = make_pose(rotmat_from_quat_xyzw(q_wxyz[:, [1, 2, 3, 0]]), arr[:, 1:4])
    cam_yaml = path.parent.parent / "cam0" / "sensor.yaml"
    if T_body_cam is None and not cam_yaml.is_file():
        return Trajectory(t, T_world_S), (f"{path}: EuRoC ground truth of the body (no cam0/sensor.yaml beside "
                                          "it: not converted to the camera)")
    gt_yaml = path.parent / "sensor.yaml"
    T_BS = read_sensor_transform(gt_yaml) if gt_yaml.is_file() else np.eye(4)
    T_BC = read_sensor_transform(cam_yaml) if T_body_cam is None else np.asarray(T_body_cam, dtype=np.float64)
    return Trajectory(t, T_world_S @ np.linalg.inv(T_BS) @ T_BC), f"{path}: EuRoC ground truth, converted to cam0"


class PoseFile:
    """A trajectory file of any format (:func:`read_pose_file`); KITTI files without ``times.txt``
    get their timestamps in :meth:`trajectory` (from another trajectory by index, or frame / 10 Hz)."""

    def __init__(self, path: Path, fmt: str, poses: np.ndarray, timestamps, note: str = ""):
        self.path, self.format, self.poses, self.timestamps, self.note = path, fmt, poses, timestamps, note

    def trajectory(self, reference: "Trajectory | None" = None) -> tuple[Trajectory, str]:
        """(trajectory, note on the timestamps' origin). ``reference``: the trajectory this one is
        compared with; its timestamps are taken by index when this file has none of its own."""
        if self.timestamps is not None:
            return Trajectory(self.timestamps, self.poses), self.note
        n = len(self.poses)
        if reference is None:
            return (Trajectory(np.arange(n) / KITTI_FPS, self.poses),
                    f"{self.path}: KITTI poses without times.txt: timestamps frame / {KITTI_FPS:g} Hz")
        if len(reference) != n:
            raise InputError(f"{self.path}: KITTI poses have no timestamps (no times.txt beside the file) and "
                             f"their count {n} differs from the {len(reference)} poses of the other trajectory, so "
                             "they cannot be paired by index; put the frame timestamps into a times.txt beside it")
        return (Trajectory(reference.timestamps, self.poses),
                f"{self.path}: KITTI poses without times.txt: timestamps of the other trajectory, by index")


def read_pose_file(path: str | os.PathLike, what: str = "trajectory file") -> PoseFile:
    """Read a TUM, KITTI or EuRoC CSV trajectory, recognised by its content (:func:`trajectory_format`).
    KITTI timestamps come from a ``times.txt`` beside the file when there is one."""
    path = Path(path)
    fmt = trajectory_format(path, what)
    if fmt == "tum":
        tr = read_trajectory(path, what)
        return PoseFile(path, fmt, tr.poses, tr.timestamps)
    if fmt == "euroc":
        tr, note = read_euroc_groundtruth(path, what)
        return PoseFile(path, fmt, tr.poses, tr.timestamps, note)
    poses = read_kitti_poses(path, what)
    times = path.parent / "times.txt"
    if times.is_file():
        return PoseFile(path, fmt, poses, read_kitti_times(times, len(poses)),
                        f"{path}: KITTI poses, timestamps from {times}")
    return PoseFile(path, fmt, poses, None)


def write_trajectory_kitti(path: str | os.PathLike, trajectory: Trajectory, times: bool = True) -> None:
    """Write ``trajectory`` in KITTI format (``r11 r12 r13 tx ... r33 tz`` per pose, no timestamps)
    and, with ``times``, its timestamps into ``times.txt`` beside it, which :func:`read_pose_file`
    reads back (KITTI files have one line per frame; lost frames are missing here, so the times
    are what pairs the lines with frames)."""
    path = Path(path)
    lines = [" ".join(f"{v:.9g}" for v in T[:3, :].reshape(-1)) for T in trajectory.poses]
    write_file_atomic(path, "".join(s + "\n" for s in lines))
    if times:
        write_file_atomic(path.parent / "times.txt", "".join(f"{t:.9f}\n" for t in trajectory.timestamps))
