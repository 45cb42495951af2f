"""Trajectory evaluation: association by timestamp, SE(3)/Sim(3) alignment (Umeyama), absolute
trajectory error (ATE) and relative pose error per second (RPE, TUM RGB-D benchmark style,
the metric of the thesis' Table 5.1).

Pure computation on :class:`~lite_vo.io.Trajectory` objects: imports numpy, ``lite_vo.geometry``
and the io data types only; never the CLI, plotting or sequence readers' image code.

Definitions (``E`` estimate, ``G`` ground truth, both ``T_world_cam``):

* association: one-to-one, greedy by smallest time difference, pairs within ``max_dt`` seconds;
* alignment ``S = (s, R, t)`` minimising ``sum |p_gt - (s R p_est + t)|^2`` over matched camera
  centres (Umeyama 1991); ``none``: identity; ``se3``: s = 1; ``sim3``: free scale. The scale is
  applied to the estimate's translations before RPE as well;
* ATE RMSE: ``sqrt(mean |p_gt - S(p_est)|^2)`` in metres;
* RPE: for each matched pose i, the matched pose j whose timestamp is closest to ``t_i + delta_s``
  (pairs whose target lies more than ``max_dt`` beyond the end, or whose ``t_j`` is more than
  ``delta_s / 2`` from the target because of a gap, are skipped); error ``inv(G_i^-1 G_j) (E_i^-1 E_j)``; translational
  norm and rotation angle each divided by the actual ``t_j - t_i``; RMSE over pairs, reported in
  cm/s and deg/s. ``motion_cm_per_s`` / ``rot_motion_deg_per_s`` are the mean ground-truth
  speeds over the same pairs, ``rpe_trans_pct = 100 * rpe_trans / motion``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError
from .io.sequences import associate_nearest
from .io.types import Trajectory

ALIGN_MODES = ("none", "se3", "sim3")


def associate(t_est: np.ndarray, t_gt: np.ndarray, max_dt: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Index arrays ``(i_est, i_gt)`` of one-to-one matches within ``max_dt``, sorted by estimate time."""
    match = associate_nearest(t_est, t_gt, max_dt)
    i_est = np.nonzero(match >= 0)[0]
    return i_est, match[i_est]


def umeyama_alignment(src_xyz: np.ndarray, dst_xyz: np.ndarray, with_scale: bool
                      ) -> tuple[float, np.ndarray, np.ndarray]:
    """``(s, R, t)`` minimising ``sum |dst - (s R src + t)|^2`` (Umeyama 1991).

    Degenerate input (fewer than 3 distinct points, collinear points) still gives a minimiser;
    when ``src`` does not move at all the scale is undefined and 1 is returned."""
    src = np.asarray(src_xyz, dtype=np.float64)
    dst = np.asarray(dst_xyz, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) == 0:
        raise ValueError(f"expected two (N, 3) arrays, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = float((xs ** 2).sum(1).mean())
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    if with_scale and var_s > 1e-24:
        s = float(np.trace(np.diag(D) @ S) / var_s)
    else:
        s = 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t


def _rot_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle in radians (accurate near 0 and pi: atan2 of sine and cosine parts)."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    sv = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    return np.arctan2(0.5 * np.linalg.norm(sv, axis=-1), c)


def _nan_to_none(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


@dataclass
class EvalResult:
    """Accuracy of an estimated trajectory against ground truth (see the module docstring)."""
    rpe_trans_cm_per_s: float
    rpe_rot_deg_per_s: float
    ate_rmse_m: float
    scale: float
    matched_poses: int
    rpe_pairs: int
    motion_cm_per_s: float
    rot_motion_deg_per_s: float
    rpe_trans_pct: float
    path_length_m: float
    ate_pct_of_path: float
    ate_mean_m: float
    ate_median_m: float
    ate_max_m: float
    rpe_trans_mean_cm_per_s: float
    rpe_rot_mean_deg_per_s: float
    align: str
    delta_s: float
    max_dt: float
    estimated_poses: int
    gt_poses: int
    T_gt_est: np.ndarray = field(repr=False)        # 4x4 similarity applied to the estimate
    ate_errors_m: np.ndarray = field(repr=False)    # per matched pose
    warnings: list = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-ready dict: the contract keys ``rpe_trans_cm_per_s``, ``rpe_rot_deg_per_s``,
        ``ate_rmse_m``, ``scale``, ``matched_poses`` plus the extras (NaN -> None)."""
        keys = ["rpe_trans_cm_per_s", "rpe_rot_deg_per_s", "ate_rmse_m", "scale", "matched_poses",
                "rpe_pairs", "motion_cm_per_s", "rot_motion_deg_per_s", "rpe_trans_pct", "path_length_m",
                "ate_pct_of_path", "ate_mean_m", "ate_median_m", "ate_max_m", "rpe_trans_mean_cm_per_s",
                "rpe_rot_mean_deg_per_s", "align", "delta_s", "max_dt", "estimated_poses", "gt_poses"]
        d = {k: getattr(self, k) for k in keys}
        d = {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in d.items()}
        d = {k: _nan_to_none(v) for k, v in d.items()}
        d["T_gt_est"] = np.asarray(self.T_gt_est).tolist()
        d["warnings"] = list(self.warnings)
        return d

    def table(self) -> str:
        """A small human-readable table."""
        def f(v, fmt):
            return "n/a" if v is None or not math.isfinite(v) else format(v, fmt)
        scale = f" (scale {self.scale:.4f})" if self.align == "sim3" else ""
        rows = [
            ("matched poses", f"{self.matched_poses} (estimate {self.estimated_poses}, ground truth {self.gt_poses}, "
                              f"max dt {self.max_dt:g} s)"),
            ("alignment", f"{self.align}{scale}"),
            ("ATE RMSE", f"{f(self.ate_rmse_m, '.4f')} m  ({f(self.ate_pct_of_path, '.2f')} % of the "
                         f"{f(self.path_length_m, '.3f')} m path; max {f(self.ate_max_m, '.4f')} m)"),
            ("RPE translation", f"{f(self.rpe_trans_cm_per_s, '.3f')} cm/s  ({f(self.rpe_trans_pct, '.1f')} % of "
                                f"{f(self.motion_cm_per_s, '.2f')} cm/s motion; {self.rpe_pairs} pairs, "
                                f"delta {self.delta_s:g} s)"),
            ("RPE rotation", f"{f(self.rpe_rot_deg_per_s, '.3f')} deg/s  (motion "
                             f"{f(self.rot_motion_deg_per_s, '.2f')} deg/s)"),
        ]
        w = max(len(r[0]) for r in rows)
        out = [f"{k:<{w}}  {v}" for k, v in rows]
        out += [f"warning: {m}" for m in self.warnings]
        return "\n".join(out)


def relative_pairs(t: np.ndarray, delta_s: float, end_tol: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i, j)``: for each i the j with ``t_j`` closest to ``t_i + delta_s``; pairs whose
    target time lies more than ``end_tol`` beyond the last timestamp, or whose ``t_j`` misses the
    target by more than ``delta_s / 2`` (a gap), are left out."""
    t = np.asarray(t, dtype=np.float64)
    n = len(t)
    if n < 2:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    target = t + delta_s
    j = np.clip(np.searchsorted(t, target), 1, n - 1)
    j = np.where(np.abs(t[j - 1] - target) <= np.abs(t[j] - target), j - 1, j)
    i = np.arange(n)
    tol = 1e-6  # seconds: float noise only (a tolerance relative to Unix timestamps would be ~1 s)
    ok = (j > i) & (target <= t[-1] + end_tol + tol) & (np.abs(t[j] - target) <= 0.5 * delta_s + tol)
    return i[ok], j[ok]


def evaluate(gt: Trajectory, est: Trajectory, align: str = "sim3", delta_s: float = 1.0,
             max_dt: float = 0.02) -> EvalResult:
    """Compare ``est`` with ``gt`` (both ``T_world_cam``); see the module docstring for definitions.

    Raises InputError when fewer than 2 poses match (or fewer than 3 with alignment)."""
    if align not in ALIGN_MODES:
        raise InputError(f"unknown alignment {align!r} (use one of {', '.join(ALIGN_MODES)})")
    if not (delta_s > 0) or not (max_dt >= 0):
        raise InputError(f"delta_s must be > 0 and max_dt >= 0 (got {delta_s}, {max_dt})")
    i_est, i_gt = associate(est.timestamps, gt.timestamps, max_dt)
    n = len(i_est)
    need = 3 if align != "none" else 2
    if n < need:
        span = lambda tr: f"{tr.timestamps[0]:.3f}..{tr.timestamps[-1]:.3f} s" if len(tr) else "empty"
        raise InputError(f"only {n} estimated poses match the ground truth within {max_dt:g} s (need {need}; "
                         f"estimate {span(est)}, ground truth {span(gt)})")
    warnings: list[str] = []
    t = est.timestamps[i_est]
    E = est.poses[i_est]
    G = gt.poses[i_gt]
    p_est, p_gt = E[:, :3, 3], G[:, :3, 3]
    if align == "none":
        s, R, tr = 1.0, np.eye(3), np.zeros(3)
    else:
        s, R, tr = umeyama_alignment(p_est, p_gt, with_scale=(align == "sim3"))
        if align == "sim3" and float(((p_est - p_est.mean(0)) ** 2).sum(1).mean()) <= 1e-24:
            warnings.append("the estimate does not move: the Sim(3) scale is undefined (set to 1)")
    S = np.eye(4)
    S[:3, :3] = s * R
    S[:3, 3] = tr
    aligned = p_est @ (s * R).T + tr
    err = np.linalg.norm(p_gt - aligned, axis=1)
    ate_rmse = float(np.sqrt(np.mean(err ** 2)))
    path = float(np.linalg.norm(np.diff(p_gt, axis=0), axis=1).sum()) if n > 1 else 0.0

    # RPE on the scale-corrected estimate (rotation of the alignment cancels in relative motions)
    Es = E.copy()
    Es[:, :3, 3] *= s
    i, j = relative_pairs(t, delta_s, end_tol=max_dt)
    nan = float("nan")
    if len(i) == 0:
        warnings.append(f"no pose pairs {delta_s:g} s apart: RPE undefined (trajectory spans "
                        f"{t[-1] - t[0]:.3f} s)")
        rpe_t = rpe_r = mot_t = mot_r = pct = rpe_t_mean = rpe_r_mean = nan
    else:
        dt = t[j] - t[i]
        E_rel = np.linalg.inv(Es[i]) @ Es[j]
        G_rel = np.linalg.inv(G[i]) @ G[j]
        D = np.linalg.inv(G_rel) @ E_rel
        et = np.linalg.norm(D[:, :3, 3], axis=1) / dt
        er = np.degrees(_rot_angle(D[:, :3, :3])) / dt
        mt = np.linalg.norm(G_rel[:, :3, 3], axis=1) / dt
        mr = np.degrees(_rot_angle(G_rel[:, :3, :3])) / dt
        rpe_t = 100.0 * float(np.sqrt(np.mean(et ** 2)))
        rpe_r = float(np.sqrt(np.mean(er ** 2)))
        rpe_t_mean = 100.0 * float(et.mean())
        rpe_r_mean = float(er.mean())
        mot_t = 100.0 * float(mt.mean())
        mot_r = float(mr.mean())
        pct = 100.0 * rpe_t / mot_t if mot_t > 0 else nan
    return EvalResult(
        rpe_trans_cm_per_s=rpe_t, rpe_rot_deg_per_s=rpe_r, ate_rmse_m=ate_rmse, scale=float(s),
        matched_poses=int(n), rpe_pairs=int(len(i)), motion_cm_per_s=mot_t, rot_motion_deg_per_s=mot_r,
        rpe_trans_pct=pct, path_length_m=path, ate_pct_of_path=100.0 * ate_rmse / path if path > 0 else nan,
        ate_mean_m=float(err.mean()), ate_median_m=float(np.median(err)), ate_max_m=float(err.max()),
        rpe_trans_mean_cm_per_s=rpe_t_mean, rpe_rot_mean_deg_per_s=rpe_r_mean, align=align,
        delta_s=float(delta_s), max_dt=float(max_dt), estimated_poses=len(est), gt_poses=len(gt),
        T_gt_est=S, ate_errors_m=err, warnings=warnings)


@dataclass
class PoseErrors:
    """Per matched pose after the alignment of an :class:`EvalResult` (for plots):
    ``timestamps`` (N,), ``gt_xyz`` and ``est_xyz`` (N, 3) camera centres (estimate aligned),
    ``trans_err_m`` (N,) and ``rot_err_deg`` (N,) (angle of ``R_gt^T R_align R_est``)."""
    timestamps: np.ndarray
    gt_xyz: np.ndarray
    est_xyz: np.ndarray
    trans_err_m: np.ndarray
    rot_err_deg: np.ndarray


def pose_errors(gt: Trajectory, est: Trajectory, result: EvalResult) -> PoseErrors:
    """Absolute translation and rotation error of each matched pose under ``result``'s alignment
    (the same association as :func:`evaluate`)."""
    i_est, i_gt = associate(est.timestamps, gt.timestamps, result.max_dt)
    S = np.asarray(result.T_gt_est)
    R_align = S[:3, :3] / result.scale
    G, E = gt.poses[i_gt], est.poses[i_est]
    est_xyz = E[:, :3, 3] @ S[:3, :3].T + S[:3, 3]
    rot = np.degrees(_rot_angle(np.swapaxes(G[:, :3, :3], -1, -2) @ (R_align @ E[:, :3, :3])))
    return PoseErrors(est.timestamps[i_est], G[:, :3, 3], est_xyz,
                      np.linalg.norm(G[:, :3, 3] - est_xyz, axis=1), rot)


# ----------------------------------------------------------------------------------------------
# Relative drift over a window (thesis Fig. 5.8; the initialisation study of lite_vo.profiling)
# ----------------------------------------------------------------------------------------------

def window_pairs(t: np.ndarray, window_s: float = 0.5,
                 window_frames: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(k, j)`` of increasing timestamps ``t``: j is ``window_frames`` poses before k,
    or (without ``window_frames``) the pose whose time is closest to ``t_k - window_s``; pairs whose
    window reaches back before ``t_0`` are left out."""
    t = np.asarray(t, dtype=np.float64)
    k = np.arange(len(t))
    if window_frames is not None:
        k = k[k >= window_frames]
        return k, k - window_frames
    if len(t) < 2:
        return k[:0], k[:0]
    target = t - window_s
    j = np.clip(np.searchsorted(t, target), 1, len(t) - 1)
    j = np.where(np.abs(t[j - 1] - target) <= np.abs(t[j] - target), j - 1, j)
    ok = (target >= t[0] - 1e-9) & (j != k)
    return k[ok], j[ok]


def relative_drift(gt: Trajectory, est: Trajectory, scale: float = 1.0, window_s: float = 0.5,
                   window_frames: int | None = None, min_motion_m: float = 1e-3,
                   max_dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Relative translational drift over a window, per estimated pose (thesis Fig. 5.8).

    For each matched estimated pose k and the pose j one window earlier (:func:`window_pairs`:
    ``window_s`` seconds, or ``window_frames`` poses), the error is
    ``|scale * t(E_j^-1 E_k) - t(G_j^-1 G_k)| / |t(G_j^-1 G_k)|``. Poses are matched within
    ``max_dt`` (default: half the median frame interval, at least 0.02 s). Returns (time since the
    first matched pose, error); pairs whose ground-truth motion is below ``min_motion_m`` are
    skipped (no meaningful relative error).
    """
    empty = (np.zeros(0), np.zeros(0))
    if len(est) < 2 or len(gt) < 2:
        return empty
    if max_dt is None:
        max_dt = max(0.02, 0.5 * float(np.median(np.diff(est.timestamps))))
    i_est, i_gt = associate(est.timestamps, gt.timestamps, max_dt)
    if len(i_est) < 2:
        return empty
    t = est.timestamps[i_est]
    k, j = window_pairs(t, window_s, window_frames)
    E, G = est.poses[i_est], gt.poses[i_gt]
    rel_e = (np.linalg.inv(E[j]) @ E[k])[:, :3, 3]
    rel_g = (np.linalg.inv(G[j]) @ G[k])[:, :3, 3]
    motion = np.linalg.norm(rel_g, axis=1)
    keep = motion >= min_motion_m
    err = np.linalg.norm(scale * rel_e[keep] - rel_g[keep], axis=1) / motion[keep]
    return (t[k] - t[0])[keep], err
