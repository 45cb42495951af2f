"""Start-up cost: the first frames of a fresh process with a cold vs a warm numba cache, and the
warm-up that runs before a sweep.

:func:`startup_probe` runs in a fresh process (:data:`PROBE_CODE`) and times the import, the
set-up and the first frames; :func:`measure_startup` runs it with an empty numba cache (cold) and
after ``lite_vo.warmup.warmup()`` (warm), each in its own temporary cache, so the user's cache is
never touched. :func:`run_warmup` is ``lite-vo warmup`` in a child process before the sweep.

Imports the standard library and ``lite_vo.profiling.sweep`` only; ``lite_vo.session`` inside the
probe (its import is what the probe times).
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from .sweep import last_line

# numpy is imported before the probe's clock starts: ``import_s`` is the import of lite_vo's
# own modules, as it was when the probe lived in a module that imported numpy itself.
PROBE_CODE = ("import json, sys; import numpy; from lite_vo.profiling.startup import startup_probe; "
              "print('STARTUP_JSON ' + json.dumps(startup_probe(sys.argv[1], sys.argv[2], int(sys.argv[3]))))")
WARMUP_CODE = ("import json, time; from lite_vo.warmup import warmup; t = time.perf_counter(); "
               "res = warmup(); print('STARTUP_JSON ' + json.dumps({'warmup_s': time.perf_counter() - t, "
               "'modules': [r.to_dict() for r in res]}))")


def first_frames_ms(session) -> list[float]:
    """Milliseconds of each frame of a :class:`~lite_vo.session.Session` (the first one counted from
    the moment the session started, so it includes whatever the first frame compiles or loads)."""
    from lite_vo.session import OutputSink

    class FrameClock(OutputSink):
        def on_start(self, info):
            self.last, self.ms = time.perf_counter(), []

        def on_frame(self, event):
            now = time.perf_counter()
            self.ms.append((now - self.last) * 1e3)
            self.last = now

    clock = FrameClock()
    session.sinks = [*session.sinks, clock]
    session.run()
    return clock.ms


def startup_probe(sequence: str, profile: str = "phone", n_frames: int = 3) -> dict:
    """In THIS process: time the import, the set-up (opening the sequence for a session) and the
    first ``n_frames`` frames (ms), through the frame driver but without its kernel warm-up, so a
    cold numba cache shows in the first frames. Meant to run in a fresh subprocess (see
    :func:`measure_startup`); prints nothing."""
    t0 = time.perf_counter()
    import lite_vo
    from lite_vo.session import Session
    t_import = time.perf_counter() - t0
    cfg = lite_vo.load_profile(profile, ["system.mode=sync"])
    t1 = time.perf_counter()
    session = Session(sequence, cfg, max_frames=n_frames, warm_up_kernels=False)
    t_setup = time.perf_counter() - t1
    frame_ms = first_frames_ms(session)
    return {"import_s": t_import, "setup_s": t_setup, "frame_ms": frame_ms,
            "total_s": time.perf_counter() - t0}


def compiled_kernels(numba_debug_output: str) -> list[str]:
    """Kernels numba compiled (and saved to its cache) according to ``NUMBA_DEBUG_CACHE=1`` output."""
    out = []
    for m in re.finditer(r"data saved to '([^']+)'", numba_debug_output):
        p = Path(m.group(1))
        pkg = p.parent.name.rsplit("_", 1)[0] if "_" in p.parent.name else p.parent.name  # "<dir>_<hash>"
        name = re.sub(r"\.py\d+\.\d+\.nbc$", "", p.name)
        name = re.sub(r"-\d+$", "", name)
        out.append(f"{pkg}/{name}")
    return sorted(set(out))


def python_json(code: str, args: Sequence[str], env: dict, timeout: float) -> dict:
    """Run ``python -c code args`` and return the JSON it printed after ``STARTUP_JSON`` (plus
    ``process_s``, ``ok`` and, with ``NUMBA_DEBUG_CACHE=1``, the kernels it compiled)."""
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
            "error": last_line(proc.stderr) or f"exit status {proc.returncode}"}


def _timed_step(log: Callable[[str], None], step: str, what: str, fn: Callable[[], dict]) -> dict:
    """Say what a long step does, run it, say how long it took."""
    log(f"start-up {step}: {what} ...")
    res = fn()
    state = f"{res['process_s']:.1f} s" if res.get("ok") else f"failed: {res.get('error')}"
    log(f"start-up {step}: {state}")
    return res


def measure_startup(sequence: str, profile: str = "phone", n_frames: int = 3, timeout: float = 900.0,
                    log: Callable[[str], None] | None = None) -> dict:
    """Time of the first frames in a fresh process, cold (empty numba cache) vs after a warm-up.

    Three subprocesses, each with its own ``NUMBA_CACHE_DIR``: (1) ``cold``: a probe with an
    empty cache (every kernel compiles on first use); (2) ``lite_vo.warmup.warmup()`` into a
    second empty cache; (3) ``warm``: the same probe with that warmed cache. The user's own
    cache is never touched. ``log`` gets a line before and after each step.
    """
    log = log or (lambda msg: None)
    out: dict[str, Any] = {"sequence": str(sequence), "profile": profile, "n_frames": n_frames}
    args = [str(sequence), str(profile), str(n_frames)]
    with tempfile.TemporaryDirectory(prefix="lite_vo_cold_") as cold_dir, \
            tempfile.TemporaryDirectory(prefix="lite_vo_warm_") as warm_dir:
        env_cold = dict(os.environ, NUMBA_CACHE_DIR=cold_dir)
        env_warm = dict(os.environ, NUMBA_CACHE_DIR=warm_dir)
        try:
            out["cold"] = _timed_step(log, "1/3", f"first {n_frames} frames with an empty numba cache "
                                      "(compiles every kernel)", lambda: python_json(PROBE_CODE, args, env_cold, timeout))
            out["warmup"] = _timed_step(log, "2/3", "lite-vo warmup into a second empty cache",
                                        lambda: python_json(WARMUP_CODE, [], env_warm, timeout))
            # NUMBA_DEBUG_CACHE lists what still had to be compiled although warmup() ran
            out["warm"] = _timed_step(log, "3/3", f"first {n_frames} frames with the warmed cache",
                                      lambda: python_json(PROBE_CODE, args, dict(env_warm, NUMBA_DEBUG_CACHE="1"),
                                                          timeout))
        except subprocess.TimeoutExpired as err:
            out["error"] = f"timed out after {err.timeout:.0f} s"
    return out


def run_warmup(timeout: float = 1800.0, log: Callable[[str], None] | None = None) -> dict:
    """``lite-vo warmup --quiet`` in a child process (so sweep runs do not all compile at once);
    ``log`` gets a line before and after."""
    log = log or (lambda msg: None)
    log("warming up numba kernels (lite-vo warmup) ...")
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "lite_vo.cli.main", "warmup", "--quiet"],
                              capture_output=True, text=True, timeout=timeout)
        res = {"ok": proc.returncode == 0, "seconds": time.perf_counter() - t0,
               "error": last_line(proc.stderr) if proc.returncode else ""}
    except subprocess.TimeoutExpired:
        res = {"ok": False, "seconds": time.perf_counter() - t0, "error": "timed out"}
    log(f"warm-up done in {res['seconds']:.1f} s" if res["ok"]
        else f"warm-up failed after {res['seconds']:.1f} s: {res['error']} (each run compiles what it needs)")
    return res
