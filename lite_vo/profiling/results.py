"""Judging the runs of a sweep and pooling them into the tables of the report.

:func:`collect_run` reads one run folder (the file contract of ARCHITECTURE.md), evaluates its
trajectory against the ground truth and says whether the run is ``ok``, ``fail`` or ``crash``;
:func:`aggregate` pools the records into accuracy per (sequence, profile) and timing and
per-stage timing per profile (thesis Tables 5.1 and 5.2).

Imports: numpy, the standard library and ``lite_vo.profiling`` at module level; ``lite_vo.io``
and ``lite_vo.eval`` lazily.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from .profiles import profile_label
from .sweep import RunOutcome, RunSpec

#: Files a finished run must have written.
RUN_FILES: tuple[str, ...] = ("trajectory.txt", "timing.json", "run.json")

#: run.json statuses of a run that finished tracking (losses are judged from the frame counts).
OK_STATUSES: tuple[str, ...] = ("ok", "ok_with_losses")

#: Evaluation numbers averaged over the successful repetitions of a cell of the accuracy table.
ACCURACY_KEYS = ("rpe_trans_cm_per_s", "rpe_rot_deg_per_s", "ate_rmse_m", "rpe_trans_pct", "scale")


# ----------------------------------------------------------------------------------------------
# Sequences
# ----------------------------------------------------------------------------------------------

def load_groundtruth(sequence: str | os.PathLike):
    """Ground truth of a sequence (a :class:`lite_vo.io.Trajectory`): ``groundtruth.txt`` in the
    folder, else ``open_sequence(...).groundtruth`` (None when there is none)."""
    from ..io import open_sequence, read_trajectory
    p = Path(sequence)
    gt_file = p / "groundtruth.txt"
    if gt_file.is_file():
        return read_trajectory(gt_file)
    return open_sequence(p).groundtruth


def sequence_has_depth(sequence: str | os.PathLike) -> bool | None:
    """Does a TUM-layout sequence have depth images? (None: not a TUM-layout folder.)"""
    p = Path(sequence)
    if (p / "depth.txt").is_file() or (p / "depth").is_dir():
        return True
    if (p / "rgb.txt").is_file():
        return False
    return None


# ----------------------------------------------------------------------------------------------
# One run
# ----------------------------------------------------------------------------------------------

def read_json_object(path: Path) -> dict:
    """A JSON file holding an object (ValueError when it holds anything else)."""
    with open(path, encoding="utf-8") as fh:
        data = json.load(fh)
    if not isinstance(data, dict):
        raise ValueError("not a JSON object")
    return data


def run_is_metric(run_json: dict, sequence: str | None = None) -> bool:
    """Was the run depth-initialised (metric scale)? Decides se3 vs sim3 alignment."""
    for key in ("metric", "metric_scale"):
        if isinstance(run_json.get(key), bool):
            return run_json[key]
    for key in ("init_used", "init"):
        v = run_json.get(key)
        if v in ("depth", "random"):
            return v == "depth"
    cfg = run_json.get("config") or {}
    init = (cfg.get("system") or {}).get("init") if isinstance(cfg, dict) else None
    if init in ("depth", "random"):
        return init == "depth"
    if sequence is not None:
        return bool(sequence_has_depth(sequence))
    return False


def _depth_series_candidates(run_json: dict, run_dir: Path | None) -> list:
    """Where a run may have stored its per-frame depth accuracy, in order of preference."""
    candidates = []
    if run_dir is not None and (Path(run_dir) / "depth_accuracy.json").is_file():
        try:
            with open(Path(run_dir) / "depth_accuracy.json", encoding="utf-8") as fh:
                candidates.append(json.load(fh))
        except (OSError, ValueError):
            pass
    candidates.append(run_json.get("depth_accuracy_series"))
    da = run_json.get("depth_accuracy") or {}
    if isinstance(da, dict):
        candidates += [da.get("series"), da.get("frames")]
    return candidates


def _usable_depth_entry(x: dict) -> dict | None:
    """An entry with the scale-aligned error (when present) as ``median_abs_rel_error``; None when
    it has no time or no finite error."""
    x = dict(x)
    if x.get("median_abs_rel_error_aligned") is not None:
        x["median_abs_rel_error_raw"] = x.get("median_abs_rel_error")
        x["median_abs_rel_error"] = x["median_abs_rel_error_aligned"]
    e = x.get("median_abs_rel_error")
    return x if "t" in x and isinstance(e, (int, float)) and math.isfinite(e) else None


def depth_error_series(run_json: dict, run_dir: Path | None = None) -> list[dict]:
    """Per-frame depth accuracy ``[{"t": s, "median_abs_rel_error": x, ...}]`` if the run stored it
    (``depth_accuracy.json`` in the run folder, or a list inside ``run.json``), sorted by time.

    When the entries carry a scale-aligned error (``median_abs_rel_error_aligned``, the error
    after choosing the optimal scale, needed for random initialisation), it replaces
    ``median_abs_rel_error`` (the raw value is kept as ``median_abs_rel_error_raw``).
    """
    for c in _depth_series_candidates(run_json, run_dir):
        if isinstance(c, list) and c and all(isinstance(x, dict) for x in c):
            out = [e for e in map(_usable_depth_entry, c) if e is not None]
            if out:
                return sorted(out, key=lambda x: x["t"])
    return []


def _failure_reasons(outcome: RunOutcome, run_json: dict, frames: dict, max_lost_ratio: float) -> list[str]:
    """Why a run that wrote its files still failed (exit status, run status, lost frames)."""
    reasons = []
    if outcome.returncode != 0:
        tail = f": {outcome.stderr_tail}" if outcome.stderr_tail else ""
        reasons.append(f"exit status {outcome.returncode}{tail}")
    if run_json.get("status") is None:
        reasons.append("run.json has no status")
    elif run_json.get("status") not in OK_STATUSES:
        reasons.append(f"status {run_json.get('status')!r}")
    n_in = int(frames.get("in") or 0)
    n_lost = int(frames.get("lost") or 0)
    if n_lost > max_lost_ratio * max(n_in, 1):
        reasons.append(f"tracking lost on {n_lost}/{n_in} frames")
    return reasons


def _evaluate(gt, est, align: str, evaluator: Callable | None, delta_s: float) -> tuple[dict | None, str]:
    """``(evaluation dict, "")`` or ``(None, why not)``."""
    if gt is None:
        return None, "no ground truth"
    if len(est) < 2:
        return None, f"only {len(est)} pose(s) in trajectory.txt"
    try:
        if evaluator is None:
            from ..eval import evaluate as evaluator  # type: ignore[no-redef]
        res = evaluator(gt, est, align=align, delta_s=delta_s)
    except ImportError as err:
        return None, f"evaluation unavailable ({err})"
    except Exception as err:  # noqa: BLE001 - a run we cannot evaluate is a failed run
        return None, f"evaluation failed: {type(err).__name__}: {err}"
    return (res.to_dict() if hasattr(res, "to_dict") else dict(res)), ""


def _run_record(spec: RunSpec, outcome: RunOutcome) -> dict[str, Any]:
    """The record of a run before its files are read (status ``ok`` until proven otherwise)."""
    return {
        "key": spec.key, "kind": spec.kind, "sequence": str(spec.sequence), "seq_name": spec.seq_name,
        "profile": profile_label(spec.profile), "rep": spec.rep, "dir": str(spec.out_dir),
        "start_frame": spec.start_frame, "seed": spec.seed, "returncode": outcome.returncode,
        "wall_s": round(outcome.wall_s, 3), "core": outcome.core, "status": "ok", "reason": "",
        "stderr_tail": outcome.stderr_tail, "timing": None, "frames": None, "run_status": None,
        "depth_accuracy": None, "metric": None, "eval": None,
    }


def _crash_reason(spec: RunSpec, outcome: RunOutcome) -> tuple[str, dict, dict]:
    """``(reason, timing, run_json)``: a non-empty reason when the run's files are missing or unreadable."""
    exit_reason = f"exit status {outcome.returncode}" + (f": {outcome.stderr_tail}" if outcome.stderr_tail else "")
    missing = [f for f in RUN_FILES if not (spec.out_dir / f).is_file()]
    if missing:
        return (exit_reason if outcome.returncode != 0 else f"missing {', '.join(missing)}"), {}, {}
    try:
        return "", read_json_object(spec.out_dir / "timing.json"), read_json_object(spec.out_dir / "run.json")
    except (OSError, ValueError) as err:
        return (exit_reason if outcome.returncode != 0 else f"unreadable timing.json/run.json: {err}"), {}, {}


def collect_run(spec: RunSpec, outcome: RunOutcome, gt=None, evaluator: Callable | None = None,
                max_lost_ratio: float = 0.0, delta_s: float = 1.0) -> dict:
    """Read one run folder and judge it: a JSON-ready record.

    ``status``: ``"crash"`` (non-zero exit, missing or unreadable files), ``"fail"`` (run.json
    status not ok, more than ``max_lost_ratio`` of the frames lost, or nothing to evaluate) or
    ``"ok"``. The trajectory is evaluated against ``gt`` with ``evaluator(gt, est, align=...,
    delta_s=...)`` (default ``lite_vo.eval.evaluate``), SE(3)-aligned for depth-initialised runs
    and Sim(3)-aligned otherwise; evaluation numbers are kept even for failed runs.
    """
    from ..io import read_trajectory
    rec = _run_record(spec, outcome)
    reason, timing, run_json = _crash_reason(spec, outcome)
    if reason:
        rec["status"], rec["reason"] = "crash", reason
        return rec
    # a run that wrote its files and then exited non-zero (e.g. "failed: no frame tracked")
    # is a failed run, judged below from its files
    rec["timing"] = {k: timing.get(k) for k in ("tracking", "mapping", "stages", "wall_s")}
    frames = timing.get("frames") or {}
    rec["frames"] = frames
    rec["run_status"] = run_json.get("status")
    rec["depth_accuracy"] = run_json.get("depth_accuracy")
    rec["depth_series"] = depth_error_series(run_json, spec.out_dir)
    rec["metric"] = run_is_metric(run_json, spec.sequence)
    try:
        est = read_trajectory(spec.out_dir / "trajectory.txt")
    except Exception as err:  # noqa: BLE001
        rec["status"], rec["reason"] = "crash", f"unreadable trajectory.txt: {err}"
        return rec
    rec["poses"] = len(est)
    reasons = _failure_reasons(outcome, run_json, frames, max_lost_ratio)
    rec["align"] = "se3" if rec["metric"] else "sim3"
    rec["eval"], why_not = _evaluate(gt, est, rec["align"], evaluator, delta_s)
    if why_not:
        reasons.append(why_not)
    if reasons:
        rec["status"], rec["reason"] = "fail", "; ".join(reasons)
    return rec


# ----------------------------------------------------------------------------------------------
# Aggregation
# ----------------------------------------------------------------------------------------------

def pool_stats(stats: Iterable[dict | None]) -> dict | None:
    """Combine ``{count, mean, std, ...}`` summaries of several runs exactly (pooled mean/std).

    The median and p95 cannot be pooled exactly: ``median`` is the median of the runs' medians
    and ``p95`` the largest p95.
    """
    items = [s for s in stats if isinstance(s, dict) and (s.get("count") or 0) > 0
             and s.get("mean") is not None]
    if not items:
        return None
    n = np.array([float(s["count"]) for s in items])
    m = np.array([float(s["mean"]) for s in items])
    sd = np.array([float(s.get("std") or 0.0) for s in items])
    total = n.sum()
    mean = float((n * m).sum() / total)
    var = float((n * (sd ** 2 + m ** 2)).sum() / total - mean ** 2)
    out = {"count": int(total), "mean": mean, "std": math.sqrt(max(var, 0.0)), "runs": len(items)}
    med = [s.get("median") for s in items if s.get("median") is not None]
    p95 = [s.get("p95") for s in items if s.get("p95") is not None]
    if med:
        out["median"] = float(np.median(med))
    if p95:
        out["p95"] = float(max(p95))
    return out


def mean_std(values: list[float]) -> dict | None:
    """``{mean, std, n}`` of the values (None when there are none)."""
    if not values:
        return None
    a = np.asarray(values, float)
    return {"mean": float(a.mean()), "std": float(a.std()), "n": len(a)}


def accuracy_cell(runs: list[dict]) -> dict:
    """One cell of the accuracy table: run counts and the mean/std of :data:`ACCURACY_KEYS` over
    the successful runs (``failed`` counts runs that crashed or failed)."""
    good = [r for r in runs if r["status"] == "ok" and r.get("eval")]
    cell: dict[str, Any] = {"runs": len(runs), "ok": len(good), "failed": len(runs) - len(good),
                            "crashed": sum(r["status"] == "crash" for r in runs),
                            "reasons": sorted({r["reason"] for r in runs if r["status"] != "ok"})}
    for k in ACCURACY_KEYS:
        cell[k] = mean_std([float(r["eval"][k]) for r in good if isinstance(r["eval"].get(k), (int, float))
                            and math.isfinite(r["eval"][k])])
    return cell


def pooled_timing(runs: list[dict]) -> dict:
    """Tracking, mapping and per-stage timings pooled over runs, and their wall-clock seconds."""
    usable = [r for r in runs if r.get("timing")]
    stage_names = sorted({n for r in usable for n in ((r["timing"].get("stages") or {}).keys())})
    return {
        "tracking": pool_stats(r["timing"].get("tracking") for r in usable),
        "mapping": pool_stats(r["timing"].get("mapping") for r in usable),
        "stages": {n: pool_stats((r["timing"].get("stages") or {}).get(n) for r in usable)
                   for n in stage_names},
        "runs": len(usable),
        "wall_s": mean_std([float(r["timing"]["wall_s"]) for r in usable if r["timing"].get("wall_s") is not None]),
    }


def aggregate(records: Sequence[dict], profiles: Sequence[str], seq_names: Sequence[str]) -> dict:
    """Accuracy per (sequence, profile), timing and per-stage timing per profile (and per sequence).

    Accuracy cells average the successful repetitions; a cell with no successful run is a
    failure (shown as ``fail``).
    """
    labels = [profile_label(p) for p in profiles]
    sweep = [r for r in records if r.get("kind", "sweep") == "sweep"]

    def runs_of(p: str, s: str | None = None) -> list[dict]:
        return [r for r in sweep if r["profile"] == p and (s is None or r["seq_name"] == s)]

    return {
        "accuracy": {s: {p: accuracy_cell(runs_of(p, s)) for p in labels} for s in seq_names},
        "timing": {p: pooled_timing(runs_of(p)) for p in labels},
        "timing_per_sequence": {s: {p: pooled_timing(runs_of(p, s)) for p in labels} for s in seq_names},
        "counts": {k: sum(r["status"] == k for r in sweep) for k in ("ok", "fail", "crash")},
    }
