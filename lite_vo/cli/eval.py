"""``lite-vo eval``: accuracy of an estimated trajectory against ground truth (ATE, RPE per second).

Parser (argparse only) and ``run``; the computation lives in :mod:`lite_vo.eval`.
"""
from __future__ import annotations

import argparse


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "eval", help="ATE and drift per second (RPE) of a trajectory against ground truth",
        description="Compare an estimated trajectory with ground truth (T_world_cam): associate poses by "
                    "timestamp, align (none / SE(3) / Sim(3), Umeyama), report the absolute trajectory error "
                    "(ATE RMSE, m) and the relative pose error over pairs --delta-s seconds apart (RMSE, cm/s "
                    "and deg/s, as the TUM RGB-D benchmark). Trajectory files may be TUM (timestamp tx ty tz "
                    "qx qy qz qw), KITTI (12 numbers per line; timestamps from a times.txt beside the file, "
                    "else those of the other trajectory by index) or EuRoC CSV ground truth (data.csv of "
                    "state_groundtruth_estimate0), recognised by their content.")
    p.add_argument("--gt", required=True, metavar="GT",
                   help="ground truth: a TUM, KITTI or EuRoC CSV trajectory file, or a sequence folder that has "
                        "ground truth")
    p.add_argument("--est", required=True, metavar="EST",
                   help="estimate: a TUM or KITTI trajectory file, or a run folder containing trajectory.txt")
    p.add_argument("--align", choices=("none", "se3", "sim3"), default="sim3",
                   help="alignment of the estimate to the ground truth (default: sim3, for monocular scale)")
    p.add_argument("--delta-s", type=float, default=1.0, metavar="S",
                   help="time between the poses of an RPE pair in seconds (default: 1.0)")
    p.add_argument("--max-dt", type=float, default=0.02, metavar="S",
                   help="maximum timestamp difference when associating poses (default: 0.02)")
    p.add_argument("--json", metavar="FILE", help="also store the results as JSON in FILE")
    p.add_argument("--plot", metavar="FILE.png",
                   help="also draw the aligned trajectory against the ground truth (top view) and the error of "
                        "each pose over time into FILE.png (needs matplotlib: the [plot] extra)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --json / --plot file")
    return p


def _load_gt(spec: str):
    """The ground truth: a sequence folder's Trajectory, or a PoseFile (TUM, KITTI, EuRoC CSV)."""
    from pathlib import Path

    from ..errors import InputError
    from ..io.trajectory import read_pose_file
    path = Path(spec)
    if path.is_dir():
        from ..io import open_sequence
        seq = open_sequence(path)
        if seq.groundtruth is None:
            raise InputError(f"{path}: sequence has no ground truth")
        return seq.groundtruth
    return read_pose_file(path, "ground truth file")


def _load_est(spec: str):
    from pathlib import Path

    from ..errors import InputError
    from ..io.trajectory import read_pose_file
    path = Path(spec)
    if path.is_dir():
        if not (path / "trajectory.txt").is_file():
            raise InputError(f"{path}: folder has no trajectory.txt")
        path = path / "trajectory.txt"
    return read_pose_file(path, "trajectory file")


def load_pair(gt_spec: str, est_spec: str):
    """(ground truth, estimate, notes): KITTI files without times.txt take the other trajectory's
    timestamps by index (frame / 10 Hz when neither has any); notes say where timestamps came from."""
    from ..io import Trajectory
    gt, est = _load_gt(gt_spec), _load_est(est_spec)
    notes: list[str] = []

    def own_times(x):
        if isinstance(x, Trajectory):
            return x
        return x.trajectory()[0] if x.timestamps is not None else None

    def resolve(x, other):
        if isinstance(x, Trajectory):
            return x
        tr, note = x.trajectory(own_times(other))
        if note:
            notes.append(note)
        return tr

    return resolve(gt, est), resolve(est, gt), notes


def _check_out(path, force: bool, what: str):
    from ..errors import InputError
    from ..io import check_output_file
    if path is None:
        return
    check_output_file(path, force)
    if not path.parent.is_dir():
        raise InputError(f"{path.parent}: folder for {what} does not exist")


def run(args) -> int:
    import json
    from pathlib import Path

    from ..eval import evaluate
    from ..io import write_file_atomic
    out = Path(args.json) if args.json else None
    plot = Path(args.plot) if args.plot else None
    _check_out(out, args.force, "--json")
    _check_out(plot, args.force, "--plot")
    if plot is not None:
        from ..plots import require_matplotlib
        require_matplotlib()
    gt, est, notes = load_pair(args.gt, args.est)
    res = evaluate(gt, est, align=args.align, delta_s=args.delta_s, max_dt=args.max_dt)
    for n in notes:
        print(f"note: {n}")
    print(res.table())
    if plot is not None:
        from ..plots import plot_trajectory
        plot_trajectory(gt, est, plot, result=res, name=Path(args.est).stem if Path(args.est).is_file()
                        else Path(args.est).name)
        print(f"plot: {plot}")
    if out is not None:
        d = res.to_dict()
        d["gt"] = str(args.gt)
        d["est"] = str(args.est)
        d["notes"] = notes
        write_file_atomic(out, json.dumps(d, indent=2) + "\n")
    return 0
