"""``lite-vo profile``: run profiles on sequences and write the accuracy/timing report
(parser + run; the work is in :mod:`lite_vo.profiling`)."""
from __future__ import annotations

import argparse

from ..profiling.profiles import PAPER_PROFILES  # standard library only: the parser stays free of numpy

_DESCRIPTION = """\
Run each profile on each sequence (one `lite-vo run --mode sync` process per run, several in
parallel), evaluate the trajectories against the ground truth and write report.md, report.json
and PNG plots into --out: the accuracy table (drift in cm/s and deg/s, like thesis Table 5.1),
the timing table (tracking and mapping ms, mean +- std, like Table 5.2), per-stage timings, the
cold vs warm start-up time and the machine the report was made on.
With --init-study N: instead of the sweep, N random-initialisation runs on sub-sequences
(different start frames and seeds), their success rate and errors over time (Fig. 5.8).
"""

_EPILOG = """\
examples:
  lite-vo profile ../shared/data/icl_livingroom_211 --profiles phone,desktop,m160_t80 --max-frames 100
  lite-vo profile SEQ --pin-core --workers 2          # emulate a low-power CPU: 1 core, 1 thread per run
  lite-vo profile SEQ --init-study 20 --init-study-len 4
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("profile", help="accuracy and timing of profiles on sequences (Tables 5.1, 5.2)",
                              description=_DESCRIPTION, epilog=_EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sequences", nargs="+", metavar="SEQUENCE", help="sequence folders or files (with ground truth)")
    p.add_argument("--profiles", default=",".join(PAPER_PROFILES),
                   help="comma-separated profile names or .toml paths (default: the paper's six: %(default)s)")
    p.add_argument("--repeat", type=int, default=1, metavar="N",
                   help="runs per sequence and profile (default 1); sync runs are deterministic, so repeats "
                        "only measure the spread of the timings")
    p.add_argument("--out", default="lite_vo_out/profile", metavar="DIR",
                   help="output folder (default: %(default)s); never overwritten without --force")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="runs in parallel (default: min(2, cores)); timings are cleaner with 1")
    p.add_argument("--pin-core", action="store_true",
                   help="pin each run to one core with one numba thread (low-power CPU emulation)")
    p.add_argument("--max-frames", type=int, default=None, metavar="N", help="only the first N frames of each sequence")
    p.add_argument("--init", choices=("auto", "depth", "random"), default=None,
                   help="map initialisation passed to lite-vo run (default: the profile's, i.e. auto: "
                        "the first depth image when the sequence has one, as in the paper's Table 5.1)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a value in every profile of the sweep, e.g. --set tracking.constant_velocity=true "
                        "(repeatable)")
    p.add_argument("--max-lost-ratio", type=float, default=0.0, metavar="R",
                   help="a run counts as failed when more than this share of its frames was lost (default 0)")
    p.add_argument("--init-study", type=int, default=0, metavar="N",
                   help="run the initialisation study with N sub-sequences instead of the sweep "
                        "(uses the first profile of --profiles if given explicitly, else phone)")
    p.add_argument("--init-study-len", type=float, default=4.0, metavar="SECONDS",
                   help="length of each initialisation sub-sequence (default 4 s; the criterion looks at 3 s)")
    p.add_argument("--no-warmup", action="store_true", help="do not run lite-vo warmup before the sweep")
    p.add_argument("--no-startup", action="store_true", help="skip the cold vs warm start-up measurement")
    p.add_argument("--no-plots", action="store_true", help="write no PNG plots (no matplotlib needed)")
    p.add_argument("--force", action="store_true", help="overwrite the report and runs in an existing --out folder")
    p.add_argument("--calib", default=None,
                   help="calibration file for the sequences (calib.txt, OpenCV/Kalibr/ROS YAML), passed to every run")
    p.add_argument("--quiet", action="store_true",
                   help="no progress lines on stderr (warm-up, each run, the start-up probe); warnings still show")
    return p


def run(args) -> int:
    import sys
    from pathlib import Path

    from ..errors import InputError
    from ..profiling import ProfileSettings, parse_profiles, run_profile

    if args.workers is not None and args.workers < 1:
        raise InputError("--workers must be at least 1")
    if args.init_study < 0:
        raise InputError("--init-study must be at least 0")
    if args.init_study_len <= 0:
        raise InputError("--init-study-len must be positive")
    if not 0.0 <= args.max_lost_ratio <= 1.0:
        raise InputError("--max-lost-ratio must be in [0, 1]")
    from ..config import load_profile
    for name in [p for p in args.profiles.split(",") if p.strip()]:
        load_profile(name.strip(), args.overrides)  # a bad --set fails here, not in every run
    profiles_text = args.profiles
    if args.init_study and profiles_text == ",".join(PAPER_PROFILES):
        profiles_text = "phone"  # the paper's initialisation study used the phone resolutions
    settings = ProfileSettings(
        sequences=list(args.sequences), profiles=parse_profiles(profiles_text), repeat=args.repeat,
        out=Path(args.out), workers=args.workers, pin_core=args.pin_core, max_frames=args.max_frames,
        init=args.init, force=args.force, init_study=args.init_study, init_study_len=args.init_study_len,
        max_lost_ratio=args.max_lost_ratio, warmup=not args.no_warmup, startup=not args.no_startup,
        plots=not args.no_plots, overrides=list(args.overrides),
        calib=str(args.calib) if args.calib is not None else None)

    def log(msg: str) -> None:
        if not args.quiet or msg.startswith("warning"):
            print(msg, file=sys.stderr, flush=True)

    command = "lite-vo profile " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["profile"] else None
    report = run_profile(settings, log=log, command=command)
    counts = report.get("counts")
    if counts is not None:
        summary = f"{counts['ok']} ok, {counts['fail']} failed, {counts['crash']} crashed"
    else:
        study = report.get("init_study") or {}
        summary = "; ".join(f"{s}: {v['successes']}/{v['runs']} initialisations succeeded" for s, v in study.items())
    print(f"report: {Path(args.out) / 'report.md'} ({summary})")
    return 0
