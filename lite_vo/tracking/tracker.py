"""Tracker: coarse-to-fine direct SE(3) alignment of a new frame against a TrackingReference.

The tracker estimates ``T_new_ref`` internally (reference points warped into the new image, cheap
Jacobians at the warped point) and returns ``T_ref_new`` (its inverse), as the API contract says.
Owned by the tracking thread (its scratch buffers are not thread-safe: one Tracker per thread).
Imports numpy, :mod:`lite_vo.image`, :mod:`lite_vo.geometry` and the tracking kernels only.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..camera import PinholeIntrinsics
from ..geometry import inverse_se3, project_to_se3
from ..image import bspline_coefficient_stack, gaussian_blur, intensity_gradient_stack
from . import _kernels as kernels
from .config import TrackingConfig
from .reference import TrackingReference


@dataclass
class TrackingResult:
    """Outcome of one :meth:`Tracker.track` call.

    ``residual``: mean robust (Huber) energy of the normalised residuals on the finest level
    (about 1 when residuals match ``sigma_i``); ``good_ratio``: good/(good+bad) (good-residual test
    of ALGORITHM_NOTES); ``inside_ratio``: points that warped inside / the level's pixel count;
    ``points_used``: points that warped inside on the finest level; ``mean_abs_residual``: mean
    ``|I_new - I_ref|`` there (grey levels); ``lost_reason``: '' or why.
    """
    T_ref_new: np.ndarray
    lost: bool
    residual: float = float("nan")
    good_ratio: float = 0.0
    inside_ratio: float = 0.0
    points_used: int = 0
    level_ms: dict = field(default_factory=dict)
    iterations: dict = field(default_factory=dict)
    affine: tuple = (1.0, 0.0)
    lost_reason: str = ""
    mean_abs_residual: float = float("nan")
    total_ms: float = 0.0

    def quality(self) -> dict:
        """Scalar quality numbers as a plain dict (for logs and FrameResult.quality)."""
        return {"residual": self.residual, "mean_abs_residual": self.mean_abs_residual, "good_ratio": self.good_ratio, "inside_ratio": self.inside_ratio,
                "points_used": self.points_used, "lost": self.lost, "lost_reason": self.lost_reason,
                "affine_a": self.affine[0], "affine_b": self.affine[1], "track_ms": self.total_ms}


def tracking_params(c: TrackingConfig) -> np.ndarray:
    """The float64 parameter vector of the tracking kernels (layout: ``_kernels.TP_*``), built once
    per configuration."""
    p = np.zeros(kernels.TP_N, np.float64)
    p[kernels.TP_SIGMA_I2] = c.sigma_i * c.sigma_i
    p[kernels.TP_HUBER] = c.huber
    p[kernels.TP_AFF_K] = c.affine_huber
    p[kernels.TP_GOOD_C2] = c.good_residual_const ** 2
    p[kernels.TP_GOOD_G2] = c.good_residual_grad ** 2
    p[kernels.TP_BORDER] = c.border_px
    p[kernels.TP_MIN_Z] = c.min_warp_depth
    p[kernels.TP_CONV_RATIO] = c.converge_ratio
    p[kernels.TP_CONV_EPS] = c.converge_eps
    p[kernels.TP_LAMBDA_INIT] = c.lm_lambda_init
    p[kernels.TP_LAMBDA_ACCEPT_MAX] = c.lm_lambda_accept_max
    p[kernels.TP_LAMBDA_ACCEPT_FACTOR] = c.lm_lambda_accept_factor
    p[kernels.TP_LAMBDA_REJECT_FACTOR] = c.lm_lambda_reject_factor
    p[kernels.TP_MIN_POINTS] = c.min_points
    p[kernels.TP_SOLVE_EPS] = c.solve_eps
    p[kernels.TP_MIN_HESSIAN_DIAG] = c.min_hessian_diag
    p[kernels.TP_AFF_ENABLED] = 1.0 if c.affine_brightness else 0.0
    p[kernels.TP_AFF_MIN_VAR] = c.affine_min_var
    return p


class Tracker:
    """Direct SE(3) tracker (tracking thread only).

    ``Tracker(config.tracking, intrinsics0, pyramid_levels, track_level)``; ``intrinsics0`` are the
    mapping-resolution (level 0) intrinsics. Levels ``min(coarsest_level, pyramid_levels-1)`` down to
    ``track_level`` are used.
    """

    def __init__(self, config: TrackingConfig, intrinsics0: PinholeIntrinsics, pyramid_levels: int,
                 track_level: int):
        if not 0 <= track_level < pyramid_levels:
            raise ValueError(f"track_level {track_level} must be in [0, pyramid_levels={pyramid_levels})")
        self.config = config
        self.intrinsics0 = intrinsics0
        self.pyramid_levels = int(pyramid_levels)
        self.track_level = int(track_level)
        self.coarsest = max(self.track_level, min(self.pyramid_levels - 1, config.coarsest_level))
        self._intr = [intrinsics0.level(l) for l in range(self.pyramid_levels)]
        self._cams = [np.array([k.fx, k.fy, k.cx, k.cy], np.float64) for k in self._intr]
        self._params = tracking_params(config)
        self._img3 = [None] * self.pyramid_levels
        self._acc = np.zeros(kernels.ACC_SIZE)
        self._T_out = np.empty((4, 4))
        self._aff = np.empty(2)
        self._aff_out = np.empty(2)
        self._stats = np.zeros(kernels.ST_SIZE)
        self._buf = np.empty((kernels.BUF_ROWS, 1024))
        modes = {"bspline": kernels.INTERP_BSPLINE, "bilinear": kernels.INTERP_BILINEAR}
        self._interp_fine = modes[config.interpolation]
        self._interp_coarse = modes[config.interpolation_coarse]
        if kernels.INTERP_BSPLINE in (self._interp_fine, self._interp_coarse) and config.border_px < 1.0:
            raise ValueError("tracking.border_px must be >= 1 with bspline interpolation")

    def _max_iter(self, lvl: int) -> int:
        c = self.config
        d = lvl - self.track_level
        return c.max_iter_finest if d == 0 else c.max_iter_coarse if d == 1 else c.max_iter_coarsest

    def track(self, ref: TrackingReference, image_pyr_new, T_ref_new_guess) -> TrackingResult:
        """Align ``image_pyr_new`` (float32 pyramid, level 0 = mapping resolution) to ``ref``."""
        t_start = time.perf_counter()
        c = self.config
        guess = np.asarray(T_ref_new_guess, dtype=np.float64)
        if guess.shape != (4, 4) or not np.all(np.isfinite(guess)):
            raise ValueError("T_ref_new_guess must be a finite 4x4 matrix")
        guess = project_to_se3(guess)
        T = np.ascontiguousarray(inverse_se3(guess))          # T_new_ref
        n_lvl = min(len(image_pyr_new), ref.num_levels)
        top = min(self.coarsest, n_lvl - 1)
        finest = self.track_level
        if finest > top:
            raise ValueError(f"pyramids have {n_lvl} levels, tracking needs level {finest}")
        aff = self._aff
        aff[0], aff[1] = 1.0, 0.0
        level_ms: dict = {}
        iterations: dict = {}
        acc = self._acc
        finest_acc = None
        finest_status = 1
        for lvl in range(top, finest - 1, -1):
            t0 = time.perf_counter()
            lv = ref.levels[lvl]
            intr = self._intr[lvl]
            if lv.num_points < c.min_points and lvl != finest:
                level_ms[lvl] = (time.perf_counter() - t0) * 1e3
                iterations[lvl] = 0
                continue
            img = image_pyr_new[lvl]
            if img.shape != (intr.height, intr.width):
                raise ValueError(f"new image level {lvl} has shape {img.shape}, expected "
                                 f"{(intr.height, intr.width)}")
            if self._buf.shape[1] < lv.num_points:
                self._buf = np.empty((kernels.BUF_ROWS, max(lv.num_points, 2 * self._buf.shape[1])))
            if ref.smooth_sigma > 0:
                img = gaussian_blur(img, ref.smooth_sigma)
            interp = self._interp_fine if lvl == finest else self._interp_coarse
            if interp == kernels.INTERP_BSPLINE:
                img3 = self._img3[lvl] = bspline_coefficient_stack(img, self._img3[lvl])
            else:
                img3 = self._img3[lvl] = intensity_gradient_stack(img, self._img3[lvl])
            kernels.lm_level(lv.points, img3, interp, T, self._cams[lvl], self._params, self._max_iter(lvl), aff,
                             self._buf, self._T_out, acc, self._aff_out, self._stats)
            status = int(self._stats[kernels.ST_STATUS])
            if status != 1 and np.all(np.isfinite(self._T_out)):
                T = self._T_out.copy()
                aff[:] = self._aff_out
            iterations[lvl] = int(self._stats[kernels.ST_ITER])
            if lvl == finest:
                finest_acc = acc.copy()
                finest_status = status
                finest_err = float(self._stats[kernels.ST_ERR])
            level_ms[lvl] = (time.perf_counter() - t0) * 1e3

        lv = ref.levels[finest]
        res = TrackingResult(T_ref_new=guess.copy(), lost=True, level_ms=level_ms, iterations=iterations,
                             affine=(float(aff[0]), float(aff[1])))
        if finest_acc is None or finest_status == 1:
            res.lost_reason = ("no points (empty map, or reference built with min_level above the tracking level)"
                               if lv.num_points == 0 else "too few points inside the image")
            res.points_used = 0 if finest_acc is None else int(finest_acc[kernels.ACC_N])
            res.inside_ratio = res.points_used / max(lv.num_pixels, 1)
            res.total_ms = (time.perf_counter() - t_start) * 1e3
            return res
        n_in = finest_acc[kernels.ACC_N]
        n_good, n_bad = finest_acc[kernels.ACC_GOOD], finest_acc[kernels.ACC_BAD]
        res.points_used = int(n_in)
        res.inside_ratio = float(n_in / max(lv.num_pixels, 1))
        res.good_ratio = float(n_good / max(n_good + n_bad, 1.0))
        res.residual = finest_err
        res.mean_abs_residual = float(finest_acc[kernels.ACC_ABS_R] / max(n_in, 1.0))
        if np.all(np.isfinite(T)):
            res.T_ref_new = inverse_se3(project_to_se3(T))
        if not np.all(np.isfinite(T)):
            res.lost_reason = "non-finite pose"
        elif res.inside_ratio < c.min_inside_ratio:
            res.lost_reason = "too few points inside the image"
        elif res.good_ratio < c.min_good_ratio:
            res.lost_reason = "too few good residuals"
        elif c.max_abs_residual > 0 and not res.mean_abs_residual <= c.max_abs_residual:
            res.lost_reason = "residual too large"
        res.lost = bool(res.lost_reason)
        res.total_ms = (time.perf_counter() - t_start) * 1e3
        return res
