"""Calibration sources: the project's ``calib.txt``, the published TUM Freiburg calibrations,
and EuRoC ``sensor.yaml`` files (read by a small tolerant parser, no PyYAML).

``calib.txt`` (comments with ``#``)::

    fx fy cx cy [k1 k2 p1 p2 [k3]]      # pixels; OpenCV radial-tangential order
    width height
    depth_scale 5000                    # optional: depth PNG units per metre (TUM default 5000)
    model fov                           # optional: then line 1 is `fx fy cx cy omega` (FOV/ATAN model)

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
                if len(f) != 2 or f[1].lower() not in ("radtan", "fov", "none", "pinhole"):
                    raise InputError(f"{path} line {n}: expected 'model radtan|fov|none'")
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
    elif len(k) not in (4, 8, 9):
        raise InputError(f"{path} line {n1}: expected 'fx fy cx cy [k1 k2 p1 p2 [k3]]' (4, 8 or 9 values), "
                         f"got {len(k)}")
    if k[0] <= 0 or k[1] <= 0:
        raise InputError(f"{path} line {n1}: focal lengths fx fy must be positive")
    pin = PinholeIntrinsics(k[0], k[1], k[2], k[3], w, h)
    try:
        if model == "fov":
            cam = Camera(pin, "fov", (k[4],)) if k[4] != 0 else Camera(pin)
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
    else:
        lines += ["# fx fy cx cy [k1 k2 p1 p2 [k3]]  (pixels; distortion in OpenCV order)"]
    vals = [i.fx, i.fy, i.cx, i.cy, *camera.params]
    lines += [" ".join(repr(float(v)) for v in vals), "# width height", f"{i.width} {i.height}"]
    if depth_scale is not None:
        lines += ["# depth PNG units per metre", f"depth_scale {float(depth_scale)!r}"]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


# ------------------------------------------------------------------------------------------------
# A small YAML subset: `key: scalar`, `key: [flow, list]` (may span lines), and one level of
# nested mappings (`T_BS:` followed by indented `data: [...]`). Enough for EuRoC sensor.yaml.
# ------------------------------------------------------------------------------------------------

def _yaml_scalar(tok: str):
    tok = tok.strip()
    if len(tok) >= 2 and tok[0] == tok[-1] and tok[0] in "'\"":
        return tok[1:-1]
    try:
        return int(tok)
    except ValueError:
        pass
    try:
        return float(tok)
    except ValueError:
        return tok


def _strip_comment(line: str) -> str:
    out, quote = [], None
    for ch in line:
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch == "#":
            break
        out.append(ch)
    return "".join(out).rstrip()


def parse_simple_yaml(path: str | Path) -> dict:
    """Parse the YAML subset of EuRoC ``sensor.yaml`` files into nested dicts / lists / scalars."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: not found")
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot read ({err})") from None
    root: dict = {}
    stack: list[tuple[int, dict]] = [(-1, root)]
    i = 0
    while i < len(lines):
        n = i + 1
        raw = _strip_comment(lines[i])
        i += 1
        if not raw.strip() or raw.lstrip().startswith("%") or raw.strip() == "---":
            continue
        indent = len(raw) - len(raw.lstrip(" "))
        text = raw.strip()
        if ":" not in text:
            raise InputError(f"{path} line {n}: expected 'key: value'")
        key, _, value = text.partition(":")
        key, value = key.strip(), value.strip()
        while stack and indent <= stack[-1][0]:
            stack.pop()
        parent = stack[-1][1]
        if value.startswith("!!"):  # OpenCV tags like !!opencv-matrix
            value = value.split(None, 1)[1] if " " in value else ""
        if value == "":
            child: dict = {}
            parent[key] = child
            stack.append((indent, child))
        elif value.startswith("["):
            buf = value
            while "]" not in buf:
                if i >= len(lines):
                    raise InputError(f"{path} line {n}: unterminated list for {key!r}")
                buf += " " + _strip_comment(lines[i]).strip()
                i += 1
            inner = buf[1:buf.index("]")]
            parent[key] = [_yaml_scalar(t) for t in inner.split(",") if t.strip()]
        else:
            parent[key] = _yaml_scalar(value)
    return root


def _numbers(path: Path, d: dict, key: str, count: int | tuple) -> list[float]:
    v = d.get(key)
    counts = count if isinstance(count, tuple) else (count,)
    if not isinstance(v, list) or len(v) not in counts or not all(isinstance(x, (int, float)) for x in v):
        raise InputError(f"{path}: key {key!r} must be a list of {' or '.join(map(str, counts))} numbers")
    return [float(x) for x in v]


def yaml_matrix4(path: Path, d: dict, key: str = "T_BS") -> np.ndarray:
    """A 4x4 matrix stored as ``key: {rows: 4, cols: 4, data: [...]}`` (identity if absent)."""
    if key not in d:
        return np.eye(4)
    m = d[key]
    if isinstance(m, dict):
        data = _numbers(path, m, "data", 16)
    elif isinstance(m, list):
        data = _numbers(path, d, key, 16)
    else:
        raise InputError(f"{path}: key {key!r} must be a 4x4 matrix")
    T = np.asarray(data).reshape(4, 4)
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise InputError(f"{path}: {key} is not a rigid transform")
    return T


def read_euroc_camera_yaml(path: str | Path) -> tuple[Camera, np.ndarray]:
    """(Camera, T_body_cam) from an EuRoC ``cam0/sensor.yaml``."""
    path = Path(path)
    d = parse_simple_yaml(path)
    model = str(d.get("camera_model", "pinhole")).lower()
    if model != "pinhole":
        raise InputError(f"{path}: camera_model {model!r} is not supported (only pinhole)")
    fx, fy, cx, cy = _numbers(path, d, "intrinsics", 4)
    w, h = _numbers(path, d, "resolution", 2)
    dist_model = str(d.get("distortion_model", "none")).lower().replace("_", "-")
    pin = PinholeIntrinsics(fx, fy, cx, cy, int(w), int(h))
    if dist_model in ("radial-tangential", "radtan", "plumb-bob"):
        coeffs = _numbers(path, d, "distortion_coefficients", (4, 5))
        cam = Camera(pin, "radtan", tuple(coeffs))
    elif dist_model in ("fov", "atan"):
        coeffs = _numbers(path, d, "distortion_coefficients", 1)
        cam = Camera(pin, "fov", tuple(coeffs))
    elif dist_model in ("none", ""):
        cam = Camera(pin)
    else:
        raise InputError(f"{path}: distortion_model {dist_model!r} is not supported (radial-tangential, fov, none)")
    return cam, yaml_matrix4(path, d, "T_BS")
