"""Re-image a pinhole TUM-layout sequence through an equidistant (fisheye) lens with cv2.fisheye.

For every pixel of the fisheye image ``cv2.fisheye.undistortPoints`` gives the ray, and so the
position in the pinhole source image; the source is resampled there (at twice the resolution,
then area-averaged, so the compressed periphery does not alias). Depth images are re-imaged with
nearest-neighbour sampling: the camera centre and axis do not change, so their z-depth stays valid.

The fisheye cannot see more than the pinhole source: its focal length is chosen as the smallest
(widest field of view) for which every fisheye pixel, corners included, still falls inside the
source image, so there is no black border. With ICL (640x480, f = 525) and the default lens the
result is a 640x480 equidistant image whose periphery is compressed as a real fisheye's.

The output folder has the TUM layout: ``rgb/`` + ``rgb.txt``, ``depth/`` + ``depth.txt`` when the
source has them, ``groundtruth.txt`` and ``accelerometer.txt`` copied, and a ``calib.txt`` with
``model equidistant``. Deterministic (nothing random).

    python tools/make_fisheye.py ../shared/data/icl_livingroom_211 /tmp/icl_fisheye
"""
from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from lite_vo.camera import Camera
from lite_vo.io import open_sequence, read_calibration, write_calib_txt

#: Kannala-Brandt coefficients of a real wide-angle lens (the order of magnitude of T265/Kalibr results)
DEFAULT_K = (-0.0139, 0.0451, -0.0412, 0.0077)


def _source_coords(fish: Camera, src_K: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Source (pinhole) pixel coordinates of every pixel centre of a fisheye image of this size."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pts = np.stack([u, v], -1).reshape(-1, 1, 2)
    out = cv2.fisheye.undistortPoints(pts, fish.intrinsics.K, np.array(fish.params), P=src_K)
    out = out.reshape(height, width, 2)
    return out[..., 0], out[..., 1]


def _border(width: int, height: int, n: int = 200) -> np.ndarray:
    us, vs = np.linspace(-0.5, width - 0.5, n), np.linspace(-0.5, height - 0.5, n)
    return np.concatenate([np.stack([us, np.full(n, -0.5)], -1), np.stack([us, np.full(n, height - 0.5)], -1),
                           np.stack([np.full(n, -0.5), vs], -1), np.stack([np.full(n, width - 0.5), vs], -1)])


def widest_fisheye(src: Camera, width: int, height: int, k: tuple, margin: float = 1.0) -> Camera:
    """The equidistant camera of ``width`` x ``height`` with coefficients ``k`` and the smallest
    focal length (widest view) whose whole image lies inside the pinhole ``src`` (``margin`` px)."""
    si = src.intrinsics
    border = _border(width, height).reshape(-1, 1, 2)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0

    def inside(f: float) -> bool:
        fish = Camera.equidistant(f, f, cx, cy, width, height, *k)
        p = cv2.fisheye.undistortPoints(border, fish.intrinsics.K, np.array(k), P=si.K).reshape(-1, 2)
        return bool(np.all(np.isfinite(p)) and p[:, 0].min() >= margin - 0.5 and p[:, 1].min() >= margin - 0.5
                    and p[:, 0].max() <= si.width - 0.5 - margin and p[:, 1].max() <= si.height - 0.5 - margin)

    lo, hi = 1.0, 100.0 * max(si.fx, si.fy)
    if not inside(hi):
        raise SystemExit(f"a {width}x{height} fisheye does not fit into the {si.width}x{si.height} source")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if inside(mid) else (mid, hi)
    return Camera.equidistant(hi, hi, cx, cy, width, height, *k)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", type=Path, help="pinhole TUM-layout folder (rgb.txt, calib.txt without distortion)")
    ap.add_argument("out", type=Path, help="output folder (must not exist, or use --force)")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--k", default=",".join(map(str, DEFAULT_K)), metavar="K1,K2,K3,K4",
                    help="equidistant coefficients (default: %(default)s)")
    ap.add_argument("--margin", type=float, default=1.0, help="pixels kept away from the source border")
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)

    k = tuple(float(x) for x in args.k.split(","))
    if len(k) != 4:
        raise SystemExit("--k needs four numbers")
    src_dir = args.source
    cal = read_calibration(src_dir / "calib.txt")
    src = cal.camera
    if src.model != "none":
        raise SystemExit(f"{src_dir}: the source must be an undistorted pinhole camera, got {src.describe()}")
    if args.out.exists():
        if not args.force:
            raise SystemExit(f"{args.out}: exists (use --force)")
        shutil.rmtree(args.out)

    fish = widest_fisheye(src, args.width, args.height, k, args.margin)
    fi = fish.intrinsics
    # 2x supersampled fisheye (pixel-area convention), area-averaged back down
    ss = 2
    fish2 = Camera.equidistant(fi.fx * ss, fi.fy * ss, (fi.cx + 0.5) * ss - 0.5, (fi.cy + 0.5) * ss - 0.5,
                               fi.width * ss, fi.height * ss, *k)
    mx2, my2 = _source_coords(fish2, src.intrinsics.K, fi.width * ss, fi.height * ss)
    m1, m2 = cv2.convertMaps(mx2.astype(np.float32), my2.astype(np.float32), cv2.CV_16SC2)
    dx, dy = _source_coords(fish, src.intrinsics.K, fi.width, fi.height)
    d1, d2 = cv2.convertMaps(dx.astype(np.float32), dy.astype(np.float32), cv2.CV_16SC2)

    seq = open_sequence(src_dir)
    out = args.out
    (out / "rgb").mkdir(parents=True)
    half = np.degrees(np.array([fi.width / 2 / fi.fx, fi.height / 2 / fi.fy, np.hypot(fi.width, fi.height) / 2 / fi.fx]))
    print(f"fisheye {fish.describe()}: about {2 * half[0]:.0f} x {2 * half[1]:.0f} degrees "
          f"(source pinhole {src.describe()})", file=sys.stderr)
    rgb_lines, depth_lines = ["# timestamp filename (re-imaged through an equidistant lens)"], []
    t_last = time.monotonic()
    for i, (t, path) in enumerate(zip(seq.timestamps, seq.image_paths)):
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise SystemExit(f"{path}: cannot read image")
        big = cv2.remap(img, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        small = cv2.resize(big, (fi.width, fi.height), interpolation=cv2.INTER_AREA)
        rel = path.relative_to(src_dir)
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out / rel), small, [cv2.IMWRITE_JPEG_QUALITY, 95])
        rgb_lines.append(f"{t:.6f} {rel.as_posix()}")
        if seq.depth_paths is not None and seq.depth_paths[i] is not None:
            dp = seq.depth_paths[i]
            d = cv2.imread(str(dp), cv2.IMREAD_UNCHANGED)
            drel = dp.relative_to(src_dir)
            (out / drel).parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(out / drel), cv2.remap(d, d1, d2, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE))
            depth_lines.append(f"{t:.6f} {drel.as_posix()}")
        if time.monotonic() - t_last > 2.0:
            print(f"re-imaging frame {i + 1}/{len(seq)}", file=sys.stderr)
            t_last = time.monotonic()
    (out / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    if depth_lines:
        (out / "depth.txt").write_text("# timestamp filename (z-depth, re-imaged)\n" + "\n".join(depth_lines) + "\n")
    for name in ("groundtruth.txt", "accelerometer.txt"):
        if (src_dir / name).is_file():
            shutil.copy2(src_dir / name, out / name)
    write_calib_txt(out / "calib.txt", fish, cal.depth_scale,
                    comment=f"{src_dir.name} re-imaged through an equidistant (fisheye) lens by tools/make_fisheye.py")
    print(f"wrote {len(seq)} frames to {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
