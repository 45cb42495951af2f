#!/usr/bin/env python
"""A long TUM sequence without copying data: a TUM folder played back and forth (ping-pong).

Frames ``0..N-1, N-2..1, 0..`` of SRC with strictly increasing timestamps at SRC's frame rate (its
median frame interval). The output folder holds only text files: ``rgb.txt`` (and ``depth.txt``)
list SRC's own image files again by absolute path, ``groundtruth.txt`` repeats SRC's poses with the
new timestamps, ``calib.txt`` is copied. Any reader of TUM folders (``lite-vo run``, ``lite-vo ar``,
``lite_vo.Session``) plays it as one long sequence.

    python tools/pingpong.py ../shared/data/icl_livingroom_211 /tmp/icl_pingpong --frames 10000
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np


def pingpong_indices(n: int, frames: int) -> np.ndarray:
    """Source frame of each of ``frames`` output frames: 0..n-1, n-2..1, 0.. (period 2n-2)."""
    if n < 1 or frames < 0:
        raise ValueError(f"need n >= 1 and frames >= 0, got n={n}, frames={frames}")
    if n == 1:
        return np.zeros(frames, dtype=np.int64)
    k = np.arange(frames, dtype=np.int64) % (2 * n - 2)
    return np.where(k < n, k, 2 * n - 2 - k)


def _read_list(path: Path) -> list[tuple[float, str]]:
    rows = []
    for line in path.read_text(encoding="utf-8").splitlines():
        s = line.strip()
        if s and not s.startswith("#"):
            t, name = s.split()[:2]
            rows.append((float(t), name))
    return rows


def write_pingpong(src, dst, frames: int) -> Path:
    """Write the ping-pong TUM folder ``dst`` of ``frames`` frames played from the TUM folder ``src``."""
    src, dst = Path(src).resolve(), Path(dst)
    rgb = _read_list(src / "rgb.txt")
    if len(rgb) < 2:
        raise SystemExit(f"{src}/rgb.txt: needs at least 2 frames")
    t_src = np.array([t for t, _ in rgb])
    dt = float(np.median(np.diff(t_src)))
    idx = pingpong_indices(len(rgb), frames)
    t_out = t_src[0] + dt * np.arange(frames)
    dst.mkdir(parents=True, exist_ok=True)
    note = f"# ping-pong playback of {src} ({len(rgb)} frames) as {frames} frames at {1 / dt:.3f} Hz\n"
    with open(dst / "rgb.txt", "w", encoding="utf-8") as f:
        f.write(note)
        f.writelines(f"{t:.6f} {src / rgb[i][1]}\n" for t, i in zip(t_out, idx))
    if (src / "depth.txt").is_file():
        # pair each rgb frame with SRC's depth image nearest in time (as the TUM reader would)
        depth = _read_list(src / "depth.txt")
        t_d = np.array([t for t, _ in depth])
        near = np.abs(t_d[None, :] - t_src[:, None]).argmin(axis=1)
        with open(dst / "depth.txt", "w", encoding="utf-8") as f:
            f.write(note)
            f.writelines(f"{t:.6f} {src / depth[near[i]][1]}\n" for t, i in zip(t_out, idx))
    if (src / "groundtruth.txt").is_file():
        gt = np.loadtxt(src / "groundtruth.txt", comments="#", ndmin=2)
        near = np.abs(gt[None, :, 0] - t_src[:, None]).argmin(axis=1)
        with open(dst / "groundtruth.txt", "w", encoding="utf-8") as f:
            f.write(note)
            for t, i in zip(t_out, idx):
                f.write(f"{t:.6f} " + " ".join(f"{v:.9g}" for v in gt[near[i], 1:8]) + "\n")
    if (src / "calib.txt").is_file():
        shutil.copyfile(src / "calib.txt", dst / "calib.txt")
    return dst


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("src", type=Path, help="TUM folder (rgb.txt [+ depth.txt, groundtruth.txt, calib.txt])")
    p.add_argument("dst", type=Path, help="output folder (text files only)")
    p.add_argument("--frames", type=int, default=10000)
    args = p.parse_args(argv)
    out = write_pingpong(args.src, args.dst, args.frames)
    print(f"{out}: {args.frames} frames")
    return 0


if __name__ == "__main__":
    sys.exit(main())
