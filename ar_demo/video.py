"""Video output of the AR demo: an OpenCV ``.mp4`` writer (``mp4v``) and the side panels.

Layout with panels: the AR view (W x H) on the left, a right column of width W/2 with the
semi-dense depth map colour-coded by inverse depth (Fig. 5.3; black where the map is empty) on top
and the collision mesh seen from another viewpoint (Fig. 5.1) below. Frames are RGB uint8 here and
converted to BGR for OpenCV.

Imports: numpy, cv2, lite_vo (errors).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from lite_vo.errors import InputError


class VideoWriter:
    """``.mp4`` (mp4v) writer with a fixed frame size; ``write(rgb)``, ``close()``."""

    def __init__(self, path: str | Path, fps: float, size_wh: tuple[int, int]):
        self.path = Path(path)
        if self.path.suffix.lower() != ".mp4":
            raise InputError(f"{self.path}: the AR video must be an .mp4 file")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.size = (int(size_wh[0]), int(size_wh[1]))
        self.fps = float(fps)
        self._w = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, self.size)
        if not self._w.isOpened():
            raise InputError(f"{self.path}: cannot open an mp4v video writer")
        self.frames = 0

    def write(self, rgb: np.ndarray) -> None:
        img = np.asarray(rgb)
        if img.shape[1::-1] != self.size:
            raise InputError(f"{self.path}: frame {img.shape[1]}x{img.shape[0]} does not match {self.size[0]}x{self.size[1]}")
        self._w.write(np.ascontiguousarray(img[..., ::-1]))
        self.frames += 1

    def close(self) -> None:
        if self._w is not None:
            self._w.release()
            self._w = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def colorize_idepth(idepth: np.ndarray, size_wh: tuple[int, int] | None = None,
                    lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """RGB uint8 image of an inverse-depth map: near red, far blue (jet), black where empty."""
    d = np.asarray(idepth, dtype=np.float64)
    ok = np.isfinite(d) & (d > 0)
    out = np.zeros(d.shape + (3,), np.uint8)
    if ok.any():
        lo = np.percentile(d[ok], 2) if lo is None else lo
        hi = np.percentile(d[ok], 98) if hi is None else hi
        t = np.clip((np.where(ok, d, lo) - lo) / max(hi - lo, 1e-12), 0, 1)
        jet = cv2.applyColorMap((t * 255).astype(np.uint8), cv2.COLORMAP_JET)[..., ::-1]
        out[ok] = jet[ok]
    if size_wh is not None and out.shape[1::-1] != tuple(size_wh):
        out = cv2.resize(out, tuple(size_wh), interpolation=cv2.INTER_NEAREST)
    return out


def label(img: np.ndarray, text: str) -> np.ndarray:
    out = np.ascontiguousarray(img)
    cv2.putText(out, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def compose_panels(main: np.ndarray, top: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """Main view plus a right column (top, bottom), each resized to half the main size."""
    H, W = main.shape[:2]
    pw, ph = W // 2, H // 2
    col = np.zeros((H, pw, 3), np.uint8)
    for k, p in enumerate((top, bottom)):
        if p is None:
            continue
        p = cv2.resize(p, (pw, ph), interpolation=cv2.INTER_AREA) if p.shape[1::-1] != (pw, ph) else p
        col[k * ph:(k + 1) * ph] = p
    return np.concatenate([main, col], axis=1)


def panel_size(width: int, height: int) -> tuple[int, int]:
    return width // 2, height // 2


def read_video_info(path: str | Path) -> tuple[int, int, int]:
    """(frame count by decoding, width, height) of a video file."""
    cap = cv2.VideoCapture(str(path))
    n = 0
    w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
    h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    while True:
        ok, _ = cap.read()
        if not ok:
            break
        n += 1
    cap.release()
    return n, w, h
