"""The output sinks of ``lite-vo run`` (contract in ARCHITECTURE.md), each one job:

* :class:`TrajectorySink`: ``trajectory.txt`` (TUM, ``T_world_cam``) appended line by line as the
  run goes (each line reaches the file when its frame is done), rewritten atomically when earlier
  poses are corrected and once more at the end, so a killed process leaves every pose it had;
* :class:`RunInfoSink`: ``run.json`` (written at the start with status ``running``, again at the end
  with the final status), ``timing.json``, and the depth accuracy files when the sequence has depth;
* :class:`MapSink`: ``map.ply``, the whole-scene coloured point cloud of the keyframes;
* :class:`TrajectoryExportSink`: at the end, the trajectory in KITTI format and/or as a picture
  (against the ground truth when there is one);
* :class:`ProgressSink`: a progress bar on a terminal (tqdm), a plain line every few seconds when
  the output is piped.

All of them are plain :class:`~lite_vo.session.OutputSink` objects called on the session's thread.
"""
from __future__ import annotations

import json
import logging
import os
import platform
from pathlib import Path

import numpy as np

from .config import tracking_level
from .geometry.quaternion import quat_xyzw_one
from .io import Trajectory, write_file_atomic, write_ply, write_ply_parts, write_trajectory
from .io.trajectory import write_trajectory_kitti
from .profiling.machine import cpu_model
from .progress import Progress
from .records import PoseRecord, RowRecord
from .session import FrameEvent, OutputSink, PublishedMap, RunEnd, SessionInfo

log = logging.getLogger(__name__)


def tum_line(t: float, T: np.ndarray) -> str:
    """One TUM line ``t tx ty tz qx qy qz qw`` (newline included) of a 4x4 pose."""
    T = np.asarray(T, dtype=np.float64)
    x, y, z = (float(v) for v in T[:3, 3])
    qx, qy, qz, qw = quat_xyzw_one(T[:3, :3])          # tum_from_pose's quaternion, for one pose
    return f"{t:.6f} {x:.9g} {y:.9g} {z:.9g} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}\n"


class TrajectorySink(OutputSink):
    """``trajectory.txt`` written as the run goes (see the module docstring).

    ``poses`` (a :class:`~lite_vo.records.PoseRecord`: frame index -> timestamp, T_world_cam) is
    the trajectory with every correction applied; lost frames are absent (a gap) unless a later
    correction gives them a pose (frames lost during a monocular start-up get the two-view start-up's).
    """

    def __init__(self, path, comment: str | None = None) -> None:
        self.path = Path(path)
        self.comment = comment
        self.poses = PoseRecord()
        self._file = None

    def on_start(self, info: SessionInfo) -> None:
        self._rewrite()

    def on_frame(self, event: FrameEvent) -> None:
        r = event.result
        T = None if r.lost else r.T_world_cam      # a lost frame: recorded without a pose, which a
        self.poses.add(r.index, r.timestamp, T)    # start-up correction may give it later
        if T is not None:
            self._file.write(tum_line(r.timestamp, T))   # line-buffered: one whole line per write

    def on_corrections(self, corrections: dict) -> None:
        changed = [self.poses.correct(idx, T) for idx, T in corrections.items()]
        if any(changed):
            self._rewrite()

    def on_finish(self, end: RunEnd) -> None:
        self._rewrite(reopen=False)

    def trajectory(self) -> Trajectory:
        _, timestamps, poses = self.poses.arrays()
        return Trajectory(timestamps, poses)

    def _rewrite(self, reopen: bool = True) -> None:
        """All poses so far, atomically (temporary file + rename); then append from there on."""
        if self._file is not None:
            self._file.close()
            self._file = None
        write_trajectory(self.path, self.trajectory(), comment=self.comment)
        if reopen:
            self._file = open(self.path, "a", encoding="utf-8", buffering=1)


def versions() -> dict:
    """Versions of the program and its main dependencies, and the machine it runs on."""
    import cv2
    import numba
    from . import __version__
    return {"lite_vo": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "numba": numba.__version__, "opencv": cv2.__version__, "platform": platform.platform(),
            "machine": platform.machine(), "cpu": cpu_model()}


def _columns(series, names) -> dict[str, np.ndarray]:
    """Columns of a depth accuracy series (a RowRecord, or a list of row dicts: absent values NaN)."""
    if isinstance(series, RowRecord):
        return {n: series.column(n) for n in names}
    return {n: np.array([r.get(n, np.nan) for r in series], dtype=np.float64) for n in names}


def summarize_depth_accuracy(series, skip_s: float = 1.0) -> dict | None:
    """Contract ``depth_accuracy`` over the mapped frames after the first ``skip_s`` seconds."""
    c = _columns(series, ("t", "density", "median_abs_rel_error", "within_5pct", "within_10pct"))
    finite = np.isfinite(c["median_abs_rel_error"])
    rows = finite & (c["t"] >= skip_s)
    if not rows.any():
        rows = finite
    if not rows.any():
        return None
    return {
        "density": float(np.mean(c["density"][rows])),
        "median_abs_rel_error": float(np.median(c["median_abs_rel_error"][rows])),
        "within_5pct": float(np.mean(c["within_5pct"][rows])),
        "within_10pct": float(np.mean(c["within_10pct"][rows])),
        "frames": int(rows.sum()),
    }


def plot_depth_error(series, path: Path, title: str) -> bool:
    """Depth error over time (thesis Fig. 5.8) as a PNG; False when matplotlib is missing."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    c = _columns(series, ("t", "median_abs_rel_error", "within_10pct", "density"))
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(c["t"], 100 * c["median_abs_rel_error"], label="median |rel. error| (%)")
    ax.plot(c["t"], 100 * (1 - c["within_10pct"]), label="outside 10% (%)")
    ax.plot(c["t"], 100 * c["density"], label="density (% of pixels)")
    ax.set_xlabel("time since start (s)")
    ax.set_ylim(bottom=0)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


class RunInfoSink(OutputSink):
    """``run.json`` (at the start with status ``running``, at the end with the final status),
    ``timing.json`` and, when the sequence has depth images, ``depth_accuracy.json`` and
    ``depth_error.png``. ``info`` holds the last ``run.json`` content (``out_dir=None``: kept in
    memory only)."""

    def __init__(self, out_dir=None) -> None:
        self.out = Path(out_dir) if out_dir is not None else None
        self.info: dict = {}
        self.timing: dict = {}
        self._start: SessionInfo | None = None

    def on_start(self, info: SessionInfo) -> None:
        self._start = info
        self.info = self._info("running")
        self._write_json("run.json", self.info)

    def on_finish(self, end: RunEnd) -> None:
        s = self._start
        depth_acc = summarize_depth_accuracy(end.depth_accuracy_series) if s.has_depth else None
        self.info = self._info(end.status) | {
            "depth_accuracy": depth_acc, "metric_scale": end.metric, "frames": end.frames,
            "events": end.events[:1000]}
        if end.error:
            self.info["error"] = end.error
        if end.vignette is not None:
            self.info["vignette_during_run"] = end.vignette
        self.timing = end.timing
        self._write_json("timing.json", end.timing)
        self._write_json("run.json", self.info)
        if end.depth_accuracy_series and self.out is not None:
            self._write_json("depth_accuracy.json", end.depth_accuracy_series)
            plot_depth_error(end.depth_accuracy_series, self.out / "depth_error.png",
                             f"{s.name}: depth error over time")

    def _info(self, status: str) -> dict:
        s = self._start
        return {
            "profile": s.profile, "config": s.config.to_dict(), "versions": versions(),
            "sequence": {"name": s.name, "path": s.path, "frames_total": s.frames_total,
                         "start_frame": s.start_frame, "max_frames": s.max_frames},
            "status": status, "depth_accuracy": None, "mode": s.config.system.mode,
            "depth_source": s.depth_source, "pose_source": s.pose_source, "resolution": _resolution(s),
            "machine": {"machine": platform.machine(), "cpu": cpu_model(), "cores": os.cpu_count()},
        }

    def _write_json(self, name: str, data) -> None:
        if self.out is None:
            return
        write_file_atomic(self.out / name, json.dumps(data, indent=2, default=_json_default) + "\n")


def _resolution(s: SessionInfo) -> dict:
    """Mapping and tracking image sizes of a run (the tracking level after the wide-image rule)."""
    cam, res = s.map_camera, s.config.resolution
    level = tracking_level(res, cam.width, cam.height)
    return {"map": [cam.width, cam.height], "track_level": level,
            "track": [cam.level(level).width, cam.level(level).height]}


class MapSink(OutputSink):
    """``map.ply``: the whole-scene point cloud of the VO's keyframes (world frame, coloured from the
    images, outliers removed; ``cloud_params`` override the defaults of
    :func:`lite_vo.keyframes.scene_cloud`, e.g. ``voxel``) with each point's idepth variance. Without a
    keyframe store (a session that has none) the last published map is written."""

    def __init__(self, path, **cloud_params) -> None:
        self.path = Path(path)
        self.params = dict(cloud_params)
        self.last: PublishedMap | None = None
        self.store = None
        self.points = 0

    def on_start(self, info: SessionInfo) -> None:
        self.store = info.keyframes

    def on_map(self, published: PublishedMap) -> None:
        self.last = published

    def on_finish(self, end: RunEnd) -> None:
        params = dict(self.params)
        voxel = params.pop("voxel", 0.0)
        if self.store is not None and len(self.store) and not voxel > 0:
            # streamed one keyframe at a time: the whole cloud (27 bytes a point, a million points on
            # ICL) is never in memory
            from .keyframes import scene_cloud_parts
            parts = ((c.points, c.idepth_var, c.colors) for c in scene_cloud_parts(self.store, **params))
            self.points = write_ply_parts(self.path, parts)
            return
        if self.store is not None and len(self.store):
            from .keyframes import scene_cloud
            cloud = scene_cloud(self.store, voxel=voxel, **params)
            pts, var, colors = cloud.points, cloud.idepth_var, cloud.colors
        elif self.last is not None:
            pts, var, (v, u) = self.last.points_world()
            colors = self.last.image[v, u]
        else:
            pts, var, colors = np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
        self.points = len(pts)
        write_ply(self.path, pts, idepth_var=var, colors=colors)


class TrajectoryExportSink(OutputSink):
    """At the end of a run: ``trajectory_kitti.txt`` (+ ``times.txt``) and/or ``trajectory.png``
    from the poses of a :class:`TrajectorySink`. A picture that cannot be drawn (too few poses, no
    matplotlib) is a warning, never a failed run."""

    def __init__(self, trajectory: TrajectorySink, kitti_path=None, plot_path=None, groundtruth=None) -> None:
        self.source = trajectory
        self.kitti_path = Path(kitti_path) if kitti_path else None
        self.plot_path = Path(plot_path) if plot_path else None
        self.groundtruth = groundtruth
        self._name = ""

    def on_start(self, info: SessionInfo) -> None:
        self._name = info.name

    def on_finish(self, end: RunEnd) -> None:
        from .errors import LiteVOError
        traj = self.source.trajectory()
        if self.kitti_path is not None:
            write_trajectory_kitti(self.kitti_path, traj)
        if self.plot_path is not None:
            from .plots import plot_trajectory
            try:
                plot_trajectory(self.groundtruth, traj, self.plot_path, name=self._name)
            except LiteVOError as err:
                log.warning("no trajectory picture: %s", err)


class ProgressSink(OutputSink):
    """Frames processed: a tqdm bar on a terminal, a plain line every few seconds when piped."""

    def __init__(self, stream=None, every_s: float = 5.0) -> None:
        self.stream, self.every_s = stream, every_s
        self._progress: Progress | None = None
        self._lost = 0

    def on_start(self, info: SessionInfo) -> None:
        self._progress = Progress(info.frames_total, info.name, stream=self.stream, every_s=self.every_s)

    def on_frame(self, event: FrameEvent) -> None:
        lost = bool(event.result.lost) and event.result.event != "waiting"   # waiting: skipped before the start
        self._lost += lost
        self._progress.update(1, note=f"{self._lost} lost" if lost or self._progress.done % 10 == 9 else None)

    def on_finish(self, end: RunEnd) -> None:
        if self._progress is not None:
            self._progress.close()


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, RowRecord):
        return o.to_list()
    raise TypeError(f"not JSON serialisable: {type(o)}")
