"""PNG plots of a ``lite-vo profile`` report: drift and time per resolution, the initialisation study.

matplotlib is imported inside :func:`figure` only (``pip install lite-vo[plot]``); without it the
plot functions raise :class:`~lite_vo.errors.MissingExtraError` and the report says so.

Imports: numpy, the standard library and ``lite_vo.errors`` at module level.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import MissingExtraError


def figure(*args, **kwargs):
    """A matplotlib Figure on the Agg canvas (no GUI backend, no pyplot state)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise MissingExtraError("plots need matplotlib: pip install 'lite-vo[plot]' "
                                "(or run lite-vo profile with --no-plots)") from None
    fig = Figure(*args, **kwargs)
    FigureCanvasAgg(fig)
    return fig


def _profiles_by_resolution(report: dict) -> tuple[list[str], list[str]]:
    """Profiles from the finest to the coarsest resolution, and their ``map/track`` width labels."""
    res = report["profiles"]
    profiles = sorted(res, key=lambda p: (
        -(res[p].get("map_width") or 0), -(res[p].get("track_width") or 0)))
    return profiles, [res[p].get("label", p) for p in profiles]


def failed_run_points(report: dict, seq_name: str, key: str, profiles: list[str]) -> tuple[list[int], list[float]]:
    """``(profile index, value of key)`` of the failed sweep runs on a sequence that could still be
    evaluated (drawn as crosses)."""
    fx, fy = [], []
    for r in report.get("runs", []):
        if r.get("kind", "sweep") == "sweep" and r["seq_name"] == seq_name and r["status"] == "fail" \
                and r.get("eval") and r["eval"].get(key) is not None and r["profile"] in profiles:
            fx.append(profiles.index(r["profile"]))
            fy.append(r["eval"][key])
    return fx, fy


def plot_accuracy(report: dict, path: Path) -> Path:
    """Drift (cm/s, deg/s) per profile, ordered from the finest to the coarsest resolution."""
    profiles, labels = _profiles_by_resolution(report)
    x = np.arange(len(profiles))
    fig = figure(figsize=(9, 3.6), layout="constrained")
    axes = fig.subplots(1, 2)
    for ax, key, unit in zip(axes, ("rpe_trans_cm_per_s", "rpe_rot_deg_per_s"), ("cm/s", "deg/s")):
        for s, cells in (report.get("accuracy") or {}).items():
            ys, es = [], []
            for p in profiles:
                c = cells.get(p) or {}
                v = c.get(key) if c.get("ok") else None
                ys.append(v["mean"] if v else np.nan)
                es.append(v["std"] if v else 0.0)
            line = ax.errorbar(x, ys, yerr=es, marker="o", capsize=3, label=s)
            fx, fy = failed_run_points(report, s, key, profiles)
            if fx:
                ax.plot(fx, fy, "x", color=line[0].get_color(), markersize=9, label=f"{s}: failed runs")
        ax.set_xticks(x, labels)
        ax.set_xlabel("mapping / tracking width (px)")
        ax.set_ylabel(f"drift ({unit})")
        ax.grid(alpha=0.3)
    axes[0].set_title("translational drift (x: runs that lost tracking)")
    axes[1].set_title("rotational drift")
    axes[0].legend(fontsize=8)
    fig.savefig(path, dpi=110)
    return path


def plot_timing(report: dict, path: Path) -> Path:
    """Tracking and mapping ms (mean ± std) per profile, finest resolution first."""
    profiles, labels = _profiles_by_resolution(report)
    x = np.arange(len(profiles))
    fig = figure(figsize=(6.5, 3.8), layout="constrained")
    ax = fig.subplots()
    w = 0.38
    for off, key, color in ((-w / 2, "tracking", "tab:blue"), (w / 2, "mapping", "tab:orange")):
        vals = [((report.get("timing") or {}).get(p) or {}).get(key) for p in profiles]
        means = np.array([v["mean"] if v else 0.0 for v in vals])
        stds = np.array([v["std"] if v else 0.0 for v in vals])
        lower = np.minimum(stds, 0.9 * means)  # log axis: keep the error bar above zero
        ax.bar(x + off, means, w, yerr=[lower, stds], capsize=3, label=f"{key}: mean ± std (ms)", color=color)
        med = [v.get("median") if v else None for v in vals]
        mx = [x[i] + off for i, m in enumerate(med) if m]
        ax.plot(mx, [m for m in med if m], "D", color="white", markeredgecolor="black", markersize=5,
                label="median" if key == "mapping" else None)
    ax.set_xticks(x, labels)
    ax.set_xlabel("mapping / tracking width (px)")
    ax.set_ylabel("ms per frame / per mapping iteration")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, axis="y")
    ax.legend()
    fig.savefig(path, dpi=110)
    return path


def plot_init_study(report: dict, path: Path) -> Path:
    """Fig. 5.8: depth and tracking error over time, all successful runs (grey) and their mean."""
    runs = [r for r in report.get("runs", []) if r.get("kind") == "init" and r.get("status") != "crash"]
    fig = figure(figsize=(9, 3.6), layout="constrained")
    axes = fig.subplots(1, 2)
    for r in runs:
        style = dict(color="0.65", lw=0.8) if r.get("success") else dict(color="0.85", lw=0.8, ls=":")
        if r.get("depth_series"):
            axes[0].plot([x["t"] for x in r["depth_series"]],
                         [x["median_abs_rel_error"] for x in r["depth_series"]], **style)
        if r.get("drift_series") and r["drift_series"]["t"]:
            axes[1].plot(r["drift_series"]["t"], r["drift_series"]["error"], **style)
    for s, v in (report.get("init_study") or {}).items():
        for ax, key in ((axes[0], "depth_error_over_time"), (axes[1], "tracking_error_over_time")):
            for suffix, color, ls, what in (("", "tab:blue", "-", "successful"), ("_all", "tab:red", "--", "all")):
                d = v.get(key + suffix)
                if d:
                    t = [(b["t0"] + b["t1"]) / 2 for b in d["bins"] if b["mean"] is not None]
                    m = [b["mean"] for b in d["bins"] if b["mean"] is not None]
                    ax.plot(t, m, color=color, ls=ls, lw=2, label=f"mean of {what} runs ({s})")
    axes[0].set_title("relative depth error")
    axes[1].set_title("tracking error (drift per 0.5 s / distance)")
    for ax in axes:
        ax.set_xlabel("time since start (s)")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    axes[1].set_yscale("log")
    if not runs:
        axes[0].text(0.5, 0.5, "no run finished", ha="center", transform=axes[0].transAxes)
    fig.savefig(path, dpi=110)
    return path


def make_plots(report: dict, out: Path) -> list[Path]:
    paths = []
    if report.get("accuracy") is not None:
        paths.append(plot_accuracy(report, out / "accuracy_vs_resolution.png"))
        paths.append(plot_timing(report, out / "time_vs_resolution.png"))
    if report.get("init_study"):
        paths.append(plot_init_study(report, out / "init_study.png"))
    return paths
