"""Report writing for ``lite-vo profile``: ``report.json`` and ``report.md`` (plots: :mod:`.plots`).

Owns the presentation of the dictionary built by :func:`lite_vo.profiling.run_profile`: the
accuracy table (thesis Table 5.1), the timing table (Table 5.2), per-stage timings, the
cold/warm start-up table, the initialisation study (Fig. 5.8), the list of runs and the machine.
When matplotlib is missing the report says so and everything else is still written.

Imports: the standard library, numpy, ``lite_vo.errors`` and ``lite_vo.profiling.plots`` (which
imports matplotlib only inside its functions). No other part of ``lite_vo``.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import MissingExtraError
from .plots import make_plots


def _num(x: Any, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}f}"


def _ms(stats: dict | None, digits: int = 1) -> str:
    if not stats:
        return "-"
    return f"{stats['mean']:.{digits}f} ± {stats['std']:.{digits}f}"


def format_cell(cell: dict | None, key: str, digits: int = 2) -> str:
    """One accuracy cell: the mean over successful runs, ``fail`` when none succeeded."""
    if not cell or cell.get("runs", 0) == 0:
        return "-"
    v = cell.get(key)
    if cell.get("ok", 0) == 0:
        return "crash" if cell.get("crashed") == cell.get("runs") else "fail"
    if v is None:
        return "n/a"  # e.g. a run shorter than the RPE interval
    text = _num(v["mean"], digits)
    if v.get("n", 1) > 1:
        text += f" ± {_num(v['std'], digits)}"
    if cell.get("failed"):
        text += f" ({cell['failed']}/{cell['runs']} fail)"
    return text


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(str(c).replace("|", "\\|") for c in r) + " |" for r in rows]
    return out


def profile_order(report: dict) -> list[str]:
    """Profiles in the order given on the command line."""
    return list(report.get("profiles", {}).keys())


def _res(report: dict, p: str) -> tuple[str, str]:
    r = report.get("profiles", {}).get(p) or {}
    return str(r.get("map_width", "?")), str(r.get("track_width", "?"))


def machine_lines(m: dict) -> list[str]:
    cores = m.get("cpu_count")
    avail = m.get("cores_available")
    lines = [
        f"- CPU: {m.get('cpu_model')} ({cores} logical cores"
        + (f", {avail} available to the profiler" if avail is not None and avail != cores else "") + ")",
        f"- platform: {m.get('platform')}; memory: {m.get('memory_gb', '?')} GB; "
        f"load average at start: {m.get('load_avg_1_5_15')}",
        f"- Python {m.get('python')}, numpy {m.get('numpy')}, numba {m.get('numba')}, "
        f"OpenCV {m.get('opencv')}, lite-vo {m.get('lite_vo')}",
    ]
    return lines


def accuracy_lines(report: dict) -> list[str]:
    acc = report.get("accuracy") or {}
    seqs = list(acc.keys())
    profiles = profile_order(report)
    header = ["profile", "mapping", "tracking"]
    for s in seqs:
        header += [f"{s} (cm/s)", f"{s} (deg/s)"]
    rows = []
    for p in profiles:
        m, t = _res(report, p)
        row = [p, m, t]
        for s in seqs:
            cell = acc[s].get(p)
            row += [format_cell(cell, "rpe_trans_cm_per_s"), format_cell(cell, "rpe_rot_deg_per_s")]
        rows.append(row)
    lines = _table(header, rows)
    header2 = ["profile"] + [f"{s} ATE (m)" for s in seqs] + [f"{s} scale" for s in seqs]
    rows2 = []
    for p in profiles:
        rows2.append([p] + [format_cell(acc[s].get(p), "ate_rmse_m", 3) for s in seqs]
                     + [format_cell(acc[s].get(p), "scale", 3) for s in seqs])
    return lines + ["", "Absolute trajectory error after alignment, and the alignment scale:", ""] + _table(header2, rows2)


def timing_lines(report: dict) -> list[str]:
    timing = report.get("timing") or {}
    rows = []
    for p in profile_order(report):
        t = timing.get(p) or {}
        m, tr = _res(report, p)
        trk, mp = t.get("tracking"), t.get("mapping")
        rows.append([p, m, tr, _ms(trk), _num((trk or {}).get("median"), 1), _ms(mp),
                     _num((mp or {}).get("median"), 1), str(trk["count"]) if trk else "0",
                     str(mp["count"]) if mp else "0", str(t.get("runs", 0))])
    return _table(["profile", "mapping", "tracking", "tracking (ms)", "tracking median", "mapping (ms)",
                   "mapping median", "tracked frames", "mapping iterations", "runs"], rows)


def stage_lines(report: dict) -> list[str]:
    timing = report.get("timing") or {}
    profiles = profile_order(report)
    stages = sorted({n for p in profiles for n in ((timing.get(p) or {}).get("stages") or {})})
    if not stages:
        return ["No per-stage timings were recorded."]
    rows = [[n] + [_ms(((timing.get(p) or {}).get("stages") or {}).get(n), 2) for p in profiles]
            for n in stages]
    return _table(["stage (ms)"] + profiles, rows)


def startup_lines(report: dict) -> list[str]:
    st = report.get("startup")
    if not st:
        return []
    lines = ["## Start-up: cold vs warm numba cache", ""]
    if st.get("error"):
        return lines + [f"Not measured: {st['error']}", ""]
    lines += [f"Fresh processes running `{st.get('profile')}` on `{Path(str(st.get('sequence'))).name}`: "
              "*cold* with an empty numba cache (every kernel compiles on first use), *warm* after "
              "`lite-vo warmup` filled the cache.", ""]
    rows = []
    n = int(st.get("n_frames") or 0)
    for name in ("cold", "warm"):
        r = st.get(name) or {}
        if not r.get("ok"):
            rows.append([name, f"failed: {r.get('error', 'not run')}"] + [""] * (n + 2))
            continue
        fr = r.get("frame_ms") or []
        rows.append([name, _num(r.get("import_s"), 2), _num(r.get("setup_s"), 2)]
                    + [_num(fr[i], 0) if i < len(fr) else "-" for i in range(n)]
                    + [_num(r.get("process_s"), 1)])
    header = ["cache", "import (s)", "set-up (s)"] + [f"frame {i} (ms)" for i in range(n)] + ["whole process (s)"]
    lines += _table(header, rows)
    lines += ["", "The first frames include compiling (cold) or loading from the cache (warm) every kernel they "
                  "call; a warm frame that is still seconds late means a kernel was called with argument types "
                  "its module's `warmup()` does not cover (e.g. read-only arrays)."]
    missed = (st.get("warm") or {}).get("compiled")
    if missed:
        lines += ["", "Kernels still compiled in the warm process (their `warmup()` calls them with other argument "
                      "types than the system does): " + ", ".join(f"`{k}`" for k in missed) + "."]
    elif (st.get("warm") or {}).get("ok") and "compiled" in (st.get("warm") or {}):
        lines += ["", "No kernel had to be compiled in the warm process."]
    w = st.get("warmup") or {}
    if w.get("ok"):
        lines += ["", f"`lite-vo warmup` itself took {_num(w.get('warmup_s'), 1)} s "
                      f"(process {_num(w.get('process_s'), 1)} s)."]
    elif w:
        lines += ["", f"`lite-vo warmup` failed: {w.get('error')}"]
    return lines + [""]


def runs_lines(report: dict) -> list[str]:
    rows = []
    for r in report.get("runs", []):
        fr = r.get("frames") or {}
        frames = f"{fr.get('in', '-')}/{fr.get('tracked', '-')}/{fr.get('lost', '-')}/{fr.get('dropped', '-')}" if fr else "-"
        ev = r.get("eval") or {}
        rows.append([r["key"], r["status"], frames, _num(ev.get("rpe_trans_cm_per_s"), 2),
                     _num(ev.get("rpe_rot_deg_per_s"), 2), _num(ev.get("ate_rmse_m"), 3),
                     _num(r.get("wall_s"), 1), r.get("align") or "-",
                     r.get("reason") or "; ".join(map(str, ev.get("warnings") or []))])
    return _table(["run (sequence/profile/repetition)", "status", "frames in/tracked/lost/dropped",
                   "cm/s", "deg/s", "ATE (m)", "wall (s)", "align", "reason"], rows)


INIT_STUDY_INTRO = (
    "Random initialisation (profile `{profile}`) on sub-sequences of {length} s from evenly spaced start "
    "frames, one seed each. A run succeeds when the relative depth error (median over the map's pixels, after "
    "choosing the optimal scale, of the last map at or before {depth_at_s} s) is at most {depth_max:.0%} and "
    "the final relative translational drift over {drift_frames} frames (with the Sim(3) scale of the whole run) "
    "is at most {drift_max:.0%} (chapter 5.4; the paper reports 67% on fr2/desk with mapping on every 4th "
    "frame). Runs that end lost (`status 'lost'`) also count as failures.")


def init_run_lines(runs: list[dict]) -> list[str]:
    """One row per initialisation-study run: depth error, final drift, success and why not."""
    rows = []
    for r in runs:
        de = r.get("depth_error")
        at = r.get("depth_error_at_s")
        at_txt = f" (at {at:.1f} s)" if isinstance(at, (int, float)) else (" (at end)" if at else "")
        rows.append([r["seq_name"], str(r.get("start_frame")), str(r.get("seed")),
                     (f"{de:.1%}" + at_txt) if de is not None else "-",
                     f"{r['final_drift']:.1%}" if r.get("final_drift") is not None else "-",
                     "yes" if r.get("success") else "no", r.get("init_reason") or r.get("reason") or ""])
    return _table(["sequence", "start frame", "seed", "depth error", "final drift", "success", "why not"], rows)


def _bin_text(series: dict | None, i: int) -> str:
    b = series["bins"][i] if series and i < len(series["bins"]) else None
    return f"{b['mean']:.1%} (n={b['n']})" if b and b["mean"] is not None else "-"


def errors_over_time_lines(name: str, summary: dict) -> list[str]:
    """Fig. 5.8 as a table: mean depth and tracking error per time bin on one sequence."""
    cols = [summary.get(k) for k in ("depth_error_over_time", "tracking_error_over_time",
                                     "depth_error_over_time_all", "tracking_error_over_time_all")]
    longest = max((c for c in cols if c), key=lambda c: len(c["bins"]), default=None)
    if longest is None:
        return []
    rows = [[f"{b['t0']:.1f}-{b['t1']:.1f}"] + [_bin_text(c, i) for c in cols] for i, b in enumerate(longest["bins"])]
    return ["", f"Mean errors over time on {name} (Fig. 5.8), of the successful runs and of all runs that "
                "did not crash (tracking error: translational drift per 0.5 s relative to the distance "
                "travelled):", ""] + _table(["time (s)", "depth error (successful)", "tracking error (successful)",
                                             "depth error (all)", "tracking error (all)"], rows)


def init_study_lines(report: dict) -> list[str]:
    study = report.get("init_study") or {}
    if not study:
        return []
    crit = next(iter(study.values())).get("criterion", {})
    intro = INIT_STUDY_INTRO.format(
        profile=report.get("init_study_profile"), length=report.get("settings", {}).get("init_study_len"),
        depth_at_s=crit.get("depth_at_s"), depth_max=crit.get("depth_error_max", 0),
        drift_frames=crit.get("drift_frames"), drift_max=crit.get("drift_max", 0))
    rows = [[s, str(v["runs"]), str(v["successes"]),
             f"{v['success_rate']:.0%}" if v.get("success_rate") is not None else "-", str(v["crashed"])]
            for s, v in study.items()]
    lines = ["## Initialisation study (thesis Fig. 5.8)", "", intro, ""]
    lines += _table(["sequence", "runs", "successes", "success rate", "crashed"], rows) + [""]
    lines += init_run_lines([r for r in report.get("runs", []) if r.get("kind") == "init"])
    for s, v in study.items():
        lines += errors_over_time_lines(s, v)
    return lines + [""]


ACCURACY_INTRO = (
    "Drift per second: RMSE of the relative pose error over 1-second pairs, translation in cm/s "
    "and rotation in deg/s, after SE(3) alignment for depth-initialised (metric) runs and Sim(3) "
    "alignment otherwise. Mean ± std over repetitions; `n/a` when the runs were too short for the "
    "1-second pairs; `fail` when tracking was lost (any lost "
    "frame, unless `--max-lost-ratio` allows some) or the run did not end with status ok; "
    "`crash` when the run process failed. Resolutions are image widths (heights follow the "
    "camera's aspect ratio).")
TIMING_INTRO = (
    "Milliseconds per tracked frame (whole tracking) and per mapping iteration, mean ± std pooled "
    "over all runs of the profile (sync mode, so tracking and mapping did not overlap). "
    "The paper's phone numbers (Sony Xperia Z1, 320x240 mapping, NEON): tracking 14.7 ± 6.8 ms, "
    "mapping 52.6 ± 37.7 ms. The median (of the runs' medians) is less sensitive to the first "
    "frame of each process, which also loads the compiled kernels from numba's cache.")


def header_lines(report: dict) -> list[str]:
    """Title, when and how the report was made, the machine, the settings, warm-up and sequences."""
    s = report.get("settings", {})
    lines = ["# lite-vo profile report", ""]
    lines.append(f"Created {report.get('created_utc')} in {report.get('elapsed_s', '?')} s"
                 + (f" by `{report['command']}`" if report.get("command") else "") + ".")
    lines += ["", "Machine:", ""] + machine_lines(report.get("machine", {})) + [""]
    opts = [f"repeat {s.get('repeat')}", f"{s.get('workers') or report.get('workers') or 'default'} worker(s)",
            "pinned to one core + 1 numba thread per run" if s.get("pin_core") else "not pinned",
            f"max frames {s.get('max_frames') or 'all'}", f"init {s.get('init') or 'profile default'}"]
    if s.get("overrides"):
        opts.append("overrides " + " ".join(f"`{o}`" for o in s["overrides"]))
    lines += ["Settings: " + ", ".join(opts) + ". Runs use `lite-vo run --mode sync`.", ""]
    w = report.get("warmup")
    if w:
        lines += [f"Before the runs, `lite-vo warmup` compiled/loaded the kernels in {_num(w.get('seconds'), 1)} s"
                  + ("." if w.get("ok") else f" and failed: {w.get('error')}."), ""]
    seqs = report.get("sequences", {})
    if seqs:
        lines += ["Sequences: " + ", ".join(f"`{k}` ({v})" for k, v in seqs.items()), ""]
    return lines


def sweep_lines(report: dict) -> list[str]:
    """The accuracy, timing and per-stage sections (none for an initialisation study)."""
    if report.get("accuracy") is None:
        return []
    return (["## Accuracy (thesis Table 5.1)", "", ACCURACY_INTRO, ""] + accuracy_lines(report) + [""]
            + ["## Timing (thesis Table 5.2)", "", TIMING_INTRO, ""] + timing_lines(report) + [""]
            + ["## Per-stage timings", "", "Milliseconds per call, mean ± std over all runs of the profile.", ""]
            + stage_lines(report) + [""])


def plot_lines(plots: list[str], plot_note: str) -> list[str]:
    if not (plots or plot_note):
        return []
    lines = ["## Plots", ""] + [f"![{Path(p).stem}]({Path(p).name})" for p in plots]
    if plot_note:
        lines.append(plot_note)
    return lines + [""]


def run_list_lines(report: dict) -> list[str]:
    if not report.get("runs"):
        return []
    return ["## Runs", ""] + runs_lines(report) + [
        "", "Each run's files and log are under `runs/<sequence>/<profile>/<repetition>` "
            "(`init_study/<sequence>/<n>` for the initialisation study).", ""]


def render_markdown(report: dict, plots: list[str], plot_note: str = "") -> str:
    """``report.md`` of a report dictionary (``plots``: the PNG files written beside it)."""
    return "\n".join(header_lines(report) + sweep_lines(report) + init_study_lines(report)
                     + plot_lines(plots, plot_note) + startup_lines(report) + run_list_lines(report))


def json_ready(o):
    """A copy that ``json.dumps`` takes: NaN/inf floats -> None (JSON has no NaN), numpy numbers and
    arrays -> Python numbers and lists, paths -> strings, keys -> strings."""
    if isinstance(o, dict):
        return {str(k): json_ready(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [json_ready(v) for v in o]
    if isinstance(o, np.ndarray):
        return json_ready(o.tolist())
    if isinstance(o, (float, np.floating)):
        return float(o) if math.isfinite(o) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, Path):
        return str(o)
    return o


def write_report(report: dict, out: Path, plots: bool = True,
                 log: Callable[[str], None] | None = None) -> list[Path]:
    """Write ``report.json``, the PNG plots (if matplotlib is installed) and ``report.md``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plot_paths: list[Path] = []
    note = ""
    if plots:
        try:
            plot_paths = make_plots(report, out)
        except MissingExtraError as err:
            note = f"Plots skipped: {err}"
            if log:
                log(f"warning: {err}")
    report["plots"] = [p.name for p in plot_paths]
    json_path = out / "report.json"
    json_path.write_text(json.dumps(json_ready(report), indent=1, allow_nan=False) + "\n", encoding="utf-8")
    md_path = out / "report.md"
    md_path.write_text(render_markdown(report, [str(p) for p in plot_paths], note), encoding="utf-8")
    return [md_path, json_path, *plot_paths]
