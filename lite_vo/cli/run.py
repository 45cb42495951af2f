"""``lite-vo run``: argparse only; the work is :func:`lite_vo.runner.run_sequence`."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from .common import add_profile_args, add_viewer_args, config_from_args, viewer_sinks


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "run", help="run visual odometry on a sequence",
        description="Run the visual odometry on SEQUENCE (TUM RGB-D folder, EuRoC folder, image folder or "
                    "video with calib.txt, or a camera index) and write trajectory.txt, timing.json, run.json "
                    "and map.ply into the output folder.")
    p.add_argument("sequence", help="sequence folder, video file, or live camera index (e.g. 0)")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default ./lite_vo_out/<sequence name>); never overwritten without --force")
    add_profile_args(p)
    p.add_argument("--mode", choices=("sync", "realtime"), default=None,
                   help="sync: deterministic, mapping every k-th frame; realtime: two threads at the frames' timestamps")
    p.add_argument("--init", choices=("auto", "depth", "random"), default=None,
                   help="map initialisation (auto: depth image when the sequence has one)")
    p.add_argument("--depth", choices=("filter", "images"), default="filter",
                   help="images: track every frame against the previous depth image (RGB-D odometry, no mapping)")
    p.add_argument("--poses", choices=("estimate", "gt"), default="estimate",
                   help="gt: take the poses from the ground truth (mapping only)")
    p.add_argument("--max-frames", type=int, default=None, help="process at most N frames")
    p.add_argument("--start-frame", type=int, default=0, help="skip the first N frames")
    p.add_argument("--seed", type=int, default=None, help="seed of random initialisation (system.seed)")
    p.add_argument("--calib", type=Path, default=None,
                   help="calibration file for the source (calib.txt, OpenCV YAML, Kalibr or ROS camera_info YAML); "
                        "overrides the sequence's own")
    p.add_argument("--photometric", type=Path, default=None,
                   help="folder with a photometric calibration in DSO's format (pcalib.txt, vignette.png; exposure "
                        "times from times.txt); such files beside calib.txt are used without this option")
    p.add_argument("--estimate-vignette", action="store_true",
                   help="fit the camera's vignetting (darker corners) to this run's maps and write vignette.png + "
                        "vignette.json into the output folder; pass that folder as --photometric to later runs")
    p.add_argument("--topic", default=None, help="image topic of a ROS bag (needed when it has several)")
    p.add_argument("--format", choices=("tum", "kitti"), default="tum",
                   help="kitti: also write trajectory_kitti.txt (+ times.txt) for KITTI tables (trajectory.txt stays TUM)")
    p.add_argument("--plot", action="store_true",
                   help="also draw trajectory.png (against the ground truth when the sequence has one; needs matplotlib)")
    p.add_argument("--map-voxel", type=float, default=0.0, metavar="SIZE",
                   help="map.ply with one point per SIZE-sized voxel (world units: metres when the run is metric; "
                        "the mean position and colour); default 0: every point")
    add_viewer_args(p)
    p.add_argument("--max-bad-frames", type=int, default=10,
                   help="unreadable frames in a row that are skipped before the run stops with an error (default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--force", action="store_true", help="overwrite an existing output folder")
    return p


def run(args) -> int:
    from ..errors import InputError
    from ..io import open_sequence
    from ..runner import run_sequence

    overrides = []
    if args.mode:
        overrides.append(f'system.mode="{args.mode}"')
    if args.init:
        overrides.append(f'system.init="{args.init}"')
    if args.seed is not None:
        overrides.append(f"system.seed={args.seed}")
    config = config_from_args(args, extra=overrides)
    if args.max_frames is not None and args.max_frames <= 0:
        raise InputError(f"--max-frames must be positive, got {args.max_frames}")
    if not args.map_voxel >= 0:
        raise InputError(f"--map-voxel must be 0 (off) or a positive size, got {args.map_voxel}")
    sinks = viewer_sinks(args)
    source = int(args.sequence) if args.sequence.isdigit() else args.sequence
    seq = open_sequence(source, calib=args.calib, topic=args.topic)
    out = args.out or Path("lite_vo_out") / seq.name
    res = run_sequence(seq, config, out, force=args.force, depth_source=args.depth, pose_source=args.poses,
                       max_frames=args.max_frames, start_frame=args.start_frame, quiet=args.quiet,
                       profile_name=args.profile, max_bad_frames=args.max_bad_frames,
                       kitti=args.format == "kitti", plot=args.plot, photometric=args.photometric, sinks=sinks,
                       map_voxel=args.map_voxel, estimate_vignette=args.estimate_vignette)
    c = res.info["frames"]
    skipped = f", {c['skipped']} unreadable skipped" if c.get("skipped") else ""
    back = c.get("backfilled", 0)
    if c.get("waited"):
        skipped += f", {c['waited']} blown out or too dark to start on ({back} of them posed afterwards)"
    later = c.get("posed", c["tracked"]) - c["tracked"] - back
    later = f" ({later} of them posed later by the two-view start-up)" if later > 0 else ""
    msg = (f"{seq.name}: {res.status}; {c['tracked']} of {c['in']} frames tracked, {c['lost']} lost{later}, "
           f"{res.timing['frames']['dropped']} dropped{skipped}; tracking {res.timing['tracking']['median']:.1f} ms, "
           f"mapping {res.timing['mapping']['median']:.1f} ms (medians); output in {out}")
    acc = res.info.get("depth_accuracy")
    if acc:
        msg += (f"\n  depth: density {100 * acc['density']:.1f}%, median rel. error "
                f"{100 * acc['median_abs_rel_error']:.2f}%, within 10% {100 * acc['within_10pct']:.1f}%")
    vr = res.info.get("vignette_during_run")
    if vr is not None:
        msg += (f"\n  vignette during the run: {100 * vr['corner']:.1f} % in the corners, corrected from frame "
                f"{vr['from_frames'][0]} on ({vr['corrections']} correction(s); {vr['ended']})" if vr["corrections"]
                else f"\n  vignette during the run: no correction ({vr['ended']})")
    if args.estimate_vignette:
        vj = out / "vignette.json"
        v = json.loads(vj.read_text()) if vj.exists() else {"written": False, "reason": "the run ended before the fit"}
        if v.get("written", True):
            msg += (f"\n  vignette: {100 * v['corner']:.1f} % (+- {100 * v['corner_std']:.1f}) of the centre's brightness in "
                    f"the corners, from {v['pairs']} pairs of maps -> {out / 'vignette.png'} (use --photometric {out})")
        else:
            msg += f"\n  vignette: not written: {v['reason']}"
    print(msg)
    return 0 if not res.status.startswith("failed") else 3
