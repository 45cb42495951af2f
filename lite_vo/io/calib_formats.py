"""Calibration files in the formats people have: the project's ``calib.txt``, OpenCV YAML
(``calibrateCamera`` results written with ``cv2.FileStorage``), Kalibr camchain YAML, ROS
``camera_info`` YAML and EuRoC ``sensor.yaml``; :func:`read_calibration` detects the format.

YAML is read with PyYAML; files with OpenCV's own ``!!opencv-matrix`` nodes are read with
``cv2.FileStorage``. Every file becomes a plain dict first, then one of three layouts is
recognised:

* **Kalibr / EuRoC** (``intrinsics: [fu, fv, pu, pv]``, ``resolution: [w, h]``,
  ``distortion_model``, ``distortion_coeffs`` or ``distortion_coefficients``); a camchain holds
  them under ``cam0``, ``cam1``, ... (``cam0`` is used, or the only camera);
* **camera matrix** layouts: ROS ``camera_info`` YAML (``image_width``, ``camera_matrix``,
  ``distortion_model``, ``distortion_coefficients``), ``rostopic echo`` dumps (``width``, ``K``,
  ``D``; ROS 2 ``k``, ``d``) and OpenCV's calibration sample (``camera_matrix``,
  ``distortion_coefficients``, ``image_width``); matrices as ``{rows, cols, data}`` or lists;
* nothing else: an error that says which keys were expected.

Distortion models: ``radtan`` (OpenCV/ROS ``plumb_bob``, Kalibr ``radtan``, EuRoC
``radial-tangential``), ``rational_polynomial`` only when its k4..k6 are zero, ``equidistant``
(fisheye: ``cv2.fisheye``, Kalibr and ROS ``equidistant``), ``fov`` and ``none``.

Every problem is an :class:`~lite_vo.errors.InputError` naming the file and the field.
Imports numpy, ``lite_vo.camera``, the io helpers; PyYAML and cv2 lazily.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from ..camera import Camera, PinholeIntrinsics
from ..errors import InputError
from .calib import Calibration, read_calib_txt

YAML_SUFFIXES = (".yaml", ".yml", ".json")
_YAML_KEY = re.compile(r"^[A-Za-z_][\w\-]*\s*:")

#: distortion model names of ROS, Kalibr, EuRoC and OpenCV -> the Camera model
_MODEL_NAMES = {
    "plumb_bob": "radtan", "radtan": "radtan", "radial-tangential": "radtan", "radial_tangential": "radtan",
    "rational_polynomial": "rational", "equidistant": "equidistant", "fisheye": "equidistant",
    "kannala_brandt": "equidistant", "kannala-brandt": "equidistant", "fov": "fov", "atan": "fov",
    "none": "none", "pinhole": "none", "": None,
}


# ------------------------------------------------------------------------------------------------
# reading YAML into a dict
# ------------------------------------------------------------------------------------------------

def _read_text(path: Path) -> str:
    if not path.is_file():
        if path.exists():
            raise InputError(f"{path}: is not a file")
        raise InputError(f"{path}: calibration file not found")
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror or err})") from None


def _fs_value(node) -> Any:
    """A cv2.FileNode as plain Python: matrices as {rows, cols, data}, maps, lists, scalars."""
    if node.isMap():
        keys = list(node.keys())
        if {"rows", "cols", "data"} <= set(keys):
            m = node.mat()
            if m is not None:
                m = np.asarray(m, dtype=np.float64)
                return {"rows": int(m.shape[0]), "cols": int(m.shape[1]) if m.ndim > 1 else 1,
                        "data": m.ravel().tolist()}
        return {k: _fs_value(node.getNode(k)) for k in keys}
    if node.isSeq():
        return [_fs_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def _load_opencv_yaml(path: Path) -> dict:
    import cv2
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except Exception as err:  # cv2.error, or SystemError wrapping it
        cause = err.__cause__ or err
        msg = str(cause).strip().splitlines()
        detail = msg[-1] if msg else type(cause).__name__
        m = re.search(r"\(-?\d+:[^)]*\)\s*(.*)", " ".join(msg))
        raise InputError(f"{path}: OpenCV cannot parse this YAML ({(m.group(1) if m else detail).strip()})") from None
    try:
        if not fs.isOpened():
            raise InputError(f"{path}: OpenCV cannot open this YAML file")
        root = fs.root()
        return {k: _fs_value(root.getNode(k)) for k in root.keys()}
    finally:
        fs.release()


def load_yaml(path: str | Path) -> dict:
    """A YAML calibration file as a dict (PyYAML; ``cv2.FileStorage`` for OpenCV's own files).

    OpenCV's ``%YAML:1.0`` first line (EuRoC ``sensor.yaml``, OpenCV 3/4 output), which is not
    valid YAML, is skipped."""
    path = Path(path)
    text = _read_text(path)
    if "!!opencv-matrix" in text or "!!opencv-nd-matrix" in text:
        return _load_opencv_yaml(path)
    import yaml
    if text.startswith("%YAML:"):
        text = "#" + text          # keep the line numbers of the messages
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise InputError(f"{path}{where}: not valid YAML ({problem})") from None
    if not isinstance(d, dict):
        raise InputError(f"{path}: expected a YAML mapping of calibration keys, got {type(d).__name__}")
    return d


# ------------------------------------------------------------------------------------------------
# fields
# ------------------------------------------------------------------------------------------------

def _flat_numbers(source: str, key: str, value, counts: Sequence[int] | None = None) -> list[float]:
    """Numbers of a list, a nested list or a {rows, cols, data} matrix; checks count and NaN."""
    v = value
    if isinstance(v, dict):
        if "data" not in v:
            raise InputError(f"{source}: {key} must be a list of numbers or a matrix with 'data'")
        data = v["data"]
        rows, cols = v.get("rows"), v.get("cols")
        if isinstance(data, list) and isinstance(rows, int) and isinstance(cols, int) and rows * cols != len(data):
            raise InputError(f"{source}: {key} says {rows}x{cols} but has {len(data)} values")
        v = data
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        v = [v]
    if isinstance(v, list) and v and all(isinstance(r, list) for r in v):
        v = [x for r in v for x in r]
    if not isinstance(v, list):
        raise InputError(f"{source}: {key} must be a list of numbers")
    out = []
    for n, x in enumerate(v, start=1):
        try:                                 # YAML 1.1 reads 1e-05 (no dot) and nan as strings
            if isinstance(x, bool):
                raise ValueError
            out.append(float(x))
        except (TypeError, ValueError):
            raise InputError(f"{source}: {key} value {n} ({x!r}) is not a number") from None
    if counts is not None and len(out) not in counts:
        raise InputError(f"{source}: {key} must have {' or '.join(map(str, counts))} values, got {len(out)}")
    bad = [i for i, x in enumerate(out) if not np.isfinite(x)]
    if bad:
        raise InputError(f"{source}: {key} value {bad[0] + 1} is {out[bad[0]]} (must be a finite number)")
    return out


def _size(source: str, key: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) \
            or value != int(value) or value <= 0:
        raise InputError(f"{source}: {key} must be a positive integer, got {value!r}")
    return int(value)


def _first(d: dict, keys: Sequence[str]) -> tuple[Optional[str], Any]:
    for k in keys:
        if k in d and d[k] is not None:
            return k, d[k]
    return None, None


def _camera(source: str, fx: float, fy: float, cx: float, cy: float, width: int, height: int,
            model: str, coeffs: Sequence[float], k_field: str, d_field: str) -> Camera:
    """Validated Camera; messages name ``k_field`` (intrinsics) or ``d_field`` (distortion)."""
    for name, v in (("fx", fx), ("fy", fy)):
        if not v > 0:
            raise InputError(f"{source}: {k_field}: focal length {name} = {v:g} must be positive")
    for name, v, size, side in (("cx", cx, width, "wide"), ("cy", cy, height, "high")):
        if not (-0.5 <= v <= size - 0.5):
            raise InputError(f"{source}: {k_field}: principal point {name} = {v:g} lies outside the image "
                             f"({width}x{height}, {size} pixels {side}): a calibration for another image size?")
    pin = PinholeIntrinsics(float(fx), float(fy), float(cx), float(cy), int(width), int(height))
    c = [float(v) for v in coeffs]
    if model == "rational":
        if len(c) > 5 and any(abs(v) > 1e-9 for v in c[5:8]):
            raise InputError(f"{source}: {d_field}: rational_polynomial with k4..k6 = "
                             f"{', '.join(f'{v:g}' for v in c[5:8])} is not supported (only k1 k2 p1 p2 k3)")
        model, c = "radtan", c[:5]
    if model == "radtan":
        if len(c) > 5 and any(abs(v) > 1e-9 for v in c[5:]):
            raise InputError(f"{source}: {d_field}: {len(c)} coefficients with non-zero k4.. are not supported "
                             "(radial-tangential k1 k2 p1 p2 [k3])")
        c = c[:5]
        if len(c) not in (0, 4, 5):
            raise InputError(f"{source}: {d_field}: radial-tangential needs 4 or 5 coefficients "
                             f"(k1 k2 p1 p2 [k3]), got {len(c)}")
        if not any(c):
            model, c = "none", []
    elif model == "equidistant":
        if len(c) == 0:
            c = [0.0] * 4
        if len(c) != 4:
            raise InputError(f"{source}: {d_field}: equidistant (fisheye) needs 4 coefficients k1 k2 k3 k4, "
                             f"got {len(c)}")
    elif model == "fov":
        if len(c) != 1:
            raise InputError(f"{source}: {d_field}: fov needs 1 coefficient (omega), got {len(c)}")
        if c[0] == 0:
            model, c = "none", []
    elif model == "none":
        if any(c):
            raise InputError(f"{source}: {d_field}: distortion model none with non-zero coefficients")
        c = []
    try:
        return Camera(pin, model, tuple(c))
    except ValueError as err:
        raise InputError(f"{source}: {d_field}: {err}") from None


def _model(source: str, key: str, name) -> Optional[str]:
    if name is None:
        return None
    m = _MODEL_NAMES.get(str(name).strip().lower())
    if m is None and str(name).strip().lower() not in _MODEL_NAMES:
        raise InputError(f"{source}: {key} {name!r} is not supported (plumb_bob/radtan, rational_polynomial, "
                         "equidistant, fov, none)")
    return m


def camera_from_ros(width: int, height: int, distortion_model: str, K, D, source: str) -> Camera:
    """A :class:`Camera` from the fields of a ROS ``sensor_msgs/CameraInfo``.

    ``K``: 9 numbers (row-major 3x3); ``D``: the distortion coefficients; ``distortion_model``:
    ``plumb_bob`` (k1 k2 p1 p2 k3), ``rational_polynomial`` (its first five; k4..k6 must be 0),
    ``equidistant`` (k1..k4), or empty with empty ``D`` (no distortion). ``source`` names where
    the message came from in error messages (e.g. ``"rec.bag /cam/camera_info"``)."""
    return _from_matrix(source, _size(source, "width", width), _size(source, "height", height),
                        _model(source, "distortion_model", distortion_model),
                        K, list(D) if D is not None else [], "K", "D")


def _from_matrix(source: str, width: int, height: int, model: Optional[str], K, D,
                 k_field: str, d_field: str) -> Camera:
    k = _flat_numbers(source, k_field, list(np.asarray(K, dtype=np.float64).ravel())
                      if isinstance(K, np.ndarray) else K, (9,))
    Km = np.asarray(k).reshape(3, 3)
    if abs(Km[0, 1]) > 1e-6 * max(abs(Km[0, 0]), 1.0):
        raise InputError(f"{source}: {k_field}: skew {Km[0, 1]:g} is not supported (must be 0)")
    if not np.allclose(Km[1:, :], [[0, Km[1, 1], Km[1, 2]], [0, 0, 1]], atol=1e-9):
        raise InputError(f"{source}: {k_field}: not a camera matrix [[fx 0 cx] [0 fy cy] [0 0 1]]")
    d = _flat_numbers(source, d_field, list(np.asarray(D, dtype=np.float64).ravel())
                      if isinstance(D, np.ndarray) else D)
    if model is None:                      # OpenCV files name no model: radtan (or none)
        model = "radtan" if d else "none"
    return _camera(source, Km[0, 0], Km[1, 1], Km[0, 2], Km[1, 2], width, height, model, d, k_field, d_field)


# ------------------------------------------------------------------------------------------------
# layouts
# ------------------------------------------------------------------------------------------------

def _kalibr_camera(source: str, d: dict) -> Camera:
    """Kalibr camchain entry or EuRoC sensor.yaml (intrinsics, resolution, distortion_*)."""
    cm = str(d.get("camera_model", "pinhole")).strip().lower()
    if cm != "pinhole":
        raise InputError(f"{source}: camera_model {cm!r} is not supported (only pinhole, with radtan, "
                         "equidistant, fov or no distortion)")
    fx, fy, cx, cy = _flat_numbers(source, "intrinsics", d.get("intrinsics"), (4,))
    if "resolution" not in d:
        raise InputError(f"{source}: resolution [width, height] is missing")
    w, h = _flat_numbers(source, "resolution", d["resolution"], (2,))
    w, h = _size(source, "resolution width", w), _size(source, "resolution height", h)
    d_field, coeffs = _first(d, ("distortion_coeffs", "distortion_coefficients"))
    d_field = d_field or "distortion_coeffs"
    coeffs = _flat_numbers(source, d_field, coeffs) if coeffs is not None else []
    model = _model(source, "distortion_model", d.get("distortion_model", "none" if not coeffs else "radtan"))
    if model is None:
        model = "radtan" if coeffs else "none"
    return _camera(source, fx, fy, cx, cy, w, h, model, coeffs, "intrinsics", d_field)


_K_KEYS = ("camera_matrix", "cameraMatrix", "K", "k", "intrinsic_matrix", "intrinsic")
_D_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "distortion_coeffs", "D", "d", "distortion")
_W_KEYS = ("image_width", "width", "imageWidth")
_H_KEYS = ("image_height", "height", "imageHeight")
_SIZE_KEYS = ("image_size", "imageSize", "resolution")


def _matrix_camera(source: str, d: dict) -> Camera:
    k_field, K = _first(d, _K_KEYS)
    d_field, D = _first(d, _D_KEYS)
    w_field, w = _first(d, _W_KEYS)
    h_field, h = _first(d, _H_KEYS)
    if w is None or h is None:
        s_field, size = _first(d, _SIZE_KEYS)
        if size is None:
            raise InputError(f"{source}: image size missing (image_width and image_height, or image_size)")
        w, h = _flat_numbers(source, s_field, size, (2,))
        w_field = h_field = s_field
    width, height = _size(source, w_field, w), _size(source, h_field, h)
    model = _model(source, "distortion_model", _first(d, ("distortion_model", "model"))[1])
    return _from_matrix(source, width, height, model, K, D if D is not None else [], k_field, d_field or "D")


def camera_from_yaml_dict(d: dict, source: str) -> Camera:
    """The camera of a parsed calibration YAML (layouts in the module docstring)."""
    cams = sorted(k for k, v in d.items() if re.fullmatch(r"cam\d+", str(k)) and isinstance(v, dict))
    if cams:
        key = "cam0" if "cam0" in cams else cams[0]
        return _kalibr_camera(f"{source} {key}", d[key])
    if "intrinsics" in d:
        return _kalibr_camera(source, d)
    if _first(d, _K_KEYS)[0] is not None:
        return _matrix_camera(source, d)
    raise InputError(f"{source}: not a calibration file this reader knows (expected calib.txt lines, or YAML "
                     "with camera_matrix + distortion_coefficients (OpenCV, ROS camera_info), K + D, "
                     "cam0: (Kalibr camchain) or intrinsics + resolution (Kalibr, EuRoC))")


def is_yaml_file(path: Path, text: str) -> bool:
    if path.suffix.lower() in YAML_SUFFIXES:
        return True
    for line in text.splitlines():
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        return s.startswith("%YAML") or s == "---" or s.startswith("{") or bool(_YAML_KEY.match(s))
    return False


def read_calibration(path: str | Path) -> Calibration:
    """A calibration file in any supported format (module docstring), detected from the file's
    extension and content: YAML (``.yaml``/``.yml``, or a first line ``key: ...``) or ``calib.txt``."""
    path = Path(path).expanduser()
    text = _read_text(path)
    if not is_yaml_file(path, text):
        return read_calib_txt(path)
    return Calibration(camera_from_yaml_dict(load_yaml(path), str(path)), None, str(path))


def load_calibration(calib) -> Calibration:
    """``calib`` as a :class:`Calibration`: a Calibration, a Camera, or a file path in any format."""
    if isinstance(calib, Calibration):
        return calib
    if isinstance(calib, Camera):
        return Calibration(calib, None, "camera object")
    if isinstance(calib, (str, Path)) or hasattr(calib, "__fspath__"):
        return read_calibration(calib)
    raise TypeError(f"calib must be a path, a Calibration or a Camera, not {type(calib).__name__}")


# ------------------------------------------------------------------------------------------------
# EuRoC sensor.yaml (camera + extrinsics)
# ------------------------------------------------------------------------------------------------

def yaml_matrix4(path: Path, d: dict, key: str = "T_BS") -> np.ndarray:
    """A 4x4 rigid transform stored as ``key: {rows: 4, cols: 4, data: [...]}`` or a list
    (identity if absent)."""
    if key not in d:
        return np.eye(4)
    T = np.asarray(_flat_numbers(str(path), key, d[key], (16,))).reshape(4, 4)
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise InputError(f"{path}: {key} is not a rigid transform")
    return T


def read_sensor_transform(path: str | Path, key: str = "T_BS") -> np.ndarray:
    """``key`` (default EuRoC's ``T_BS``, sensor in body) of a YAML file."""
    path = Path(path)
    return yaml_matrix4(path, load_yaml(path), key)


def read_euroc_camera_yaml(path: str | Path) -> tuple[Camera, np.ndarray]:
    """(Camera, T_body_cam) from an EuRoC ``cam0/sensor.yaml``."""
    path = Path(path)
    d = load_yaml(path)
    return camera_from_yaml_dict(d, str(path)), yaml_matrix4(path, d, "T_BS")
