#!/usr/bin/env python
"""Add what a phone camera adds to a TUM-layout sequence: auto-exposure, vignetting, motion blur,
noise and JPEG, seeded, so every number measured on the result is reproducible.

    python tools/augment.py SRC DST [--exposure] [--vignette [C]] [--blur] [--noise [SIGMA]] [--jpeg [Q]] [--seed S]

SRC: a folder with ``rgb.txt`` and the images it lists (TUM layout). Everything else (ground truth,
depth, calib.txt, accelerometer, ...) is copied unchanged; the images are written grey (8 bit) in
the order the camera would apply the effects:

* ``--vignette [C]``: radial fall-off ``1 - (1 - C) (r / r_corner)^2`` (C = 0.5 by default: 50 % at the corners); the true
  vignette is written to ``DST/true_vignette/vignette.png`` (16 bit, DSO's format), so
  ``lite-vo run DST --photometric DST/true_vignette`` corrects with it;
* ``--blur``: horizontal motion blur, a box of 3..7 px (uniform per frame);
* ``--exposure``: auto-exposure ``gain(t) * I + offset(t)`` with gain within 0.55..1.45 and offset
  within +-10 grey levels, each a sine of period 1.5..2 s (random phase);
* ``--noise [SIGMA]``: Gaussian noise of std SIGMA grey levels (default 3);
* ``--dark-start N``: a camera still opening: the first N frames' gain ramps up as ``(k / N)^2`` (frame 0
  black), on top of ``--exposure``;
* ``--cover A B``: frames A .. B-1 black (a hand over the lens);
* ``--step K G``: from frame K on, the gain is multiplied by G (auto-exposure jumping in one frame);
* ``--jpeg [Q]``: JPEG at quality Q (default 85; the images become .jpg, rgb.txt follows).

The parameters of every frame are written to ``DST/augment.json``. Errors are one line.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np


def exposure_curve(times: np.ndarray, rng: np.random.Generator, gain_range=(0.55, 1.45),
                   offset_amp: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """(gain, offset) per timestamp: sines of periods in [1.5, 2] s with random phases, the gain
    within ``gain_range``, the offset within +-``offset_amp``."""
    p_gain, p_off = rng.uniform(1.5, 2.0, 2)
    ph_gain, ph_off = rng.uniform(0, 2 * np.pi, 2)
    lo, hi = gain_range
    gain = 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.sin(2 * np.pi * times / p_gain + ph_gain)
    offset = offset_amp * np.sin(2 * np.pi * times / p_off + ph_off)
    return gain, offset


def vignette_map(h: int, w: int, corner: float = 0.5) -> np.ndarray:
    """1 at the centre, ``corner`` at the corners, quadratic in the radius."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    r2 = (xs - (w - 1) / 2) ** 2 + (ys - (h - 1) / 2) ** 2
    return 1.0 - (1.0 - corner) * r2 / r2.max()


def motion_blur(img: np.ndarray, length: int) -> np.ndarray:
    """Horizontal box blur of ``length`` px (the camera moving sideways during the exposure)."""
    import cv2
    k = np.ones((1, length), np.float64) / length
    return cv2.filter2D(img, cv2.CV_64F, k, borderType=cv2.BORDER_REFLECT)


def augment_image(img: np.ndarray, vignette: np.ndarray | None, blur_px: int, gain: float, offset: float,
                  noise_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """One grey frame through the camera model; returns uint8."""
    x = img.astype(np.float64)
    if vignette is not None:
        x = x * vignette
    if blur_px > 1:
        x = motion_blur(x, blur_px)
    x = gain * x + offset
    if noise_sigma > 0:
        x = x + rng.normal(0.0, noise_sigma, x.shape)
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def read_grey(path: Path) -> np.ndarray:
    """The 8-bit grey image lite_vo itself sees (its own reader: a JPEG's luma plane, other formats
    decoded and converted with ``COLOR_BGR2GRAY``; the VO reacts to differences of a grey level)."""
    from lite_vo.errors import InputError
    from lite_vo.io.sequences import _imread
    try:
        return _imread(Path(path), defer_colour=True)[0]
    except InputError as err:
        raise SystemExit(f"augment: {err}") from None


def _read_rgb_list(src: Path) -> list[tuple[str, float, str]]:
    f = src / "rgb.txt"
    if not f.exists():
        raise SystemExit(f"augment: {f}: not found (expected a TUM-layout sequence)")
    rows = []
    for n, line in enumerate(f.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split()
        try:
            rows.append((parts[0], float(parts[0]), parts[1]))
        except (IndexError, ValueError):
            raise SystemExit(f"augment: {f}:{n}: expected 'timestamp filename', got {line.strip()!r}") from None
    if not rows:
        raise SystemExit(f"augment: {f}: no images listed")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--exposure", action="store_true", help="auto-exposure (gain 0.55..1.45, offset +-10)")
    ap.add_argument("--gain-range", nargs=2, type=float, default=(0.55, 1.45), metavar=("LO", "HI"),
                    help="--exposure: range of the gain (default 0.55 1.45)")
    ap.add_argument("--offset", type=float, default=10.0, metavar="B",
                    help="--exposure: amplitude of the offset in grey levels (default 10)")
    ap.add_argument("--vignette", nargs="?", type=float, const=0.5, default=None, metavar="C",
                    help="vignetting: the corners at C times the centre's brightness (default 0.5)")
    ap.add_argument("--blur", action="store_true", help="horizontal motion blur of 3..7 px")
    ap.add_argument("--noise", nargs="?", type=float, const=3.0, default=0.0, metavar="SIGMA",
                    help="Gaussian noise std in grey levels (default 3)")
    ap.add_argument("--jpeg", nargs="?", type=int, const=85, default=0, metavar="Q", help="JPEG quality (default 85)")
    ap.add_argument("--dark-start", type=int, default=0, metavar="N",
                    help="the first N frames ramp up from black (gain (k/N)^2)")
    ap.add_argument("--cover", nargs=2, type=int, default=None, metavar=("A", "B"),
                    help="frames A .. B-1 black (a covered lens)")
    ap.add_argument("--step", nargs=2, type=float, default=None, metavar=("K", "G"),
                    help="from frame K on, multiply the gain by G (an exposure step)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--force", action="store_true", help="replace DST")
    args = ap.parse_args(argv)
    if args.vignette is not None and not 0.0 < args.vignette <= 1.0:
        ap.error(f"--vignette {args.vignette}: the corners' brightness must be in (0, 1]")

    import cv2

    src, dst = Path(args.src), Path(args.dst)
    rows = _read_rgb_list(src)
    if dst.exists():
        if not args.force:
            raise SystemExit(f"augment: {dst} exists (use --force to replace it)")
        shutil.rmtree(dst)
    if not 0 < args.gain_range[0] <= args.gain_range[1]:
        raise SystemExit(f"augment: --gain-range {args.gain_range[0]:g} {args.gain_range[1]:g}: need 0 < LO <= HI")
    if args.dark_start < 0:
        raise SystemExit(f"augment: --dark-start {args.dark_start}: need N >= 0")
    if args.cover is not None and not 0 <= args.cover[0] < args.cover[1]:
        raise SystemExit(f"augment: --cover {args.cover[0]} {args.cover[1]}: need 0 <= A < B")
    if args.step is not None and not (args.step[0] >= 0 and args.step[0] == int(args.step[0]) and args.step[1] > 0):
        raise SystemExit(f"augment: --step {args.step[0]:g} {args.step[1]:g}: need a frame K >= 0 and a gain G > 0")
    if args.jpeg and not 1 <= args.jpeg <= 100:
        raise SystemExit(f"augment: --jpeg {args.jpeg}: quality must be in 1..100")
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("rgb", "rgb.txt"))
    rng = np.random.default_rng(args.seed)
    times = np.array([t for _, t, _ in rows]) - rows[0][1]
    gain, offset = exposure_curve(times, rng, tuple(args.gain_range), args.offset) if args.exposure else (np.ones(len(rows)), np.zeros(len(rows)))
    blur = rng.integers(3, 8, len(rows)) if args.blur else np.ones(len(rows), np.int64)
    if args.cover is not None:
        gain[args.cover[0]:args.cover[1]] = 0.0
        offset[args.cover[0]:args.cover[1]] = 0.0
    if args.step is not None:
        gain[int(args.step[0]):] = gain[int(args.step[0]):] * args.step[1]
    n_dark = min(args.dark_start, len(rows))
    gain[:n_dark] = gain[:n_dark] * (np.arange(n_dark) / max(args.dark_start, 1)) ** 2
    vig = None
    params = []
    out_lines = ["# timestamp filename (augmented: " + " ".join(a for a in sys.argv[1:] if a.startswith("--")) + ")"]
    for k, (ts_text, _, name) in enumerate(rows):
        img = read_grey(src / name)
        if args.vignette is not None and (vig is None or vig.shape != img.shape):
            vig = vignette_map(*img.shape, corner=args.vignette)
        out = augment_image(img, vig, int(blur[k]), float(gain[k]), float(offset[k]), args.noise, rng)
        rel = Path(name)
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        if args.jpeg:
            rel = rel.with_suffix(".jpg")
            ok = cv2.imwrite(str(dst / rel), out, [cv2.IMWRITE_JPEG_QUALITY, args.jpeg])
        else:
            rel = rel.with_suffix(".png")
            ok = cv2.imwrite(str(dst / rel), out)
        if not ok:
            raise SystemExit(f"augment: {dst / rel}: cannot write the image")
        out_lines.append(f"{ts_text} {rel.as_posix()}")
        params.append({"timestamp": float(ts_text), "gain": float(gain[k]), "offset": float(offset[k]),
                       "blur_px": int(blur[k])})
    if vig is not None:
        (dst / "true_vignette").mkdir()
        if not cv2.imwrite(str(dst / "true_vignette" / "vignette.png"), np.rint(vig * 65535).astype(np.uint16)):
            raise SystemExit(f"augment: {dst / 'true_vignette'}: cannot write vignette.png")
    (dst / "rgb.txt").write_text("\n".join(out_lines) + "\n")
    (dst / "augment.json").write_text(json.dumps({
        "source": str(src), "seed": args.seed, "exposure": args.exposure,
        "gain_range": list(args.gain_range), "offset_amplitude": args.offset, "vignette": args.vignette is not None,
        "vignette_corner": args.vignette,
        "blur": args.blur, "dark_start": args.dark_start, "cover": args.cover, "step": args.step, "noise_sigma": args.noise, "jpeg_quality": args.jpeg, "frames": params}, indent=1))
    print(f"augment: {len(rows)} frames -> {dst}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
