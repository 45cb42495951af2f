#!/usr/bin/env python3
"""Write ``DIR/report.md`` of ``tools/arm_check.sh``: the arm64 (emulated) run against the host's.

Reads what the check left in ``DIR``: ``check.env`` (date, commit, qemu, mirror), ``steps.tsv`` (time
and status of every step), ``{aarch64,host}/{run.json,timing.json,trajectory.txt,pip_report.json}``
(pip's installation report: which package came as a wheel and which was built from source),
``logs/*-warmup.log`` and, after ``--ar``, ``aarch64/ar_wheels.tsv`` and ``aarch64/pybullet_progress.tsv``.

The trajectory comparison matches poses by timestamp and gives the translation difference in mm
(trajectories of a depth-initialised run are metric) and the rotation difference in degrees. Exit
status 1 when a run is not ``ok``, the two runs track different frames or a difference exceeds the
tolerance (the report is written first). Standard library only: it runs before any venv exists.

    python3 tools/arm_report.py --out DIR [--tol-mm 1.0] [--tol-deg 0.1] [--ar] [--ar-only]
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import re
import sys
from pathlib import Path

SIDES = ("aarch64", "host")


class ReportError(Exception):
    """Bad input to the report (a malformed file), one line naming the file."""


# --------------------------------------------------------------------------------------------------
# Trajectories


def read_tum(path) -> dict[float, tuple[tuple[float, float, float], tuple[float, float, float, float]]]:
    """``{timestamp: ((tx, ty, tz), (qx, qy, qz, qw))}`` of a TUM trajectory file."""
    poses = {}
    path = Path(path)
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 8:
            raise ReportError(f"{path}:{n}: expected 8 numbers (timestamp tx ty tz qx qy qz qw), got {len(parts)}")
        try:
            v = [float(p) for p in parts]
        except ValueError:
            raise ReportError(f"{path}:{n}: not a number in {line!r}") from None
        poses[round(v[0], 6)] = (tuple(v[1:4]), tuple(v[4:8]))
    return poses


def rotation_angle_deg(qa, qb) -> float:
    """The angle of the relative rotation between unit quaternions ``qa`` and ``qb`` (x, y, z, w)."""
    na = math.sqrt(sum(c * c for c in qa))
    nb = math.sqrt(sum(c * c for c in qb))
    d = abs(sum(a * b for a, b in zip(qa, qb))) / (na * nb)
    return math.degrees(2.0 * math.acos(min(1.0, d)))


def compare_trajectories(a: dict, b: dict) -> dict:
    """Differences between two trajectories (``read_tum`` dicts) over their common timestamps."""
    common = sorted(set(a) & set(b))
    dt = [1000.0 * math.dist(a[t][0], b[t][0]) for t in common]
    dr = [rotation_angle_deg(a[t][1], b[t][1]) for t in common]
    return {
        "matched": len(common), "only_a": len(set(a) - set(b)), "only_b": len(set(b) - set(a)),
        "max_mm": max(dt, default=float("nan")), "mean_mm": sum(dt) / len(dt) if dt else float("nan"),
        "final_mm": dt[-1] if dt else float("nan"),
        "max_deg": max(dr, default=float("nan")), "mean_deg": sum(dr) / len(dr) if dr else float("nan"),
    }


# --------------------------------------------------------------------------------------------------
# Packages


def package_sources(report: dict) -> dict[str, dict]:
    """``{name: {version, kind, file}}`` from pip's installation report (``pip install --report``).

    ``kind`` is ``wheel`` (a binary wheel from the index), ``source`` (an sdist, built on the machine)
    or ``local`` (a directory, i.e. this checkout).
    """
    out = {}
    for item in report.get("install", []):
        meta = item.get("metadata", {})
        name = str(meta.get("name", "?")).lower().replace("_", "-")
        info = item.get("download_info", {})
        url = info.get("url", "")
        file = url.rsplit("/", 1)[-1].split("#", 1)[0]
        if "dir_info" in info or url.startswith("file://") and not file.endswith((".whl", ".tar.gz", ".zip")):
            kind, file = "local", "this checkout"
        elif file.endswith(".whl"):
            kind = "wheel"
        else:
            kind = "source"
        out[name] = {"version": str(meta.get("version", "?")), "kind": kind, "file": file}
    return out


def wheel_tag(file: str) -> str:
    """The platform tag of a wheel file name (``manylinux_2_17_aarch64...``), else ``file``."""
    m = re.match(r"^.+?-[^-]+(?:-\d[^-]*)?-([^-]+)-([^-]+)-(.+)\.whl$", file)
    return m.group(3) if m else file


# --------------------------------------------------------------------------------------------------
# Reading the check's folder


def read_steps(path) -> list[dict]:
    path = Path(path)
    if not path.exists():
        return []
    with path.open(encoding="utf-8") as f:
        return list(csv.DictReader(f, delimiter="\t"))


def read_env(path) -> dict:
    env = {}
    path = Path(path)
    if path.exists():
        for line in path.read_text(encoding="utf-8").splitlines():
            key, sep, value = line.partition("=")
            if sep:
                env[key.strip()] = value.strip()
    return env


def read_json(path):
    path = Path(path)
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise ReportError(f"{path}: not valid JSON ({e.msg}, line {e.lineno})") from None


def warmup_seconds(log) -> float | None:
    """The total of ``lite-vo warmup``'s last line (``done: N module(s) warmed up in X s``)."""
    log = Path(log)
    if not log.exists():
        return None
    m = re.findall(r"warmed up in ([0-9.]+) s", log.read_text(encoding="utf-8", errors="replace"))
    return float(m[-1]) if m else None


def _f(x, digits=1) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return f"{x:.{digits}f}"


# --------------------------------------------------------------------------------------------------
# The report


def build_report(out: Path, tol_mm: float, tol_deg: float, ar: bool, ar_only: bool,
                 ar_minutes: float | None = None) -> tuple[str, list[str]]:
    """The markdown text and the list of problems (empty when the check passed)."""
    env = read_env(out / "check.env")
    steps = read_steps(out / "steps.tsv")
    problems = [f"step '{s['side']}: {s['step']}' {s['status']}" for s in steps if s["status"] != "ok"]
    run = {s: read_json(out / s / "run.json") for s in SIDES}
    timing = {s: read_json(out / s / "timing.json") for s in SIDES}
    pips = {s: read_json(out / s / "pip_report.json") for s in SIDES}
    frames = env.get("frames", "?")

    L = ["# ARM check: lite_vo on arm64 (emulated) against this machine", ""]
    L += [f"Made by `tools/arm_check.sh` on {env.get('date', '?')} (commit {env.get('commit', '?')}) on "
          f"{env.get('host_os', '?')}, {env.get('host_kernel', '?')}; arm64 Debian bookworm root made with "
          f"debootstrap from {env.get('mirror', '?')}, run with qemu-user-static {env.get('qemu', '?')} "
          "(binfmt). The emulated steps ran under `nice -n 19` on a machine shared with other work: every "
          "aarch64 time below is an **upper bound** for a real board's, not a measurement of one.", ""]

    cmp = None
    if not ar_only:
        L += ["## Result", ""]
        seqname = (run["host"] or run["aarch64"] or {}).get("sequence", {}).get("name", "?")
        L += [f"`lite-vo run {seqname} --init depth --mode sync --max-frames {frames}` on both sides:", ""]
        for s in SIDES:
            r = run[s]
            if r is None:
                L.append(f"- {s}: no run.json")
                problems.append(f"{s}: no run.json")
                continue
            fr = r.get("frames", {})
            m = r.get("machine", {})
            L.append(f"- {s}: status `{r.get('status')}`, {fr.get('tracked', '?')} of {fr.get('in', '?')} frames "
                     f"tracked; run.json machine: `{m.get('machine')}`, CPU `{m.get('cpu')}`, {m.get('cores')} cores")
            if r.get("status") != "ok":
                problems.append(f"{s}: run status {r.get('status')!r}")
        ta, tb = out / "aarch64" / "trajectory.txt", out / "host" / "trajectory.txt"
        if ta.exists() and tb.exists():
            cmp = compare_trajectories(read_tum(ta), read_tum(tb))
            ok = (cmp["matched"] > 0 and cmp["only_a"] == 0 and cmp["only_b"] == 0
                  and cmp["max_mm"] <= tol_mm and cmp["max_deg"] <= tol_deg)
            L += ["", f"Trajectories (aarch64 against host, {cmp['matched']} poses matched by timestamp, "
                  f"{cmp['only_a']} only on aarch64, {cmp['only_b']} only on the host): translation difference "
                  f"max **{_f(cmp['max_mm'], 4)} mm** (mean {_f(cmp['mean_mm'], 4)}, last pose "
                  f"{_f(cmp['final_mm'], 4)}), rotation difference max **{_f(cmp['max_deg'], 5)} deg** "
                  f"(mean {_f(cmp['mean_deg'], 5)}). Tolerance {tol_mm} mm / {tol_deg} deg: "
                  + ("**within**." if ok else "**exceeded**.")]
            if not ok:
                problems.append(f"trajectories differ: {cmp}")
        else:
            L += ["", "Trajectories: missing, no comparison."]
            problems.append("trajectory missing")

        L += ["", "## Machines and versions (from run.json)", "",
              "| | " + " | ".join(SIDES) + " |", "|---|" + "---|" * len(SIDES)]
        keys = ("machine", "cpu", "python", "numpy", "numba", "opencv", "platform")
        for k in keys:
            L.append(f"| {k} | " + " | ".join(str((run[s] or {}).get("versions", {}).get(k, "-")) for s in SIDES) + " |")
        L += ["", "Under qemu-user `/proc/cpuinfo` is the host's, so the CPU model recorded on the aarch64 "
              "side is the host CPU's name while `platform.machine()` says `aarch64`.", ""]

        L += ["## Per-frame cost of the run (timing.json)", "",
              "| | " + " | ".join(SIDES) + " |", "|---|" + "---|" * len(SIDES)]
        for label, get in (("tracking median (ms)", lambda t: t.get("tracking", {}).get("median")),
                           ("mapping iteration median (ms)", lambda t: t.get("mapping", {}).get("median")),
                           ("wall time (s)", lambda t: t.get("wall_s")),
                           ("wall time per frame (ms)",
                            lambda t: 1000.0 * t["wall_s"] / max(1, t.get("tracking", {}).get("count", 0))
                            if t.get("wall_s") is not None else None)):
            L.append(f"| {label} | " + " | ".join(_f(get(timing[s] or {})) for s in SIDES) + " |")
        ratio = None
        if timing["aarch64"] and timing["host"] and timing["host"].get("wall_s"):
            ratio = timing["aarch64"]["wall_s"] / timing["host"]["wall_s"]
        if ratio:
            L += ["", f"Emulation slowdown on this run: {ratio:.0f}x the host's wall time."]
        L.append("")

    L += ["## Time per step (s)", "", "| step | " + " | ".join(SIDES) + " |", "|---|" + "---|" * len(SIDES)]
    names = list(dict.fromkeys(s["step"] for s in steps))
    for n in names:
        cells = []
        for side in SIDES:
            row = [s for s in steps if s["step"] == n and s["side"] == side]
            cells.append("-" if not row else row[-1]["seconds"] + ("" if row[-1]["status"] == "ok"
                                                                    else f" ({row[-1]['status']})"))
        L.append(f"| {n} | " + " | ".join(cells) + " |")
    w = {s: warmup_seconds(out / "logs" / f"{s}-warmup.log") for s in SIDES}
    if any(v is not None for v in w.values()):
        L += ["", "`lite-vo warmup` (all kernels compiled into numba's cache, as it reports itself): "
              + ", ".join(f"{s} {_f(w[s])} s" for s in SIDES) + "."]
    L.append("")

    L += ["## Packages (pip's installation report)", "",
          "`wheel`: a binary wheel from PyPI (platform tag shown); `source`: an sdist built on the machine; "
          "`local`: this checkout.", "",
          "| package | " + " | ".join(SIDES) + " |", "|---|" + "---|" * len(SIDES)]
    srcs = {s: package_sources(pips[s]) if pips[s] else {} for s in SIDES}
    for name in sorted(set().union(*srcs.values())):
        cells = []
        for s in SIDES:
            p = srcs[s].get(name)
            if p is None:
                cells.append("-")
            elif p["kind"] == "wheel":
                cells.append(f"{p['version']} wheel ({wheel_tag(p['file'])})")
            else:
                cells.append(f"{p['version']} {p['kind']}" + (f" ({p['file']})" if p["kind"] == "source" else ""))
        L.append(f"| {name} | " + " | ".join(cells) + " |")
    built = [n for n, p in srcs["aarch64"].items() if p["kind"] == "source"]
    L += ["", "Built from source on aarch64: " + (", ".join(sorted(built)) if built else "nothing") + ".", ""]

    if ar:
        L += ar_section(out, steps, ar_minutes)
    return "\n".join(L).rstrip() + "\n", problems


def ar_section(out: Path, steps: list[dict], ar_minutes: float | None = None) -> list[str]:
    L = ["## The [ar] extra on aarch64", ""]
    wheels = out / "aarch64" / "ar_wheels.tsv"
    if wheels.exists():
        L += ["aarch64 wheels on PyPI for this Python (`pip download --only-binary=:all:` in the arm64 root):", "",
              "| package | aarch64 wheel |", "|---|---|"]
        with wheels.open(encoding="utf-8") as f:
            for row in csv.DictReader(f, delimiter="\t"):
                L.append(f"| {row['package']} | {row['aarch64_wheel']} |")
        L.append("")
    for s in steps:
        if s["side"] == "aarch64" and s["step"].startswith("ar-"):
            L.append(f"- `{s['step']}`: {s['status']} after {s['seconds']} s")
    log = out / "logs" / "aarch64-ar-moderngl.log"
    if log.exists():
        text = log.read_text(encoding="utf-8", errors="replace")
        for pattern in (r"^Successfully installed .*$", r"^EGL context: .*$"):
            found = re.findall(pattern, text, flags=re.M)
            if found:
                L.append(f"- `ar-moderngl` log: {found[-1]}")
    prog = out / "aarch64" / "pybullet_progress.tsv"
    if prog.exists():
        with prog.open(encoding="utf-8") as f:
            rows = list(csv.DictReader(f, delimiter="\t"))
        if rows:
            last = rows[-1]
            timed = [r for r in rows if r["minutes"] != "end"]
            limit = f" (time limit {ar_minutes:g} min)" if ar_minutes else ""
            L += ["", f"pybullet source build{limit}: {last['object_files']} object files compiled when it "
                  f"{'ended' if last['minutes'] == 'end' else 'was last checked'} "
                  f"(after {timed[-1]['minutes'] if timed else 0} min)."]
            marks = [r for r in timed if int(r["minutes"]) % 5 == 0]
            if marks:
                L.append("Object files over time: " + ", ".join(f"{r['minutes']} min: {r['object_files']}" for r in marks)
                         + ".")
    L.append("")
    return L


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Write DIR/report.md of tools/arm_check.sh.")
    ap.add_argument("--out", type=Path, required=True, help="the check's output folder")
    ap.add_argument("--tol-mm", type=float, default=1.0, help="largest accepted translation difference (mm)")
    ap.add_argument("--tol-deg", type=float, default=0.1, help="largest accepted rotation difference (deg)")
    ap.add_argument("--ar", action="store_true", help="add the [ar] extra section")
    ap.add_argument("--ar-only", action="store_true", help="the check ran the AR steps only")
    ap.add_argument("--ar-minutes", type=float, default=None, help="time limit of the pybullet build (minutes)")
    args = ap.parse_args(argv)
    if not args.out.is_dir():
        print(f"arm_report: not a folder: {args.out}", file=sys.stderr)
        return 1
    try:
        text, problems = build_report(args.out, args.tol_mm, args.tol_deg, args.ar or args.ar_only, args.ar_only,
                                       args.ar_minutes)
    except (ReportError, OSError) as e:
        print(f"arm_report: {e}", file=sys.stderr)
        return 1
    (args.out / "report.md").write_text(text, encoding="utf-8")
    print(text)
    if problems:
        print("arm_report: problems: " + "; ".join(problems), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
