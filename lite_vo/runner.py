"""Run the system over a whole sequence and write the ``lite-vo run`` outputs (contract in
ARCHITECTURE.md): ``trajectory.txt``, ``timing.json``, ``run.json``, ``map.ply`` and, when the
sequence has depth images, ``depth_accuracy.json`` (+ ``depth_error.png`` if matplotlib exists).

Library layer of the ``run`` command: no argparse here; the CLI module parses and calls
:func:`run_sequence`. Imports no GL or physics package.
"""
from __future__ import annotations

import json
import logging
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .config import VOConfig
from .errors import InputError
from .system import VisualOdometry

log = logging.getLogger(__name__)

RUN_OUTPUTS = ("trajectory.txt", "timing.json", "run.json", "map.ply", "depth_accuracy.json", "depth_error.png")
CORE_KERNEL_MODULES = ("lite_vo.image", "lite_vo.tracking._kernels", "lite_vo.mapping._kernels")


@dataclass
class RunResult:
    """What a run produced (also written to disk)."""
    out_dir: Path | None
    status: str
    timestamps: list = field(default_factory=list)
    poses: list = field(default_factory=list)
    timing: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)


def versions() -> dict:
    import numba
    import cv2
    from . import __version__
    return {"lite_vo": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "numba": numba.__version__, "opencv": cv2.__version__, "platform": platform.platform(),
            "machine": platform.machine()}


class _Progress:
    """A one-line progress bar with frames per second, only on a terminal."""

    def __init__(self, total: int | None, enabled: bool) -> None:
        self.total, self.enabled = total, enabled and sys.stderr.isatty()
        self.t0 = time.perf_counter()
        self._last = 0.0

    def update(self, done: int, lost: int) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self._last < 0.1 and done != self.total:
            return
        self._last = now
        fps = done / max(now - self.t0, 1e-9)
        if self.total:
            n = int(30 * done / self.total)
            bar = f"[{'#' * n}{'.' * (30 - n)}] {done}/{self.total}"
        else:
            bar = f"{done} frames"
        sys.stderr.write(f"\r{bar}  {fps:5.1f} fps  lost {lost}   ")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


def _gt_lookup(seq, max_dt: float = 0.02):
    """``t -> T_world_cam`` of the ground-truth pose nearest ``t`` (None when none within max_dt)."""
    gt = seq.groundtruth
    if gt is None:
        raise InputError(f"{seq.name}: --poses gt needs ground truth, the sequence has none")

    def lookup(t: float):
        i = gt.nearest(t, max_dt)
        return None if i is None else gt.poses[i]
    return lookup


def summarize_depth_accuracy(series: list[dict], skip_s: float = 1.0) -> dict | None:
    """Contract ``depth_accuracy`` over the mapped frames after the first ``skip_s`` seconds."""
    rows = [r for r in series if r["t"] >= skip_s and np.isfinite(r.get("median_abs_rel_error", np.nan))]
    if not rows:
        rows = [r for r in series if np.isfinite(r.get("median_abs_rel_error", np.nan))]
    if not rows:
        return None
    return {
        "density": float(np.mean([r["density"] for r in rows])),
        "median_abs_rel_error": float(np.median([r["median_abs_rel_error"] for r in rows])),
        "within_5pct": float(np.mean([r["within_5pct"] for r in rows])),
        "within_10pct": float(np.mean([r["within_10pct"] for r in rows])),
        "frames": len(rows),
    }


def plot_depth_error(series: list[dict], path: Path, title: str) -> bool:
    """Depth error over time (thesis Fig. 5.8) as a PNG; False when matplotlib is missing."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    t = [r["t"] for r in series]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(t, [100 * r["median_abs_rel_error"] for r in series], label="median |rel. error| (%)")
    ax.plot(t, [100 * (1 - r["within_10pct"]) for r in series], label="outside 10% (%)")
    ax.plot(t, [100 * r["density"] for r in series], label="density (% of pixels)")
    ax.set_xlabel("time since start (s)")
    ax.set_ylim(bottom=0)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def _prefetch(seq, start_frame: int, max_frames: int | None, depth: int = 4):
    """Frames ``start_frame ..`` of ``seq`` decoded ahead in a reader thread (a camera driver's job).

    Order is unchanged, so sync runs stay deterministic; an exception in the reader is re-raised
    in the caller.
    """
    import itertools
    import queue
    import threading

    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    end = object()

    def reader():
        try:
            if start_frame > 0 and hasattr(seq, "frame"):  # random access: skip without decoding
                source = (seq.frame(i) for i in range(start_frame, len(seq)))
            else:
                source = itertools.islice(seq, start_frame, None)
            for n, fr in enumerate(source):
                if stop.is_set() or (max_frames is not None and n >= max_frames):
                    break
                q.put(fr)
            q.put(end)
        except BaseException as err:  # handed to the consumer
            q.put(err)

    t = threading.Thread(target=reader, name="lite_vo-reader", daemon=True)
    t.start()
    try:
        while True:
            item = q.get()
            if item is end:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        while t.is_alive():
            try:
                q.get_nowait()
            except queue.Empty:
                t.join(0.05)


def run_sequence(sequence, config: VOConfig, out_dir: Path | None = None, *, force: bool = False,
                 depth_source: str = "filter", pose_source: str = "estimate", max_frames: int | None = None,
                 start_frame: int = 0, quiet: bool = True, sinks=(), profile_name: str | None = None) -> RunResult:
    """Run :class:`VisualOdometry` over ``sequence`` (a path or an opened sequence).

    Writes the contract files into ``out_dir`` (when given). ``pose_source="gt"`` takes the
    poses from the ground truth (mapping only); ``depth_source="images"`` tracks against the
    depth images (tracking only).
    """
    from .io import Trajectory, open_sequence, prepare_output_dir, write_ply, write_trajectory

    seq = open_sequence(sequence) if isinstance(sequence, (str, Path, int)) else sequence
    if depth_source == "images" and not seq.has_depth:
        raise InputError(f"{seq.name}: --depth images needs depth images, the sequence has none")
    if config.system.init == "depth" and not seq.has_depth:
        raise InputError(f"{seq.name}: --init depth needs depth images, the sequence has none")
    gt_pose = _gt_lookup(seq) if pose_source == "gt" else None
    if start_frame < 0:
        raise InputError(f"--start-frame must be >= 0, got {start_frame}")
    try:
        total = len(seq) - start_frame
    except TypeError:
        total = None
    if total is not None and total <= 0:
        raise InputError(f"{seq.name}: --start-frame {start_frame} is past the last frame ({len(seq)} frames)")
    if max_frames is not None and total is not None:
        total = min(total, max_frames)
    if out_dir is not None:  # only once the input is known to be usable
        prepare_output_dir(Path(out_dir), force, clean=RUN_OUTPUTS)
    # load (or compile) the kernels before the clock starts, so the first frame's timing is honest
    from .warmup import warmup
    t_warm = time.perf_counter()
    warmup(CORE_KERNEL_MODULES)
    warmup_s = time.perf_counter() - t_warm
    vo = VisualOdometry(seq.camera, config, sinks=sinks, depth_source=depth_source,
                        pose_source="given" if pose_source == "gt" else "estimate")
    realtime = config.system.mode == "realtime"
    progress = _Progress(total, not quiet)
    tracked: dict[int, tuple[float, np.ndarray]] = {}  # frame index -> (timestamp, T_world_cam)
    events = []
    t_wall = time.perf_counter()
    t_first = None
    done = 0
    status = "ok"
    try:
        last_ts = None
        for fr in _prefetch(seq, start_frame, max_frames):
            done += 1
            if realtime:
                if t_first is None:
                    t_first = (fr.timestamp, time.perf_counter())
                speed = config.system.realtime_speed
                period = fr.timestamp - last_ts if last_ts is not None else 1.0 / 30.0
                last_ts = fr.timestamp
                due = (fr.timestamp - t_first[0]) / speed
                now = time.perf_counter() - t_first[1]
                if now < due:
                    time.sleep(due - now)
                elif now > due + period / speed:
                    # the next frame has already arrived: drop this one, as a live camera would
                    vo.note_dropped()
                    progress.update(done, vo.counts["lost"])
                    continue
            T_given = None
            if gt_pose is not None:
                T_given = gt_pose(fr.timestamp)
                if T_given is None:
                    vo.note_dropped()
                    continue
            res = vo.process(fr.image, fr.timestamp, depth=fr.depth, T_world_cam=T_given)
            if res.event:
                events.append({"frame": res.index, "t": res.timestamp, "event": res.event})
            for idx, T in res.corrections.items():  # earlier poses re-estimated (two-view bootstrap)
                if idx in tracked:
                    if T is None:
                        del tracked[idx]
                    else:
                        tracked[idx] = (tracked[idx][0], T)
            if not res.lost and res.T_world_cam is not None:
                tracked[res.index] = (res.timestamp, res.T_world_cam)
            progress.update(done, vo.counts["lost"])
    finally:
        progress.close()
        vo.close()
    wall_s = time.perf_counter() - t_wall
    stamps = [tracked[i][0] for i in sorted(tracked)]
    poses = [tracked[i][1] for i in sorted(tracked)]
    if vo.counts["tracked"] == 0:
        status = "failed: no frame tracked"
    elif events and events[-1]["event"] == "lost":
        status = "lost"
    elif vo.counts["lost"] > 0 or vo.counts["reinit"] > 0:
        status = "ok_with_losses"
    timing = vo.timing()
    timing["wall_s"] = wall_s
    timing["warmup_s"] = warmup_s
    series = vo.depth_accuracy_series
    depth_acc = summarize_depth_accuracy(series) if seq.has_depth else None
    info = {
        "profile": profile_name or config.name,
        "config": config.to_dict(),
        "versions": versions(),
        "sequence": {"name": seq.name, "path": str(getattr(seq, "path", sequence)), "frames_total": len(seq) if total is not None else None,
                     "start_frame": start_frame, "max_frames": max_frames},
        "status": status,
        "depth_accuracy": depth_acc,
        "mode": config.system.mode,
        "depth_source": depth_source,
        "pose_source": pose_source,
        "metric_scale": bool(vo.metric or pose_source == "gt"),
        "frames": {**{k: int(v) for k, v in vo.counts.items()}},
        "events": events[:1000],
    }
    result = RunResult(Path(out_dir) if out_dir is not None else None, status, stamps, poses, timing, info)
    if out_dir is not None:
        out = Path(out_dir)
        traj = Trajectory(np.asarray(stamps, dtype=np.float64),
                          np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4))
        write_trajectory(out / "trajectory.txt", traj)
        (out / "timing.json").write_text(json.dumps(timing, indent=2))
        (out / "run.json").write_text(json.dumps(info, indent=2, default=_json_default))
        pts, var = vo.map_points()
        write_ply(out / "map.ply", pts, idepth_var=var)
        if series:
            (out / "depth_accuracy.json").write_text(json.dumps(series, indent=1, default=_json_default))
            plot_depth_error(series, out / "depth_error.png", f"{seq.name}: depth error over time")
    return result


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")
