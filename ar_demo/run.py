"""``lite-vo ar`` as a library call: the frame driver (:mod:`lite_vo.session`) with the AR sink and
the trajectory writer, so the AR world and ``trajectory.txt`` see the same poses and corrections.

Outputs (contract): next to ``DIR/NAME.mp4`` go ``DIR/trajectory.txt`` (camera, ``T_world_cam``, TUM),
``DIR/car.txt`` (``T_world_car``, TUM, same world frame and units; origin at the centre of the car's
footprint on its surface, x forward, z up; one line per frame with a car) and ``DIR/ar_summary.json``
(ground source, car size, world extent, timings).

Imports: numpy, lite_vo; pybullet/moderngl/trimesh through :mod:`ar_demo.sink`.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

import lite_vo
from lite_vo.errors import InputError
from lite_vo.session import Session
from lite_vo.sinks import TrajectorySink
from lite_vo.viewer import RerunSink

from .config import ARConfig
from .sink import ARSink


def sequence_fps(seq, n: int | None = None) -> float:
    """Frame rate of a sequence from its timestamps (30 when it has none)."""
    ts = getattr(seq, "timestamps", None)
    if ts is None or len(ts) < 2:
        return 30.0
    ts = np.asarray(ts)[: max(2, n or len(ts))]
    return float(1.0 / np.median(np.diff(ts)))


def run_ar(sequence_path, out_video, profile: str = "phone", poses: str = "estimate",
           max_frames: int | None = None, cfg: ARConfig | None = None, panels: bool | None = None,
           overrides=(), trajectory_out: str | Path | None = None, mesh_out: str | Path | None = None,
           quiet: bool = True, vo_mode: str = "sync", sinks=(), calib=None, topic: str | None = None,
           car_out: str | Path | None = None, summary_out: str | Path | None = None) -> dict:
    """Run the AR demo on a sequence and write ``out_video`` (.mp4). Returns a summary dict.

    ``poses="estimate"``: the visual odometry with ``profile`` and VO ``overrides``; ``poses="gt"``:
    the ground-truth poses (the VO maps only). ``cfg``: AR settings (``ar_config(...)``).
    ``trajectory_out`` / ``car_out`` / ``summary_out``: the camera trajectory, the car poses and the
    summary (default: ``trajectory.txt``, ``car.txt``, ``ar_summary.json`` next to the video).
    """
    from lite_vo.sinks import ProgressSink
    cfg = cfg or ARConfig()
    if panels is not None:
        cfg = cfg.replace(panels=bool(panels))
    if poses not in ("estimate", "gt"):
        raise InputError(f"poses must be 'estimate' or 'gt', not {poses!r}")
    t_start = time.perf_counter()
    vo_cfg = lite_vo.load_profile(profile, list(overrides) + [f'system.mode="{vo_mode}"'])
    session = Session(sequence_path, vo_cfg, pose_source=poses, max_frames=max_frames, profile_name=profile,
                      calib=calib, topic=topic)
    fps = sequence_fps(session.sequence, max_frames)
    out_dir = Path(out_video).parent
    car_out = out_dir / "car.txt" if car_out is None else car_out
    trajectory_out = out_dir / "trajectory.txt" if trajectory_out is None else trajectory_out
    summary_out = out_dir / "ar_summary.json" if summary_out is None else Path(summary_out)
    viewer = next((k for k in sinks if isinstance(k, RerunSink)), None)
    ar = ARSink(cfg, out_video, fps=fps, metric=True if poses == "gt" else None, mesh_out=mesh_out, car_out=car_out,
                viewer=viewer)
    own = [ar, TrajectorySink(trajectory_out, comment="T_world_cam")]
    if not quiet:
        own.append(ProgressSink())
    session.sinks = own + list(sinks)
    res = session.run()
    summary = dict(ar.summary)
    summary.update({"sequence": str(sequence_path), "poses": poses, "profile": profile,
                    "status": res.status, "frames_in": res.end.frames_read, "frames_with_pose": len(res.poses),
                    "wall_s": time.perf_counter() - t_start,
                    "outputs": {"video": str(out_video), "trajectory": str(trajectory_out), "car": str(car_out),
                                "summary": str(summary_out)}})
    summary_out.parent.mkdir(parents=True, exist_ok=True)
    summary_out.write_text(json.dumps(summary, indent=2, default=float) + "\n")
    return summary


def write_summary(summary: dict, out_dir: Path, name: str = "summary") -> None:
    """``<name>.json`` and a human-readable ``<name>.txt``."""
    out_dir = Path(out_dir)
    (out_dir / f"{name}.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    t = summary.get("timing_ms", {})
    ground = summary.get("ground_plane") or {}
    lines = [f"AR demo on {summary.get('sequence')} (poses: {summary.get('poses')}, status: {summary.get('status')})",
             f"video: {summary.get('video')} ({summary.get('frames_written')} frames, {summary.get('video_size')})",
             f"frames with a pose: {summary.get('frames_with_pose')} of {summary.get('frames_in')}",
             f"ground plane: from {ground.get('source', 'nowhere (the world never started)')}",
             f"world models built: {summary.get('world_models_built')}, updates: {summary.get('world_updates')}",
             f"car: distance {summary.get('car_distance_phys', 0):.2f} m (physics units), "
             f"collisions {summary.get('car_collisions')}, reversals {summary.get('car_reversals')}"]
    for k in ("world_model", "simulation", "render", "frame"):
        if k in t:
            s = t[k]
            lines.append(f"{k:12s} median {s['median']:.1f} ms, mean {s['mean']:.1f} ms, p95 {s['p95']:.1f} ms (n={s['count']})")
    lines.append(f"wall time: {summary.get('wall_s', 0):.1f} s")
    (out_dir / f"{name}.txt").write_text("\n".join(lines) + "\n")
