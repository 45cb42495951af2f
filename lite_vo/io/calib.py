"""The project's ``calib.txt`` and the published TUM Freiburg calibrations. The YAML formats
(OpenCV, Kalibr, ROS, EuRoC) and format detection are in :mod:`lite_vo.io.calib_formats`.

``calib.txt`` (comments with ``#``)::

    fx fy cx cy [k1 k2 p1 p2 [k3]]      # pixels; OpenCV radial-tangential order
    width height
    depth_scale 5000                    # optional: depth PNG units per metre (TUM default 5000)
    model fov                           # optional: then line 1 is `fx fy cx cy omega` (FOV/ATAN model)
    model equidistant                   # optional: then line 1 is `fx fy cx cy k1 k2 k3 k4` (fisheye,
                                        # the Kannala-Brandt model of cv2.fisheye and Kalibr)

Imports numpy, ``lite_vo.camera`` and the io helpers only.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from ..camera import Camera, PinholeIntrinsics
from ..errors import InputError
from ._text import parse_float, read_lines

TUM_DEPTH_SCALE = 5000.0

#: published TUM RGB-D calibrations (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats)
FREIBURG = {
    1: (517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    2: (520.9, 521.0, 325.1, 249.7, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    3: (535.4, 539.2, 320.1, 247.6, None),
}

_FREIBURG_NAME = re.compile(r"^rgbd_dataset_freiburg([123])_")


@dataclass(frozen=True)
class Calibration:
    """A camera plus the depth scale (depth PNG units per metre; None = not given)."""
    camera: Camera
    depth_scale: Optional[float] = None
    source: str = ""


def freiburg_number(folder_name: str) -> Optional[int]:
    """N of a folder named ``rgbd_dataset_freiburgN_*`` (N in 1..3), else None."""
    m = _FREIBURG_NAME.match(folder_name)
    return int(m.group(1)) if m else None


def freiburg_camera(n: int) -> Camera:
    """The published calibration of TUM RGB-D Freiburg camera ``n`` (640x480)."""
    fx, fy, cx, cy, d = FREIBURG[n]
    if d is None:
        return Camera.pinhole(fx, fy, cx, cy, 640, 480)
    return Camera.radtan(fx, fy, cx, cy, 640, 480, *d)


def read_calib_txt(path: str | Path) -> Calibration:
    """Parse the project's ``calib.txt`` (format in the module docstring)."""
    path = Path(path)
    numeric: list[tuple[int, list[float]]] = []
    depth_scale, model = None, None
    for n, s in read_lines(path, "calibration file"):
        s = s.split("#", 1)[0].strip()
        f = s.split()
        if not f:
            continue
        if f[0][0].isalpha() and f[0].lower() not in ("nan", "inf"):
            key = f[0].lower()
            if key == "depth_scale":
                if len(f) != 2:
                    raise InputError(f"{path} line {n}: expected 'depth_scale N'")
                depth_scale = parse_float(path, n, f[1], "depth_scale")
                if not (np.isfinite(depth_scale) and depth_scale > 0):
                    raise InputError(f"{path} line {n}: depth_scale must be a positive number")
            elif key == "model":
                if len(f) != 2 or f[1].lower() not in ("radtan", "fov", "equidistant", "none", "pinhole"):
                    raise InputError(f"{path} line {n}: expected 'model radtan|fov|equidistant|none'")
                model = f[1].lower()
            else:
                raise InputError(f"{path} line {n}: unknown key {f[0]!r} (known: depth_scale, model)")
            continue
        vals = [parse_float(path, n, tok, "value") for tok in f]
        if not all(np.isfinite(vals)):
            raise InputError(f"{path} line {n}: values must be finite")
        numeric.append((n, vals))
    if len(numeric) < 2:
        raise InputError(f"{path}: expected a line 'fx fy cx cy [k1 k2 p1 p2 [k3]]' and a line 'width height'")
    if len(numeric) > 2:
        raise InputError(f"{path} line {numeric[2][0]}: unexpected extra line (expected only "
                         "'fx fy cx cy [k1 k2 p1 p2 [k3]]' and 'width height')")
    (n1, k), (n2, size) = numeric
    if len(size) != 2 or size[0] != int(size[0]) or size[1] != int(size[1]) or min(size) <= 0:
        raise InputError(f"{path} line {n2}: expected 'width height' (two positive integers)")
    w, h = int(size[0]), int(size[1])
    if model == "fov":
        if len(k) != 5:
            raise InputError(f"{path} line {n1}: model fov expects 'fx fy cx cy omega', got {len(k)} values")
    elif model == "equidistant":
        if len(k) not in (4, 8):
            raise InputError(f"{path} line {n1}: model equidistant expects 'fx fy cx cy k1 k2 k3 k4', "
                             f"got {len(k)} values")
    elif len(k) not in (4, 8, 9):
        raise InputError(f"{path} line {n1}: expected 'fx fy cx cy [k1 k2 p1 p2 [k3]]' (4, 8 or 9 values), "
                         f"got {len(k)}")
    if k[0] <= 0 or k[1] <= 0:
        raise InputError(f"{path} line {n1}: focal lengths fx fy must be positive")
    for name, v, size in (("cx", k[2], w), ("cy", k[3], h)):
        if not -0.5 <= v <= size - 0.5:
            raise InputError(f"{path} line {n1}: principal point {name} = {v:g} lies outside the {w}x{h} image "
                             f"(line {n2}): a calibration for another image size?")
    pin = PinholeIntrinsics(k[0], k[1], k[2], k[3], w, h)
    try:
        if model == "fov":
            cam = Camera(pin, "fov", (k[4],)) if k[4] != 0 else Camera(pin)
        elif model == "equidistant":
            cam = Camera(pin, "equidistant", tuple(k[4:]) if len(k) == 8 else (0.0,) * 4)
        elif len(k) > 4 and model not in ("none", "pinhole") and any(v != 0 for v in k[4:]):
            cam = Camera(pin, "radtan", tuple(k[4:]))
        else:
            cam = Camera(pin)
    except ValueError as err:
        raise InputError(f"{path} line {n1}: {err}") from None
    return Calibration(cam, depth_scale, str(path))


def write_calib_txt(path: str | Path, camera: Camera, depth_scale: Optional[float] = None,
                    comment: str | None = None) -> Path:
    """Write ``camera`` (and the depth scale) in the ``calib.txt`` format read by :func:`read_calib_txt`."""
    path = Path(path)
    i = camera.intrinsics
    lines = [f"# {c}" for c in (comment or "").splitlines()]
    if camera.model == "fov":
        lines += ["model fov", "# fx fy cx cy omega"]
    elif camera.model == "equidistant":
        lines += ["model equidistant", "# fx fy cx cy k1 k2 k3 k4  (pixels; fisheye, as cv2.fisheye)"]
    else:
        lines += ["# fx fy cx cy [k1 k2 p1 p2 [k3]]  (pixels; distortion in OpenCV order)"]
    vals = [i.fx, i.fy, i.cx, i.cy, *camera.params]
    lines += [" ".join(repr(float(v)) for v in vals), "# width height", f"{i.width} {i.height}"]
    if depth_scale is not None:
        lines += ["# depth PNG units per metre", f"depth_scale {float(depth_scale)!r}"]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
