#!/usr/bin/env python
"""Tracking speed benchmark: time per frame of Tracker.track at a profile's tracking resolution.

Frame-to-frame on a real sequence with depth (default: ICL living room, phone profile: mapping
320x240, tracking level 1 = 160x120): the reference of each frame is the previous frame's depth
image restricted to pixels with gradient >= --min-grad (the mapper's selection rule), so the point
counts are those of a rich semi-dense map. One core (NUMBA_NUM_THREADS=1, set before numba loads).
Kernels are compiled (warm-up) and the whole sequence is tracked once untimed before measuring.

Writes ``benchmarks/tracking.md`` and ``benchmarks/tracking.json`` (median/mean/std/p95 per frame and
per pyramid level, iterations per level, points per level, reference build time).

    NUMBA_NUM_THREADS=1 python tools/bench_tracking.py [SEQ] [--profile phone] [--repeat 3]
"""
from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from lite_vo.timing import timing_stats  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SEQ = ROOT.parent / "shared" / "data" / "icl_livingroom_211"



def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("sequence", nargs="?", default=str(DEFAULT_SEQ))
    p.add_argument("--profile", default="phone")
    p.add_argument("--set", action="append", metavar="section.key=value")
    p.add_argument("--max-frames", type=int, default=0)
    p.add_argument("--repeat", type=int, default=3, help="timed passes over the sequence")
    p.add_argument("--out-dir", default=str(ROOT / "benchmarks"))
    args = p.parse_args(argv)

    import numba

    import lite_vo
    from lite_vo import image as image_mod
    from lite_vo.image import image_pyramid
    from lite_vo.tracking import Tracker, TrackingReference, _kernels, depth_image_idepth

    numba.set_num_threads(1)
    image_mod.warmup()
    _kernels.warmup()

    if not Path(args.sequence).exists():
        print(f"{args.sequence}: sequence not found", file=sys.stderr)
        return 1
    cfg = lite_vo.load_profile(args.profile, args.set or ())
    r = cfg.resolution
    seq = lite_vo.open_sequence(args.sequence)
    rect = seq.camera.rectifier(r.map_width)
    intr = rect.intrinsics
    tracker = Tracker(cfg.tracking, intr, r.pyramid_levels, r.track_level)

    frames = []
    for fr in seq:
        if args.max_frames and len(frames) >= args.max_frames:
            break
        img = rect(fr.image)
        depth = rect.depth(fr.depth)
        frames.append((img, depth))

    pyr_ms, build_ms = [], []
    pyrs, refs = [], []
    for k, (img, depth) in enumerate(frames):
        t0 = time.perf_counter()
        pyr = image_pyramid(img, r.pyramid_levels)
        pyr_ms.append((time.perf_counter() - t0) * 1e3)
        idepth, valid = depth_image_idepth(pyr[0], depth, cfg.tracking)
        t0 = time.perf_counter()
        ref = TrackingReference.build(pyr, idepth, np.full_like(idepth, 1e-4), valid, intr, k,
                                      smooth_sigma=cfg.tracking.smooth_sigma,
                                      min_level=r.track_level, point_stride=cfg.tracking.point_stride,
                                      coarse_point_stride=cfg.tracking.coarse_point_stride)
        build_ms.append((time.perf_counter() - t0) * 1e3)
        pyrs.append(pyr)
        refs.append(ref)

    def one_pass():
        out = []
        for k in range(1, len(frames)):
            t0 = time.perf_counter()
            res = tracker.track(refs[k - 1], pyrs[k], np.eye(4))
            out.append(((time.perf_counter() - t0) * 1e3, res))
        return out

    one_pass()                                    # warm-up pass (caches, branch predictors, allocations)
    total, per_level, iters = [], {}, {}
    lost = 0
    for _ in range(args.repeat):
        for ms, res in one_pass():
            total.append(ms)
            lost += int(res.lost)
            for lvl, v in res.level_ms.items():
                per_level.setdefault(lvl, []).append(v)
            for lvl, v in res.iterations.items():
                iters.setdefault(lvl, []).append(v)
    points = {lvl: timing_stats([ref.num_points(lvl) for ref in refs]) for lvl in sorted(per_level)}

    result = {
        "sequence": Path(args.sequence).name, "profile": args.profile,
        "map_resolution": [intr.width, intr.height], "track_level": r.track_level,
        "track_resolution": [intr.level(r.track_level).width, intr.level(r.track_level).height],
        "frames_tracked_per_pass": len(frames) - 1, "passes": args.repeat, "lost": lost,
        "numba_threads": numba.get_num_threads(), "cpu": platform.processor() or platform.machine(),
        "track_ms": timing_stats(total),
        "level_ms": {str(l): timing_stats(v) for l, v in sorted(per_level.items(), reverse=True)},
        "iterations": {str(l): timing_stats(v) for l, v in sorted(iters.items(), reverse=True)},
        "points": {str(l): v for l, v in sorted(points.items(), reverse=True)},
        "point_stride": cfg.tracking.point_stride, "coarse_point_stride": cfg.tracking.coarse_point_stride,
        "reference_build_ms": timing_stats(build_ms), "image_pyramid_ms": timing_stats(pyr_ms),
        "load_average": os.getloadavg()[0],
    }
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "tracking.json").write_text(json.dumps(result, indent=1))
    (out_dir / "tracking.md").write_text(render_md(result, " ".join(sys.argv[1:])))
    print(render_md(result, " ".join(sys.argv[1:])))
    return 0


def render_md(res: dict, cmdline: str) -> str:
    def row(name, s):
        return (f"| {name} | {s['median']:.3f} | {s['mean']:.3f} | {s['std']:.3f} | {s['p95']:.3f} | "
                f"{s['min']:.3f} | {s['max']:.3f} |")
    tw, th = res["track_resolution"]
    lines = [
        "# Tracking speed", "",
        f"`NUMBA_NUM_THREADS=1 python tools/bench_tracking.py {cmdline}`".replace(" `", "`"), "",
        f"Sequence `{res['sequence']}`, profile `{res['profile']}`: mapping {res['map_resolution'][0]}x"
        f"{res['map_resolution'][1]}, tracking level {res['track_level']} = {tw}x{th}; frame-to-frame "
        f"against the previous frame's depth image (pixels with gradient >= 5 away from depth edges; the "
        f"profile's `tracking.point_stride` {res['point_stride']} on the finest level, `coarse_point_stride` "
        f"{res['coarse_point_stride']} on the next), identity initial guess; "
        f"{res['frames_tracked_per_pass']} frames x {res['passes']} timed passes after a warm-up pass, one core "
        f"(numba threads: {res['numba_threads']}); machine load average at the end: {res['load_average']:.2f} "
        f"(shared 2-core machine: numbers are noisy, medians are the robust ones). Lost frames: {res['lost']}.", "",
        "| ms per frame | median | mean | std | p95 | min | max |", "|---|---|---|---|---|---|---|",
        row("**Tracker.track (total)**", res["track_ms"]),
    ]
    for lvl, s in res["level_ms"].items():
        it = res["iterations"][lvl]
        pts = res["points"][lvl]
        lines.append(row(f"level {lvl} ({pts['median']:.0f} points, {it['mean']:.1f} LM iterations)", s))
    lines += [row("TrackingReference.build (per map update)", res["reference_build_ms"]),
              row("image_pyramid of a 320x240 frame (system side)", res["image_pyramid_ms"]), ""]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
