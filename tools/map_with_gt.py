#!/usr/bin/env python
"""Tuning driver for the mapping filter: run the Mapper alone on a sequence with ground-truth
poses (the ``--poses gt`` isolation mode of ``lite-vo run``) and measure its depth accuracy.

    python tools/map_with_gt.py ../shared/data/icl_livingroom_211 --init random \
        --plot benchmarks/mapping_icl_depth_error.png --json benchmarks/mapping_icl.json
    python tools/map_with_gt.py --synth handheld --frames 150 --init random
    python tools/map_with_gt.py SEQ --set ssd_max=1500 --set buffer_size=20

Schedule (the system's sync mode): map every ``--map-every-startup`` (4) frames during the first
``--startup-s`` (3) seconds, then every ``--map-every`` (1) frame. Frames in between are given
to the mapper as stereo references only (``Mapper.add_reference``) unless ``--no-references``.
Accuracy (``depth_accuracy``) is evaluated on every mapped frame; the summary averages over
the mapped frames after ``--skip-s`` (1) seconds. Writes a "depth error over time" plot (like
Figure 5.8 of the thesis) when ``--plot`` is given (matplotlib imported lazily).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _parse_value(text: str):
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def _frames_io(seq_dir: Path, map_width: int):
    """Through lite_vo.open_sequence + the camera's rectifier (the system's path)."""
    import lite_vo
    seq = lite_vo.open_sequence(seq_dir)
    rect = seq.camera.rectifier(map_width)
    gt = seq.groundtruth
    if gt is None:
        raise SystemExit(f"{seq_dir}: no ground truth poses")

    def frames():
        for fr in seq:
            k = int(np.argmin(np.abs(gt.timestamps - fr.timestamp)))
            T = gt.poses[k] if abs(gt.timestamps[k] - fr.timestamp) < 0.02 else None
            depth = rect.depth(fr.depth) if fr.depth is not None else None
            yield fr.index, fr.timestamp, rect(fr.image), depth, T
    return rect.intrinsics, frames(), len(seq)


def _frames_synth(trajectory: str, n_frames: int, map_width: int, seed: int, noise: float):
    """lite_vo.synth room scene rendered directly at the mapping resolution (exact depth and poses)."""
    from lite_vo.synth import default_intrinsics, iter_frames
    mh = map_width * 3 // 4
    K = default_intrinsics(map_width, mh)

    def frames():
        for fr in iter_frames(scene="room", trajectory=trajectory, n_frames=n_frames, seed=seed,
                              width=map_width, height=mh, noise_sigma=noise):
            yield fr.index, fr.timestamp, np.asarray(fr.image, np.float32), np.asarray(fr.depth, np.float32), \
                np.asarray(fr.T_world_cam, np.float64)
    return K, frames(), n_frames


def run(args) -> dict:
    import numba

    from lite_vo.mapping import MapFrame, Mapper, MappingConfig, depth_accuracy
    if args.threads:
        numba.set_num_threads(args.threads)
    overrides = {}
    for kv in args.set or []:
        k, v = kv.split("=", 1)
        overrides[k.strip()] = _parse_value(v.strip())
    cfg = dataclasses.replace(MappingConfig(), **overrides)
    if args.synth:
        K, frames, n = _frames_synth(args.synth, args.frames or 150, args.width, args.seed, args.noise)
        name = f"synth_{args.synth}"
    else:
        seq_dir = Path(args.sequence)
        K, frames, n = _frames_io(seq_dir, args.width)
        name = seq_dir.name
    mapper = Mapper(cfg, K, seed=args.seed)
    rows = []
    t_start = None
    count = 0
    for idx, ts, img, depth, T in frames:
        if args.frames and count >= args.frames:
            break
        count += 1
        if T is None:
            continue
        f = MapFrame(int(idx), float(ts), img, T)
        if t_start is None:
            t_start = ts
            if args.init == "depth":
                mapper.initialize_from_depth(f, depth)
            else:
                mapper.initialize_random(f)
            last_idx = idx
            continue
        every = args.map_every_startup if ts - t_start < args.startup_s else args.map_every
        if idx - last_idx < every:
            if not args.no_references:
                mapper.add_reference(f)
            continue
        last_idx = idx
        t0 = time.perf_counter()
        st = mapper.update(f)
        ms = 1e3 * (time.perf_counter() - t0)
        row = {"frame": int(idx), "t": float(ts - t_start), "ms": ms, **{k + "_ms": v for k, v in st.stage_ms.items()},
               "valid": st.valid_count, "updated": st.updated, "created": st.created,
               "inconsistent": st.inconsistent, "failed": st.failed, "filled": st.filled,
               "stride": st.stride}
        if depth is not None:
            idp, var, val = mapper.current()
            row.update(depth_accuracy(idp, val, depth))
            m = val & (depth > 0) & (idp > 0)
            if m.any():   # signed error: a bias (scale) shows here, noise does not
                row["median_signed_rel_error"] = float(np.median((1.0 / idp[m] - depth[m]) / depth[m]))
        rows.append(row)
        if args.verbose:
            print(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
    after = [r for r in rows if r["t"] >= args.skip_s and "density" in r]
    summary = {"sequence": name, "init": args.init, "frames_mapped": len(rows), "frames_evaluated": len(after),
               "overrides": overrides}
    if after:
        for key in ("density", "median_abs_rel_error", "within_5pct", "within_10pct"):
            vals = np.array([r[key] for r in after], float)
            summary[key] = float(np.nanmean(vals))
            summary[key + "_median"] = float(np.nanmedian(vals))
        last = after[-1]
        summary["final"] = {k: last[k] for k in ("density", "median_abs_rel_error", "within_5pct", "within_10pct")}
    ms = np.array([r["ms"] for r in rows]) if rows else np.zeros(1)
    summary["iteration_ms_median"] = float(np.median(ms))
    summary["iteration_ms_mean"] = float(np.mean(ms))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"summary": summary, "frames": rows}, indent=1))
    if args.plot:
        _plot(rows, summary, args.plot)
    return summary


def _plot(rows, summary, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = [r for r in rows if "density" in r]
    if not rows:
        return
    t = np.array([r["t"] for r in rows])
    fig, ax = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    ax[0].plot(t, 100 * np.array([r["median_abs_rel_error"] for r in rows]), label="median |rel. error|")
    ax[0].plot(t, 100 * (1 - np.array([r["within_10pct"] for r in rows])), label="share with error > 10%")
    ax[0].set_ylabel("depth error (%)")
    ax[0].set_yscale("log")
    ax[0].grid(True, which="both", alpha=0.3)
    ax[0].legend()
    ax[0].set_title(f"{summary['sequence']}: {summary['init']} init, GT poses")
    ax[1].plot(t, 100 * np.array([r["density"] for r in rows]), color="C2")
    ax[1].set_ylabel("density (% of pixels)")
    ax[1].set_xlabel("time (s)")
    ax[1].grid(True, alpha=0.3)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence", nargs="?", default=str(ROOT.parent / "shared" / "data" / "icl_livingroom_211"))
    ap.add_argument("--synth", default=None, help="use lite_vo.synth (room scene) with this trajectory instead")
    ap.add_argument("--noise", type=float, default=0.0, help="synthetic image noise sigma (grey levels)")
    ap.add_argument("--init", choices=("random", "depth"), default="random")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--frames", type=int, default=0, help="stop after this many input frames (0 = all)")
    ap.add_argument("--map-every", type=int, default=1)
    ap.add_argument("--map-every-startup", type=int, default=4)
    ap.add_argument("--startup-s", type=float, default=3.0)
    ap.add_argument("--skip-s", type=float, default=1.0, help="evaluate mapped frames after this time")
    ap.add_argument("--no-references", action="store_true", help="do not add unmapped frames to the buffer")
    ap.add_argument("--set", action="append", help="MappingConfig override key=value")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=0, help="numba threads (0 = default)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--plot", default=None)
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    summary = run(args)
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
