"""Trajectory pictures as evo users expect them: the estimate against the ground truth seen from
above (after the alignment of the evaluation), the translational and rotational error of every
pose over time, and the numbers (ATE, RPE, rotation drift, scale) in the title.

matplotlib is imported inside the functions (``pip install 'lite-vo[plot]'``; a one-line
MissingExtraError without it) through its object API (``Figure`` + Agg canvas), so the global
pyplot state and the user's backend are never touched. Imports numpy, ``lite_vo.eval`` and the io
data types; never the CLI.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Optional

import numpy as np

from .errors import InputError, MissingExtraError
from .io.types import Trajectory

PLOT_EXTRA_MESSAGE = "plots need matplotlib: pip install 'lite-vo[plot]'"
GT_COLOUR = "#404040"
EST_COLOUR = "#1f77b4"
PLANES = ("xy", "xz", "yz")


def require_matplotlib() -> None:
    """Raise the one-line MissingExtraError when matplotlib is not installed (check it before work)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise MissingExtraError(PLOT_EXTRA_MESSAGE) from None


def _figure(width_px: int, height_px: int, dpi: int):
    require_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def top_view_plane(xyz: np.ndarray) -> str:
    """The two axes along which the positions spread most (e.g. ``"xz"`` for a camera frame with y
    down, ``"xy"`` for a z-up world): a top view whatever the world's up axis."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    extent = np.ptp(xyz, axis=0) if len(xyz) else np.zeros(3)
    keep = sorted(np.argsort(-extent, kind="stable")[:2])
    return "".join("xyz"[k] for k in keep)


def _with_gaps(t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``xy`` with a NaN row where the timestamps jump (lost frames), so no line bridges the gap."""
    if len(t) < 3:
        return xy
    dt = np.diff(t)
    gaps = np.nonzero(dt > 3.0 * np.median(dt))[0]
    return np.insert(xy.astype(np.float64), gaps + 1, np.nan, axis=0) if len(gaps) else xy


def _fmt(v: float, fmt: str) -> str:
    return "n/a" if v is None or not math.isfinite(v) else format(v, fmt)


def eval_title(result, name: str = "") -> str:
    """One or two lines with the numbers of an :class:`~lite_vo.eval.EvalResult`."""
    r = result
    head = f"{name}: " if name else ""
    scale = f", scale {_fmt(r.scale, '.4f')}" if r.align == "sim3" else ""
    return (f"{head}ATE {_fmt(r.ate_rmse_m * 100, '.2f')} cm ({_fmt(r.ate_pct_of_path, '.2f')} % of the "
            f"{_fmt(r.path_length_m, '.2f')} m path), {r.matched_poses} poses, align {r.align}{scale}\n"
            f"RPE ({r.delta_s:g} s) {_fmt(r.rpe_trans_cm_per_s, '.2f')} cm/s ({_fmt(r.rpe_trans_pct, '.1f')} % "
            f"of the motion), rotation drift {_fmt(r.rpe_rot_deg_per_s, '.2f')} deg/s")


def plot_trajectory(gt: Optional[Trajectory], est: Trajectory, path: str | os.PathLike, *, align: str = "sim3",
                    result=None, name: str = "", plane: Optional[str] = None, size_px: tuple = (1500, 1000),
                    dpi: int = 100, delta_s: float = 1.0, max_dt: float = 0.02) -> Path:
    """Write a PNG of ``est`` (``T_world_cam``) into ``path``, exactly ``size_px`` pixels.

    With ground truth: the top view of both after the alignment (``result`` of
    :func:`lite_vo.eval.evaluate`, computed with ``align`` / ``delta_s`` / ``max_dt`` when not
    given) and the translational (cm) and rotational (deg) error of each matched pose over time,
    the numbers in the title. Without (``gt=None``): the estimate's top view alone (map units).
    ``plane``: ``"xy"``, ``"xz"`` or ``"yz"``; default :func:`top_view_plane` of the ground
    truth poses matched with the estimate (else the estimate). The ground truth outside the
    estimate's time span (+-1 s) is drawn faintly."""
    from .eval import evaluate, pose_errors
    path = Path(path)
    if plane is not None and plane not in PLANES:
        raise InputError(f"unknown plot plane {plane!r} (use one of {', '.join(PLANES)})")
    if len(est) == 0:
        raise InputError(f"{name or 'estimate'}: the trajectory is empty, nothing to plot")
    w, h = (int(v) for v in size_px)
    fig = _figure(w, h, dpi)
    if gt is not None:
        if result is None:
            result = evaluate(gt, est, align=align, delta_s=delta_s, max_dt=max_dt)
        err = pose_errors(gt, est, result)
        S = np.asarray(result.T_gt_est)
        est_xyz = est.positions_xyz @ S[:3, :3].T + S[:3, 3]
        t0 = min(float(gt.timestamps[0]), float(est.timestamps[0]))
        ref = err.gt_xyz
        axes = fig.subplot_mosaic([["top", "trans"], ["top", "rot"]], width_ratios=[1.15, 1.0])
        top, unit = axes["top"], "m"
        fig.suptitle(eval_title(result, name), fontsize=12)
    else:
        est_xyz = est.positions_xyz
        ref = est_xyz
        top, unit = fig.subplots(1, 1), "map units"
        fig.suptitle(f"{name + ': ' if name else ''}{len(est)} poses, path {_fmt(est.path_length(), '.3f')} {unit} "
                     "(no ground truth)", fontsize=12)
    plane = plane or top_view_plane(ref)
    a, b = ("xyz".index(plane[0]), "xyz".index(plane[1]))
    if gt is not None:  # the whole ground truth faint, the part the estimate covers (+-1 s) dashed
        g = gt.positions_xyz[:, [a, b]]
        top.plot(*_with_gaps(gt.timestamps, g).T, color=GT_COLOUR, lw=1.0, alpha=0.3)
        span = (gt.timestamps >= est.timestamps[0] - 1.0) & (gt.timestamps <= est.timestamps[-1] + 1.0)
        top.plot(*_with_gaps(gt.timestamps[span], g[span]).T, color=GT_COLOUR, lw=1.5, ls="--", label="ground truth")
    e = est_xyz[:, [a, b]]
    top.plot(*_with_gaps(est.timestamps, e).T, color=EST_COLOUR, lw=2.0,
             label=f"estimate ({result.align} aligned)" if gt is not None else "estimate")
    top.plot(*e[0], marker="o", color=EST_COLOUR, ms=7, ls="none", label="start")
    top.set_xlabel(f"{plane[0]} [{unit}]")
    top.set_ylabel(f"{plane[1]} [{unit}]")
    top.set_aspect("equal", adjustable="datalim")
    top.grid(True, alpha=0.3)
    top.legend(loc="best", fontsize=9)
    top.set_title(f"top view ({plane[0]}-{plane[1]} plane)", fontsize=10)
    if gt is not None:
        tt = err.timestamps - t0
        for key, values, label in (("trans", err.trans_err_m * 100.0, "translation error [cm]"),
                                   ("rot", err.rot_err_deg, "rotation error [deg]")):
            ax = axes[key]
            ax.plot(*_with_gaps(err.timestamps, np.stack([tt, values], 1)).T, color=EST_COLOUR, lw=1.5)
            ax.axhline(float(np.sqrt(np.mean(values ** 2))), color="#d62728", lw=1, ls=":", label="RMSE")
            ax.set_ylabel(label)
            ax.set_ylim(bottom=0)
            ax.grid(True, alpha=0.3)
            ax.legend(loc="upper left", fontsize=9)
        axes["rot"].set_xlabel("time [s]")
        axes["trans"].set_title("absolute error of each pose after alignment", fontsize=10)
    try:
        fig.savefig(path, dpi=dpi)
    except OSError as err_:
        raise InputError(f"{path}: cannot write the plot ({err_.strerror or err_})") from None
    return path
