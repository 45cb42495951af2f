"""Benchmark of the synthetic-sequence generator (lite_vo.synth).

Measures (1) per-frame render time of ``render_frame`` at 640x480 over a trajectory (median,
mean, p95, wall and process CPU) for supersample 1/2/3, and (2) the end-to-end time of
``generate_sequence`` (300 frames, 640x480, room/handheld by default: render + PNG writing),
and writes ``benchmarks/synth.md`` + ``benchmarks/synth.json``. The machine may be shared:
the load average is recorded next to the numbers.

    /work/venv/bin/python tools/bench_synth.py [--frames 300] [--out benchmarks/synth]
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path


from lite_vo.timing import timing_stats



def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--scene", default="room")
    ap.add_argument("--trajectory", default="handheld")
    ap.add_argument("--out", default="benchmarks/synth")
    args = ap.parse_args()

    import numba

    from lite_vo.synth import (SynthConfig, default_intrinsics, generate_sequence, make_scene,
                               make_trajectory, render_frame)
    from lite_vo.synth._kernels import warmup

    warmup()
    t0 = time.perf_counter()
    scene = make_scene(args.scene, 0)
    scene_s = time.perf_counter() - t0
    K = default_intrinsics(640, 480)
    _, poses = make_trajectory(args.trajectory, 300, scene=args.scene)
    render_frame(scene, poses[0], K)
    per_ss = {}
    for ss in (1, 2, 3):
        cfg = SynthConfig(supersample=ss)
        wall, cpu = [], []
        for T in poses[::10]:
            w0, c0 = time.perf_counter(), time.process_time()
            render_frame(scene, T, K, config=cfg)
            wall.append(1000 * (time.perf_counter() - w0))
            cpu.append(1000 * (time.process_time() - c0))
        per_ss[ss] = {"wall_ms": timing_stats(wall), "cpu_ms": timing_stats(cpu)}
    tmp = Path(tempfile.mkdtemp(prefix="bench_synth_"))
    try:
        w0, c0 = time.perf_counter(), time.process_time()
        res = generate_sequence(tmp / "seq", args.scene, args.trajectory, n_frames=args.frames)
        gen_wall, gen_cpu = time.perf_counter() - w0, time.process_time() - c0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    report = {
        "scene": args.scene, "trajectory": args.trajectory, "frames": args.frames,
        "resolution": "640x480", "numba_threads": numba.get_num_threads(),
        "load_average_1min": os.getloadavg()[0], "scene_build_s": scene_s,
        "render_frame": {str(k): v for k, v in per_ss.items()},
        "generate_sequence": {"wall_s": gen_wall, "cpu_s": gen_cpu, "render_s": res.render_s},
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(report, indent=1) + "\n")
    lines = [
        "# lite_vo.synth generation speed", "",
        f"`tools/bench_synth.py`: {args.scene}/{args.trajectory}, 640x480, "
        f"{report['numba_threads']} numba threads, 1-min load average during the run "
        f"{report['load_average_1min']:.1f} (shared machine).", "",
        f"- `generate_sequence` ({args.frames} frames, render + PNG): "
        f"**{gen_wall:.1f} s wall**, {gen_cpu:.1f} s CPU of this process "
        f"(render {res.render_s:.1f} s wall)",
        f"- scene build (procedural textures): {scene_s:.2f} s", "",
        "| supersample (adaptive) | wall median ms | wall p95 ms | CPU median ms |",
        "|---|---|---|---|",
    ]
    for ss, v in per_ss.items():
        lines.append(f"| {ss} | {v['wall_ms']['median']:.1f} | {v['wall_ms']['p95']:.1f} | "
                     f"{v['cpu_ms']['median']:.1f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
