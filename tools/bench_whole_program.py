#!/usr/bin/env python3
"""Whole-program speed: per-frame wall and CPU time and per-stage medians, per profile and sequence.

Issue 18: the whole program (read + decode + rectify + track + map every frame, one process) on ICL,
sync, `phone` should cost <= 5 ms per frame, faster than the C++ LSD-SLAM run on the same frames
(5-8 ms, ``../shared/design/ANCHORS.md``), with tracking <= 1.5 ms per frame (including preprocessing)
and mapping <= 5 ms per iteration. Each run is the command a user types, in a fresh process:

    lite-vo run SEQ --profile P --mode sync [--init depth]

(not pinned, numba's default threads: on this 2-core machine mapping's parallel kernels use both
cores; `--pin-core` pins every run to one core with one numba thread instead). Per run it records
``wall_s / frames`` of ``timing.json`` (the README's definition), the process's CPU time
(user+system) after the first pose per frame (robust to a shared machine, but with two threads it
adds both), the tracking and mapping medians, every stage's median, peak RSS and the trajectory error
(``lite-vo eval``: Sim(3) for monocular runs, SE(3) when depth-initialised). The CPU column is
``cpu_s / frames`` of ``timing.json``: the process's CPU time over the frame loop (all threads), without
start-up and without the end-of-run exports. The median over
``--repeat`` runs goes into ``benchmarks/whole_program.md`` (+ ``.json``).

    python tools/bench_whole_program.py [--profiles phone,board,...] [--repeat 3] [--pin-core]
                                        [--synth-dir DIR] [--out benchmarks/whole_program.md]

Before/after on this machine, whose speed drifts by 20-30 % within a day: ``--ab DIR`` alternates every run
of the code in ``DIR`` (A: ``git archive <commit> lite_vo ar_demo profiles | tar -x -C DIR``, run through
``tools/code_under_test.py``) with one of this tree (B) and adds the B/A ratios (default output
``benchmarks/whole_program_ab.md``).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

from bench_board import lite_vo_command, machine, one_run, run_medians  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
PROFILES = ("desktop", "m640_t320", "m320_t320", "phone", "m160_t160", "m160_t80", "board")
TARGETS = {"ms_per_frame": 5.0, "tracking_median_ms": 1.5, "mapping_median_ms": 5.0}
STAGE_ORDER = ("preprocess", "track_lvl4", "track_lvl3", "track_lvl2", "track_lvl1", "track_lvl0",
               "propagate", "observe", "regularize", "fill", "build_reference")


def sequences(synth_dir: Path) -> list[tuple[str, Path, str]]:
    """(name, folder, init) of the benchmark sequences; the synthetic room is made once if missing."""
    room = synth_dir / "synth_room"
    if not (room / "rgb.txt").exists():
        subprocess.run([*lite_vo_command(), "synth", "--scene", "room", "--trajectory", "handheld",
                        "--out", str(room), "--force"], check=True, stdout=subprocess.DEVNULL)
    return [("ICL living room (211)", DATA / "icl_livingroom_211", "depth"),
            ("synthetic room (300)", room, "depth"),
            ("KITTI 07 (160)", DATA / "kitti07_160", "auto")]


def trajectory_error(seq: Path, out: Path, align: str) -> dict:
    js = out / "eval.json"
    r = subprocess.run([*lite_vo_command(), "eval", "--gt", str(seq), "--est", str(out), "--align", align,
                        "--json", str(js), "--force"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    if r.returncode != 0 or not js.exists():
        return {}
    e = json.loads(js.read_text())
    return {"ate_pct": e.get("ate_pct_of_path"), "rpe_pct": e.get("rpe_trans_pct"),
            "rpe_deg_s": e.get("rpe_rot_deg_per_s"), "raw": e}


def fmt(v, d=2) -> str:
    return "-" if v is None else f"{v:.{d}f}"


def _label(row: dict) -> str:
    return f"`{row['profile']}`" + (f" ({row['code']})" if row.get("code") else "")


def write_markdown(path: Path, res: dict) -> None:
    m = res["machine"]
    L = ["# Whole program per frame", "",
         "Issue 18. Written by:", "", "```bash", res["command"], "```", "",
         f"Each run: `lite-vo run SEQ --profile P --mode sync --init I` in a fresh process "
         f"({'pinned to one core, one numba thread' if res['pin_core'] else 'not pinned, numba threads: all cores'}), "
         f"after one `lite-vo warmup`; medians of {res['repeat']} run(s).", "",
         f"Machine: {m['cpu']}, {m['cores']} logical cores, Python {m['python']}, {m['machine']}; load average "
         f"{res['loadavg_before']} before, {res['loadavg_after']} after.", ""]
    if res.get("note"):
        L += [f"**Note:** {res['note']}", ""]
    if res.get("ab"):
        L += [f"**A/B:** rows marked (A) ran the code in `{res['ab']}` (through `tools/code_under_test.py`), rows "
              "marked (B) this tree; each repeat ran A then B, so both saw the same hour of this machine.", ""]
    L += ["**wall** = `wall_s` / frames of `timing.json` (the whole program: decoding in the reader thread, "
          "rectification, tracking and mapping); **CPU** = `cpu_s` / frames of `timing.json`: the process's CPU "
          "time over the same span (all threads: with two numba threads it adds both cores); tracking = median of the per-frame "
          "tracking time including preprocessing; mapping = median of one mapping iteration (in sync mode every "
          "4th frame is mapped during the first 3 s, then every `system.map_every`-th: 4 for every profile "
          "here but `desktop` and `m640_t320`, which map every frame). Targets on ICL `phone`: wall <= 5 ms, tracking "
          "<= 1.5 ms, mapping <= 5 ms.", "",
          "| sequence | profile | wall ms/frame | CPU ms/frame | tracking ms | mapping ms | peak RSS MB | tracked | "
          "ATE % of path | RPE % / deg/s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for row in res["rows"]:
        md = row["median"]
        err = row.get("error", {})
        L.append(f"| {row['sequence']} | {_label(row)} | **{fmt(md['ms_per_frame'])}** | "
                 f"{fmt(md['loop_cpu_ms_per_frame'])} | {fmt(md['tracking_median_ms'])} | {fmt(md['mapping_median_ms'])} | "
                 f"{fmt(md['peak_rss_mb'], 0)} | {row['tracked']} | {fmt(err.get('ate_pct'))} | "
                 f"{fmt(err.get('rpe_pct'), 1)} / {fmt(err.get('rpe_deg_s'))} |")
    L += ["", "## Stage medians (ms)", "",
          "Per tracked frame (`preprocess`, `track_lvlN`) and per mapping iteration (the rest); from "
          "`timing.json` of the first run.", ""]
    stages = [s for s in STAGE_ORDER if any(s in r["stages"] for r in res["rows"])]
    L += ["| sequence | profile | " + " | ".join(stages) + " |", "|---|---|" + "---|" * len(stages)]
    for row in res["rows"]:
        L.append(f"| {row['sequence']} | {_label(row)} | "
                 + " | ".join(fmt(row["stages"].get(s)) for s in stages) + " |")
    if res.get("ab"):
        L += ["", "## B / A (this tree against the code in " + f"`{res['ab']}`)", "",
              "Ratio of the medians; below 1: this tree is faster. Runs alternated A, B, A, B, ...", "",
              "| sequence | profile | wall | CPU | tracking | mapping | peak RSS |", "|---|---|---|---|---|---|---|"]
        a_rows = {(r["sequence"], r["profile"]): r for r in res["rows"] if r.get("code") == "A"}
        for row in (r for r in res["rows"] if r.get("code") == "B"):
            a = a_rows.get((row["sequence"], row["profile"]))
            if a is None:
                continue
            ratio = [fmt(row["median"][k] / a["median"][k], 3) if row["median"].get(k) and a["median"].get(k) else "-"
                     for k in ("ms_per_frame", "loop_cpu_ms_per_frame", "tracking_median_ms", "mapping_median_ms",
                               "peak_rss_mb")]
            L.append(f"| {row['sequence']} | `{row['profile']}` | " + " | ".join(ratio) + " |")
    icl = [r for r in res["rows"] if r["sequence"].startswith("ICL") and r["profile"] == "phone"
           and r.get("code") != "A"]
    if icl:
        md = icl[0]["median"]
        L += ["", "## Targets (ICL, `phone`, sync)", "", "| what | measured | target | met |", "|---|---|---|---|"]
        for key, label in (("ms_per_frame", "whole program, wall ms per frame"),
                           ("tracking_median_ms", "tracking ms per frame (incl. preprocessing)"),
                           ("mapping_median_ms", "mapping ms per iteration")):
            v = md[key]
            L.append(f"| {label} | {fmt(v)} | <= {TARGETS[key]:g} | {'yes' if v is not None and v <= TARGETS[key] else '**no**'} |")
    L.append("")
    path.write_text("\n".join(L), encoding="utf-8")
    path.with_suffix(".json").write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--profiles", default=",".join(PROFILES))
    ap.add_argument("--sequences", default="icl,synth,kitti", help="any of icl,synth,kitti")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--pin-core", action="store_true", help="pin every run to core 0 with one numba thread")
    ap.add_argument("--synth-dir", type=Path, default=Path(tempfile.gettempdir()) / "lite_vo_bench")
    ap.add_argument("--out", type=Path, default=None, help="default: benchmarks/whole_program.md "
                    "(benchmarks/whole_program_ab.md with --ab)")
    ap.add_argument("--ab", type=Path, default=None, metavar="DIR",
                    help="alternate every run with one of the code in DIR (before/after on the same machine)")
    ap.add_argument("--note", default="")
    args = ap.parse_args(argv)
    if args.out is None:
        args.out = ROOT / "benchmarks" / ("whole_program_ab.md" if args.ab else "whole_program.md")
    if args.ab is not None and not (args.ab / "lite_vo").is_dir():
        print(f"bench_whole_program: --ab {args.ab}: no lite_vo package there", file=sys.stderr)
        return 1
    profiles = [p.strip() for p in args.profiles.split(",") if p.strip()]
    unknown = sorted(set(profiles) - set(PROFILES))
    if unknown:
        print(f"bench_whole_program: unknown profile(s) {', '.join(unknown)}", file=sys.stderr)
        return 1
    if not (DATA / "icl_livingroom_211" / "rgb.txt").exists():
        print(f"bench_whole_program: the shared data is missing ({DATA})", file=sys.stderr)
        return 1
    want = {s.strip() for s in args.sequences.split(",")}
    seqs = [s for s, key in zip(sequences(args.synth_dir), ("icl", "synth", "kitti")) if key in want]
    subprocess.run([*lite_vo_command(), "warmup", "--quiet"], check=True)
    codes = [(None, "")]
    if args.ab is not None:
        subprocess.run([sys.executable, str(ROOT / "tools" / "code_under_test.py"), str(args.ab), "warmup", "--quiet"],
                       check=True)
        codes = [(args.ab, "A"), (ROOT, "B")]    # both through tools/code_under_test.py: the same launcher
    load_before = " / ".join(f"{x:.2f}" for x in os.getloadavg())
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_wp_") as tmp:
        for name, seq, init in seqs:
            for prof in profiles:
                runs = {label: [] for _, label in codes}
                err = {}
                for i in range(args.repeat):
                    for code, label in codes:
                        out = Path(tmp) / f"{seq.name}_{prof}_{label}{i}"
                        runs[label].append(one_run(seq, 0 if args.pin_core else None, out, init, "sync", None,
                                                   profile=prof, code=code))
                        if i == 0:
                            err[label] = trajectory_error(seq, out, "se3" if init == "depth" else "sim3")
                for _, label in codes:
                    rr = runs[label]
                    med = run_medians(rr, skip=("stages",))
                    rows.append({"sequence": name, "profile": prof, "code": label, "runs": rr, "median": med,
                                 "stages": rr[0]["stages"],
                                 "error": {k: v for k, v in err[label].items() if k != "raw"},
                                 "tracked": f"{rr[0]['tracked']}/{rr[0]['frames_in']}"})
                    print(f"{name} {prof}{' ' + label if label else ''}: {med['ms_per_frame']:.2f} ms/frame wall, "
                          f"{fmt(med['loop_cpu_ms_per_frame'])} CPU, tracking {med['tracking_median_ms']:.2f}, "
                          f"mapping {med['mapping_median_ms']:.2f}", flush=True)
    shown = [a for a in (sys.argv[1:] if argv is None else argv)]
    res = {"command": " ".join(["python tools/bench_whole_program.py", *shown]), "pin_core": args.pin_core,
           "repeat": args.repeat, "loadavg_before": load_before,
           "loadavg_after": " / ".join(f"{x:.2f}" for x in os.getloadavg()), "machine": machine(),
           "note": args.note, "targets": TARGETS, "rows": rows, "ab": str(args.ab) if args.ab else None,
           "date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())}
    write_markdown(args.out, res)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
