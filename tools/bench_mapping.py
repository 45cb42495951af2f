#!/usr/bin/env python
"""Benchmark one mapping iteration (propagate + observe + regularise + fill) at 320x240.

    python tools/bench_mapping.py                       # ICL living room, GT poses, 1 numba thread
    python tools/bench_mapping.py --threads 2 --out benchmarks/mapping_2threads
    python tools/bench_mapping.py --synth handheld

Runs the Mapper on a sequence with ground-truth poses (random initialisation, mapping every
frame), discards the first ``--skip`` iterations (compilation is done by ``warmup()`` before,
the skip covers the convergence of the random start), and reports per stage and in total the
median, mean, std and p95 of the wall-clock time (``MappingStats.stage_ms``) and of the CPU time
of the mapping thread (``stage_cpu_ms``; on a shared machine the CPU time is the better
estimate of the cost, the wall time includes waiting for a core). The whole sequence is run
``--repeat`` times; statistics pool all measured iterations. Writes ``OUT.md`` and ``OUT.json``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from lite_vo.timing import timing_stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

STAGES = ("propagate", "observe", "regularize", "fill")



ACCURACY_RUNS = (
    ("mapping_icl_random", "ICL living room 211, random init",
     "python tools/map_with_gt.py ../shared/data/icl_livingroom_211 --init random "
     "--json benchmarks/mapping_icl_random.json --plot benchmarks/mapping_icl_random_depth_error.png",
     "median <= 5%, >= 80% within 10%, density >= 10%"),
    ("mapping_icl_depth", "ICL living room 211, depth-image init",
     "python tools/map_with_gt.py ../shared/data/icl_livingroom_211 --init depth "
     "--json benchmarks/mapping_icl_depth.json --plot benchmarks/mapping_icl_depth_depth_error.png",
     "(reference: metric start)"),
    ("mapping_synth_handheld_random", "synthetic room, hand-held, random init",
     "python tools/map_with_gt.py --synth handheld --frames 150 --init random "
     "--json benchmarks/mapping_synth_handheld_random.json --plot benchmarks/mapping_synth_handheld_depth_error.png",
     "median <= 2%"),
)


def _accuracy_section(folder: Path) -> list[str]:
    """Depth accuracy of the tuning driver's runs (tools/map_with_gt.py), when their JSON exists."""
    rows = []
    for stem, title, cmd, target in ACCURACY_RUNS:
        f = folder / f"{stem}.json"
        if not f.exists():
            continue
        s = json.loads(f.read_text())["summary"]
        rows.append(f"| {title} | {100 * s['median_abs_rel_error']:.2f}% | {100 * s['within_5pct']:.1f}% | "
                    f"{100 * s['within_10pct']:.1f}% | {100 * s['density']:.1f}% | {s['frames_evaluated']} | "
                    f"{target} | `{cmd}` |")
    if not rows:
        return []
    return ["## Depth accuracy (GT poses, mapping only)", "",
            "Means over the mapped frames after the first second (sync schedule: every 4th frame during the "
            "first 3 s, then every frame; unmapped frames are stereo references). Plots: "
            "`benchmarks/<name>_depth_error.png` (depth error over time, like Figure 5.8).", "",
            "| run | median abs. rel. error | within 5% | within 10% | density | frames | target | command |",
            "|---|---|---|---|---|---|---|---|", *rows, "",
            "The ICL error floor is the same for a random and an exact (depth-image) start: it comes mostly "
            "from the pseudo ground-truth poses (the per-frame median signed error reaches +3% in the "
            "middle of the sequence in both runs), not from the filter; with the exact poses of the synthetic "
            "sequence the signed error stays between -0.5% and -0.1%.", ""]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence", nargs="?", default=str(ROOT.parent / "shared" / "data" / "icl_livingroom_211"))
    ap.add_argument("--synth", default=None, help="lite_vo.synth room scene with this trajectory instead")
    ap.add_argument("--frames", type=int, default=211)
    ap.add_argument("--skip", type=int, default=30, help="iterations not measured at the start")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--set", action="append", help="MappingConfig override key=value")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "mapping"))
    args = ap.parse_args(argv)

    import numba

    import map_with_gt as drv
    from lite_vo.mapping import MapFrame, Mapper, MappingConfig
    from lite_vo.mapping._kernels import warmup
    numba.set_num_threads(args.threads)
    overrides = {}
    for kv in args.set or []:
        k, v = kv.split("=", 1)
        overrides[k.strip()] = drv._parse_value(v.strip())
    cfg = dataclasses.replace(MappingConfig(), **overrides)
    if args.synth:
        K, frames, _ = drv._frames_synth(args.synth, args.frames, args.width, 0, 0.0)
        name = f"synth_{args.synth}"
    else:
        K, frames, _ = drv._frames_io(Path(args.sequence), args.width)
        name = Path(args.sequence).name
    frames = [f for _, f in zip(range(args.frames), frames) if f[4] is not None]
    warmup()
    wall = {s: [] for s in STAGES + ("total",)}
    cpu = {s: [] for s in STAGES + ("total",)}
    valid, updated = [], []
    load_before = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    t_run = time.perf_counter()
    for _ in range(args.repeat):
        m = Mapper(cfg, K, seed=0)
        m.measure_cpu = True
        idx, ts, img, _, T = frames[0]
        m.initialize_random(MapFrame(idx, ts, img, T))
        for k, (idx, ts, img, _, T) in enumerate(frames[1:]):
            st = m.update(MapFrame(idx, ts, img, T))
            if k < args.skip:
                continue
            for s in STAGES:
                wall[s].append(st.stage_ms[s])
                cpu[s].append(st.stage_cpu_ms[s])
            wall["total"].append(sum(st.stage_ms.values()))
            cpu["total"].append(sum(st.stage_cpu_ms.values()))
            valid.append(st.valid_count)
            updated.append(st.updated + st.created)
    run_s = time.perf_counter() - t_run
    load_after = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    result = {
        "sequence": name, "resolution": [K.width, K.height], "numba_threads": args.threads,
        "iterations": len(wall["total"]), "repeat": args.repeat, "skip": args.skip, "overrides": overrides,
        "wall_ms": {s: timing_stats(v) for s, v in wall.items()}, "cpu_ms": {s: timing_stats(v) for s, v in cpu.items()},
        "valid_median": float(np.median(valid)), "stereo_updates_median": float(np.median(updated)),
        "machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                    "loadavg_before": load_before, "loadavg_after": load_after, "python": platform.python_version(),
                    "numba": numba.__version__},
        "run_s": run_s, "date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    lines = [
        f"# Mapping iteration benchmark ({name}, {K.width}x{K.height}, {args.threads} numba thread(s))",
        "",
        f"Command: `python tools/bench_mapping.py {' '.join(argv if argv is not None else sys.argv[1:])}`  ",
        f"{result['date_utc']} UTC; {result['iterations']} measured iterations ({args.repeat} runs, first "
        f"{args.skip} of each skipped); GT poses, random initialisation, mapping every frame; "
        f"median {result['valid_median']:.0f} valid hypotheses, {result['stereo_updates_median']:.0f} "
        f"successful stereo observations per iteration.  ",
        f"Machine: {result['machine']['cores']} cores shared with other jobs (load average "
        f"{load_before:.1f} before, {load_after:.1f} after): the CPU time of the mapping thread is the "
        "reliable number, wall time includes waiting for a core.",
        "",
        "| stage | CPU median | CPU mean | CPU std | CPU p95 | wall median | wall mean | wall std | wall p95 |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for s in STAGES + ("total",):
        c, w = result["cpu_ms"][s], result["wall_ms"][s]
        lines.append(f"| {s} | {c['median']:.2f} | {c['mean']:.2f} | {c['std']:.2f} | {c['p95']:.2f} | "
                     f"{w['median']:.2f} | {w['mean']:.2f} | {w['std']:.2f} | {w['p95']:.2f} |")
    lines += ["", "Times in ms. Target: median iteration <= 25 ms on one core (the paper's phone: 52.6 +- 37.7 ms).", ""]
    lines += _accuracy_section(out.parent)
    out.with_suffix(".md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
