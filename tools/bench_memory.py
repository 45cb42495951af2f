#!/usr/bin/env python
"""Memory over long runs: peak RSS after 1k/5k/10k frames for ``lite-vo run``, ``lite-vo ar`` and the API.

The sequence is ICL living room played back and forth (``tools/pingpong.py``: frames 0..210, 209..1,
0.. at 30 Hz, the same image files listed again), processed in sync mode with the phone profile
(depth initialisation). Each measurement is a fresh process; a probe records, every 100 frames,
the process's RSS and peak RSS (``/proc/self/status`` VmRSS/VmHWM), glibc's heap statistics
(``mallinfo2``: bytes in use, free bytes held by the allocator, mmapped bytes) and the number of
Python objects, and the peak RSS at each checkpoint frame. What is measured:

* ``run``: ``lite-vo run`` (the CLI's own code path, all output sinks: trajectory.txt, run.json,
  timing.json, map.ply, depth accuracy, ``--format kitti``, ``--plot``);
* ``session``: the Python API, ``lite_vo.Session(path, config).run()`` with no sinks;
* ``loop``: a bare Python loop over ``VisualOdometry.process`` (no reader thread, no session);
* ``ar``: ``lite-vo ar`` (``ar_demo.run.run_ar``, software GL: slow; video at the camera size);
* ``reader`` (diagnostic, fast): the session's reader thread (``prefetch``: decoding in one thread,
  freeing in the other) and the VO's preprocessing (rectify, pyramid, depth) only: the allocator's
  side of a long run without tracking and mapping.

``--tracemalloc`` adds tracemalloc snapshots (top growth by line between the first and the last
checkpoint); it slows the run, so the RSS numbers of such runs are not reported.

Writes ``benchmarks/memory.md`` and ``benchmarks/memory.json``:

    python tools/bench_memory.py --what run,session,loop --repeat 3
    python tools/bench_memory.py --what ar --repeat 1 --checkpoints 1055,5275
    python tools/bench_memory.py --what run --tracemalloc --checkpoints 1055,5275 --no-write
"""
from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import gc
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SEQ = ROOT.parent / "shared" / "data" / "icl_livingroom_211"
WHATS = ("run", "session", "loop", "ar", "reader")
#: the issue's target: peak RSS after 5275 frames at most this far above the peak after 1055
CREEP_LIMIT_MB = 25.0
CORE_RUN_LIMIT_MB = 250.0


# ----------------------------------------------------------------------------------------------
# measuring (in the child process)
# ----------------------------------------------------------------------------------------------

def proc_status() -> dict:
    """VmRSS and VmHWM (peak) of this process in MB (Linux; ``resource`` elsewhere: peak only)."""
    out = {}
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith(("VmRSS:", "VmHWM:")):
                    out[line[:5]] = int(line.split()[1]) / 1024.0
    except OSError:
        import resource
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        peak = peak / 2**20 if sys.platform == "darwin" else peak / 1024.0
        out = {"VmRSS": float("nan"), "VmHWM": peak}
    return {"rss_mb": out.get("VmRSS", float("nan")), "peak_mb": out.get("VmHWM", float("nan"))}


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                               "fsmblks", "uordblks", "fordblks", "keepcost")]


def _mallinfo2():
    name = ctypes.util.find_library("c")
    try:
        fn = ctypes.CDLL(name).mallinfo2
    except (OSError, AttributeError, TypeError):
        return None
    fn.restype = _Mallinfo2
    return fn


_MALLINFO = _mallinfo2()


def heap_stats() -> dict:
    """glibc heap: bytes in use, free bytes the allocator keeps, mmapped bytes (MB); {} elsewhere."""
    if _MALLINFO is None:
        return {}
    m = _MALLINFO()
    return {"heap_used_mb": m.uordblks / 2**20, "heap_free_mb": m.fordblks / 2**20, "mmap_mb": m.hblkhd / 2**20}


class Probe:
    """Samples memory every ``every`` frames and at the checkpoints; optional tracemalloc snapshots."""

    def __init__(self, checkpoints, every: int = 100, trace: bool = False, trace_start: int = 200,
                 out: Path | None = None) -> None:
        self.checkpoints = sorted(checkpoints)
        self.out = out                     # the samples so far are written here at every checkpoint
        self.every, self.trace, self.trace_start = every, trace, trace_start
        self.frames = 0
        self.samples: list[dict] = []
        self.peaks: dict[int, float] = {}
        self.snapshots: dict[int, object] = {}
        self.t0 = time.perf_counter()

    def frame(self) -> None:
        self.frames += 1
        n = self.frames
        if self.trace and n == self.trace_start:
            import tracemalloc
            tracemalloc.start(1)
        if n % self.every == 0 or n in self.checkpoints:
            s = {"frame": n, "t_s": time.perf_counter() - self.t0, **proc_status(), **heap_stats(),
                 "py_objects": len(gc.get_objects())}
            self.samples.append(s)
            if n in self.checkpoints:
                self.peaks[n] = s["peak_mb"]
                if self.trace and n > self.trace_start:
                    import tracemalloc
                    self.snapshots[n] = tracemalloc.take_snapshot()
                if self.out is not None:
                    self.out.write_text(json.dumps({"frames": n, "peaks": self.peaks, "samples": self.samples,
                                                    "wall_s": time.perf_counter() - self.t0, "partial": True}))

    def result(self) -> dict:
        out = {"frames": self.frames, "peaks": self.peaks, "samples": self.samples,
               "wall_s": time.perf_counter() - self.t0}
        if len(self.snapshots) >= 2:
            import tracemalloc
            keys = sorted(self.snapshots)
            first, last = self.snapshots[keys[0]], self.snapshots[keys[-1]]
            stats = last.compare_to(first, "lineno")
            out["tracemalloc"] = {
                "from_frame": keys[0], "to_frame": keys[-1],
                "traced_mb": {k: sum(s.size for s in self.snapshots[k].statistics("filename")) / 2**20 for k in keys},
                "top_growth": [{"where": str(s.traceback), "size_diff_kb": s.size_diff / 1024,
                                "count_diff": s.count_diff} for s in stats[:15]]}
            tracemalloc.stop()
        return out


def _probe_sink(probe: Probe):
    from lite_vo.session import OutputSink

    class ProbeSink(OutputSink):
        def on_frame(self, event) -> None:
            probe.frame()

    return ProbeSink()


def _hook_sessions(probe: Probe) -> None:
    """Every :class:`lite_vo.Session` run in this process also feeds ``probe`` (for the CLI commands)."""
    from lite_vo import session as session_mod
    run = session_mod.Session.run

    def run_with_probe(self):
        self.sinks = list(self.sinks) + [_probe_sink(probe)]
        return run(self)

    session_mod.Session.run = run_with_probe


def child(what: str, seq: str, frames: int, checkpoints, trace: bool, workdir: Path, out: Path) -> dict:
    import logging
    logging.disable(logging.WARNING)  # lost/re-init messages are not what is measured here
    probe = Probe(checkpoints, trace=trace, out=out)
    if what == "run":
        from lite_vo.cli.main import main
        _hook_sessions(probe)
        rc = main(["run", seq, "--out", str(workdir / "run"), "--force", "--quiet", "--max-frames", str(frames),
                   "--mode", "sync", "--profile", "phone", "--format", "kitti", "--plot"])
        if rc != 0:
            raise SystemExit(f"lite-vo run exited with {rc}")
    elif what == "ar":
        from lite_vo.cli.main import main
        _hook_sessions(probe)
        rc = main(["ar", seq, "--out", str(workdir / "ar.mp4"), "--force", "--quiet", "--max-frames", str(frames),
                   "--mode", "sync", "--profile", "phone", "--trajectory", str(workdir / "ar_traj.txt")]
                  + [a for kv in filter(None, os.environ.get("BENCH_MEMORY_AR_SET", "").split(";"))
                     for a in ("--ar-set", kv)])
        if rc != 0:
            raise SystemExit(f"lite-vo ar exited with {rc}")
    elif what == "session":
        import lite_vo
        lite_vo.Session(seq, lite_vo.load_profile("phone"), sinks=[_probe_sink(probe)], max_frames=frames).run()
    elif what == "loop":
        import lite_vo
        from lite_vo.io import open_sequence
        from lite_vo.warmup import CORE_KERNEL_MODULES, warmup
        warmup(CORE_KERNEL_MODULES)
        s = open_sequence(seq)
        vo = lite_vo.VisualOdometry(s.camera, lite_vo.load_profile("phone"))
        for i in range(frames):
            fr = s.frame(i)
            vo.process(fr.image, fr.timestamp, depth=fr.depth)
            probe.frame()
        vo.close()
    elif what == "reader":
        import lite_vo
        from lite_vo.io import open_sequence
        from lite_vo.session import prefetch
        s = open_sequence(seq)
        vo = lite_vo.VisualOdometry(s.camera, lite_vo.load_profile("phone"))
        for fr in prefetch(s, 0, frames):
            vo._preprocess(fr.image, fr.timestamp, fr.depth)
            probe.frame()
    else:
        raise SystemExit(f"unknown measurement {what!r}")
    return probe.result()


# ----------------------------------------------------------------------------------------------
# driving (in the parent process)
# ----------------------------------------------------------------------------------------------

def measure(what: str, seq: Path, frames: int, checkpoints, trace: bool, env_extra: dict, knobs=(),
            code: str | None = None) -> dict:
    with tempfile.TemporaryDirectory(prefix=f"bench_memory_{what}_") as tmp:
        out = Path(tmp) / "result.json"
        cmd = [sys.executable, __file__, "--child", what, "--sequence", str(seq), "--frames", str(frames),
               "--checkpoints", ",".join(map(str, checkpoints)), "--child-out", str(out), "--workdir", tmp]
        if trace:
            cmd.append("--tracemalloc")
        for k in knobs:
            cmd += ["--knob", k]
        if code:
            cmd += ["--code", code]
        env = dict(os.environ, **env_extra)
        t = time.perf_counter()
        rc = subprocess.run(cmd, env=env).returncode
        if rc != 0 and not out.is_file():
            raise SystemExit(f"{what}: the measuring process failed (exit status {rc}) before the first checkpoint")
        res = json.loads(out.read_text())
        if rc != 0:
            res["error"] = f"exit status {rc} after frame {res['frames']}"
        res["process_s"] = time.perf_counter() - t
        return res


def machine() -> str:
    from lite_vo.sinks import cpu_model
    try:
        libc = " ".join(platform.libc_ver())
    except Exception:  # noqa: BLE001
        libc = "?"
    mem = ""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            mem = f", {int(f.readline().split()[1]) / 2**20:.1f} GB RAM"
    except OSError:
        pass
    return (f"{platform.machine()}, {cpu_model()}, {os.cpu_count()} cores{mem}, {platform.system()} "
            f"{platform.release()}, {libc}, Python {platform.python_version()}")


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.0f}"


def table(results: list[dict], checkpoints) -> list[str]:
    lo, hi = checkpoints[0], checkpoints[min(1, len(checkpoints) - 1)]
    head = " | ".join(f"peak @ {c}" for c in checkpoints)
    lines = [f"| what | run | {head} | {hi} - {lo} | target (<= {CREEP_LIMIT_MB:.0f} MB) | RSS @ {lo} -> {hi} | "
             f"RSS at end | heap free at end | Python objects {lo} -> end | s/frame |",
             "|---|---|" + "---|" * len(checkpoints) + "---|---|---|---|---|---|---|"]
    for r in results:
        peaks = {int(k): v for k, v in r["peaks"].items()}
        d = peaks[hi] - peaks[lo] if lo in peaks and hi in peaks else None
        ok = "-" if d is None else ("ok" if d <= CREEP_LIMIT_MB else "**missed**")
        last = r["samples"][-1]
        first = next((s for s in r["samples"] if s["frame"] == lo), r["samples"][0])
        at_hi = next((s for s in r["samples"] if s["frame"] == hi), None)
        rss_hi = "-" if at_hi is None else f"{at_hi['rss_mb']:.0f}"
        rss = f"{first['rss_mb']:.0f} -> {rss_hi}"
        free = last.get("heap_free_mb")
        what = r["what"] + (f" ({r['error']})" if r.get("error") else "")
        lines.append(f"| {what} | {r['repeat']} | " + " | ".join(_fmt(peaks.get(c)) for c in checkpoints)
                     + f" | {'-' if d is None else f'{d:+.1f}'} | {ok} | {rss} | {last['rss_mb']:.0f} | "
                     f"{'-' if free is None else f'{free:.0f}'} | {first['py_objects']} -> {last['py_objects']} | "
                     f"{r['wall_s'] / max(r['frames'], 1) * 1e3:.1f} ms |")
    return lines


def rss_trace(r: dict, every: int = 1000) -> str:
    """RSS (MB) every ``every`` frames of one result, for the report."""
    return " ".join(f"{s['rss_mb']:.0f}" for s in r["samples"] if s["frame"] % every == 0)


def write_report(groups: list[tuple[str, list[dict], list[int]]], path: Path, env_note: str,
                 notes: str = "") -> None:
    """``memory.md``: one table per group (label, results, checkpoints), RSS traces, ``notes``."""
    lines = ["# Memory over long runs", "",
             f"Generated by `python tools/bench_memory.py {shlex.join(sys.argv[1:])}` on "
             f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC.", "",
             f"Machine: {machine()}; shared with other jobs, so the s/frame column is not a speed figure "
             f"(speed: `benchmarks/whole_program.md`). {env_note}", "",
             "Sequence: ICL living room 211 played back and forth (`tools/pingpong.py`: frames 0..210, 209..1, "
             "0.. at 30 Hz, the same files listed again), phone profile, sync mode, depth initialisation. "
             "Each row is a fresh process; *peak @ N* is the peak RSS (VmHWM, MB) after N frames; "
             "*RSS* the resident size then; *heap free* is what glibc's malloc holds without using it "
             "(`mallinfo2().fordblks`, MB); *Python objects* counts the gc-tracked objects.", ""]
    for label, results, checkpoints in groups:
        lines += [f"## {label}", ""] + table(results, checkpoints) + [""]
        lines += [f"- {r['what']} run {r['repeat']}: RSS every 1000 frames (MB): {rss_trace(r)}" for r in results]
        lines.append("")
    if notes:
        lines += [notes.rstrip(), ""]
    path.write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--what", default="run,session,loop", help=f"comma-separated, of {', '.join(WHATS)}")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--checkpoints", default="1055,5275,10000", help="frames at which the peak RSS is taken")
    p.add_argument("--sequence", default=str(DEFAULT_SEQ), help="a TUM folder (played back and forth)")
    p.add_argument("--tracemalloc", action="store_true", help="tracemalloc snapshots (slow; RSS not reported)")
    p.add_argument("--out-dir", default=str(ROOT / "benchmarks"))
    p.add_argument("--name", default="memory", help="report name: <out-dir>/<name>.md and .json")
    p.add_argument("--note", default="", help="a line for the report (e.g. what changed)")
    p.add_argument("--env", action="append", default=[], metavar="NAME=VALUE", help="environment of the children")
    p.add_argument("--ar-set", action="append", default=[], metavar="KEY=VALUE",
                   help="AR settings for the ar child (e.g. world_thread=false)")
    p.add_argument("--knob", action="append", default=[], metavar="NAME=INT",
                   help="set lite_vo.session.NAME (e.g. TRIM_EVERY) in the children: what each fix does")
    p.add_argument("--code", default=None, help="run the children on the lite_vo/ar_demo packages in this folder "
                   "(e.g. `git archive <commit> lite_vo ar_demo profiles | tar -x -C DIR`): before/after numbers")
    p.add_argument("--merge", action="append", default=[], metavar="LABEL=JSON",
                   help="no measuring: write the report from earlier --name JSON files, one table per label")
    p.add_argument("--notes", type=Path, default=None, help="markdown appended to the report (findings)")
    p.add_argument("--no-write", action="store_true", help="print only")
    p.add_argument("--child", choices=WHATS, help=argparse.SUPPRESS)
    p.add_argument("--frames", type=int, help=argparse.SUPPRESS)
    p.add_argument("--child-out", help=argparse.SUPPRESS)
    p.add_argument("--workdir", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    checkpoints = sorted(int(c) for c in args.checkpoints.split(","))

    if args.child:
        if args.code:
            from code_under_test import use_code
            use_code(args.code)
        import lite_vo.session
        for k in args.knob:
            name, value = k.split("=", 1)
            if not hasattr(lite_vo.session, name):
                raise SystemExit(f"lite_vo.session has no {name}")
            setattr(lite_vo.session, name, int(value))
        res = child(args.child, args.sequence, args.frames, checkpoints, args.tracemalloc, Path(args.workdir),
                    Path(args.child_out))
        Path(args.child_out).write_text(json.dumps(res))
        return 0

    notes = args.notes.read_text() if args.notes else ""
    if args.merge:
        groups = {}
        for m in args.merge:
            label, path = m.split("=", 1)
            data = json.loads(Path(path).read_text())
            g = groups.setdefault(label, ([], data["checkpoints"]))
            g[0].extend(data["results"])
        out = Path(args.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        write_report([(label, res, cps) for label, (res, cps) in groups.items()], out / f"{args.name}.md", "", notes)
        (out / f"{args.name}.json").write_text(json.dumps(
            {"machine": machine(), "groups": {label: {"checkpoints": cps, "results": res}
                                              for label, (res, cps) in groups.items()}}, indent=1) + "\n")
        return 0

    sys.path.insert(0, str(ROOT / "tools"))
    from pingpong import write_pingpong

    whats = [w.strip() for w in args.what.split(",") if w.strip()]
    env_extra = dict(e.split("=", 1) for e in args.env)
    if args.ar_set:
        env_extra["BENCH_MEMORY_AR_SET"] = ";".join(args.ar_set)
    results = []
    with tempfile.TemporaryDirectory(prefix="bench_memory_seq_") as tmp:
        seq = write_pingpong(args.sequence, Path(tmp) / "icl_pingpong", max(checkpoints))
        for rep in range(1, args.repeat + 1):
            for what in whats:
                r = measure(what, seq, max(checkpoints), checkpoints, args.tracemalloc, env_extra, args.knob, args.code)
                r.update(what=what, repeat=rep)
                results.append(r)
                print("\n".join(table([r], checkpoints)[2:]), flush=True)
                if "tracemalloc" in r:
                    tm = r["tracemalloc"]
                    print(f"tracemalloc {tm['from_frame']} -> {tm['to_frame']}: traced MB {tm['traced_mb']}")
                    for g in tm["top_growth"]:
                        print(f"  {g['size_diff_kb']:+9.1f} KB {g['count_diff']:+7d}  {g['where']}")
    env_note = ("Child environment: " + ", ".join(args.env) + ". ") if args.env else ""
    env_note += f"Code: {args.code}. " if args.code else ""
    env_note += ("Settings: " + ", ".join(f"lite_vo.session.{k}" for k in args.knob) + ".") if args.knob else ""
    if not args.no_write:
        out = Path(args.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / f"{args.name}.json").write_text(json.dumps({"machine": machine(), "env": env_extra, "knobs": args.knob,
                                                          "checkpoints": checkpoints, "results": results},
                                                         indent=1) + "\n")
        write_report([(args.note or "results", results, checkpoints)], out / f"{args.name}.md", env_note, notes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
