"""Issue-15 check: does the car live in the real room? Runs ``lite-vo ar`` on ICL (VO poses, no IMU),
measures the car against the depth images (:mod:`ar_demo.evaluate`) and writes
``benchmarks/ar_world.md`` (+ ``--json``) and a strip of stills (``benchmarks/ar_world_stills.png``).

Usage::

    python tools/bench_ar_world.py [--sequence ../shared/data/icl_livingroom_211] [--frames N] [--intervals 3,4,5,6,7]

The car's path is chaotic: a small change of the VO or of the world updates sends it elsewhere, so one
run passes or fails a target by luck. The benchmark therefore runs the same sequence with the world
rebuilt every K frames for each K of ``--intervals`` (default 3 to 7; 5 is the default setting) and
judges the targets on the median over those runs; every run's measures are in the table.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MEASURES = ("in_view", "on_surface_in_view", "hidden_in_view", "upright_20deg", "tilt_p90_deg")
TARGETS = {"in_view": 0.70, "on_surface_in_view": 0.90, "hidden_in_view": 0.05, "upright_20deg": 0.90}


def stills(video: Path, frames: list[int], out: Path) -> None:
    import cv2
    import numpy as np
    cap = cv2.VideoCapture(str(video))
    imgs, i = [], 0
    while True:
        ok, f = cap.read()
        if not ok:
            break
        if i in frames:
            imgs.append(cv2.resize(f, (f.shape[1] * 240 // f.shape[0], 240), interpolation=cv2.INTER_AREA))
        i += 1
    if imgs:
        cv2.imwrite(str(out), np.concatenate(imgs, axis=1))


def run_and_evaluate(sequence: Path, work: Path, frames: int | None, ar_set: list[str]) -> dict:
    """Run ``lite-vo ar`` (world built synchronously: deterministic) into ``work`` and evaluate it."""
    from ar_demo.evaluate import evaluate_ar_run
    cmd = [str(Path(sys.executable).with_name("lite-vo")), "ar", str(sequence), "--out", str(work / "ar.mp4"),
           "--force", "--quiet", "--ar-set", "async_world=false"] + (["--max-frames", str(frames)] if frames else [])
    for kv in ar_set:
        cmd += ["--ar-set", kv]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    wall = time.perf_counter() - t0
    r = evaluate_ar_run(sequence, work)
    r["wall_s"] = wall
    return r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sequence", type=Path, default=ROOT.parent / "shared" / "data" / "icl_livingroom_211")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--work", type=Path, default=ROOT / "bench_out" / "ar_world")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "ar_world.md")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--ar-set", action="append", default=[], metavar="KEY=VALUE",
                    help="extra AR settings (the world is always built synchronously: deterministic results)")
    ap.add_argument("--intervals", default="3,4,5,6,7",
                    help="world rebuild intervals K (frames) to run; the targets are judged on the median")
    args = ap.parse_args(argv)
    ks = sorted({int(k) for k in args.intervals.split(",")})
    runs, t0 = {}, time.perf_counter()
    for k in ks:
        runs[k] = run_and_evaluate(args.sequence, args.work.with_name(args.work.name + f"_k{k}"), args.frames,
                                   args.ar_set + [f"world_update_every={k}"])
        print(k, json.dumps({m: runs[k][m] for m in MEASURES}))
    wall = time.perf_counter() - t0
    med = {m: float(statistics.median(r[m] for r in runs.values())) for m in MEASURES}
    met = {m: (med[m] <= lim if m == "hidden_in_view" else med[m] >= lim) for m, lim in TARGETS.items()}
    if args.json:
        args.json.write_text(json.dumps({"median": med, "met": met, "runs": runs}, indent=2, default=str) + "\n")
    still_k = 5 if 5 in runs else ks[0]
    stills(args.work.with_name(args.work.name + f"_k{still_k}") / "ar.mp4", [40, 90, 140, 200],
           ROOT / "benchmarks" / "ar_world_stills.png")
    ok = lambda c: "met" if c else "MISSED"   # noqa: E731
    pct = lambda v: f"{100 * v:.1f} %"        # noqa: E731
    lines = [
        "# AR world on ICL: does the car live in the real room? (issue 15)", "",
        f"Command: `python tools/bench_ar_world.py{' --intervals ' + args.intervals if args.intervals != '3,4,5,6,7' else ''}` "
        f"(runs `lite-vo ar {args.sequence.name}{' --max-frames ' + str(args.frames) if args.frames else ''} "
        f"--ar-set world_update_every=K` for K = {', '.join(map(str, ks))}: VO poses, depth-initialised, metric, no IMU, "
        f"world built synchronously (`--ar-set async_world=false`: deterministic){''.join(' --ar-set ' + kv for kv in args.ar_set)}; "
        f"{wall:.0f} s). Measured with `ar_demo.evaluate` against the ICL depth images: the car's footprint centre "
        "(car.txt) taken into the camera of trajectory.txt (what the video shows), from its first spawn on.", "",
        "The car's path is chaotic: a small change (of the VO, or of the settings) sends it elsewhere, so a "
        "single run passes or fails a target by luck. The targets are judged on the **median over the rebuild "
        "intervals** (K = 5 is the default setting).", "",
        "| K | in view (>= 70 %) | on a real surface, in view (>= 90 %) | hidden / inside, in view (<= 5 %) | "
        "tilt <= 20 deg (>= 90 %) | tilt p90 | spawns |", "|---|---|---|---|---|---|---|",
    ]
    for k, q in runs.items():
        lines.append(f"| {k}{' (default)' if k == 5 else ''} | {pct(q['in_view'])} | {pct(q['on_surface_in_view'])} | "
                     f"{pct(q['hidden_in_view'])} | {pct(q['upright_20deg'])} | {q['tilt_p90_deg']:.1f} deg | "
                     f"{q['spawns']} ({q['spawn_reasons']}) |")
    lines += [f"| **median** | **{pct(med['in_view'])}** ({ok(met['in_view'])}) | **{pct(med['on_surface_in_view'])}** "
              f"({ok(met['on_surface_in_view'])}) | **{pct(med['hidden_in_view'])}** ({ok(met['hidden_in_view'])}) | "
              f"**{pct(med['upright_20deg'])}** ({ok(met['upright_20deg'])}) | {med['tilt_p90_deg']:.1f} deg | |", "",
              f"Car length {runs[still_k]['car_length']} m (a toy car); frames from the first spawn: "
              f"{runs[still_k]['frames_from_spawn']} (K = {still_k}).", "",
              "Before (issue 15): in view 60 %, on a surface 39 %, hidden 43 %. With the first persistent world "
              "(car on the global ground plane): in view 64.8 %, on a surface 80.3 %, hidden 17.3 %, upright 100 %.", "",
              f"![stills](ar_world_stills.png) (K = {still_k})"]
    args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
