"""Helpers that write small sequences (TUM layout, EuRoC mav0, image folders, videos) into a
temporary folder, plus synthetic images and trajectories, for tests. Everything is seeded.

Import from tests as ``from data_helpers import ...`` (pytest puts ``tests/`` on sys.path) and
find the shared real data with :func:`shared_data_dir` / :func:`require_shared`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def shared_data_dir() -> Path:
    return SHARED_DATA


def require_shared(name: str = "") -> Path:
    """Path of ``../shared/data/<name>``; skips the calling test with a message when absent."""
    import pytest
    p = SHARED_DATA / name if name else SHARED_DATA
    if not p.exists():
        pytest.skip(f"shared data not available: {p} (tests on real sequences need ../shared/data)")
    return p


# ------------------------------------------------------------------------------------------------
# images and trajectories
# ------------------------------------------------------------------------------------------------

def textured_image(width: int, height: int, seed: int = 0, colour: bool = False) -> np.ndarray:
    """A smooth random texture (uint8), (H, W) or (H, W, 3)."""
    import cv2
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, size=(max(2, height // 4), max(2, width // 4), 3 if colour else 1))
    img = cv2.resize(small.astype(np.float32), (width, height), interpolation=cv2.INTER_CUBIC)
    img = np.clip(img, 0, 255).astype(np.uint8)
    return img if colour else img.reshape(height, width)


def checkerboard(width: int, height: int, square: float = 8.0, offset: float = 0.0) -> np.ndarray:
    """A float64 checkerboard 0/255 with ``square`` pixels per square (pixel centres sampled)."""
    u, v = np.meshgrid(np.arange(width) + offset, np.arange(height) + offset)
    return (((np.floor(u / square) + np.floor(v / square)) % 2) * 255.0)


def random_trajectory(n: int, seed: int = 0, dt: float = 0.05, t0: float = 0.0, speed: float = 0.3,
                      rot_speed: float = 0.3):
    """A smooth random ``Trajectory`` of ``n`` poses sampled every ``dt`` seconds."""
    from lite_vo.geometry import exp_se3
    from lite_vo.io import Trajectory
    rng = np.random.default_rng(seed)
    t = t0 + dt * np.arange(n)
    T = np.eye(4)
    poses = []
    v = rng.normal(size=3)
    w = rng.normal(size=3)
    for _ in range(n):
        poses.append(T.copy())
        v = 0.9 * v + 0.3 * rng.normal(size=3)
        w = 0.9 * w + 0.3 * rng.normal(size=3)
        xi = np.concatenate([speed * dt * v / max(np.linalg.norm(v), 1e-9),
                             rot_speed * dt * w / max(np.linalg.norm(w), 1e-9)])
        T = T @ exp_se3(xi)
    return Trajectory(t, np.array(poses))


def write_tum_trajectory(path: Path, timestamps, poses) -> Path:
    from lite_vo.geometry import tum_from_pose
    rows = tum_from_pose(np.asarray(poses))
    path = Path(path)
    with open(path, "w") as fh:
        fh.write("# timestamp tx ty tz qx qy qz qw\n")
        for t, r in zip(timestamps, rows):
            fh.write(f"{t:.6f} " + " ".join(f"{x:.9f}" for x in r) + "\n")
    return path


# ------------------------------------------------------------------------------------------------
# sequence folders
# ------------------------------------------------------------------------------------------------

def write_calib(path: Path, width: int, height: int, fx: float = 50.0, fy: float = 50.0,
                cx: Optional[float] = None, cy: Optional[float] = None,
                dist: Sequence[float] = (), depth_scale: Optional[float] = None) -> Path:
    cx = (width - 1) / 2 if cx is None else cx
    cy = (height - 1) / 2 if cy is None else cy
    lines = ["# fx fy cx cy [k1 k2 p1 p2 [k3]]", " ".join(f"{v:g}" for v in (fx, fy, cx, cy, *dist)),
             "# width height", f"{width} {height}"]
    if depth_scale is not None:
        lines.append(f"depth_scale {depth_scale:g}")
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def write_tum_folder(root: Path, n: int = 5, width: int = 64, height: int = 48, *, name: str = "seq",
                     dt: float = 0.1, t0: float = 100.0, depth: bool = True, depth_offset: float = 0.01,
                     depth_scale: Optional[float] = 1000.0, depth_value_m: float = 2.0, gt: bool = True,
                     accelerometer: bool = True, calib: bool = True, colour: bool = True,
                     dist: Sequence[float] = (), seed: int = 0) -> Path:
    """A TUM RGB-D layout folder ``root/name`` with ``n`` frames; depth timestamps shifted by
    ``depth_offset`` s; depth PNG = ``depth_value_m * depth_scale`` (TUM default 5000 if None)."""
    import cv2
    folder = Path(root) / name
    (folder / "rgb").mkdir(parents=True)
    ts = t0 + dt * np.arange(n)
    rgb_lines = ["# color images", "# timestamp filename"]
    for i, t in enumerate(ts):
        fn = f"rgb/{t:.6f}.png"
        cv2.imwrite(str(folder / fn), textured_image(width, height, seed + i, colour=colour))
        rgb_lines.append(f"{t:.6f} {fn}")
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    if depth:
        (folder / "depth").mkdir()
        scale = 5000.0 if depth_scale is None else depth_scale
        d_lines = ["# depth maps", "# timestamp filename"]
        for i, t in enumerate(ts + depth_offset):
            fn = f"depth/{t:.6f}.png"
            d = np.full((height, width), depth_value_m * scale, dtype=np.uint16)
            d[0, 0] = 0  # one invalid pixel
            cv2.imwrite(str(folder / fn), d)
            d_lines.append(f"{t:.6f} {fn}")
        (folder / "depth.txt").write_text("\n".join(d_lines) + "\n")
    if gt:
        traj = random_trajectory(3 * n, seed=seed, dt=dt / 3, t0=t0 - 0.05)
        write_tum_trajectory(folder / "groundtruth.txt", traj.timestamps, traj.poses)
    if accelerometer:
        ta = t0 + 0.01 * np.arange(10 * n)
        with open(folder / "accelerometer.txt", "w") as fh:
            fh.write("# timestamp ax ay az\n")
            for t in ta:
                fh.write(f"{t:.6f} 0.0 -9.81 0.0\n")
    if calib:
        write_calib(folder / "calib.txt", width, height, dist=dist, depth_scale=depth_scale)
    return folder


def write_euroc_folder(root: Path, n: int = 5, width: int = 64, height: int = 48, *, name: str = "euroc_seq",
                       t0_ns: int = 1403715273262142976, dt_ns: int = 50_000_000,
                       dist: Sequence[float] = (-0.1, 0.01, 0.0, 0.0),
                       T_BS: Optional[np.ndarray] = None, imu: bool = True, gt: bool = True,
                       seed: int = 0) -> Path:
    """An EuRoC-style ``root/name/mav0`` (cam0, imu0, state_groundtruth_estimate0); returns ``root/name``.

    The IMU measures +9.81 along the body's x axis (as EuRoC's vehicle at rest, x up); the ground
    truth is the identity rotation at the origin moving along body x."""
    import cv2
    T_BS = np.eye(4) if T_BS is None else np.asarray(T_BS)
    folder = Path(root) / name
    cam = folder / "mav0" / "cam0"
    (cam / "data").mkdir(parents=True)
    lines = ["#timestamp [ns],filename"]
    for i in range(n):
        ts = t0_ns + i * dt_ns
        cv2.imwrite(str(cam / "data" / f"{ts}.png"), textured_image(width, height, seed + i))
        lines.append(f"{ts},{ts}.png")
    (cam / "data.csv").write_text("\n".join(lines) + "\n")
    vals = [repr(float(v)) for v in T_BS.reshape(-1)]
    data = ",\n         ".join(", ".join(vals[4 * r:4 * r + 4]) for r in range(4))  # one row per line
    (cam / "sensor.yaml").write_text(
        "%YAML:1.0\n# General sensor definitions.\nsensor_type: camera\ncomment: test camera\n\n"
        "# Sensor extrinsics wrt. the body-frame.\nT_BS:\n  cols: 4\n  rows: 4\n"
        f"  data: [{data}]\n\n"
        f"rate_hz: 20\nresolution: [{width}, {height}]\ncamera_model: pinhole\n"
        f"intrinsics: [50.0, 50.0, {(width - 1) / 2}, {(height - 1) / 2}] #fu, fv, cu, cv\n"
        "distortion_model: radial-tangential\n"
        f"distortion_coefficients: [{', '.join(map(repr, dist))}]\n")
    if imu:
        (folder / "mav0" / "imu0").mkdir()
        rows = ["#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"]
        for i in range(4 * n):
            rows.append(f"{t0_ns + i * dt_ns // 4},0.0,0.0,0.0,9.81,0.0,0.0")
        (folder / "mav0" / "imu0" / "data.csv").write_text("\n".join(rows) + "\n")
    if gt:
        (folder / "mav0" / "state_groundtruth_estimate0").mkdir()
        rows = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
                "v_RS_R_x [m s^-1]"]
        for i in range(2 * n):
            rows.append(f"{t0_ns + i * dt_ns // 2},{0.01 * i},0.0,0.0,1.0,0.0,0.0,0.0,0.0")
        (folder / "mav0" / "state_groundtruth_estimate0" / "data.csv").write_text("\n".join(rows) + "\n")
    return folder


def write_image_folder(root: Path, n: int = 4, width: int = 64, height: int = 48, *, name: str = "images",
                       times: Optional[Sequence[float]] = None, calib: bool = True, ext: str = ".png",
                       seed: int = 0) -> Path:
    """A plain folder of images ``img1, img2, ..., img10`` (natural order) with calib.txt and times.txt."""
    import cv2
    folder = Path(root) / name
    folder.mkdir(parents=True)
    for i in range(n):
        cv2.imwrite(str(folder / f"img{i + 1}{ext}"), textured_image(width, height, seed + i, colour=True))
    if times is not None:
        (folder / "times.txt").write_text("\n".join(f"{t:.6f}" for t in times) + "\n")
    if calib:
        write_calib(folder / "calib.txt", width, height)
    return folder


def write_video(path: Path, n: int = 6, width: int = 64, height: int = 48, fps: float = 10.0,
                seed: int = 0) -> Optional[Path]:
    """An MJPG .avi video (None if this OpenCV build cannot write one)."""
    import cv2
    path = Path(path)
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (width, height))
    if not vw.isOpened():
        return None
    for i in range(n):
        vw.write(textured_image(width, height, seed + i, colour=True))
    vw.release()
    return path if path.is_file() and path.stat().st_size > 0 else None
