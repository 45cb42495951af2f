"""``lite-vo demo``: the main job with no arguments and no network.

Generates a small synthetic room sequence (with boxes on the floor as obstacles) via
:mod:`lite_vo.synth`, runs the visual odometry and the AR demo on it and writes ``demo.mp4``,
``trajectory.txt`` and ``summary.json`` / ``summary.txt`` into a folder (default
``./lite_vo_demo``). Needs the ``[ar]`` extra. Registered through the ``lite_vo.commands``
entry point; never imports pybullet, moderngl or trimesh at module level.
"""
from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "demo", help="the whole pipeline on a generated synthetic room: AR video, trajectory, summary",
        description="Generate a synthetic room sequence, run the visual odometry and the AR physics demo on it, "
                    "and write demo.mp4, trajectory.txt and summary.json/summary.txt into the output folder. "
                    "No arguments and no network needed; needs the [ar] extra.")
    p.add_argument("--out", type=Path, default=Path("lite_vo_demo"),
                   help="output folder (default ./lite_vo_demo); an existing non-empty folder needs --force")
    p.add_argument("--force", action="store_true", help="write into an existing non-empty folder")
    p.add_argument("--frames", type=int, default=120, help="number of frames to generate (default 120, 4 s)")
    p.add_argument("--poses", choices=("estimate", "gt"), default="estimate",
                   help="estimate: the visual odometry (default); gt: ground-truth poses and depth")
    p.add_argument("--profile", default="phone", help="VO profile (default: phone)")
    p.add_argument("--no-panels", action="store_true", help="video without the depth and mesh side panels")
    p.add_argument("--keep-sequence", action="store_true", help="keep the generated sequence in OUT/sequence")
    p.add_argument("--seed", type=int, default=0, help="seed of the synthetic scene and trajectory")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    return p


def run(args) -> int:
    import sys
    import tempfile

    from lite_vo.errors import InputError
    from lite_vo.io import prepare_output_dir
    from lite_vo.synth import generate_sequence

    from ..config import ARConfig
    from .ar import import_ar

    ar_run = import_ar()
    if args.frames < 10:
        raise InputError(f"--frames must be at least 10, got {args.frames}")
    out = prepare_output_dir(Path(args.out), args.force)
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr, flush=True))
    if args.keep_sequence:
        seq_dir = out / "sequence"
        tmp = None
    else:
        tmp = tempfile.TemporaryDirectory(prefix="lite_vo_demo_")
        seq_dir = Path(tmp.name) / "room"
    try:
        say(f"generating a synthetic room sequence ({args.frames} frames) ...")
        generate_sequence(seq_dir, scene="room", trajectory="handheld", n_frames=args.frames, seed=args.seed,
                          force=True)
        say(f"running the visual odometry ({args.poses}) and the AR demo ...")
        summary = ar_run.run_ar(seq_dir, out / "demo.mp4", profile=args.profile, poses=args.poses,
                                cfg=ARConfig(panels=not args.no_panels), trajectory_out=out / "trajectory.txt",
                                mesh_out=out / "collision_mesh.ply", quiet=args.quiet)
        summary["sequence"] = "synthetic room (lite_vo.synth, scene=room, trajectory=handheld, "\
                              f"seed={args.seed}, {args.frames} frames)"
        ar_run.write_summary(summary, out)
    finally:
        if tmp is not None:
            tmp.cleanup()
    print((out / "summary.txt").read_text(), end="")
    print(f"wrote {out / 'demo.mp4'}, {out / 'trajectory.txt'}, {out / 'summary.json'}")
    return 0
