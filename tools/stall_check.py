#!/usr/bin/env python3
"""A realtime run whose session thread stalls once: how a gap in the input is survived.

A sink blocks the caller's thread (which runs the sinks) for ``--stall`` seconds in ``on_frame`` once the
VO has processed frame ``--frame``; in realtime mode the frames arriving meanwhile are dropped, as after a
slow disk, a garbage-collection pause or sink work that should have been on a thread of its own. Each run
prints its ATE against the sequence's ground truth (Sim(3) for a monocular start), the frames the VO saw,
and how many were lost or relocalised:

    python tools/stall_check.py SEQ [--frame 22] [--stall 0.7] [--runs 1] [--init random] [--set KEY=VALUE ...]

The README's "Initialisation, loss and recovery" quotes it on ICL with every effect of ``tools/augment.py``.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import lite_vo  # noqa: E402
from lite_vo.eval import evaluate  # noqa: E402
from lite_vo.io import read_trajectory  # noqa: E402
from lite_vo.sinks import OutputSink, TrajectorySink  # noqa: E402


class StallSink(OutputSink):
    """Blocks the session thread once, for ``seconds``, after frame ``frame``; counts what the VO reported."""

    def __init__(self, frame: int, seconds: float) -> None:
        self.frame, self.seconds = frame, seconds
        self.stalled = False
        self.seen = self.lost = self.relocalised = 0

    def on_frame(self, event) -> None:
        r = event.result
        self.seen += 1
        self.lost += bool(r.lost)
        self.relocalised += r.event == "relocalised"
        if not self.stalled and r.index >= self.frame:
            self.stalled = True
            time.sleep(self.seconds)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequence")
    ap.add_argument("--frame", type=int, default=22, help="stall after the VO processed this frame (default 22)")
    ap.add_argument("--stall", type=float, default=0.7, help="seconds the session thread blocks (default 0.7)")
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--profile", default="phone")
    ap.add_argument("--init", default="random", choices=("random", "depth"))
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override (repeatable)")
    args = ap.parse_args(argv)
    seq = Path(args.sequence)
    gt = read_trajectory(seq / "groundtruth.txt", "ground truth file")
    overrides = ['system.mode="realtime"', f'system.init="{args.init}"'] + args.set
    for run in range(args.runs):
        cfg = lite_vo.load_profile(args.profile, overrides)
        sink = StallSink(args.frame, args.stall)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "trajectory.txt"
            lite_vo.Session(seq, cfg, sinks=[sink, TrajectorySink(path)]).run()
            est = read_trajectory(path, "trajectory")
        res = evaluate(gt, est, align="sim3" if args.init == "random" else "se3")
        print(f"run {run + 1}: ATE {res.ate_pct_of_path:.2f} % of the path, {sink.seen} frames seen "
              f"({args.stall:g} s stall after frame {args.frame}), {sink.lost} lost, {sink.relocalised} relocalised",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
