"""``lite-vo eval``: accuracy of an estimated trajectory against ground truth (ATE, RPE per second).

Parser (argparse only) and ``run``; the computation lives in :mod:`lite_vo.eval`.
"""
from __future__ import annotations

import argparse


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "eval", help="ATE and drift per second (RPE) of a trajectory against ground truth",
        description="Compare an estimated trajectory with ground truth (both TUM format, T_world_cam): "
                    "associate poses by timestamp, align (none / SE(3) / Sim(3), Umeyama), report the "
                    "absolute trajectory error (ATE RMSE, m) and the relative pose error over pairs "
                    "--delta-s seconds apart (RMSE, cm/s and deg/s, as the TUM RGB-D benchmark).")
    p.add_argument("--gt", required=True, metavar="GT",
                   help="ground truth: a TUM trajectory file, or a sequence folder that has ground truth")
    p.add_argument("--est", required=True, metavar="EST",
                   help="estimate: a TUM trajectory file, or a run folder containing trajectory.txt")
    p.add_argument("--align", choices=("none", "se3", "sim3"), default="sim3",
                   help="alignment of the estimate to the ground truth (default: sim3, for monocular scale)")
    p.add_argument("--delta-s", type=float, default=1.0, metavar="S",
                   help="time between the poses of an RPE pair in seconds (default: 1.0)")
    p.add_argument("--max-dt", type=float, default=0.02, metavar="S",
                   help="maximum timestamp difference when associating poses (default: 0.02)")
    p.add_argument("--json", metavar="FILE", help="also store the results as JSON in FILE")
    p.add_argument("--force", action="store_true", help="overwrite an existing --json file")
    return p


def _load_gt(spec: str):
    from pathlib import Path

    from ..errors import InputError
    from ..io import read_trajectory
    path = Path(spec)
    if path.is_dir():
        from ..io import open_sequence
        seq = open_sequence(path)
        if seq.groundtruth is None:
            raise InputError(f"{path}: sequence has no ground truth")
        return seq.groundtruth
    return read_trajectory(path)


def _load_est(spec: str):
    from pathlib import Path

    from ..errors import InputError
    from ..io import read_trajectory
    path = Path(spec)
    if path.is_dir():
        if not (path / "trajectory.txt").is_file():
            raise InputError(f"{path}: folder has no trajectory.txt")
        path = path / "trajectory.txt"
    return read_trajectory(path)


def run(args) -> int:
    import json
    from pathlib import Path

    from ..errors import InputError
    from ..eval import evaluate
    from ..io import check_output_file, write_file_atomic
    out = Path(args.json) if args.json else None
    if out is not None:
        check_output_file(out, args.force)
        if not out.parent.is_dir():
            raise InputError(f"{out.parent}: folder for --json does not exist")
    gt = _load_gt(args.gt)
    est = _load_est(args.est)
    res = evaluate(gt, est, align=args.align, delta_s=args.delta_s, max_dt=args.max_dt)
    print(res.table())
    if out is not None:
        d = res.to_dict()
        d["gt"] = str(args.gt)
        d["est"] = str(args.est)
        write_file_atomic(out, json.dumps(d, indent=2) + "\n")
    return 0
