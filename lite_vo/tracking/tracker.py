"""Tracker: coarse-to-fine direct SE(3) alignment of a new frame against a TrackingReference.

The tracker estimates ``T_new_ref`` internally (reference points warped into the new image, cheap
Jacobians at the warped point) and returns ``T_ref_new`` (its inverse), as the API contract says.
Owned by the tracking thread (its scratch buffers are not thread-safe: one Tracker per thread).
Imports numpy, :mod:`lite_vo.image`, :mod:`lite_vo.geometry` and the tracking kernels only.
"""
from __future__ import annotations

import itertools
import math
import statistics
import time
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from ..camera import PinholeIntrinsics
from ..geometry import exp_se3, exp_so3, inverse_se3, log_se3, make_pose, project_to_se3
from ..image import bspline_horizon, gaussian_blur, gaussian_kernel
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
    ``|I_new - (a I_ref + b)|`` there (grey levels); ``affine``: ``(a, b)`` with
    ``I_new = a * I_ref + b`` (relative to the reference frame); ``residual_sigma``: robust std
    (1.4826 MAD) of the finest level's residuals (grey levels at the tracking level);
    ``residual_spread``: their mean absolute deviation from the median (the lost test's measure: a
    common brightness offset does not count, a wrong alignment or another scene does);
    ``noise_sigma``: the image noise that explains it at the mapping resolution (grey levels; the
    residual std divided by the noise gain of the tracking pyramid, smoothing and both images);
    ``sigma_i``: the intensity noise std the weights used; ``lost_reason``: '' or why.
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
    residual_spread: float = float("nan")   # mean |r - median(r)|: the residual without a common offset
    residual_sigma: float = float("nan")
    noise_sigma: float = float("nan")
    sigma_i: float = float("nan")
    total_ms: float = 0.0
    coarse_err: float = float("nan")   # final mean energy on the coarsest level used
    hypothesis: str = ""               # with motion hypotheses: the one that won ("first": the first guess)

    def quality(self) -> dict:
        """Scalar quality numbers as a plain dict (for logs and FrameResult.quality)."""
        return {"residual": self.residual, "mean_abs_residual": self.mean_abs_residual,
                "residual_spread": self.residual_spread, "good_ratio": self.good_ratio, "inside_ratio": self.inside_ratio,
                "points_used": self.points_used, "lost": self.lost, "lost_reason": self.lost_reason,
                "affine_a": self.affine[0], "affine_b": self.affine[1], "residual_sigma": self.residual_sigma,
                "noise_sigma": self.noise_sigma, "track_ms": self.total_ms}


def tracking_params(c: TrackingConfig) -> np.ndarray:
    """The float64 parameter vector of the tracking kernels (layout: ``_kernels.TP_*``), built once
    per configuration."""
    p = np.zeros(kernels.TP_N, np.float64)
    p[kernels.TP_SIGMA_I2] = c.sigma_i * c.sigma_i
    p[kernels.TP_HUBER] = c.huber
    p[kernels.TP_AFF_PRIOR_A] = c.affine_prior_a
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
    p[kernels.TP_AFF_PRIOR_B] = c.affine_prior_b
    p[kernels.TP_SATURATION] = c.saturation
    return p


def _rotation_directions() -> list[np.ndarray]:
    """The 26 unit directions of the 3x3x3 cube around the origin (DSO's rotation tries)."""
    out = []
    for d in itertools.product((-1.0, 0.0, 1.0), repeat=3):
        if any(d):
            v = np.array(d)
            out.append(v / np.linalg.norm(v))
    return out


_DIRECTIONS = _rotation_directions()


def motion_hypotheses(T_ref_last: np.ndarray, velocity: np.ndarray, rotation_rad: float) -> list[tuple[str, np.ndarray]]:
    """Starting guesses ``T_ref_new`` for the wide basin, in the order they are tried: constant
    velocity, 2x, 0.5x, zero motion (the last pose), the reference's own pose ("keyframe"), then
    rotations by ``rotation_rad`` in 26 directions about the constant-velocity guess."""
    xi = log_se3(velocity)
    cv = T_ref_last @ velocity
    out = [("velocity", cv), ("velocity_x2", T_ref_last @ exp_se3(2.0 * xi)),
           ("velocity_x0.5", T_ref_last @ exp_se3(0.5 * xi)), ("zero_motion", T_ref_last.copy()),
           ("keyframe", np.eye(4))]
    if rotation_rad > 0:
        out += [(f"rotation_{i}", cv @ make_pose(exp_so3(rotation_rad * d), np.zeros(3)))
                for i, d in enumerate(_DIRECTIONS)]
    return out


def _residual_spread(r: np.ndarray) -> tuple[float, float]:
    """Of every 4th residual: (1.4826 * median absolute deviation, mean absolute deviation from the
    median); both ignore a common offset (a global brightness change). NaN when fewer than 8."""
    r = r[::4]
    if r.size < 8:
        return float("nan"), float("nan")
    dev = np.abs(r - _sorted_median(np.sort(r)))
    return float(1.4826 * _sorted_median(np.sort(dev))), float(np.mean(dev))


def _sorted_median(s: np.ndarray) -> float:
    """Median of an already sorted 1-D array of finite values: the same value as ``np.median`` (the middle
    element, or the two middle ones summed and halved), without its per-call overhead (tracking hot path)."""
    k = s.size // 2
    return s[k] if s.size % 2 else (s[k - 1] + s[k]) / 2


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
        self._frame_params = self._params.copy()          # per frame: sigma_i may follow the noise
        self._img3 = [None] * self.pyramid_levels         # per level: the new image's interpolation stack
        self._smoothed = [None] * self.pyramid_levels     # per level: the new image after the reference's blur
        self._shapes = [(k.height, k.width) for k in self._intr]
        self._T = np.empty((4, 4))                        # T_new_ref, handed from level to level
        self._horizon = bspline_horizon()
        self._noise_gains: dict = {}
        self._acc = np.zeros(kernels.ACC_SIZE)
        self._T_out = np.empty((4, 4))
        self._aff = np.empty(2)
        self._aff_out = np.empty(2)
        self._stats = np.zeros(kernels.ST_SIZE)
        self._buf = np.empty((kernels.BUF_ROWS, 1024))
        modes = {"bspline": kernels.INTERP_BSPLINE, "bilinear": kernels.INTERP_BILINEAR}
        self._recent_coarse: deque = deque(maxlen=max(int(config.hypothesis_window), 1))
        self.hypothesis_counts: Counter = Counter()   # which hypothesis won, over the tracker's life
        self.hypothesis_frames = 0                    # frames on which the hypotheses were tried
        self._interp_fine = modes[config.interpolation]
        self._interp_coarse = modes[config.interpolation_coarse]
        if kernels.INTERP_BSPLINE in (self._interp_fine, self._interp_coarse) and config.border_px < 1.0:
            raise ValueError("tracking.border_px must be >= 1 with bspline interpolation")

    def _max_iter(self, lvl: int) -> int:
        c = self.config
        d = lvl - self.track_level
        return c.max_iter_finest if d == 0 else c.max_iter_coarse if d == 1 else c.max_iter_coarsest

    def noise_gain(self, smooth_sigma: float) -> float:
        """Std of white image noise (mapping resolution) after the tracking pyramid's box averages and
        the reference's Gaussian smoothing, at the finest tracking level, relative to the input std."""
        g = self._noise_gains.get(smooth_sigma)
        if g is None:
            g = 0.5 ** self.track_level
            if smooth_sigma > 0:
                g *= float(np.sum(gaussian_kernel(smooth_sigma) ** 2))
            self._noise_gains[smooth_sigma] = g
        return g

    def track(self, ref: TrackingReference, image_pyr_new, T_ref_new_guess, affine_guess=(1.0, 0.0),
              sigma_i: float | None = None, motion: tuple | None = None, fix_affine: bool = False) -> TrackingResult:
        """Align ``image_pyr_new`` (float32 pyramid, level 0 = mapping resolution) to ``ref``.

        ``affine_guess``: starting ``(a, b)`` of ``I_new = a I_ref + b`` (kept fixed when
        ``affine_brightness`` is off, or for this call with ``fix_affine``: a brightness measured
        elsewhere); ``sigma_i``: intensity noise std of the weights for this frame (None: ``config.sigma_i``).

        ``motion = (T_ref_last, velocity)`` (the last frame's pose in the reference and the last
        frame-to-frame motion ``T_last_new``) enables the wide basin: when tracking from
        ``T_ref_new_guess`` is lost or its coarsest-level energy exceeds both ``hypothesis_min_energy``
        and ``hypothesis_residual_factor`` times the recent frames' median, the :func:`motion_hypotheses`
        are tried on the coarsest level and the first one whose energy is acceptable (else the lowest)
        is tracked to the finest level; it replaces a lost first result, or a tracked one whose residual
        it beats by the factor ``hypothesis_improvement`` (``result.hypothesis`` says which won)."""
        prm = self._frame_params
        enabled = prm[kernels.TP_AFF_ENABLED]
        if fix_affine:
            prm[kernels.TP_AFF_ENABLED] = 0.0
        try:
            return self._track(ref, image_pyr_new, T_ref_new_guess, affine_guess, sigma_i, motion)
        finally:
            prm[kernels.TP_AFF_ENABLED] = enabled

    def _track(self, ref, image_pyr_new, T_ref_new_guess, affine_guess, sigma_i, motion) -> TrackingResult:
        t_start = time.perf_counter()
        res = self._track_once(ref, image_pyr_new, T_ref_new_guess, affine_guess, sigma_i)
        c = self.config
        if motion is None or not c.motion_hypotheses:
            return res
        if len(self._recent_coarse) < c.hypothesis_min_history:
            # too few recent frames (a new map): "acceptable" is not defined yet, and on a fresh random
            # map some rotation always fits; the first guess only
            if not res.lost and np.isfinite(res.coarse_err):
                self._recent_coarse.append(res.coarse_err)
            return res
        limit = max(c.hypothesis_residual_factor * statistics.median(self._recent_coarse), c.hypothesis_min_energy)
        if not res.lost and res.coarse_err <= limit:
            res.hypothesis = "first"
        else:
            self.hypothesis_frames += 1
            T_last, velocity = (np.asarray(m, dtype=np.float64) for m in motion)
            top = min(self.coarsest, min(len(image_pyr_new), ref.num_levels) - 1)
            best_name, best_T, best_err = None, None, np.inf
            first = np.asarray(T_ref_new_guess, dtype=np.float64)
            for name, T_guess in motion_hypotheses(T_last, velocity, np.radians(c.hypothesis_rotation_deg)):
                if np.allclose(T_guess, first, atol=1e-9):
                    continue                            # that is the first guess
                err = self._coarsest_energy(ref, image_pyr_new, T_guess, affine_guess, top)
                if err < best_err:
                    best_name, best_T, best_err = name, T_guess, err
                if err <= limit:
                    break
            if best_T is not None:
                alt = self._track_once(ref, image_pyr_new, best_T, affine_guess, sigma_i)
                if not alt.lost and (res.lost or alt.residual < c.hypothesis_improvement * res.residual):
                    alt.level_ms = {k: v + res.level_ms.get(k, 0.0) for k, v in alt.level_ms.items()}
                    res, res.hypothesis = alt, best_name
            res.hypothesis = res.hypothesis or "first"
            res.total_ms = (time.perf_counter() - t_start) * 1e3
        if not res.lost:
            self.hypothesis_counts[res.hypothesis] += 1
            if np.isfinite(res.coarse_err):
                self._recent_coarse.append(res.coarse_err)
        return res

    def reset_motion_history(self) -> None:
        """Forget the recent coarsest-level energies (call when the map is replaced)."""
        self._recent_coarse.clear()

    def _coarsest_energy(self, ref, image_pyr_new, T_ref_new_guess, affine_guess, top: int) -> float:
        """Final mean energy of an alignment on level ``top`` only, from ``T_ref_new_guess``
        (the new image's level must already be prepared by :meth:`_track_once`)."""
        lv = ref.levels[top]
        if lv.num_points < self.config.min_points or self._img3[top] is None:
            return np.inf
        T = np.ascontiguousarray(inverse_se3(project_to_se3(np.asarray(T_ref_new_guess, dtype=np.float64))))
        aff = np.array([float(affine_guess[0]), float(affine_guess[1])])
        if not (np.isfinite(aff[0]) and aff[0] > 0 and np.isfinite(aff[1])):
            aff[:] = (1.0, 0.0)
        interp = self._interp_fine if top == self.track_level else self._interp_coarse
        kernels.lm_level(lv.points, self._img3[top], interp, T, self._cams[top], self._frame_params,
                         self._max_iter(top), aff, self._buf, self._T_out, self._acc, self._aff_out, self._stats)
        err = float(self._stats[kernels.ST_ERR])
        if int(self._stats[kernels.ST_STATUS]) == 1 or not np.isfinite(err):
            return np.inf
        return err

    def _track_once(self, ref: TrackingReference, image_pyr_new, T_ref_new_guess, affine_guess,
                    sigma_i) -> TrackingResult:
        t_start = time.perf_counter()
        c = self.config
        prm = self._frame_params
        sig = c.sigma_i if sigma_i is None or not math.isfinite(sigma_i) else max(float(sigma_i), 1e-3)
        prm[kernels.TP_SIGMA_I2] = sig * sig
        guess = np.asarray(T_ref_new_guess, dtype=np.float64)
        if guess.shape != (4, 4) or not np.isfinite(guess).all():
            raise ValueError("T_ref_new_guess must be a finite 4x4 matrix")
        guess = project_to_se3(guess)
        T = self._T                                           # T_new_ref (kernels.track_level updates it)
        T[...] = inverse_se3(guess)
        n_lvl = min(len(image_pyr_new), ref.num_levels)
        top = min(self.coarsest, n_lvl - 1)
        finest = self.track_level
        if finest > top:
            raise ValueError(f"pyramids have {n_lvl} levels, tracking needs level {finest}")
        aff = self._aff
        aff[0], aff[1] = float(affine_guess[0]), float(affine_guess[1])
        if not (math.isfinite(aff[0]) and aff[0] > 0 and math.isfinite(aff[1])):
            aff[0], aff[1] = 1.0, 0.0
        level_ms: dict = {}
        iterations: dict = {}
        acc = self._acc
        stats = self._stats
        smooth = ref.smooth_sigma
        finest_acc = None
        finest_status = 1
        coarse_err = float("nan")
        for lvl in range(top, finest - 1, -1):
            t0 = time.perf_counter()
            lv = ref.levels[lvl]
            n_pts = lv.num_points
            if n_pts < c.min_points and lvl != finest:
                level_ms[lvl] = (time.perf_counter() - t0) * 1e3
                iterations[lvl] = 0
                continue
            img = image_pyr_new[lvl]
            if img.shape != self._shapes[lvl]:
                raise ValueError(f"new image level {lvl} has shape {img.shape}, expected {self._shapes[lvl]}")
            if self._buf.shape[1] < n_pts:
                self._buf = np.empty((kernels.BUF_ROWS, max(n_pts, 2 * self._buf.shape[1])))
            if smooth > 0:
                out = self._smoothed[lvl]
                if out is None:
                    out = self._smoothed[lvl] = np.empty(self._shapes[lvl], np.float32)
                img = gaussian_blur(img, smooth, out=out)
            else:
                img = np.ascontiguousarray(img, dtype=np.float32)
            interp = self._interp_fine if lvl == finest else self._interp_coarse
            img3 = self._img3[lvl]
            channels = 1 if interp == kernels.INTERP_BSPLINE else 3
            if img3 is None or img3.shape[2] != channels:
                img3 = self._img3[lvl] = np.empty(self._shapes[lvl] + (channels,), np.float32)
            status = kernels.track_level(lv.points, img, interp, self._horizon, img3, T, self._cams[lvl], prm,
                                         self._max_iter(lvl), aff, self._buf, self._T_out, acc, self._aff_out, stats)
            iterations[lvl] = int(stats[kernels.ST_ITER])
            if status != 1 and not math.isfinite(coarse_err):
                coarse_err = float(stats[kernels.ST_ERR])
            if lvl == finest:
                finest_acc = acc.copy()
                finest_status = status
                finest_err = float(stats[kernels.ST_ERR])
                finest_sigma, finest_spread = _residual_spread(self._buf[6, :int(stats[kernels.ST_LAST_N])])
            level_ms[lvl] = (time.perf_counter() - t0) * 1e3

        lv = ref.levels[finest]
        res = TrackingResult(T_ref_new=guess.copy(), lost=True, level_ms=level_ms, iterations=iterations,
                             affine=(float(aff[0]), float(aff[1])), sigma_i=sig, coarse_err=coarse_err)
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
        res.residual_sigma = finest_sigma
        res.residual_spread = finest_spread
        res.noise_sigma = finest_sigma / (self.noise_gain(smooth) * math.sqrt(1.0 + aff[0] * aff[0]))
        finite = bool(np.isfinite(T).all())
        if finite:
            res.T_ref_new = inverse_se3(project_to_se3(T))
        res.lost_reason = self.lost_reason(res, finite)
        res.lost = bool(res.lost_reason)
        res.total_ms = (time.perf_counter() - t_start) * 1e3
        return res

    def lost_reason(self, res: TrackingResult, finite: bool = True, check_residual: bool = True,
                    check_gain: bool = True) -> str:
        """The lost test of a result with points on the finest level: the first failed check, or '' when
        it is tracked. ``finite``: whether the pose came out finite; ``check_residual=False`` leaves the
        residual spread out (the caller knows the map's residuals are large by nature); ``check_gain=False``
        the gain's bound (the caller measured the brightness change and held it)."""
        c = self.config
        if not finite:
            return "non-finite pose"
        if res.inside_ratio < c.min_inside_ratio:
            return "too few points inside the image"
        if res.good_ratio < c.min_good_ratio:
            return "too few good residuals"
        if check_residual and c.max_abs_residual > 0 and not res.residual_spread <= c.max_abs_residual:
            return "residual too large"
        if check_gain and not 1.0 / c.max_gain_change <= res.affine[0] <= c.max_gain_change:
            return "implausible brightness change"
        return ""
