#!/usr/bin/env python
"""Frame-to-frame direct RGB-D odometry: the tracking engineer's tuning driver.

Tracks every frame against the previous frame's depth image (as ``lite-vo run SEQ --depth images``
does), at a profile's mapping resolution / tracking level, writes a TUM trajectory and prints the
RPE (1 s) against the sequence's ground truth, plus tracking time statistics.

    python tools/rgbd_odometry.py ../shared/data/icl_livingroom_211 --profile phone --out /tmp/icl.txt
    python tools/rgbd_odometry.py SEQ --set tracking.huber=2.0 --min-grad 5 --idepth-var 1e-4

The reference map of a frame: :func:`lite_vo.tracking.depth_image_idepth` (valid depth, gradient >=
``tracking.depth_image_min_grad``, away from depth discontinuities), idepth = 1/depth,
``idepth_var = --idepth-var`` (+ ``--idepth-var-rel`` * idepth^2, a relative depth-noise model).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def resample_depth(rect, depth_m: np.ndarray, mode: str) -> np.ndarray:
    """Depth at the mapping resolution: ``rect`` = the rectifier's nearest-valid sample; ``average``
    (undistorted cameras whose native size is 2^k times the mapping size only) = the inverse-variance
    (here: plain) inverse-depth average over each block, i.e. the depth pyramid of lite_vo.image."""
    if mode == "rect":
        return rect.depth(depth_m)
    from lite_vo.image import idepth_pyramid
    h, w = depth_m.shape
    out_h, out_w = rect.intrinsics.height, rect.intrinsics.width
    k = int(round(np.log2(w / out_w)))
    if w != out_w << k or h != out_h << k:
        return rect.depth(depth_m)
    d = np.asarray(depth_m, np.float32)
    valid = (d > 0) & np.isfinite(d)
    idepth = np.where(valid, 1.0 / np.where(valid, d, 1.0), 0.0)
    ds, _, ms = idepth_pyramid(idepth, np.ones_like(idepth), valid, k + 1)
    return np.where(ms[k], 1.0 / np.where(ms[k], ds[k], 1.0), 0.0).astype(np.float32)


def rpe_excluding(gt, est, seams_s, delta_s=1.0) -> dict:
    """RPE over ``delta_s`` like lite_vo.eval (no alignment) but skipping pairs whose interval contains a
    ground-truth seam time (e.g. the pseudo ground truth's fragment boundaries in ICL, where the
    reference trajectory itself jumps)."""
    from lite_vo.geometry import inverse_se3
    ti = est.timestamps
    gi = np.array([int(np.argmin(np.abs(gt.timestamps - t))) for t in ti])
    tr, rot, mot = [], [], []
    for i in range(len(ti)):
        j = int(np.argmin(np.abs(ti - (ti[i] + delta_s))))
        dt = ti[j] - ti[i]
        if dt < delta_s / 2 or abs(dt - delta_s) > delta_s / 2:
            continue
        if any(ti[i] < s <= ti[j] for s in seams_s):
            continue
        G = inverse_se3(gt.poses[gi[i]]) @ gt.poses[gi[j]]
        E = inverse_se3(est.poses[i]) @ est.poses[j]
        D = inverse_se3(G) @ E
        tr.append(np.linalg.norm(D[:3, 3]) / dt)
        rot.append(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1))) / dt)
        mot.append(np.linalg.norm(G[:3, 3]) / dt)
    tr, rot, mot = map(np.asarray, (tr, rot, mot))
    rmse_t = float(np.sqrt(np.mean(tr ** 2)))
    return {"rpe_trans_cm_per_s": 100 * rmse_t, "rpe_rot_deg_per_s": float(np.sqrt(np.mean(rot ** 2))),
            "rpe_trans_pct": float(100 * rmse_t / mot.mean()), "rpe_pairs": int(len(tr)), "seams_s": list(seams_s)}


def run(args) -> dict:
    import lite_vo
    from lite_vo.eval import evaluate
    from lite_vo.image import image_pyramid
    from lite_vo.io import Trajectory, write_trajectory
    from lite_vo.tracking import Tracker, TrackingReference, depth_image_idepth

    overrides = list(args.set or ())
    if args.min_grad is not None:
        overrides.append(f"tracking.depth_image_min_grad={args.min_grad}")
    if args.max_depth_step is not None:
        overrides.append(f"tracking.depth_image_max_step={args.max_depth_step}")
    if args.edge_window is not None:
        overrides.append(f"tracking.depth_image_edge_window={args.edge_window}")
    cfg = lite_vo.load_profile(args.profile, overrides)
    res_cfg = cfg.resolution
    seq = lite_vo.open_sequence(args.sequence)
    rect = seq.camera.rectifier(res_cfg.map_width)
    intr = rect.intrinsics
    levels = res_cfg.pyramid_levels
    tracker = Tracker(cfg.tracking, intr, levels, res_cfg.track_level)

    frames = []
    for fr in seq:
        if args.max_frames and len(frames) >= args.max_frames:
            break
        if fr.depth is None:
            raise SystemExit(f"{args.sequence}: frame {fr.index} has no depth image")
        img = rect(fr.image)
        frames.append((fr.timestamp, image_pyramid(img, levels), resample_depth(rect, fr.depth, args.depth_resample)))

    gt = seq.groundtruth
    T_world = np.eye(4)
    if gt is not None and len(gt):
        T_world = gt.poses[int(np.argmin(np.abs(gt.timestamps - frames[0][0])))].copy()
    stamps, poses, times, lost, quality = [frames[0][0]], [T_world.copy()], [], 0, []
    ref = None
    T_vel = np.eye(4)
    for k, (ts, pyr, depth) in enumerate(frames):
        if ref is not None:
            guess = T_vel if args.constant_velocity else np.eye(4)
            t0 = time.perf_counter()
            res = tracker.track(ref, pyr, guess)
            times.append((time.perf_counter() - t0) * 1e3)
            quality.append(res.quality())
            if res.lost:
                lost += 1
                if not args.quiet:
                    print(f"frame {k}: lost ({res.lost_reason}, residual {res.residual:.2f}, "
                          f"good {res.good_ratio:.2f})", file=sys.stderr)
            T_vel = res.T_ref_new
            T_world = T_world @ res.T_ref_new
            stamps.append(ts)
            poses.append(T_world.copy())
        idepth, valid = depth_image_idepth(pyr[0], depth, cfg.tracking)
        var = (args.idepth_var + args.idepth_var_rel * idepth ** 2).astype(np.float32)
        ref = TrackingReference.build(pyr, idepth, var, valid, intr, k, smooth_sigma=cfg.tracking.smooth_sigma,
                                      min_level=res_cfg.track_level)

    est = Trajectory(np.array(stamps), np.array(poses))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        write_trajectory(args.out, est)
    t = np.array(times)
    out = {"frames": len(frames), "lost": lost,
           "track_ms": {"median": float(np.median(t)), "mean": float(t.mean()), "p95": float(np.percentile(t, 95))},
           "points_used_median": float(np.median([q["points_used"] for q in quality])),
           "residual_median": float(np.median([q["residual"] for q in quality])),
           "mean_abs_residual_median": float(np.median([q["mean_abs_residual"] for q in quality])),
           "mean_abs_residual_max": float(np.max([q["mean_abs_residual"] for q in quality])),
           "good_ratio_min": float(np.min([q["good_ratio"] for q in quality]))}
    if gt is not None:
        ev = evaluate(gt, est, align="none", delta_s=1.0)
        out["eval"] = {k: ev.to_dict()[k] for k in ("rpe_trans_cm_per_s", "rpe_rot_deg_per_s", "rpe_trans_pct",
                                                    "motion_cm_per_s", "rot_motion_deg_per_s", "ate_rmse_m",
                                                    "rpe_pairs")}
        if args.gt_seams:
            out["eval_without_gt_seams"] = rpe_excluding(gt, est, args.gt_seams)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("sequence")
    p.add_argument("--profile", default="phone")
    p.add_argument("--set", action="append", metavar="section.key=value", help="config override (repeatable)")
    p.add_argument("--out", help="TUM trajectory output file")
    p.add_argument("--max-frames", type=int, default=0)
    p.add_argument("--min-grad", type=float, default=None, help="reference pixel selection (0 = all with depth)")
    p.add_argument("--max-depth-step", type=float, default=None,
                   help="drop pixels whose neighbourhood depth range exceeds this fraction of their depth (0 = off)")
    p.add_argument("--edge-window", type=int, default=None, help="neighbourhood size of the depth-step test")
    p.add_argument("--idepth-var", type=float, default=1e-4, help="constant idepth variance of depth pixels")
    p.add_argument("--idepth-var-rel", type=float, default=0.0, help="extra idepth variance per idepth^2")
    p.add_argument("--constant-velocity", action="store_true", help="initial guess = last relative motion")
    p.add_argument("--depth-resample", choices=("rect", "average"), default="rect",
                   help="depth at mapping resolution: the rectifier's nearest-valid sample, or the block average")
    p.add_argument("--gt-seams", type=float, nargs="*", default=None,
                   help="also report RPE skipping 1-s pairs across these ground-truth times (s), e.g. ICL's pseudo-GT "
                        "fragment boundaries 3.3333 6.6667")
    p.add_argument("--json", help="write the summary here")
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    out = run(args)
    print(json.dumps(out, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
