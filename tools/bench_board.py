#!/usr/bin/env python3
"""The `board` profile on one pinned core: whole-program cost per frame, peak RSS, warm start.

Issue 19, item 3: a Raspberry Pi 4 class core is about 5x slower than a core of this machine, so
the `board` profile must cost <= 6.6 ms per frame here (30 Hz there), with a peak RSS <= 250 MB and
<= 2 s from a warm start (kernels cached by `lite-vo warmup`) to the first tracked frame.

Each run is the command a user types, in a fresh process pinned to one core with one numba thread:

    taskset -c CORE env NUMBA_NUM_THREADS=1 lite-vo run SEQ --profile board --init depth --mode sync

and measures
- cost per frame: ``wall_s / frames in`` of its ``timing.json`` (the whole program: decoding,
  rectification, tracking and mapping in one thread, as the README defines it), and the same from
  CPU time: ``cpu_s / frames`` (the frame loop; robust to a shared machine) and, for reference, the
  user+system time after the first pose (which also counts the end-of-run exports),
- peak RSS: ``ru_maxrss`` of the process (``os.wait4``),
- start to first pose / first tracked frame: from starting the process to the first / second line
  of ``trajectory.txt`` (written as the run goes; the first pose is the depth-initialised frame 0,
  the second the first frame tracked against the map), polled every 2 ms.

`lite-vo warmup` runs once before (timed) so the runs load every kernel from numba's cache. The
medians of ``--repeat`` runs (default 3) go into ``benchmarks/board.md`` with the targets.

    python tools/bench_board.py [--seq ../shared/data/icl_livingroom_211] [--repeat 3] [--core 0]
                                [--out benchmarks/board.md] [--note "text about the machine"]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {"ms_per_frame": 6.6, "loop_cpu_ms_per_frame": 6.6, "peak_rss_mb": 250.0, "first_tracked_s": 2.0}


def lite_vo_command() -> list[str]:
    exe = Path(sys.executable).with_name("lite-vo")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "lite_vo.cli.main"]


def count_lines(path: Path) -> int:
    try:
        with path.open("rb") as f:
            return sum(1 for line in f if line.strip() and not line.startswith(b"#"))
    except OSError:
        return 0


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time of a running process so far (``/proc/PID/stat``), None when unreadable."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def one_run(seq: Path, core: int | None, out: Path, init: str, mode: str, max_frames: int | None,
            profile: str = "board", extra: tuple = (), code: Path | None = None) -> dict:
    """One run of the whole program; the numbers above. ``core``: pin to this core with one numba
    thread (None: not pinned, numba's default threads). ``extra``: more ``lite-vo run`` arguments.
    ``code``: run the packages of this folder instead of the installed ones (``tools/code_under_test.py``)."""
    if out.exists():
        shutil.rmtree(out)
    pin = ["taskset", "-c", str(core)] if core is not None else []
    exe = ([sys.executable, str(ROOT / "tools" / "code_under_test.py"), str(code)] if code is not None
           else lite_vo_command())
    cmd = [*pin, *exe, "run", str(seq), "--profile", profile,
           "--init", init, "--mode", mode, "--out", str(out), "--force", "--quiet", *extra]
    if max_frames:
        cmd += ["--max-frames", str(max_frames)]
    env = dict(os.environ)
    if core is not None:
        env.update(NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    traj = out / "trajectory.txt"
    log = tempfile.TemporaryFile()
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    first = {}
    cpu_at_first = None
    status = None
    while status is None:
        n = count_lines(traj) if len(first) < 2 else 2
        now = time.perf_counter() - t0
        if n >= 1 and 1 not in first:
            first[1] = now
            cpu_at_first = cpu_seconds(proc.pid)
        if n >= 2:
            first.setdefault(2, now)
        pid, st, ru = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            status, rusage = os.waitstatus_to_exitcode(st), ru
            proc.returncode = status
        else:
            time.sleep(0.002)
    total_s = time.perf_counter() - t0
    if status != 0:
        log.seek(0)
        raise RuntimeError(f"run failed (exit {status}): {' '.join(cmd)}\n{log.read().decode(errors='replace')[-2000:]}")
    timing = json.loads((out / "timing.json").read_text())
    run = json.loads((out / "run.json").read_text())
    frames = run["frames"]
    cpu_total = rusage.ru_utime + rusage.ru_stime
    return {
        "cpu_ms_per_frame": (1000.0 * (cpu_total - cpu_at_first) / max(1, frames["in"] - 1)
                             if cpu_at_first is not None else None),
        "ms_per_frame": 1000.0 * timing["wall_s"] / max(1, frames["in"]),
        "loop_cpu_ms_per_frame": (1000.0 * timing["cpu_s"] / max(1, frames["in"]) if "cpu_s" in timing else None),
        "peak_rss_mb": rusage.ru_maxrss / 1024.0,  # KiB on Linux
        "first_pose_s": first.get(1), "first_tracked_s": first.get(2),
        "process_s": total_s, "process_cpu_s": cpu_total, "cpu_at_first_pose_s": cpu_at_first, "wall_s": timing["wall_s"], "frames_in": frames["in"],
        "tracked": frames["tracked"], "status": run["status"],
        "tracking_median_ms": timing["tracking"]["median"], "mapping_median_ms": timing["mapping"]["median"],
        "mapping_count": timing["mapping"]["count"],
        "stages": {k: v["median"] for k, v in timing.get("stages", {}).items()},
    }


def run_medians(runs: list[dict], skip: tuple = ()) -> dict:
    """Per key of :func:`one_run`'s results (except ``skip``): the median over the runs that have a
    value, None for keys that are not numbers."""
    return {k: (statistics.median([r[k] for r in runs if r[k] is not None])
                if any(r[k] is not None for r in runs) and isinstance(runs[0][k], (int, float)) else None)
            for k in runs[0] if k not in skip}


def machine() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "machine": platform.machine()}


#: packages outside the core install (extras and development tools) that a board install does not have
OPTIONAL_PACKAGES = ("pybullet", "trimesh", "moderngl", "matplotlib", "rerun", "rosbags", "pytest")


def environment() -> str:
    """Which Python environment ran the benchmark: core-only (what a board gets) or with extras."""
    import importlib.util
    extra = [p for p in OPTIONAL_PACKAGES if importlib.util.find_spec(p) is not None]
    return (f"`{sys.prefix}`, " + ("core only (`pip install .`, no extras)" if not extra
                                   else "with " + ", ".join(extra) + " installed"))


def write_markdown(path: Path, res: dict) -> None:
    runs, med = res["runs"], res["median"]
    m = res["machine"]
    rows = [("whole program per frame, wall (ms)", "ms_per_frame", 2),
            ("whole program per frame, CPU time of the frame loop (ms)", "loop_cpu_ms_per_frame", 2),
            ("peak RSS (MB)", "peak_rss_mb", 0),
            ("warm start to first tracked frame (s)", "first_tracked_s", 2)]
    L = ["# The `board` profile on one pinned core", "",
         "Issue 19, item 3: a Raspberry Pi 4 class core is about 5x slower than a core of this machine, so "
         "the `board` profile has to fit these targets here to run at 30 Hz there. Written by:", "",
         "```bash", res["command"], "```", "",
         f"Each run: `{res['run_command']}` (a fresh process; after one `lite-vo warmup`, "
         f"{res['warmup_s']:.1f} s, so every kernel loads from numba's cache).", "",
         f"Machine: {m['cpu']}, {m['cores']} logical cores, Python {m['python']}, {m['machine']}; "
         f"load average {res['loadavg_before']} before the runs, {res['loadavg_after']} after. "
         f"Python environment: {res['environment']}.", ""]
    if res.get("note"):
        L += [f"**Note:** {res['note']}", ""]
    L += ["| what | " + " | ".join(f"run {i + 1}" for i in range(len(runs))) + " | median | target | met |",
          "|---|" + "---|" * (len(runs) + 3)]
    for label, key, d in rows:
        v = med[key]
        met = "-" if v is None else ("yes" if v <= TARGETS[key] else "**no**")
        L.append(f"| {label} | " + " | ".join("-" if r[key] is None else f"{r[key]:.{d}f}" for r in runs)
                 + f" | **{'-' if v is None else f'{v:.{d}f}'}** | <= {TARGETS[key]:g} | {met} |")
    for label, key, d in (("CPU time after the first pose per frame, end-of-run exports included (ms)", "cpu_ms_per_frame", 2),
                          ("process start to first pose (frame 0, depth init) (s)", "first_pose_s", 2),
                          ("whole process, wall (s)", "process_s", 1),
                          ("whole process, CPU time user+sys (s)", "process_cpu_s", 1),
                          ("CPU time until the first pose (start-up, imports, cache loads) (s)", "cpu_at_first_pose_s", 2),
                          ("tracking median (ms)", "tracking_median_ms", 2),
                          ("mapping iteration median (ms)", "mapping_median_ms", 1),
                          ("mapping iterations", "mapping_count", 0)):
        v = med[key]
        L.append(f"| {label} | " + " | ".join("-" if r[key] is None else f"{r[key]:.{d}f}" for r in runs)
                 + f" | {'-' if v is None else f'{v:.{d}f}'} | | |")
    r0 = runs[0]
    L += ["", f"Frames: {r0['frames_in']} in, {r0['tracked']} tracked, status `{r0['status']}` (run 1). "
          "Per frame = `wall_s` / frames of `timing.json`; peak RSS = `ru_maxrss` of the process; the start "
          "times are measured from starting the process to the first / second line of `trajectory.txt`. "
          "On a shared machine the wall times include waiting for the core; the CPU time of the frame loop "
          "(`cpu_s` / frames of `timing.json`: the process's CPU time from the first frame to the last) does "
          "not, so it is the better estimate of the cost on an idle core. The CPU time after the first pose "
          "(from `/proc/PID/stat` and `ru_utime`/`ru_stime`) also counts the end-of-run exports (the "
          "whole-scene `map.ply`, plots).", ""]
    path.write_text("\n".join(L), encoding="utf-8")
    path.with_suffix(".json").write_text(json.dumps(res, indent=2) + "\n", encoding="utf-8")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--seq", type=Path, default=ROOT.parent / "shared" / "data" / "icl_livingroom_211")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--core", type=int, default=0)
    ap.add_argument("--init", default="depth", choices=("depth", "random", "auto"))
    ap.add_argument("--mode", default="sync", choices=("sync", "realtime"))
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "board.md")
    ap.add_argument("--note", default="", help="a sentence about the machine's state, printed in the file")
    args = ap.parse_args(argv)
    if not (args.seq / "rgb.txt").exists():
        print(f"bench_board: sequence not found: {args.seq}", file=sys.stderr)
        return 1
    if shutil.which("taskset") is None:
        print("bench_board: needs taskset (util-linux)", file=sys.stderr)
        return 1
    t = time.perf_counter()
    subprocess.run([*lite_vo_command(), "warmup", "--quiet"], check=True)
    warmup_s = time.perf_counter() - t
    load_before = " / ".join(f"{x:.2f}" for x in os.getloadavg())
    runs = []
    with tempfile.TemporaryDirectory(prefix="bench_board_") as tmp:
        for i in range(args.repeat):
            r = one_run(args.seq, args.core, Path(tmp) / f"run{i}", args.init, args.mode, args.max_frames)
            print(f"run {i + 1}: {r['ms_per_frame']:.2f} ms/frame, peak RSS {r['peak_rss_mb']:.0f} MB, "
                  f"first tracked frame after {r['first_tracked_s']:.2f} s", flush=True)
            runs.append(r)
    median = run_medians(runs)
    shown, skip = [], False
    for a in sys.argv[1:] if argv is None else argv:
        if skip or a.startswith("--note"):
            skip = a == "--note"
            continue
        shown.append(a)
    cmd = " ".join(["NUMBA_NUM_THREADS=1 python tools/bench_board.py", *shown, '--note "..."' if args.note else ""])
    res = {"command": cmd.strip(),
           "run_command": f"taskset -c {args.core} env NUMBA_NUM_THREADS=1 lite-vo run {args.seq.name} --profile board "
                          f"--init {args.init} --mode {args.mode}"
                          + (f" --max-frames {args.max_frames}" if args.max_frames else ""),
           "warmup_s": warmup_s, "loadavg_before": load_before,
           "loadavg_after": " / ".join(f"{x:.2f}" for x in os.getloadavg()),
           "machine": machine(), "environment": environment(), "note": args.note, "targets": TARGETS, "runs": runs, "median": median}
    write_markdown(args.out, res)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
