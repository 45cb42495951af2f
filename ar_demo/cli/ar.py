"""``lite-vo ar``: argparse only; the work is :func:`ar_demo.run.run_ar` (needs the ``[ar]`` extra).

Registered through the ``lite_vo.commands`` entry point; imports pybullet, moderngl and trimesh
only when the command runs.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from lite_vo.cli.common import add_viewer_args, viewer_sinks

AR_EXTRA_MESSAGE = "the AR demo needs the [ar] extra: pip install 'lite-vo[ar]'"


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "ar", help="AR physics demo: a simulated car drives through the scene, rendered into a video",
        description="Run the visual odometry on SEQUENCE, build a collision mesh from the semi-dense depth map "
                    "(ground plane from the accelerometer, variational in-painting), simulate a racecar on it with "
                    "pybullet and render it into the camera images (off-screen OpenGL) as an .mp4 video. "
                    "Needs the [ar] extra.")
    p.add_argument("sequence", help="sequence folder (TUM/EuRoC/image folder) or video file with calib.txt")
    p.add_argument("--out", type=Path, required=True, help="output video (.mp4); never overwritten without --force")
    p.add_argument("--profile", default="phone", help="VO profile name or TOML file (default: phone)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a VO profile value (repeatable)")
    p.add_argument("--ar-set", dest="ar_overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override an AR setting, e.g. --ar-set grid_width=40 (repeatable; see ar_demo/config.py)")
    p.add_argument("--max-frames", type=int, default=None, help="process at most N frames")
    p.add_argument("--poses", choices=("estimate", "gt"), default="estimate",
                   help="estimate: the visual odometry; gt: ground-truth poses and depth (testing the AR part)")
    p.add_argument("--mode", choices=("sync", "realtime"), default="sync",
                   help="VO scheduling: sync (deterministic, default) or realtime (two threads, may drop frames)")
    p.add_argument("--panels", action="store_true",
                   help="add side panels: semi-dense depth map and collision mesh from another viewpoint")
    p.add_argument("--mesh", type=Path, default=None, help="also export the last collision mesh (.obj or .ply)")
    p.add_argument("--trajectory", type=Path, default=None,
                   help="camera trajectory (TUM format; default: trajectory.txt next to the video, with car.txt "
                        "and ar_summary.json)")
    p.add_argument("--calib", type=Path, default=None,
                   help="calibration file for the source (calib.txt, OpenCV YAML, Kalibr or ROS camera_info YAML)")
    p.add_argument("--topic", default=None, help="image topic of a ROS bag (needed when it has several)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    add_viewer_args(p)
    return p


def import_ar():
    """The :mod:`ar_demo.run` module, or a one-line error saying how to install the extra."""
    from lite_vo.errors import MissingExtraError
    try:
        import moderngl  # noqa: F401
        import trimesh  # noqa: F401

        from ..physics import import_pybullet
        import_pybullet()
    except ImportError as err:
        raise MissingExtraError(f"{AR_EXTRA_MESSAGE} ({err.name} is missing)") from err
    from .. import run as ar_run
    return ar_run


def run(args) -> int:
    from lite_vo.errors import InputError
    from lite_vo.io import check_output_file

    from ..config import ar_config
    ar_run = import_ar()

    out = Path(args.out)
    if out.suffix.lower() != ".mp4":
        raise InputError(f"{out}: the output video must end in .mp4")
    traj = args.trajectory if args.trajectory is not None else out.parent / "trajectory.txt"
    for path in (out, args.mesh, traj, out.parent / "car.txt", out.parent / "ar_summary.json"):
        if path is not None:
            check_output_file(path, args.force)
    if args.mesh is not None and Path(args.mesh).suffix.lower() not in (".obj", ".ply"):
        raise InputError(f"{args.mesh}: the mesh must be .obj or .ply")
    if args.max_frames is not None and args.max_frames <= 0:
        raise InputError(f"--max-frames must be positive, got {args.max_frames}")
    cfg = ar_config(args.ar_overrides)
    summary = ar_run.run_ar(args.sequence, out, profile=args.profile, poses=args.poses,
                            max_frames=args.max_frames, cfg=cfg, panels=args.panels or None,
                            overrides=args.overrides, trajectory_out=args.trajectory, mesh_out=args.mesh,
                            quiet=args.quiet, vo_mode=args.mode, calib=args.calib, topic=args.topic,
                            sinks=viewer_sinks(args))
    t = summary["timing_ms"]
    if not summary["frames_written"]:
        raise InputError(f"{args.sequence}: no frames were processed, no video written")
    print(f"{out}: {summary['frames_written']} frames {summary['video_size'][0]}x{summary['video_size'][1]}, "
          f"{summary['frames_with_pose']} with a pose; world model {t['world_model']['median']:.1f} ms, "
          f"simulation {t['simulation']['median']:.1f} ms, rendering {t['render']['median']:.1f} ms (medians); "
          f"car: {summary['car_collisions']} collisions, {summary['car_reversals']} reversals; "
          f"wrote {out.parent / 'car.txt'}, {traj}, {out.parent / 'ar_summary.json'}")
    return 0
