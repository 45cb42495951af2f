"""The profiler: run profiles on sequences, evaluate the runs, aggregate Tables 5.1 / 5.2.

Owns the sweep orchestration (:func:`run_sweep`), the per-run evaluation (:func:`collect_run`),
the aggregation into accuracy, timing and per-stage tables (:func:`aggregate`), the
initialisation study of thesis Fig. 5.8 (:func:`plan_init_study`, :func:`summarise_init_study`),
the cold/warm start-up measurement (:func:`measure_startup`) and the description of the machine
(:func:`machine_info`). Report writing (markdown, JSON, plots) is in :mod:`lite_vo.profiler_report`.

Every run is a separate process (``python -m lite_vo.cli.main run ...``) that writes the file
contract of ARCHITECTURE.md (``trajectory.txt``, ``timing.json``, ``run.json``); this module only
reads those files, so a crashing run cannot take the sweep down. The process launcher is a
replaceable ``runner`` callable (tests use a fake one that writes the files directly).

Imports: numpy, the standard library and ``lite_vo.config`` / ``lite_vo.geometry`` at module
level; ``lite_vo.io`` and ``lite_vo.eval`` lazily. Never imports matplotlib (see
``profiler_report``), numba kernels, ``ar_demo`` or any GL/physics package.
"""
from __future__ import annotations

import json
import math
import os
import platform
import queue
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from .errors import InputError

#: The paper's mapping/tracking combinations (Table 5.1), finest first.
PAPER_PROFILES: tuple[str, ...] = ("desktop", "m640_t320", "m320_t320", "phone", "m160_t160", "m160_t80")

#: Files a finished run must have written.
RUN_FILES: tuple[str, ...] = ("trajectory.txt", "timing.json", "run.json")

#: run.json statuses of a run that finished tracking (losses are judged from the frame counts).
OK_STATUSES: tuple[str, ...] = ("ok", "ok_with_losses")

#: Initialisation success criterion (thesis chapter 5.4).
INIT_DEPTH_ERROR_MAX = 0.16      # mean relative depth error after INIT_DEPTH_AT_S seconds
INIT_DEPTH_AT_S = 3.0
INIT_DRIFT_MAX = 0.60            # final relative translational drift
INIT_DRIFT_FRAMES = 15           # ... computed over this many frames
INIT_ERROR_WINDOW_S = 0.5        # tracking error over time: drift per 0.5 s relative to the distance


# ----------------------------------------------------------------------------------------------
# Machine
# ----------------------------------------------------------------------------------------------

def _cpu_model() -> str:
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        text = ""
    keys = ("model name", "Model", "Hardware", "cpu model", "Processor")
    found = {}
    for line in text.splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            k, v = k.strip(), v.strip()
            if k in keys and v and k not in found:
                found[k] = v
    for k in keys:
        if k in found:
            return found[k]
    return platform.processor() or platform.machine() or "unknown"


def _version(module: str) -> str | None:
    try:
        from importlib.metadata import version
        return version(module)
    except Exception:  # noqa: BLE001 - not installed
        return None


def machine_info() -> dict:
    """CPU model, core counts, memory, load, platform and package versions of this machine."""
    info: dict[str, Any] = {
        "cpu_model": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": _version("numba"),
        "opencv": _version("opencv-python-headless") or _version("opencv-python"),
        "lite_vo": _version("lite-vo"),
    }
    try:
        info["cores_available"] = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        info["cores_available"] = os.cpu_count()
    try:
        info["load_avg_1_5_15"] = [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        info["load_avg_1_5_15"] = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                info["memory_gb"] = round(int(line.split()[1]) / 1024 ** 2, 1)
    except (OSError, ValueError, IndexError):
        pass
    return info


# ----------------------------------------------------------------------------------------------
# Profiles
# ----------------------------------------------------------------------------------------------

def profile_resolution(name: str) -> dict:
    """Mapping/tracking widths of a profile (heights follow the camera's aspect ratio)."""
    from .config import load_profile
    cfg = load_profile(name)
    r = cfg.resolution
    track_width = r.map_width // (2 ** r.track_level)
    return {"map_width": r.map_width, "track_level": r.track_level, "track_width": track_width,
            "pyramid_levels": r.pyramid_levels, "label": f"{r.map_width}/{track_width}"}


def parse_profiles(text: str | Sequence[str] | None) -> list[str]:
    """``"a,b"`` or a list -> validated profile names/paths (each must load)."""
    from .config import load_profile
    if text is None:
        names = list(PAPER_PROFILES)
    elif isinstance(text, str):
        names = [p.strip() for p in text.split(",") if p.strip()]
    else:
        names = [str(p) for p in text]
    if not names:
        raise InputError("--profiles: no profile given")
    for n in names:
        load_profile(n)  # raises ConfigError naming the problem
    if len(set(names)) != len(names):
        raise InputError(f"--profiles: duplicate profile in {','.join(names)}")
    return names


def profile_label(name: str) -> str:
    """A short, path-safe name for a profile given by name or file path."""
    s = str(name)
    if s.endswith(".toml") or "/" in s or os.sep in s:
        return Path(s).stem
    return s


# ----------------------------------------------------------------------------------------------
# Runs: specification, command, launching
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RunSpec:
    """One ``lite-vo run`` invocation of the sweep."""
    sequence: str                  # path as given by the user
    seq_name: str                  # unique display / folder name
    profile: str                   # profile name or path
    rep: int
    out_dir: Path                  # the run's output folder (created by ``lite-vo run``)
    init: str | None = None        # auto | depth | random (None: the profile's choice)
    max_frames: int | None = None
    start_frame: int | None = None
    seed: int | None = None
    pin_core: bool = False
    kind: str = "sweep"            # "sweep" or "init"
    overrides: tuple[str, ...] = ()

    @property
    def key(self) -> str:
        return f"{self.seq_name}/{profile_label(self.profile)}/{self.rep}"

    @property
    def log_path(self) -> Path:
        return self.out_dir.parent / f"{self.out_dir.name}.log"


@dataclass
class RunOutcome:
    """What the launcher observed: exit status, the end of stderr, wall-clock seconds."""
    returncode: int
    stderr_tail: str = ""
    wall_s: float = 0.0
    core: int | None = None


def build_run_command(spec: RunSpec) -> list[str]:
    """The ``lite-vo run`` command line for ``spec`` (``sys.executable -m lite_vo.cli.main``).

    Initialisation-study runs add ``--init random --start-frame S --set system.seed=K``; their
    ``depth_accuracy.json`` holds the depth error after choosing the optimal scale per frame (the
    system aligns non-metric maps by the median ratio).
    """
    cmd = [sys.executable, "-m", "lite_vo.cli.main", "run", str(spec.sequence),
           "--profile", str(spec.profile), "--out", str(spec.out_dir), "--quiet", "--mode", "sync"]
    if spec.init is not None:
        cmd += ["--init", spec.init]
    if spec.max_frames is not None:
        cmd += ["--max-frames", str(int(spec.max_frames))]
    if spec.start_frame is not None:
        cmd += ["--start-frame", str(int(spec.start_frame))]
    overrides = list(spec.overrides)
    if spec.seed is not None:
        overrides.append(f"system.seed={int(spec.seed)}")
    if spec.pin_core:
        overrides.append("system.numba_threads=1")
    for ov in overrides:
        cmd += ["--set", ov]
    return cmd


def run_env(pin_core: bool, base: dict | None = None) -> dict:
    """Environment of a run: one numba/BLAS thread when pinned to one core."""
    env = dict(os.environ if base is None else base)
    if pin_core:
        env.update(NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
                   MKL_NUM_THREADS="1")
    return env


def _last_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else ""


def subprocess_runner(spec: RunSpec, core: int | None = None) -> RunOutcome:
    """Launch ``lite-vo run`` for ``spec`` as a child process and wait for it.

    stdout and stderr go to ``spec.log_path``. With ``core`` set, the child is pinned to that
    core with ``os.sched_setaffinity`` right after it starts (before it imports numpy or starts
    any thread, so every later thread inherits the mask). Setting the mask from the parent
    avoids ``preexec_fn``, which is not safe in a process with threads (the sweep waits on
    children from a thread pool).
    """
    spec.out_dir.parent.mkdir(parents=True, exist_ok=True)
    cmd = build_run_command(spec)
    t0 = time.perf_counter()
    with open(spec.log_path, "w", encoding="utf-8") as log:
        log.write("$ " + " ".join(cmd) + "\n")
        log.flush()
        try:
            proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.PIPE, text=True,
                                    env=run_env(spec.pin_core))
        except OSError as err:
            return RunOutcome(127, f"could not start: {err}", 0.0, core)
        if core is not None:
            try:
                os.sched_setaffinity(proc.pid, {core})
            except (AttributeError, OSError):
                pass  # process already gone or no affinity support: reported by its exit status
        _, err_text = proc.communicate()
        log.write(err_text or "")
    return RunOutcome(proc.returncode, _last_line(err_text or ""), time.perf_counter() - t0, core)


Runner = Callable[[RunSpec, "int | None"], RunOutcome]


def available_cores() -> list[int]:
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return list(range(os.cpu_count() or 1))


def default_workers() -> int:
    return max(1, min(2, len(available_cores())))


def execute(specs: Sequence[RunSpec], runner: Runner | None = None, workers: int | None = None,
            pin_core: bool = False,
            on_done: Callable[[int, int, RunSpec, RunOutcome], None] | None = None) -> list[RunOutcome]:
    """Run every spec with ``workers`` parallel runners; returns outcomes in the order of ``specs``.

    With ``pin_core`` each running job holds one core of this process's affinity mask for its
    whole duration (so parallel runs never share a core; at most one job per core). A runner
    that raises is turned into a crash outcome; nothing stops the sweep.
    """
    runner = runner or subprocess_runner
    workers = max(1, int(workers or default_workers()))
    cores: queue.Queue | None = None
    if pin_core:
        cores = queue.Queue()
        for c in available_cores():
            cores.put(c)
    outcomes: list[RunOutcome | None] = [None] * len(specs)
    done_count = [0]
    lock = threading.Lock()

    def job(i: int) -> None:
        spec = specs[i]
        core = cores.get() if cores is not None else None
        try:
            try:
                out = runner(spec, core)
            except Exception as err:  # noqa: BLE001 - a broken launcher is a crashed run
                out = RunOutcome(-1, f"runner failed: {type(err).__name__}: {err}", 0.0, core)
        finally:
            if cores is not None:
                cores.put(core)
        outcomes[i] = out
        if on_done is not None:
            with lock:
                done_count[0] += 1
                on_done(done_count[0], len(specs), spec, out)

    if workers == 1:
        for i in range(len(specs)):
            job(i)
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(job, range(len(specs))))
    return [o for o in outcomes]  # type: ignore[misc]


# ----------------------------------------------------------------------------------------------
# Sequences and trajectories
# ----------------------------------------------------------------------------------------------

def sequence_names(sequences: Sequence[str]) -> list[str]:
    """Unique, path-safe display names (folder name; a EuRoC ``mav0`` takes its parent's name)."""
    names = []
    for s in sequences:
        p = Path(s).resolve()
        name = p.parent.name if p.name == "mav0" else p.name
        name = name or "sequence"
        if p.is_file():
            name = p.stem
        names.append(name)
    out, seen = [], {}
    for n in names:
        if names.count(n) > 1:
            seen[n] = seen.get(n, 0) + 1
            n = f"{n}_{seen[n]}"
        out.append(n)
    return out


def load_groundtruth(sequence: str | os.PathLike):
    """Ground truth of a sequence (a :class:`lite_vo.io.Trajectory`): ``groundtruth.txt`` in the
    folder, else ``open_sequence(...).groundtruth`` (None when there is none)."""
    from .io import open_sequence, read_trajectory
    p = Path(sequence)
    gt_file = p / "groundtruth.txt"
    if gt_file.is_file():
        return read_trajectory(gt_file)
    return open_sequence(p).groundtruth


def sequence_has_depth(sequence: str | os.PathLike) -> bool | None:
    p = Path(sequence)
    if (p / "depth.txt").is_file() or (p / "depth").is_dir():
        return True
    if (p / "rgb.txt").is_file():
        return False
    return None


def frame_timestamps(sequence: str | os.PathLike) -> np.ndarray:
    """Timestamps of a sequence's frames (``rgb.txt``, EuRoC ``cam0/data.csv``, else by reading it)."""
    p = Path(sequence)
    if (p / "rgb.txt").is_file():
        ts = [float(ln.split()[0]) for ln in (p / "rgb.txt").read_text().splitlines()
              if ln.strip() and not ln.lstrip().startswith("#")]
        return np.asarray(ts)
    for csv in (p / "mav0" / "cam0" / "data.csv", p / "cam0" / "data.csv"):
        if csv.is_file():
            ts = [int(ln.split(",")[0]) * 1e-9 for ln in csv.read_text().splitlines()
                  if ln.strip() and not ln.lstrip().startswith("#")]
            return np.asarray(ts)
    from . import open_sequence
    seq = open_sequence(p)
    ts = getattr(seq, "timestamps", None)
    if ts is not None:
        return np.asarray(ts, float)
    return np.asarray([fr.timestamp for fr in seq], float)


def relative_drift(gt, est, scale: float = 1.0, window_s: float | None = INIT_ERROR_WINDOW_S,
                   window_frames: int | None = None, min_motion_m: float = 1e-3,
                   max_dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Relative translational drift over a window, per estimated pose (thesis Fig. 5.8).

    For each estimated pose i and the pose j one window earlier (``window_s`` seconds, or
    ``window_frames`` estimated poses), the error is
    ``|scale * t(T_j^-1 T_i)_est - t(T_j^-1 T_i)_gt| / |t(T_j^-1 T_i)_gt|``.
    Returns (time since the first estimated pose, error); pairs whose ground-truth motion is
    below ``min_motion_m`` are skipped (no meaningful relative error).
    """
    from .eval import associate
    from .geometry import inverse_se3
    if len(est) < 2 or len(gt) < 2:
        return np.zeros(0), np.zeros(0)
    if max_dt is None:
        dt = np.diff(est.timestamps)
        max_dt = max(0.02, 0.5 * float(np.median(dt))) if len(dt) else 0.02
    ie, ig = associate(est.timestamps, gt.timestamps, max_dt)
    if len(ie) < 2:
        return np.zeros(0), np.zeros(0)
    t = est.timestamps[ie]
    Pe, Pg = est.poses[ie], gt.poses[ig]
    times, errs = [], []
    for k in range(len(ie)):
        if window_frames is not None:
            j = k - window_frames
            if j < 0:
                continue
        else:
            target = t[k] - window_s
            if target < t[0] - 1e-9:
                continue
            j = int(np.argmin(np.abs(t[:k + 1] - target)))
            if j == k:
                continue
        rel_e = inverse_se3(Pe[j]) @ Pe[k]
        rel_g = inverse_se3(Pg[j]) @ Pg[k]
        motion = float(np.linalg.norm(rel_g[:3, 3]))
        if motion < min_motion_m:
            continue
        errs.append(float(np.linalg.norm(scale * rel_e[:3, 3] - rel_g[:3, 3]) / motion))
        times.append(float(t[k] - t[0]))
    return np.asarray(times), np.asarray(errs)


# ----------------------------------------------------------------------------------------------
# Reading and judging one run
# ----------------------------------------------------------------------------------------------

def _read_json(path: Path) -> dict:
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


def depth_error_series(run_json: dict, run_dir: Path | None = None) -> list[dict]:
    """Per-frame depth accuracy ``[{"t": s, "median_abs_rel_error": x, ...}]`` if the run stored it
    (``depth_accuracy.json`` in the run folder, or a list inside ``run.json``).

    When the entries carry a scale-aligned error (``median_abs_rel_error_aligned``, the error
    after choosing the optimal scale, needed for random initialisation), it replaces
    ``median_abs_rel_error`` (the raw value is kept as ``median_abs_rel_error_raw``).
    """
    da = run_json.get("depth_accuracy") or {}
    candidates = []
    if run_dir is not None and (Path(run_dir) / "depth_accuracy.json").is_file():
        try:
            with open(Path(run_dir) / "depth_accuracy.json", encoding="utf-8") as fh:
                candidates.append(json.load(fh))
        except (OSError, ValueError):
            pass
    candidates.append(run_json.get("depth_accuracy_series"))
    if isinstance(da, dict):
        candidates += [da.get("series"), da.get("frames")]
    for c in candidates:
        if isinstance(c, list) and c and all(isinstance(x, dict) for x in c):
            out = []
            for x in c:
                x = dict(x)
                if x.get("median_abs_rel_error_aligned") is not None:
                    x["median_abs_rel_error_raw"] = x.get("median_abs_rel_error")
                    x["median_abs_rel_error"] = x["median_abs_rel_error_aligned"]
                e = x.get("median_abs_rel_error")
                if "t" in x and isinstance(e, (int, float)) and math.isfinite(e):
                    out.append(x)
            if out:
                return sorted(out, key=lambda x: x["t"])
    return []


def collect_run(spec: RunSpec, outcome: RunOutcome, gt=None, evaluator: Callable | None = None,
                max_lost_ratio: float = 0.0, delta_s: float = 1.0) -> dict:
    """Read one run folder and judge it: a JSON-ready record.

    ``status``: ``"crash"`` (non-zero exit, missing or unreadable files), ``"fail"`` (run.json
    status not ok, more than ``max_lost_ratio`` of the frames lost, or nothing to evaluate) or
    ``"ok"``. The trajectory is evaluated against ``gt`` with ``evaluator(gt, est, align=...,
    delta_s=...)`` (default ``lite_vo.eval.evaluate``), SE(3)-aligned for depth-initialised runs
    and Sim(3)-aligned otherwise; evaluation numbers are kept even for failed runs.
    """
    rec: dict[str, Any] = {
        "key": spec.key, "kind": spec.kind, "sequence": str(spec.sequence), "seq_name": spec.seq_name,
        "profile": profile_label(spec.profile), "rep": spec.rep, "dir": str(spec.out_dir),
        "start_frame": spec.start_frame, "seed": spec.seed, "returncode": outcome.returncode,
        "wall_s": round(outcome.wall_s, 3), "core": outcome.core, "status": "ok", "reason": "",
        "stderr_tail": outcome.stderr_tail, "timing": None, "frames": None, "run_status": None,
        "depth_accuracy": None, "metric": None, "eval": None,
    }

    def crash(reason: str) -> dict:
        rec["status"], rec["reason"] = "crash", reason
        return rec

    tail = f": {outcome.stderr_tail}" if outcome.stderr_tail else ""
    missing = [f for f in RUN_FILES if not (spec.out_dir / f).is_file()]
    if missing:
        if outcome.returncode != 0:
            return crash(f"exit status {outcome.returncode}{tail}")
        return crash(f"missing {', '.join(missing)}")
    try:
        timing = _read_json(spec.out_dir / "timing.json")
        run_json = _read_json(spec.out_dir / "run.json")
    except (OSError, ValueError) as err:
        if outcome.returncode != 0:
            return crash(f"exit status {outcome.returncode}{tail}")
        return crash(f"unreadable timing.json/run.json: {err}")
    # a run that wrote its files and then exited non-zero (e.g. "failed: no frame tracked")
    # is a failed run, judged below from its files
    rec["timing"] = {k: timing.get(k) for k in ("tracking", "mapping", "stages", "wall_s")}
    frames = timing.get("frames") or {}
    rec["frames"] = frames
    rec["run_status"] = run_json.get("status")
    rec["depth_accuracy"] = run_json.get("depth_accuracy")
    rec["depth_series"] = depth_error_series(run_json, spec.out_dir)
    metric = run_is_metric(run_json, spec.sequence)
    rec["metric"] = metric
    from .io import read_trajectory
    try:
        est = read_trajectory(spec.out_dir / "trajectory.txt")
    except Exception as err:  # noqa: BLE001
        return crash(f"unreadable trajectory.txt: {err}")
    rec["poses"] = len(est)

    reasons = []
    if outcome.returncode != 0:
        reasons.append(f"exit status {outcome.returncode}{tail}")
    if run_json.get("status") is None:
        reasons.append("run.json has no status")
    elif run_json.get("status") not in OK_STATUSES:
        reasons.append(f"status {run_json.get('status')!r}")
    n_in = int(frames.get("in") or 0)
    n_lost = int(frames.get("lost") or 0)
    if n_lost > max_lost_ratio * max(n_in, 1):
        reasons.append(f"tracking lost on {n_lost}/{n_in} frames")

    align = "se3" if metric else "sim3"
    rec["align"] = align
    if gt is None:
        reasons.append("no ground truth")
    elif len(est) < 2:
        reasons.append(f"only {len(est)} pose(s) in trajectory.txt")
    else:
        try:
            if evaluator is None:
                from .eval import evaluate as evaluator  # type: ignore[no-redef]
            res = evaluator(gt, est, align=align, delta_s=delta_s)
            rec["eval"] = res.to_dict() if hasattr(res, "to_dict") else dict(res)
        except ImportError as err:
            reasons.append(f"evaluation unavailable ({err})")
        except Exception as err:  # noqa: BLE001 - a run we cannot evaluate is a failed run
            reasons.append(f"evaluation failed: {type(err).__name__}: {err}")
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


def _mean_std(values: list[float]) -> dict | None:
    if not values:
        return None
    a = np.asarray(values, float)
    return {"mean": float(a.mean()), "std": float(a.std()), "n": len(a)}


ACCURACY_KEYS = ("rpe_trans_cm_per_s", "rpe_rot_deg_per_s", "ate_rmse_m", "rpe_trans_pct", "scale")


def aggregate(records: Sequence[dict], profiles: Sequence[str], seq_names: Sequence[str]) -> dict:
    """Accuracy per (sequence, profile), timing and per-stage timing per profile (and per sequence).

    Accuracy cells average the successful repetitions; ``failed`` counts runs that crashed or
    failed; a cell with no successful run is a failure (shown as ``fail``).
    """
    labels = [profile_label(p) for p in profiles]
    sweep = [r for r in records if r.get("kind", "sweep") == "sweep"]
    accuracy: dict[str, dict[str, dict]] = {}
    for s in seq_names:
        accuracy[s] = {}
        for p in labels:
            runs = [r for r in sweep if r["seq_name"] == s and r["profile"] == p]
            good = [r for r in runs if r["status"] == "ok" and r.get("eval")]
            cell: dict[str, Any] = {"runs": len(runs), "ok": len(good),
                                    "failed": len(runs) - len(good),
                                    "crashed": sum(r["status"] == "crash" for r in runs),
                                    "reasons": sorted({r["reason"] for r in runs if r["status"] != "ok"})}
            for k in ACCURACY_KEYS:
                vals = [float(r["eval"][k]) for r in good if isinstance(r["eval"].get(k), (int, float))
                        and math.isfinite(r["eval"][k])]
                cell[k] = _mean_std(vals)
            accuracy[s][p] = cell

    def timing_of(runs: list[dict]) -> dict:
        usable = [r for r in runs if r.get("timing")]
        stage_names = sorted({n for r in usable for n in ((r["timing"].get("stages") or {}).keys())})
        return {
            "tracking": pool_stats(r["timing"].get("tracking") for r in usable),
            "mapping": pool_stats(r["timing"].get("mapping") for r in usable),
            "stages": {n: pool_stats((r["timing"].get("stages") or {}).get(n) for r in usable)
                       for n in stage_names},
            "runs": len(usable),
            "wall_s": _mean_std([float(r["timing"]["wall_s"]) for r in usable
                                 if r["timing"].get("wall_s") is not None]),
        }

    timing = {p: timing_of([r for r in sweep if r["profile"] == p]) for p in labels}
    timing_per_seq = {s: {p: timing_of([r for r in sweep if r["profile"] == p and r["seq_name"] == s])
                          for p in labels} for s in seq_names}
    counts = {k: sum(r["status"] == k for r in sweep) for k in ("ok", "fail", "crash")}
    return {"accuracy": accuracy, "timing": timing, "timing_per_sequence": timing_per_seq,
            "counts": counts}


# ----------------------------------------------------------------------------------------------
# Initialisation study (thesis chapter 5.4, Fig. 5.8)
# ----------------------------------------------------------------------------------------------

def plan_init_study(sequence: str, seq_name: str, n: int, length_s: float, out_dir: Path,
                    profile: str = "phone", pin_core: bool = False,
                    timestamps: np.ndarray | None = None, overrides: tuple[str, ...] = ()) -> list[RunSpec]:
    """``n`` random-init sub-sequences of ``length_s`` seconds from evenly spaced start frames.

    Sub-sequence i starts at frame ``s_i`` (evenly spread over the frames that leave
    ``length_s`` seconds after them) and uses seed ``i + 1``.
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
                             kind="init", overrides=tuple(overrides)))
    return specs


def judge_init_run(rec: dict, gt, depth_at_s: float = INIT_DEPTH_AT_S,
                   depth_max: float = INIT_DEPTH_ERROR_MAX, drift_max: float = INIT_DRIFT_MAX,
                   drift_frames: int = INIT_DRIFT_FRAMES, window_s: float = INIT_ERROR_WINDOW_S) -> dict:
    """Add the chapter-5.4 success test and the error-over-time series to an init-study record.

    Depth error: the run's ``median_abs_rel_error`` at ``depth_at_s`` seconds (from the per-frame
    series when the run stored one, else the final value). Drift: relative translational drift
    over the last ``drift_frames`` frames, with the Sim(3) scale of the evaluation.
    """
    out = dict(rec)
    out.update(depth_error=None, depth_error_at_s=None, final_drift=None, success=False,
               drift_series=None, init_reason="")
    if rec["status"] == "crash":
        out["init_reason"] = "crashed"
        return out
    series = rec.get("depth_series") or []
    if series:
        before = [x for x in series if x["t"] <= depth_at_s + 1e-6]
        pick = before[-1] if before else series[0]
        out["depth_error"], out["depth_error_at_s"] = float(pick["median_abs_rel_error"]), float(pick["t"])
    elif isinstance(rec.get("depth_accuracy"), dict) and \
            rec["depth_accuracy"].get("median_abs_rel_error") is not None:
        out["depth_error"] = float(rec["depth_accuracy"]["median_abs_rel_error"])
        out["depth_error_at_s"] = "end"
    scale = float((rec.get("eval") or {}).get("scale") or 1.0)
    from .io import read_trajectory
    try:
        est = read_trajectory(Path(rec["dir"]) / "trajectory.txt")
    except Exception:  # noqa: BLE001
        est = None
    if est is not None and gt is not None and len(est) > drift_frames:
        _, e = relative_drift(gt, est, scale, window_frames=drift_frames)
        if len(e):
            out["final_drift"] = float(e[-1])
        ts, es = relative_drift(gt, est, scale, window_s=window_s)
        out["drift_series"] = {"t": ts.tolist(), "error": es.tolist()}
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


def _binned_mean(samples: list[tuple[np.ndarray, np.ndarray]], bin_s: float, t_max: float) -> dict:
    edges = np.arange(0.0, t_max + bin_s, bin_s)
    rows = []
    for a, b in zip(edges[:-1], edges[1:]):
        vals = []
        for t, e in samples:
            m = (t >= a) & (t < b)
            if m.any():
                vals.append(float(np.mean(e[m])))
        rows.append({"t0": float(a), "t1": float(b), "mean": float(np.mean(vals)) if vals else None,
                     "n": len(vals)})
    return {"bin_s": bin_s, "bins": rows}


def summarise_init_study(records: Sequence[dict], bin_s: float = INIT_ERROR_WINDOW_S) -> dict:
    """Success rate and mean depth / tracking error over time of the successful runs."""
    n = len(records)
    ok = [r for r in records if r.get("success")]

    def over_time(runs: list[dict]) -> tuple[dict | None, dict | None]:
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
        return (_binned_mean(depth_samples, bin_s, t_max) if depth_samples else None,
                _binned_mean(drift_samples, bin_s, t_max) if drift_samples else None)

    depth_ok, drift_ok = over_time(ok)
    depth_all, drift_all = over_time([r for r in records if r["status"] != "crash"])
    return {
        "runs": n, "successes": len(ok), "success_rate": (len(ok) / n) if n else None,
        "crashed": sum(r["status"] == "crash" for r in records),
        "criterion": {"depth_error_max": INIT_DEPTH_ERROR_MAX, "depth_at_s": INIT_DEPTH_AT_S,
                      "drift_max": INIT_DRIFT_MAX, "drift_frames": INIT_DRIFT_FRAMES},
        "depth_error_over_time": depth_ok, "tracking_error_over_time": drift_ok,
        "depth_error_over_time_all": depth_all, "tracking_error_over_time_all": drift_all,
    }


# ----------------------------------------------------------------------------------------------
# Cold vs warm start-up
# ----------------------------------------------------------------------------------------------

def startup_probe(sequence: str, profile: str = "phone", n_frames: int = 3) -> dict:
    """In THIS process: time the import, the set-up and the first ``n_frames`` frames (ms).

    Meant to run in a fresh subprocess (see :func:`measure_startup`); prints nothing.
    """
    t0 = time.perf_counter()
    import lite_vo
    from lite_vo.system import VisualOdometry
    t_import = time.perf_counter() - t0
    seq = lite_vo.open_sequence(sequence)
    cfg = lite_vo.load_profile(profile, ["system.mode=sync"])
    t1 = time.perf_counter()
    vo = VisualOdometry(seq.camera, cfg)
    t_setup = time.perf_counter() - t1
    frame_ms = []
    for i, fr in enumerate(seq):
        if i >= n_frames:
            break
        t = time.perf_counter()
        vo.process(fr.image, fr.timestamp, depth=fr.depth)
        frame_ms.append((time.perf_counter() - t) * 1e3)
    vo.close()
    return {"import_s": t_import, "setup_s": t_setup, "frame_ms": frame_ms,
            "total_s": time.perf_counter() - t0}


_PROBE_CODE = ("import json, sys; from lite_vo.profiler import startup_probe; "
               "print('STARTUP_JSON ' + json.dumps(startup_probe(sys.argv[1], sys.argv[2], int(sys.argv[3]))))")
_WARMUP_CODE = ("import json, time; from lite_vo.warmup import warmup; t = time.perf_counter(); "
                "res = warmup(); print('STARTUP_JSON ' + json.dumps({'warmup_s': time.perf_counter() - t, "
                "'modules': [r.to_dict() for r in res]}))")


def compiled_kernels(numba_debug_output: str) -> list[str]:
    """Kernels numba compiled (and saved to its cache) according to ``NUMBA_DEBUG_CACHE=1`` output."""
    import re
    out = []
    for m in re.finditer(r"data saved to '([^']+)'", numba_debug_output):
        p = Path(m.group(1))
        pkg = p.parent.name.rsplit("_", 1)[0] if "_" in p.parent.name else p.parent.name  # "<dir>_<hash>"
        name = re.sub(r"\.py\d+\.\d+\.nbc$", "", p.name)
        name = re.sub(r"-\d+$", "", name)
        out.append(f"{pkg}/{name}")
    return sorted(set(out))


def _python_json(code: str, args: Sequence[str], env: dict, timeout: float) -> dict:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True, text=True,
                          timeout=timeout)
    wall = time.perf_counter() - t0
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith("STARTUP_JSON "):
            res = json.loads(line[len("STARTUP_JSON "):]) | {"process_s": wall, "ok": True}
            if env.get("NUMBA_DEBUG_CACHE") == "1":
                res["compiled"] = compiled_kernels(proc.stdout + proc.stderr)
            return res
    return {"ok": False, "process_s": wall, "returncode": proc.returncode,
            "error": _last_line(proc.stderr) or f"exit status {proc.returncode}"}


def measure_startup(sequence: str, profile: str = "phone", n_frames: int = 3, timeout: float = 900.0) -> dict:
    """Time of the first frames in a fresh process, cold (empty numba cache) vs after a warm-up.

    Three subprocesses, each with its own ``NUMBA_CACHE_DIR``: (1) ``cold``: a probe with an
    empty cache (every kernel compiles on first use); (2) ``lite_vo.warmup.warmup()`` into a
    second empty cache; (3) ``warm``: the same probe with that warmed cache. The user's own
    cache is never touched.
    """
    out: dict[str, Any] = {"sequence": str(sequence), "profile": profile, "n_frames": n_frames}
    with tempfile.TemporaryDirectory(prefix="lite_vo_cold_") as cold_dir, \
            tempfile.TemporaryDirectory(prefix="lite_vo_warm_") as warm_dir:
        args = [str(sequence), str(profile), str(n_frames)]
        env_cold = dict(os.environ, NUMBA_CACHE_DIR=cold_dir)
        env_warm = dict(os.environ, NUMBA_CACHE_DIR=warm_dir)
        try:
            out["cold"] = _python_json(_PROBE_CODE, args, env_cold, timeout)
            out["warmup"] = _python_json(_WARMUP_CODE, [], env_warm, timeout)
            # NUMBA_DEBUG_CACHE lists what still had to be compiled although warmup() ran
            out["warm"] = _python_json(_PROBE_CODE, args, dict(env_warm, NUMBA_DEBUG_CACHE="1"), timeout)
        except subprocess.TimeoutExpired as err:
            out["error"] = f"timed out after {err.timeout:.0f} s"
    return out


# ----------------------------------------------------------------------------------------------
# The whole command
# ----------------------------------------------------------------------------------------------

@dataclass
class ProfileSettings:
    """Options of ``lite-vo profile`` (see ``lite_vo/cli/profile.py`` for their meaning)."""
    sequences: list[str]
    profiles: list[str] = field(default_factory=lambda: list(PAPER_PROFILES))
    repeat: int = 1
    out: Path = Path("lite_vo_out/profile")
    workers: int | None = None
    pin_core: bool = False
    max_frames: int | None = None
    init: str | None = None
    force: bool = False
    init_study: int = 0
    init_study_len: float = 4.0
    max_lost_ratio: float = 0.0
    warmup: bool = True
    startup: bool = True
    plots: bool = True
    delta_s: float = 1.0
    overrides: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["out"] = str(self.out)
        return d


#: What ``--force`` removes from an existing output folder (nothing else is ever deleted).
OUTPUT_ENTRIES = ("runs", "init_study", "report.md", "report.json", "accuracy_vs_resolution.png",
                  "time_vs_resolution.png", "init_study.png")


def prepare_out(out: Path, force: bool) -> None:
    """Refuse an existing, non-empty output folder unless ``force``; with it, remove our own entries."""
    from .io import prepare_output_dir
    prepare_output_dir(out, force, clean=OUTPUT_ENTRIES)


def run_warmup_subprocess(timeout: float = 1800.0) -> dict:
    """``lite-vo warmup --quiet`` in a child process (so sweep runs do not all compile at once)."""
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "lite_vo.cli.main", "warmup", "--quiet"],
                              capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"ok": False, "seconds": time.perf_counter() - t0, "error": "timed out"}
    return {"ok": proc.returncode == 0, "seconds": time.perf_counter() - t0,
            "error": _last_line(proc.stderr) if proc.returncode else ""}


def run_profile(settings: ProfileSettings, runner: Runner | None = None, evaluator: Callable | None = None,
                gt_loader: Callable | None = None, log: Callable[[str], None] | None = None,
                startup_fn: Callable[..., dict] | None = None, command: str | None = None) -> dict:
    """Run the sweep (or the initialisation study), evaluate, aggregate and write the report.

    Returns the report dictionary (also written to ``report.json``). ``runner``, ``evaluator``,
    ``gt_loader`` and ``startup_fn`` replace the real subprocess launcher, ``lite_vo.eval.evaluate``,
    :func:`load_groundtruth` and :func:`measure_startup` (tests).
    """
    from . import profiler_report

    log = log or (lambda msg: None)
    s = settings
    if not s.sequences:
        raise InputError("no sequence given")
    for seq in s.sequences:
        if not Path(seq).exists():
            raise InputError(f"{seq}: sequence not found")
    if s.repeat < 1:
        raise InputError("--repeat must be at least 1")
    if s.max_frames is not None and s.max_frames < 1:
        raise InputError("--max-frames must be at least 1")
    s.profiles = parse_profiles(s.profiles)
    out = Path(s.out)
    prepare_out(out, s.force)
    gt_loader = gt_loader or load_groundtruth
    seq_names = sequence_names(s.sequences)
    started = time.time()

    report: dict[str, Any] = {
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(started)),
        "command": command,
        "machine": machine_info(), "settings": s.to_dict(),
        "profiles": {}, "sequences": dict(zip(seq_names, map(str, s.sequences))),
    }
    for p in s.profiles:
        report["profiles"][profile_label(p)] = profile_resolution(p)

    gts: dict[str, Any] = {}
    for name, seq in zip(seq_names, s.sequences):
        try:
            gts[name] = gt_loader(seq)
        except Exception as err:  # noqa: BLE001 - reported per run as "no ground truth"
            log(f"warning: {seq}: no ground truth ({err})")
            gts[name] = None

    workers = report["workers"] = int(s.workers or default_workers())
    if s.warmup and runner is None:
        log("warming up numba kernels (lite-vo warmup) ...")
        report["warmup"] = run_warmup_subprocess()

    def progress(i: int, n: int, spec: RunSpec, o: RunOutcome) -> None:
        state = "ok" if o.returncode == 0 else f"exit {o.returncode}"
        log(f"[{i}/{n}] {spec.key}: {state} ({o.wall_s:.1f} s)")

    if s.init_study > 0:
        prof = s.profiles[0]
        specs = []
        for name, seq in zip(seq_names, s.sequences):
            specs += plan_init_study(seq, name, s.init_study, s.init_study_len, out / "init_study",
                                     profile=prof, pin_core=s.pin_core, overrides=tuple(s.overrides))
        log(f"initialisation study: {len(specs)} runs on {workers} worker(s)")
        outcomes = execute(specs, runner, workers, s.pin_core, progress)
        records = []
        for spec, o in zip(specs, outcomes):
            rec = collect_run(spec, o, gts.get(spec.seq_name), evaluator, max_lost_ratio=1.0,
                              delta_s=s.delta_s)
            records.append(judge_init_run(rec, gts.get(spec.seq_name)))
        report["runs"] = records
        report["init_study"] = {name: summarise_init_study([r for r in records if r["seq_name"] == name])
                                for name in seq_names}
        report["init_study_profile"] = profile_label(prof)
    else:
        specs = [RunSpec(sequence=seq, seq_name=name, profile=p, rep=k,
                         out_dir=out / "runs" / name / profile_label(p) / str(k), init=s.init,
                         max_frames=s.max_frames, pin_core=s.pin_core, overrides=tuple(s.overrides))
                 for k in range(s.repeat) for name, seq in zip(seq_names, s.sequences) for p in s.profiles]
        log(f"{len(specs)} runs ({len(s.sequences)} sequence(s) x {len(s.profiles)} profile(s) x "
            f"{s.repeat}) on {workers} worker(s)"
            + (", each pinned to one core" if s.pin_core else ""))
        outcomes = execute(specs, runner, workers, s.pin_core, progress)
        records = [collect_run(spec, o, gts.get(spec.seq_name), evaluator, s.max_lost_ratio, s.delta_s)
                   for spec, o in zip(specs, outcomes)]
        report["runs"] = records
        report.update(aggregate(records, s.profiles, seq_names))
        if s.startup:
            log("measuring cold vs warm start-up (fresh processes, empty numba caches) ...")
            fn = startup_fn or measure_startup
            try:
                report["startup"] = fn(s.sequences[0], s.profiles[0])
            except Exception as err:  # noqa: BLE001 - the sweep results matter more
                report["startup"] = {"error": f"{type(err).__name__}: {err}"}
    report["elapsed_s"] = round(time.time() - started, 1)
    paths = profiler_report.write_report(report, out, plots=s.plots, log=log)
    report["written"] = [str(p) for p in paths]
    return report
