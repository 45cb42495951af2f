"""Fakes shared by the tests of lite_vo.profiling (tests/test_profiling_*.py).

A fake launcher writes the run-folder contract (trajectory.txt / timing.json / run.json) directly
instead of starting ``lite-vo run``; a fake evaluator gives numbers that follow the trajectories'
noise without the real ``lite_vo.eval``; sequences are rgb.txt / depth.txt / groundtruth.txt only.
Import as ``from profiling_fakes import ...`` (pytest puts ``tests/`` on sys.path).
"""
from __future__ import annotations

import json
import threading
import time
import zlib
from pathlib import Path

import numpy as np

from lite_vo.eval import associate
from lite_vo.geometry import exp_se3, tum_from_pose
from lite_vo.profiling.command import ProfileSettings
from lite_vo.profiling.profiles import profile_label
from lite_vo.profiling.sweep import RunOutcome, RunSpec
from lite_vo.timing import Timers

FPS = 30.0


def gt_poses(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A smooth hand-held-like trajectory: timestamps and T_world_cam (n, 4, 4)."""
    t = 100.0 + np.arange(n) / FPS
    s = t - t[0]
    xi = np.zeros((n, 6))
    xi[:, 0] = 0.3 * np.sin(0.8 * s)
    xi[:, 1] = 0.1 * np.sin(1.3 * s + 0.5)
    xi[:, 2] = 0.05 * s
    xi[:, 3] = 0.1 * np.sin(0.7 * s)
    xi[:, 4] = 0.2 * np.sin(0.5 * s + 1.0)
    return t, exp_se3(xi)


def write_tum(path: Path, t: np.ndarray, poses: np.ndarray) -> None:
    rows = np.concatenate([t[:, None], tum_from_pose(poses)], axis=1)
    path.write_text("".join(" ".join(f"{v:.9f}" for v in r) + "\n" for r in rows))


def make_sequence(root: Path, name: str = "seqA", n: int = 150, depth: bool = True) -> Path:
    seq = root / name
    seq.mkdir(parents=True)
    t, poses = gt_poses(n)
    (seq / "rgb.txt").write_text("# timestamp filename\n" + "".join(f"{x:.6f} rgb/{i:04d}.png\n" for i, x in enumerate(t)))
    if depth:
        (seq / "depth.txt").write_text("".join(f"{x:.6f} depth/{i:04d}.png\n" for i, x in enumerate(t)))
    write_tum(seq / "groundtruth.txt", t, poses)
    return seq


def stats(values) -> dict:
    """A ``timing.json`` entry of ``values``."""
    return Timers.summary(values)


class FakeLauncher:
    """Writes the run-folder contract; behaviour per profile label: ok, crash, missing, lost, status."""

    def __init__(self, behaviour: dict[str, str] | None = None, noise: dict[str, float] | None = None,
                 scale: float = 1.0, delay: float = 0.0):
        self.behaviour = behaviour or {}
        self.noise = noise or {}
        self.scale = scale
        self.delay = delay
        self.calls: list[tuple[RunSpec, int | None]] = []
        self.lock = threading.Lock()
        self.active_cores: set = set()
        self.core_clash = False

    def __call__(self, spec: RunSpec, core):
        with self.lock:
            self.calls.append((spec, core))
            if core is not None and core in self.active_cores:
                self.core_clash = True
            self.active_cores.add(core)
        try:
            if self.delay:
                time.sleep(self.delay)
            return self._run(spec, core)
        finally:
            with self.lock:
                self.active_cores.discard(core)

    def _run(self, spec: RunSpec, core):
        label = profile_label(spec.profile)
        mode = self.behaviour.get(label, "ok")
        if mode == "crash":
            return RunOutcome(1, "ValueError: boom in mapping", 0.5, core)
        out = spec.out_dir
        out.mkdir(parents=True)
        t, poses = gt_poses(150)
        lo = spec.start_frame or 0
        hi = lo + (spec.max_frames or 150)
        t, poses = t[lo:hi], poses[lo:hi].copy()
        rng = np.random.default_rng(zlib.crc32(f"{label}/{spec.rep}".encode()))  # same in every process
        poses[:, :3, 3] += rng.normal(0.0, self.noise.get(label, 0.002), (len(t), 3)).cumsum(axis=0) * 0.1
        poses[:, :3, 3] /= self.scale
        write_tum(out / "trajectory.txt", t, poses)
        trk = {"phone": [4.0, 5.0, 6.0], "desktop": [20.0, 30.0, 25.0]}.get(label, [1.0, 2.0])
        timing = {"tracking": stats(trk), "mapping": stats([10.0 * x for x in trk]),
                  "stages": {"track_lvl1": stats(trk), "propagate": stats([1.0, 1.5])},
                  "frames": {"in": len(t), "tracked": len(t), "lost": 5 if mode == "lost" else 0, "dropped": 0},
                  "wall_s": 1.5}
        if mode != "missing":
            (out / "timing.json").write_text(json.dumps(timing))
        init = spec.init or "depth"
        series = [{"frame": i, "t": i / FPS, "median_abs_rel_error": 0.5 * np.exp(-i / 20.0) + 0.05,
                   "density": 0.3} for i in range(0, len(t), 5)]
        run = {"profile": label, "config": {"system": {"init": init}}, "versions": {}, "sequence": spec.seq_name,
               "status": "error" if mode == "status" else "ok",
               "depth_accuracy": {"density": 0.3, "median_abs_rel_error": series[-1]["median_abs_rel_error"],
                                  "within_5pct": 0.5, "within_10pct": 0.7, "frames": series}}
        (out / "run.json").write_text(json.dumps(run))
        return RunOutcome(0, "", 0.5, core)


class FakeResult:
    def __init__(self, d):
        self.d = d

    def to_dict(self):
        return dict(self.d)


class FakeEvaluator:
    """Mean position error (cm) and the alignment it was asked for; scale from the path lengths."""

    def __init__(self):
        self.aligns = []

    def __call__(self, gt, est, align="sim3", delta_s=1.0):
        self.aligns.append(align)
        ig, ie = associate(gt.timestamps, est.timestamps, 0.01)
        pg, pe = gt.poses[ig, :3, 3], est.poses[ie, :3, 3]
        scale = 1.0
        if align == "sim3":
            scale = float(np.linalg.norm(np.diff(pg, axis=0), axis=1).sum()
                          / np.linalg.norm(np.diff(pe, axis=0), axis=1).sum())
        err = float(np.linalg.norm(pg - scale * pe, axis=1).mean())
        return FakeResult({"rpe_trans_cm_per_s": 100 * err, "rpe_rot_deg_per_s": 0.1, "ate_rmse_m": err,
                           "scale": scale, "matched_poses": len(ig)})


def settings(tmp_path, seqs, **kw) -> ProfileSettings:
    base = dict(sequences=[str(s) for s in seqs], profiles=["phone", "desktop", "m160_t80"], repeat=1,
                out=tmp_path / "report", workers=2, warmup=False, startup=False)
    base.update(kw)
    return ProfileSettings(**base)

