"""The initialisation study of thesis chapter 5.4 (Fig. 5.8): random-init runs on sub-sequences.

:func:`plan_init_study` spreads ``n`` sub-sequences over a sequence (one seed each),
:func:`judge_init_run` applies the chapter-5.4 success test to a run's record (depth error after
3 s, final relative drift) and adds its errors over time, :func:`summarise_init_study` gives the
success rate and the mean errors over time.

Imports: numpy, the standard library, ``lite_vo.errors``, ``lite_vo.eval`` and
``lite_vo.profiling.sweep``; ``lite_vo.io`` lazily.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputError
from ..eval import relative_drift
from .sweep import RunSpec

#: Initialisation success criterion (thesis chapter 5.4).
INIT_DEPTH_ERROR_MAX = 0.16      # mean relative depth error after INIT_DEPTH_AT_S seconds
INIT_DEPTH_AT_S = 3.0
INIT_DRIFT_MAX = 0.60            # final relative translational drift
INIT_DRIFT_FRAMES = 15           # ... computed over this many frames
INIT_ERROR_WINDOW_S = 0.5        # tracking error over time: drift per 0.5 s relative to the distance


def _comment_free_lines(path: Path) -> list[str]:
    return [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def frame_timestamps(sequence: str | os.PathLike) -> np.ndarray:
    """Timestamps of a sequence's frames (``rgb.txt``, EuRoC ``cam0/data.csv``, else by reading it)."""
    p = Path(sequence)
    if (p / "rgb.txt").is_file():
        return np.asarray([float(ln.split()[0]) for ln in _comment_free_lines(p / "rgb.txt")])
    for csv in (p / "mav0" / "cam0" / "data.csv", p / "cam0" / "data.csv"):
        if csv.is_file():
            return np.asarray([int(ln.split(",")[0]) * 1e-9 for ln in _comment_free_lines(csv)])
    from ..io import open_sequence
    seq = open_sequence(p)
    ts = getattr(seq, "timestamps", None)
    if ts is not None:
        return np.asarray(ts, float)
    return np.asarray([fr.timestamp for fr in seq], float)


def plan_init_study(sequence: str, seq_name: str, n: int, length_s: float, out_dir: Path,
                    profile: str = "phone", pin_core: bool = False,
                    timestamps: np.ndarray | None = None, overrides: tuple[str, ...] = (),
                    calib: str | None = None) -> list[RunSpec]:
    """``n`` random-init sub-sequences of ``length_s`` seconds from evenly spaced start frames.

    Sub-sequence i starts at frame ``s_i`` (evenly spread over the frames that leave
    ``length_s`` seconds after them) and uses seed ``i + 1``. Every mapped frame is compared with
    the depth images (``system.depth_eval_every=1``): the criterion reads the map at a given time.
    """
    if n < 1:
        raise InputError("--init-study: need at least 1 sub-sequence")
    ts = frame_timestamps(sequence) if timestamps is None else np.asarray(timestamps, float)
    if len(ts) < 2:
        raise InputError(f"{sequence}: too few frames for an initialisation study")
    last_start = int(np.searchsorted(ts, ts[-1] - length_s, side="right")) - 1
    if last_start < 0:
        raise InputError(f"{sequence}: shorter ({ts[-1] - ts[0]:.1f} s) than --init-study-len {length_s} s")
    starts = np.unique(np.round(np.linspace(0, last_start, n)).astype(int))
    specs = []
    for i in range(n):
        s = int(starts[i % len(starts)])
        m = int(np.searchsorted(ts, ts[s] + length_s, side="right") - s)
        specs.append(RunSpec(sequence=sequence, seq_name=seq_name, profile=profile, rep=i,
                             out_dir=out_dir / seq_name / f"{i:03d}", init="random",
                             max_frames=max(m, 2), start_frame=s, seed=i + 1, pin_core=pin_core,
                             kind="init", overrides=("system.depth_eval_every=1", *overrides), calib=calib))
    return specs


def depth_error_at(rec: dict, depth_at_s: float) -> tuple[float | None, float | str | None]:
    """``(error, at)``: the run's depth error at ``depth_at_s`` seconds from its per-frame series
    (the last entry at or before that time), else its final value (``at == "end"``)."""
    series = rec.get("depth_series") or []
    if series:
        before = [x for x in series if x["t"] <= depth_at_s + 1e-6]
        pick = before[-1] if before else series[0]
        return float(pick["median_abs_rel_error"]), float(pick["t"])
    da = rec.get("depth_accuracy")
    if isinstance(da, dict) and da.get("median_abs_rel_error") is not None:
        return float(da["median_abs_rel_error"]), "end"
    return None, None


def drift_of_run(rec: dict, gt, drift_frames: int, window_s: float) -> tuple[float | None, dict | None]:
    """``(final drift over drift_frames frames, drift series per window_s)`` of a run's trajectory,
    with the Sim(3) scale of its evaluation; ``(None, None)`` without trajectory or ground truth."""
    from ..io import read_trajectory
    try:
        est = read_trajectory(Path(rec["dir"]) / "trajectory.txt")
    except Exception:  # noqa: BLE001 - judged as "no drift"
        return None, None
    if gt is None or len(est) <= drift_frames:
        return None, None
    scale = float((rec.get("eval") or {}).get("scale") or 1.0)
    _, e = relative_drift(gt, est, scale, window_frames=drift_frames)
    ts, es = relative_drift(gt, est, scale, window_s=window_s)
    return (float(e[-1]) if len(e) else None), {"t": ts.tolist(), "error": es.tolist()}


def judge_init_run(rec: dict, gt, depth_at_s: float = INIT_DEPTH_AT_S,
                   depth_max: float = INIT_DEPTH_ERROR_MAX, drift_max: float = INIT_DRIFT_MAX,
                   drift_frames: int = INIT_DRIFT_FRAMES, window_s: float = INIT_ERROR_WINDOW_S) -> dict:
    """Add the chapter-5.4 success test and the error-over-time series to an init-study record.

    Depth error: :func:`depth_error_at`. Drift: relative translational drift over the last
    ``drift_frames`` frames, with the Sim(3) scale of the evaluation (:func:`drift_of_run`).
    """
    out = dict(rec)
    out.update(depth_error=None, depth_error_at_s=None, final_drift=None, success=False,
               drift_series=None, init_reason="")
    if rec["status"] == "crash":
        out["init_reason"] = "crashed"
        return out
    out["depth_error"], out["depth_error_at_s"] = depth_error_at(rec, depth_at_s)
    out["final_drift"], out["drift_series"] = drift_of_run(rec, gt, drift_frames, window_s)
    reasons = []
    if out["depth_error"] is None:
        reasons.append("no depth error (sequence without depth?)")
    elif out["depth_error"] > depth_max:
        reasons.append(f"depth error {out['depth_error']:.0%} > {depth_max:.0%}")
    if out["final_drift"] is None:
        reasons.append("no drift (trajectory too short or no ground truth)")
    elif out["final_drift"] > drift_max:
        reasons.append(f"drift {out['final_drift']:.0%} > {drift_max:.0%}")
    if rec["status"] == "fail" and "lost" in rec.get("reason", ""):
        reasons.append(rec["reason"])
    out["success"] = not reasons
    out["init_reason"] = "; ".join(reasons)
    return out


def binned_mean(samples: list[tuple[np.ndarray, np.ndarray]], bin_s: float, t_max: float) -> dict:
    """Mean over runs of each run's mean error in ``bin_s``-second bins from 0 to ``t_max``."""
    edges = np.arange(0.0, t_max + bin_s, bin_s)
    rows = []
    for a, b in zip(edges[:-1], edges[1:]):
        vals = [float(np.mean(e[(t >= a) & (t < b)])) for t, e in samples if ((t >= a) & (t < b)).any()]
        rows.append({"t0": float(a), "t1": float(b), "mean": float(np.mean(vals)) if vals else None,
                     "n": len(vals)})
    return {"bin_s": bin_s, "bins": rows}


def errors_over_time(runs: list[dict], bin_s: float) -> tuple[dict | None, dict | None]:
    """Binned mean depth error and tracking error over time of some runs (None without data)."""
    t_max = 0.0
    depth_samples, drift_samples = [], []
    for r in runs:
        if r.get("depth_series"):
            t = np.array([x["t"] for x in r["depth_series"]], float)
            e = np.array([x["median_abs_rel_error"] for x in r["depth_series"]], float)
            depth_samples.append((t, e))
            t_max = max(t_max, float(t.max()))
        if r.get("drift_series") and r["drift_series"]["t"]:
            t = np.array(r["drift_series"]["t"], float)
            drift_samples.append((t, np.array(r["drift_series"]["error"], float)))
            t_max = max(t_max, float(t.max()))
    return (binned_mean(depth_samples, bin_s, t_max) if depth_samples else None,
            binned_mean(drift_samples, bin_s, t_max) if drift_samples else None)


def summarise_init_study(records: Sequence[dict], bin_s: float = INIT_ERROR_WINDOW_S) -> dict:
    """Success rate and mean depth / tracking error over time of the successful runs (and of all
    runs that did not crash)."""
    n = len(records)
    ok = [r for r in records if r.get("success")]
    depth_ok, drift_ok = errors_over_time(ok, bin_s)
    depth_all, drift_all = errors_over_time([r for r in records if r["status"] != "crash"], bin_s)
    return {
        "runs": n, "successes": len(ok), "success_rate": (len(ok) / n) if n else None,
        "crashed": sum(r["status"] == "crash" for r in records),
        "criterion": {"depth_error_max": INIT_DEPTH_ERROR_MAX, "depth_at_s": INIT_DEPTH_AT_S,
                      "drift_max": INIT_DRIFT_MAX, "drift_frames": INIT_DRIFT_FRAMES},
        "depth_error_over_time": depth_ok, "tracking_error_over_time": drift_ok,
        "depth_error_over_time_all": depth_all, "tracking_error_over_time_all": drift_all,
    }
