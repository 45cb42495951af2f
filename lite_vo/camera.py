"""Cameras: pinhole intrinsics (per pyramid level), lens distortion, rectification.

:class:`PinholeIntrinsics` is the undistorted camera the whole pipeline works with after
rectification: ``u = fx * x / z + cx`` with pixel centres at integer coordinates.
Pyramid level l+1 halves fx, fy and maps ``c -> (c + 0.5) / 2 - 0.5`` (2x2 box averaging).

:class:`Camera` is a calibrated camera as recorded (native size, radial-tangential or FOV
distortion, thesis ch. 2.1); :meth:`Camera.rectifier` builds a :class:`Rectifier` that turns
native frames (and depth images) into undistorted pinhole images at the working resolution.
Fisheye lenses use the equidistant (Kannala-Brandt) model of OpenCV's ``cv2.fisheye`` and Kalibr.

Imports numpy (and cv2 lazily, for the rectifier) only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PinholeIntrinsics:
    """Undistorted pinhole camera of an image of ``width`` x ``height`` pixels."""
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def level(self, lvl: int) -> "PinholeIntrinsics":
        """Intrinsics of pyramid level ``lvl`` (each level halves the size, 2x2 box average)."""
        fx, fy, cx, cy, w, h = self.fx, self.fy, self.cx, self.cy, self.width, self.height
        for _ in range(lvl):
            fx, fy = fx * 0.5, fy * 0.5
            cx, cy = (cx + 0.5) * 0.5 - 0.5, (cy + 0.5) * 0.5 - 0.5
            w, h = w // 2, h // 2
        return PinholeIntrinsics(fx, fy, cx, cy, w, h)

    def scaled(self, width: int, height: int) -> "PinholeIntrinsics":
        """The same camera resampled to ``width`` x ``height`` (pixel-area convention)."""
        sx, sy = width / self.width, height / self.height
        return PinholeIntrinsics(self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5,
                                 (self.cy + 0.5) * sy - 0.5, int(width), int(height))

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of camera-frame points (N, 3) (z must be > 0)."""
        p = np.asarray(points_cam, dtype=np.float64)
        z = p[:, 2]
        return np.stack([self.fx * p[:, 0] / z + self.cx, self.fy * p[:, 1] / z + self.cy], axis=1)

    def unproject_idepth(self, u: np.ndarray, v: np.ndarray, idepth: np.ndarray) -> np.ndarray:
        """Camera-frame points (N, 3) of pixels (u, v) with inverse depth ``idepth`` (> 0)."""
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        z = 1.0 / np.asarray(idepth, dtype=np.float64)
        return np.stack([(u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z], axis=-1)


# --------------------------------------------------------------------------------------------
# Distortion models and the native (as recorded) camera
# --------------------------------------------------------------------------------------------

DISTORTION_MODELS = ("none", "radtan", "fov", "equidistant")

#: the rectified pinhole never looks further than this from the optical axis (its corners); only
#: very wide lenses (fisheyes beyond ~140 degrees diagonal) reach it. A pinhole image of a wider
#: view spends almost all its pixels on the periphery and becomes useless in the centre.
MAX_RECTIFIED_HALF_ANGLE_DEG = 70.0


def _distort_radtan(x: np.ndarray, y: np.ndarray, k: tuple) -> tuple[np.ndarray, np.ndarray]:
    k1, k2, p1, p2, k3 = k
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def _undistort_radtan(xd: np.ndarray, yd: np.ndarray, k: tuple, iterations: int = 30
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Newton's method on the 2x2 system; points that do not converge become NaN."""
    k1, k2, p1, p2, k3 = k
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
        fx_ = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
        fy_ = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        j00 = radial + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
        j01 = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
        j10 = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
        j11 = radial + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
        det = j00 * j11 - j01 * j10
        with np.errstate(divide="ignore", invalid="ignore"):
            dx = (j11 * fx_ - j01 * fy_) / det
            dy = (-j10 * fx_ + j00 * fy_) / det
        x = x - dx
        y = y - dy
        with np.errstate(invalid="ignore"):
            if not (np.abs(dx) > 1e-15).any() and not (np.abs(dy) > 1e-15).any():
                break
    with np.errstate(invalid="ignore", over="ignore"):
        xr, yr = _distort_radtan(x, y, k)
        bad = ~(np.hypot(xr - xd, yr - yd) < 1e-9 * (1.0 + np.hypot(xd, yd)))
        # a solution beyond the turning point of the radial polynomial is not the physical one
        r2 = x * x + y * y
        bad |= ~(1.0 + r2 * (3 * k1 + r2 * (5 * k2 + 7 * k3 * r2)) > 0)
    x = np.where(bad, np.nan, x)
    y = np.where(bad, np.nan, y)
    return x, y


def _fov_factor_distort(r_u: np.ndarray, omega: float) -> np.ndarray:
    t = 2.0 * np.tan(omega / 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.arctan(r_u * t) / (omega * r_u)
    return np.where(r_u > 1e-12, f, t / omega)


def _fov_factor_undistort(r_d: np.ndarray, omega: float) -> np.ndarray:
    t = 2.0 * np.tan(omega / 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.tan(r_d * omega) / (t * r_d)
    f = np.where(r_d > 1e-12, f, omega / t)
    return np.where(r_d * omega < np.pi / 2, f, np.nan)  # beyond 180 degrees field of view


def _equidistant_theta_d(theta: np.ndarray, k: tuple) -> np.ndarray:
    k1, k2, k3, k4 = k
    t2 = theta * theta
    return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


def _distort_equidistant(x: np.ndarray, y: np.ndarray, k: tuple) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.fisheye``'s model: theta = atan(r), r_d = theta (1 + k1 theta^2 + ... + k4 theta^8)."""
    r = np.hypot(x, y)
    theta = np.arctan(r)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = _equidistant_theta_d(theta, k) / r
    s = np.where(r > 1e-12, s, 1.0)
    return x * s, y * s


def _undistort_equidistant(xd: np.ndarray, yd: np.ndarray, k: tuple, iterations: int = 30
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Newton's method on theta; NaN where there is no physical solution: at or beyond 90 degrees
    from the axis (a pinhole cannot show it) or past the turning point of the polynomial."""
    k1, k2, k3, k4 = k
    rd = np.hypot(xd, yd)
    theta = np.minimum(rd, 1.5)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        for _ in range(iterations):
            t2 = theta * theta
            f = _equidistant_theta_d(theta, k) - rd
            df = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
            step = f / df
            theta = theta - step
            if not (np.abs(step) > 1e-15).any():
                break
        t2 = theta * theta
        df = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
        bad = ~(np.abs(_equidistant_theta_d(theta, k) - rd) < 1e-9 * (1.0 + rd))
        bad |= ~(df > 0) | ~(theta >= 0) | ~(theta < np.pi / 2 - 1e-9)
        s = np.where(rd > 1e-12, np.tan(theta) / rd, 1.0)
    s = np.where(bad, np.nan, s)
    return xd * s, yd * s


@dataclass(frozen=True)
class Camera:
    """A calibrated camera at its native resolution, with lens distortion.

    ``intrinsics`` holds fx, fy, cx, cy (pixels) and the native image size; a point ``(x, y, z)``
    in the camera frame projects to ``K @ gamma(x / z, y / z)`` (thesis eq. 2.5) where ``gamma`` is

    * ``"none"``: the identity (``params = ()``);
    * ``"radtan"``: OpenCV radial-tangential, ``params = (k1, k2, p1, p2, k3)`` (eq. 2.10, k4..k6 = 0);
    * ``"fov"``: the FOV/ATAN model of Devernay and Faugeras, ``params = (omega,)`` (eq. 2.6-2.9),
      ``r_d = atan(2 r_u tan(omega / 2)) / omega``; omega in radians;
    * ``"equidistant"``: the fisheye model of ``cv2.fisheye``, Kalibr's ``equidistant`` and ROS
      (Kannala-Brandt), ``params = (k1, k2, k3, k4)``: ``theta = atan(r_u)``,
      ``r_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``. With all k = 0 it is
      still the equidistant projection ``r_d = theta``, not a pinhole.

    The pipeline never works on distorted images: :meth:`rectifier` builds remap tables once and
    turns each frame into an undistorted pinhole image at the working resolution.
    """
    intrinsics: PinholeIntrinsics
    model: str = "none"
    params: tuple = ()

    def __post_init__(self):
        if self.model not in DISTORTION_MODELS:
            raise ValueError(f"unknown distortion model {self.model!r} (known: {', '.join(DISTORTION_MODELS)})")
        p = tuple(float(v) for v in self.params)
        if self.model == "radtan":
            if len(p) == 4:
                p = p + (0.0,)
            if len(p) != 5:
                raise ValueError("radtan distortion needs (k1, k2, p1, p2[, k3])")
        elif self.model == "fov":
            if len(p) != 1 or not (0.0 <= p[0] < np.pi):
                raise ValueError("fov distortion needs (omega,) with 0 <= omega < pi")
        elif self.model == "equidistant":
            if len(p) != 4:
                raise ValueError("equidistant distortion needs (k1, k2, k3, k4)")
        elif p:
            raise ValueError("model 'none' takes no distortion parameters")
        if not all(np.isfinite(p)):
            raise ValueError("distortion parameters must be finite")
        i = self.intrinsics
        if not (i.fx > 0 and i.fy > 0 and i.width > 0 and i.height > 0):
            raise ValueError("focal lengths and image size must be positive")
        object.__setattr__(self, "params", p)

    # -- constructors -------------------------------------------------------------------------
    @classmethod
    def pinhole(cls, fx, fy, cx, cy, width, height) -> "Camera":
        return cls(PinholeIntrinsics(float(fx), float(fy), float(cx), float(cy), int(width), int(height)))

    @classmethod
    def radtan(cls, fx, fy, cx, cy, width, height, k1, k2, p1, p2, k3=0.0) -> "Camera":
        return cls(PinholeIntrinsics(float(fx), float(fy), float(cx), float(cy), int(width), int(height)),
                   "radtan", (k1, k2, p1, p2, k3))

    @classmethod
    def fov(cls, fx, fy, cx, cy, width, height, omega) -> "Camera":
        return cls(PinholeIntrinsics(float(fx), float(fy), float(cx), float(cy), int(width), int(height)),
                   "fov", (omega,))

    @classmethod
    def equidistant(cls, fx, fy, cx, cy, width, height, k1=0.0, k2=0.0, k3=0.0, k4=0.0) -> "Camera":
        return cls(PinholeIntrinsics(float(fx), float(fy), float(cx), float(cy), int(width), int(height)),
                   "equidistant", (k1, k2, k3, k4))

    # -- properties ---------------------------------------------------------------------------
    @property
    def width(self) -> int:
        return self.intrinsics.width

    @property
    def height(self) -> int:
        return self.intrinsics.height

    @property
    def is_distorted(self) -> bool:
        if self.model == "none":
            return False
        if self.model == "equidistant":
            return True            # r_d = theta is not r_u = tan(theta) even without coefficients
        return any(v != 0.0 for v in self.params)

    def describe(self) -> str:
        i = self.intrinsics
        s = f"{i.width}x{i.height} fx={i.fx:g} fy={i.fy:g} cx={i.cx:g} cy={i.cy:g}"
        if self.model != "none":
            s += f" {self.model}(" + ", ".join(f"{v:g}" for v in self.params) + ")"
        return s

    # -- distortion on normalised coordinates -------------------------------------------------
    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Distorted normalised coordinates (..., 2) of undistorted ones (``gamma``)."""
        xy = np.asarray(xy, dtype=np.float64)
        x, y = xy[..., 0], xy[..., 1]
        if not self.is_distorted:
            return xy.copy()
        if self.model == "radtan":
            xd, yd = _distort_radtan(x, y, self.params)
        elif self.model == "equidistant":
            xd, yd = _distort_equidistant(x, y, self.params)
        else:
            f = _fov_factor_distort(np.hypot(x, y), self.params[0])
            xd, yd = x * f, y * f
        return np.stack([xd, yd], axis=-1)

    def undistort(self, xy_distorted: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates (..., 2) of distorted ones (``gamma^-1``).

        Closed form for FOV, Newton iterations for radtan and equidistant; NaN where there is no
        (physical) solution (e.g. beyond the turning point of the radial polynomial, or 90 degrees
        and more from the optical axis)."""
        xy = np.asarray(xy_distorted, dtype=np.float64)
        x, y = xy[..., 0], xy[..., 1]
        if not self.is_distorted:
            return xy.copy()
        if self.model == "radtan":
            xu, yu = _undistort_radtan(x, y, self.params)
        elif self.model == "equidistant":
            xu, yu = _undistort_equidistant(x, y, self.params)
        else:
            f = _fov_factor_undistort(np.hypot(x, y), self.params[0])
            xu, yu = x * f, y * f
        return np.stack([xu, yu], axis=-1)

    # -- pixels ---------------------------------------------------------------------------------
    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Distorted pixel coordinates (N, 2) of camera-frame points (N, 3) with z > 0."""
        p = np.asarray(points_cam, dtype=np.float64)
        d = self.distort(p[..., :2] / p[..., 2:3])
        i = self.intrinsics
        return np.stack([i.fx * d[..., 0] + i.cx, i.fy * d[..., 1] + i.cy], axis=-1)

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates (N, 2) (ray ``(x, y, 1)``) of distorted pixels (N, 2)."""
        uv = np.asarray(uv, dtype=np.float64)
        i = self.intrinsics
        xd = np.stack([(uv[..., 0] - i.cx) / i.fx, (uv[..., 1] - i.cy) / i.fy], axis=-1)
        return self.undistort(xd)

    def rectifier(self, map_width: int, multiple_of: int = 16) -> "Rectifier":
        """Undistort + resize to ``map_width`` keeping the aspect ratio, with an explicit centre crop
        so both output dimensions are multiples of ``multiple_of``. See :class:`Rectifier`."""
        return Rectifier(self, map_width, multiple_of)


def _valid_normalised_rect(cam: Camera, samples: int = 400) -> tuple[float, float, float, float]:
    """Largest axis-aligned rectangle (x0, x1, y0, y1) of undistorted normalised coordinates
    whose every point distorts into the native image (pixel-area extent ``[-0.5, W - 0.5]``),
    shrunk about its centre when a corner would look more than ``MAX_RECTIFIED_HALF_ANGLE_DEG``
    away from the optical axis (fisheye lenses)."""
    i = cam.intrinsics
    W, H = i.width, i.height
    if not cam.is_distorted:
        return ((-0.5 - i.cx) / i.fx, (W - 0.5 - i.cx) / i.fx, (-0.5 - i.cy) / i.fy, (H - 0.5 - i.cy) / i.fy)
    us = np.linspace(-0.5, W - 0.5, samples)
    vs = np.linspace(-0.5, H - 0.5, samples)
    left = cam.unproject(np.stack([np.full_like(vs, -0.5), vs], -1))
    right = cam.unproject(np.stack([np.full_like(vs, W - 0.5), vs], -1))
    top = cam.unproject(np.stack([us, np.full_like(us, -0.5)], -1))
    bottom = cam.unproject(np.stack([us, np.full_like(us, H - 0.5)], -1))
    # border points at 90 degrees or more from the axis (wide fisheyes) lie at infinity: no limit
    r_max = np.tan(np.radians(MAX_RECTIFIED_HALF_ANGLE_DEG))

    def bound(values, pick, default):
        v = values[np.isfinite(values)]
        return float(np.clip(pick(v), -r_max, r_max)) if len(v) else default

    x0, x1 = bound(left[:, 0], np.max, -r_max), bound(right[:, 0], np.min, r_max)
    y0, y1 = bound(top[:, 1], np.max, -r_max), bound(bottom[:, 1], np.min, r_max)
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"camera {cam.describe()}: cannot find an undistorted image region")
    # verify on a grid (edges dense, interior coarse); shrink about the centre until inside
    mx, my = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    hx, hy = 0.5 * (x1 - x0), 0.5 * (y1 - y0)
    g = np.linspace(-1.0, 1.0, 41)
    e = np.linspace(-1.0, 1.0, samples)
    pts = np.concatenate([
        np.stack(np.meshgrid(g, g), -1).reshape(-1, 2),
        np.stack([e, -np.ones_like(e)], -1), np.stack([e, np.ones_like(e)], -1),
        np.stack([-np.ones_like(e), e], -1), np.stack([np.ones_like(e), e], -1)])
    tol = 1e-6
    for _ in range(200):
        xy = np.stack([mx + hx * pts[:, 0], my + hy * pts[:, 1]], -1)
        uv = cam.project(np.concatenate([xy, np.ones((len(xy), 1))], 1))
        ok = np.all(np.isfinite(uv)) and uv[:, 0].min() >= -0.5 - tol and uv[:, 0].max() <= W - 0.5 + tol \
            and uv[:, 1].min() >= -0.5 - tol and uv[:, 1].max() <= H - 0.5 + tol
        if ok:
            break
        hx *= 0.995
        hy *= 0.995
    else:  # pragma: no cover - pathological calibration
        raise ValueError(f"camera {cam.describe()}: cannot find an undistorted image region")
    # widest useful view: no corner further than MAX_RECTIFIED_HALF_ANGLE_DEG from the axis
    scale = 1.0
    for sx, sy in ((-1, -1), (-1, 1), (1, -1), (1, 1)):
        a = hx * hx + hy * hy                              # |m + s h|^2 = r_max^2, largest root s
        b = mx * sx * hx + my * sy * hy
        c = mx * mx + my * my - r_max * r_max
        scale = min(scale, (-b + np.sqrt(max(b * b - a * c, 0.0))) / a)
    hx, hy = hx * scale, hy * scale
    return mx - hx, mx + hx, my - hy, my + hy


def _rectified_pinhole(cam: Camera, map_width: int, multiple_of: int):
    """(output intrinsics, uncropped size (w0, h0), supersampling factor k)."""
    i = cam.intrinsics
    map_width = int(map_width)
    multiple_of = int(multiple_of)
    from .errors import ConfigError
    if multiple_of < 1:
        raise ConfigError(f"multiple_of must be >= 1, got {multiple_of}")
    w0 = map_width
    h0 = max(1, int(round(map_width * i.height / i.width)))
    w = (w0 // multiple_of) * multiple_of
    h = (h0 // multiple_of) * multiple_of
    if map_width < 8 or w < 1 or h < 1:
        raise ConfigError(f"map_width {map_width} is too small for the {i.width}x{i.height} camera: the "
                          f"{w0}x{h0} image has no side that is a multiple of {multiple_of}")
    x0, x1, y0, y1 = _valid_normalised_rect(cam)
    # keep the native pixel aspect (fx/fy); the uncropped w0 x h0 output must fit into the rectangle
    s = max(w0 / ((x1 - x0) * i.fx), h0 / ((y1 - y0) * i.fy))
    fx, fy = i.fx * s, i.fy * s
    # the uncropped image's pixel-area extent is centred on the rectangle's centre
    cx0 = (w0 - 1) / 2.0 - fx * 0.5 * (x0 + x1)
    cy0 = (h0 - 1) / 2.0 - fy * 0.5 * (y0 + y1)
    cx = cx0 - 0.5 * (w0 - w)
    cy = cy0 - 0.5 * (h0 - h)
    k = max(1, int(round(i.fx / fx)))
    return PinholeIntrinsics(float(fx), float(fy), float(cx), float(cy), w, h), (w0, h0), k


class Rectifier:
    """Turns native (distorted) frames into undistorted pinhole images at the working resolution.

    Geometry (computed once, in the constructor):

    * the output size is ``map_width`` x ``round(map_width * H / W)`` (the native aspect ratio),
      then **centre-cropped** to the largest multiples of ``multiple_of`` (e.g. KITTI 1226x370 at
      ``map_width=320`` -> 320x97 -> 320x96); the crop shifts cx, cy by half the removed pixels;
    * the output pinhole keeps the native pixel aspect ``fx / fy`` and is chosen so the whole
      output image lies inside the area the native image covers after undistortion: there is
      **no black or undefined border** (a little of the field of view near the corners or edges
      is given up instead; undistorted cameras lose nothing but the crop); for fisheye lenses the
      view is also limited to ``MAX_RECTIFIED_HALF_ANGLE_DEG`` from the axis at the corners;
    * images are remapped (bilinear, ``cv2.remap`` with tables built once) to ``k`` times the output
      size, where ``k ~ native fx / output fx``, then box-averaged by ``k`` (``cv2.INTER_AREA``)
      to avoid aliasing when downsampling. When that remap is the identity it is skipped.

    ``intrinsics`` is the output :class:`PinholeIntrinsics`; use ``.level(l)`` for pyramid levels.
    Instances are immutable after construction and safe to share between threads.
    """

    def __init__(self, camera: Camera, map_width: int, multiple_of: int = 16):
        import cv2
        self.camera = camera
        self.intrinsics, self.uncropped_size, self.factor = _rectified_pinhole(camera, map_width, multiple_of)
        out, k = self.intrinsics, self.factor
        # intermediate (k times supersampled) pinhole whose k x k box average is `out`
        mid = PinholeIntrinsics(out.fx * k, out.fy * k, (out.cx + 0.5) * k - 0.5, (out.cy + 0.5) * k - 0.5,
                                out.width * k, out.height * k)
        mx, my = self._source_coords(mid)
        nat = camera.intrinsics
        self._identity = (mid.width == nat.width and mid.height == nat.height
                          and np.allclose(mx, np.arange(nat.width)[None, :], atol=1e-6)
                          and np.allclose(my, np.arange(nat.height)[:, None], atol=1e-6))
        #: colour images may also come decoded at 1/r of the native size (a JPEG decoder scales for free),
        #: r the largest of 8, 4, 2 that divides the box-averaging factor and the native size, when no
        #: remap is needed; else 1 (see :meth:`color`)
        self.color_reduction = next((r for r in (8, 4, 2) if self._identity and k % r == 0
                                     and nat.width % r == 0 and nat.height % r == 0), 1)
        if self._identity:
            self._map1 = self._map2 = None
        else:
            self._map1, self._map2 = cv2.convertMaps(mx.astype(np.float32), my.astype(np.float32), cv2.CV_16SC2)
        # depth: nearest valid native pixel around the source location of each output pixel centre
        dx, dy = self._source_coords(out)
        self._depth_base = (np.clip(np.rint(dx), 0, nat.width - 1).astype(np.int32),
                            np.clip(np.rint(dy), 0, nat.height - 1).astype(np.int32))
        r = max(0, int(np.ceil((nat.fx / out.fx) / 2.0 - 1e-9)))
        offs = [(ox, oy) for oy in range(-r, r + 1) for ox in range(-r, r + 1) if ox * ox + oy * oy <= r * r + 1e-9]
        self._depth_offsets = sorted(offs, key=lambda o: (o[0] ** 2 + o[1] ** 2, o[1], o[0]))

    def _source_coords(self, pin: PinholeIntrinsics) -> tuple[np.ndarray, np.ndarray]:
        """Native (distorted) pixel coordinates of every pixel centre of pinhole image ``pin``."""
        u, v = np.meshgrid(np.arange(pin.width, dtype=np.float64), np.arange(pin.height, dtype=np.float64))
        xy = np.stack([(u - pin.cx) / pin.fx, (v - pin.cy) / pin.fy], -1)
        d = self.camera.distort(xy)
        nat = self.camera.intrinsics
        return nat.fx * d[..., 0] + nat.cx, nat.fy * d[..., 1] + nat.cy

    @property
    def size(self) -> tuple[int, int]:
        """Output ``(width, height)``."""
        return self.intrinsics.width, self.intrinsics.height

    def _check(self, image: np.ndarray, what: str, channels: int = 1) -> None:
        nat = self.camera.intrinsics
        ok = image.ndim == 2 if channels == 1 else (image.ndim == 3 and image.shape[2] == channels)
        if not ok or image.shape[:2] != (nat.height, nat.width):
            from .errors import InputError
            expected = (f"a {nat.height}x{nat.width} grey image" if channels == 1
                        else f"{nat.height}x{nat.width}x{channels}")
            raise InputError(f"{what} of shape {image.shape} does not match the camera's "
                             f"{nat.width}x{nat.height} (expected {expected})")

    def _warp(self, img: np.ndarray) -> np.ndarray:
        """Undistortion (when the camera has distortion) and the area-averaging resize, any channels."""
        import cv2
        if not self._identity:
            img = cv2.remap(img, self._map1, self._map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if self.factor > 1:
            img = cv2.resize(img, self.size, interpolation=cv2.INTER_AREA)
        return img

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Rectified, resized float32 image (0..255) of a native grey image (uint8 or float)."""
        image = np.asarray(image)
        self._check(image, "image")
        if self._identity and self.factor == 2 and image.dtype == np.uint8:
            from .image import box_average2_u8    # the same values as the float resize below, in one pass
            return box_average2_u8(image)
        img = self._warp(image.astype(np.float32, copy=False))
        if np.shares_memory(img, image):
            return np.array(img, dtype=np.float32)     # never hand out the caller's buffer
        return np.ascontiguousarray(img, dtype=np.float32)

    def color(self, bgr: np.ndarray) -> np.ndarray:
        """Rectified, resized uint8 (H, W, 3) image of a native 3-channel uint8 image (all channels in one
        pass, in uint8: for display, the point cloud and textures; the grey image goes through
        :meth:`__call__`). When :attr:`color_reduction` ``> 1`` the image may also be ``1/r`` of the
        native size for ``r`` dividing it (a JPEG decoded at reduced size: only box-averaged further)."""
        import cv2
        img = np.asarray(bgr)
        nat = self.camera.intrinsics
        r = self.color_reduction          # the reduction this image was decoded at (1: native size)
        while r > 1 and not (img.ndim == 3 and img.shape == (nat.height // r, nat.width // r, 3)):
            r //= 2
        if r == 1:
            self._check(img, "colour image", channels=3)
        if img.dtype != np.uint8:
            img = np.clip(img.astype(np.float32) + 0.5, 0, 255).astype(np.uint8)
        if r == 1:
            img = self._warp(img)
        elif self.factor > r:             # no remap needed here: only the rest of the box average
            img = cv2.resize(img, self.size, interpolation=cv2.INTER_AREA)
        return np.array(img, dtype=np.uint8) if np.shares_memory(img, bgr) else img

    def depth(self, depth_m: np.ndarray) -> np.ndarray:
        """Depth image (metres, 0 or NaN = invalid) in the output geometry: for each output pixel the
        valid native depth nearest to its source location within the pixel's footprint; depths are
        never blended (no mixed values across depth edges). 0 where none is valid."""
        d = np.asarray(depth_m, dtype=np.float32)
        self._check(d, "depth image")
        nat = self.camera.intrinsics
        bx, by = self._depth_base
        out = d[by, bx]                                   # nearest pixel first (most are valid)
        bad = ~((out > 0) & np.isfinite(out))            # 0, negative, NaN, inf: invalid
        out[bad] = 0.0
        todo = np.nonzero(bad.ravel())[0]
        flat = out.reshape(-1)
        tx, ty = bx.reshape(-1)[todo], by.reshape(-1)[todo]
        for ox, oy in self._depth_offsets[1:]:            # then the footprint, nearest first
            if len(todo) == 0:
                break
            cand = d[np.clip(ty + oy, 0, nat.height - 1), np.clip(tx + ox, 0, nat.width - 1)]
            take = (cand > 0) & np.isfinite(cand)
            flat[todo[take]] = cand[take]
            keep = ~take
            todo, tx, ty = todo[keep], tx[keep], ty[keep]
        return out
