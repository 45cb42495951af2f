"""Report writing for ``lite-vo profile``: ``report.json``, ``report.md`` and PNG plots.

Owns the presentation of the dictionary built by :func:`lite_vo.profiler.run_profile`: the
accuracy table (thesis Table 5.1), the timing table (Table 5.2), per-stage timings, the
cold/warm start-up table, the initialisation study (Fig. 5.8), the list of runs and the machine.
Plots use matplotlib, imported lazily (``pip install lite-vo[plot]``); when it is missing the
report says so and everything else is still written.

Imports: the standard library, numpy; matplotlib only inside the plot functions. No other part
of ``lite_vo`` except ``lite_vo.errors``.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .errors import MissingExtraError


def _num(x: Any, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}f}"


def _ms(stats: dict | None, digits: int = 1) -> str:
    if not stats:
        return "-"
    return f"{stats['mean']:.{digits}f} ± {stats['std']:.{digits}f}"


def _cell(cell: dict | None, key: str, digits: int = 2) -> str:
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


def _profiles_sorted(report: dict) -> list[str]:
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
    profiles = _profiles_sorted(report)
    header = ["profile", "mapping", "tracking"]
    for s in seqs:
        header += [f"{s} (cm/s)", f"{s} (deg/s)"]
    rows = []
    for p in profiles:
        m, t = _res(report, p)
        row = [p, m, t]
        for s in seqs:
            cell = acc[s].get(p)
            row += [_cell(cell, "rpe_trans_cm_per_s"), _cell(cell, "rpe_rot_deg_per_s")]
        rows.append(row)
    lines = _table(header, rows)
    header2 = ["profile"] + [f"{s} ATE (m)" for s in seqs] + [f"{s} scale" for s in seqs]
    rows2 = []
    for p in profiles:
        rows2.append([p] + [_cell(acc[s].get(p), "ate_rmse_m", 3) for s in seqs]
                     + [_cell(acc[s].get(p), "scale", 3) for s in seqs])
    return lines + ["", "Absolute trajectory error after alignment, and the alignment scale:", ""] + _table(header2, rows2)


def timing_lines(report: dict) -> list[str]:
    timing = report.get("timing") or {}
    rows = []
    for p in _profiles_sorted(report):
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
    profiles = _profiles_sorted(report)
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


def init_study_lines(report: dict) -> list[str]:
    study = report.get("init_study") or {}
    if not study:
        return []
    runs = [r for r in report.get("runs", []) if r.get("kind") == "init"]
    any_s = next(iter(study.values()))
    crit = any_s.get("criterion", {})
    lines = ["## Initialisation study (thesis Fig. 5.8)", "",
             f"Random initialisation (profile `{report.get('init_study_profile')}`) on sub-sequences of "
             f"{report.get('settings', {}).get('init_study_len')} s from evenly spaced start frames, "
             "one seed each. A run succeeds when the relative depth error (median over the map's pixels, after "
             f"choosing the optimal scale, of the last map at or before {crit.get('depth_at_s')} s) is at most "
             f"{crit.get('depth_error_max', 0):.0%} and the final relative translational drift over "
             f"{crit.get('drift_frames')} frames (with the Sim(3) scale of the whole run) is at most "
             f"{crit.get('drift_max', 0):.0%} (chapter 5.4; the paper reports 67% on fr2/desk with mapping on every "
             "4th frame). Runs that end lost (`status 'lost'`) also count as failures.", ""]
    rows = [[s, str(v["runs"]), str(v["successes"]),
             f"{v['success_rate']:.0%}" if v.get("success_rate") is not None else "-", str(v["crashed"])]
            for s, v in study.items()]
    lines += _table(["sequence", "runs", "successes", "success rate", "crashed"], rows) + [""]
    prow = []
    for r in runs:
        de = r.get("depth_error")
        at = r.get("depth_error_at_s")
        at_txt = f" (at {at:.1f} s)" if isinstance(at, (int, float)) else (" (at end)" if at else "")
        prow.append([r["seq_name"], str(r.get("start_frame")), str(r.get("seed")),
                     (f"{de:.1%}" + at_txt) if de is not None else "-",
                     f"{r['final_drift']:.1%}" if r.get("final_drift") is not None else "-",
                     "yes" if r.get("success") else "no", r.get("init_reason") or r.get("reason") or ""])
    lines += _table(["sequence", "start frame", "seed", "depth error", "final drift", "success", "why not"], prow)
    def at(series: dict | None, i: int) -> str:
        b = series["bins"][i] if series and i < len(series["bins"]) else None
        return f"{b['mean']:.1%} (n={b['n']})" if b and b["mean"] is not None else "-"

    for s, v in study.items():
        cols = [v.get(k) for k in ("depth_error_over_time", "tracking_error_over_time",
                                   "depth_error_over_time_all", "tracking_error_over_time_all")]
        longest = max((c for c in cols if c), key=lambda c: len(c["bins"]), default=None)
        if longest is None:
            continue
        lines += ["", f"Mean errors over time on {s} (Fig. 5.8), of the successful runs and of all runs that "
                      "did not crash (tracking error: translational drift per 0.5 s relative to the distance "
                      "travelled):", ""]
        rows = [[f"{b['t0']:.1f}-{b['t1']:.1f}"] + [at(c, i) for c in cols] for i, b in enumerate(longest["bins"])]
        lines += _table(["time (s)", "depth error (successful)", "tracking error (successful)",
                         "depth error (all)", "tracking error (all)"], rows)
    return lines + [""]


def render_markdown(report: dict, plots: list[str], plot_note: str = "") -> str:
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

    if report.get("accuracy") is not None:
        lines += ["## Accuracy (thesis Table 5.1)", "",
                  "Drift per second: RMSE of the relative pose error over 1-second pairs, translation in cm/s "
                  "and rotation in deg/s, after SE(3) alignment for depth-initialised (metric) runs and Sim(3) "
                  "alignment otherwise. Mean ± std over repetitions; `n/a` when the runs were too short for the "
                  "1-second pairs; `fail` when tracking was lost (any lost "
                  "frame, unless `--max-lost-ratio` allows some) or the run did not end with status ok; "
                  "`crash` when the run process failed. Resolutions are image widths (heights follow the "
                  "camera's aspect ratio).", ""]
        lines += accuracy_lines(report) + [""]
        lines += ["## Timing (thesis Table 5.2)", "",
                  "Milliseconds per tracked frame (whole tracking) and per mapping iteration, mean ± std pooled "
                  "over all runs of the profile (sync mode, so tracking and mapping did not overlap). "
                  "The paper's phone numbers (Sony Xperia Z1, 320x240 mapping, NEON): tracking 14.7 ± 6.8 ms, "
                  "mapping 52.6 ± 37.7 ms. The median (of the runs' medians) is less sensitive to the first "
                  "frame of each process, which also loads the compiled kernels from numba's cache.", ""]
        lines += timing_lines(report) + [""]
        lines += ["## Per-stage timings", "", "Milliseconds per call, mean ± std over all runs of the profile.", ""]
        lines += stage_lines(report) + [""]
    lines += init_study_lines(report)
    if plots or plot_note:
        lines += ["## Plots", ""]
        lines += [f"![{Path(p).stem}]({Path(p).name})" for p in plots]
        if plot_note:
            lines.append(plot_note)
        lines.append("")
    lines += startup_lines(report)
    if report.get("runs"):
        lines += ["## Runs", ""] + runs_lines(report) + [""]
        lines.append("Each run's files and log are under `runs/<sequence>/<profile>/<repetition>` "
                     "(`init_study/<sequence>/<n>` for the initialisation study).")
        lines.append("")
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Plots (matplotlib, lazily)
# ----------------------------------------------------------------------------------------------

def _figure(*args, **kwargs):
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
    profiles = sorted(_profiles_sorted(report), key=lambda p: (
        -(res[p].get("map_width") or 0), -(res[p].get("track_width") or 0)))
    return profiles, [res[p].get("label", p) for p in profiles]


def plot_accuracy(report: dict, path: Path) -> Path:
    """Drift (cm/s, deg/s) per profile, ordered from the finest to the coarsest resolution."""
    profiles, labels = _profiles_by_resolution(report)
    x = np.arange(len(profiles))
    fig = _figure(figsize=(9, 3.6), layout="constrained")
    axes = fig.subplots(1, 2)
    for ax, key, unit in zip(axes, ("rpe_trans_cm_per_s", "rpe_rot_deg_per_s"), ("cm/s", "deg/s")):
        for s, cells in (report.get("accuracy") or {}).items():
            ys, es = [], []
            for i, p in enumerate(profiles):
                c = cells.get(p) or {}
                v = c.get(key) if c.get("ok") else None
                ys.append(v["mean"] if v else np.nan)
                es.append(v["std"] if v else 0.0)
            line = ax.errorbar(x, ys, yerr=es, marker="o", capsize=3, label=s)
            # failed runs that could still be evaluated: their drift as crosses
            fx, fy = [], []
            for r in report.get("runs", []):
                if r.get("kind", "sweep") == "sweep" and r["seq_name"] == s and r["status"] == "fail" \
                        and r.get("eval") and r["eval"].get(key) is not None and r["profile"] in profiles:
                    fx.append(profiles.index(r["profile"]))
                    fy.append(r["eval"][key])
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
    fig = _figure(figsize=(6.5, 3.8), layout="constrained")
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
    fig = _figure(figsize=(9, 3.6), layout="constrained")
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


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _finite(o):
    """A copy with NaN/inf floats replaced by None (JSON has no NaN)."""
    if isinstance(o, dict):
        return {str(k): _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    if isinstance(o, np.ndarray):
        return _finite(o.tolist())
    if isinstance(o, (float, np.floating)):
        return float(o) if math.isfinite(o) else None
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
    json_path.write_text(json.dumps(_finite(report), indent=1, default=_json_default, allow_nan=False)
                         + "\n", encoding="utf-8")
    md_path = out / "report.md"
    md_path.write_text(render_markdown(report, [str(p) for p in plot_paths], note), encoding="utf-8")
    return [md_path, json_path, *plot_paths]
