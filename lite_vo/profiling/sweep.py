"""Launching the runs of a sweep: what to run, the ``lite-vo run`` command, worker processes.

Every run is a separate process (``python -m lite_vo.cli.main run ...``) that writes the file
contract of ARCHITECTURE.md (``trajectory.txt``, ``timing.json``, ``run.json``), so a crashing run
cannot take the sweep down. :func:`execute` runs a list of :class:`RunSpec` on a few worker
threads, each waiting on one child process, optionally pinning each child to a core of its own.
How a child is started is a replaceable :data:`RunLauncher` (tests pass one that writes the files
directly); the default is :func:`launch_run`.

Imports: the standard library and ``lite_vo.profiling.profiles`` only.
"""
from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from .profiles import profile_label


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
    calib: str | None = None       # a calibration file for the sequence (--calib)

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


#: Starts the run of a spec (on the given core, or anywhere for None) and waits for it.
RunLauncher = Callable[[RunSpec, "int | None"], RunOutcome]

#: Progress callbacks of :func:`execute`: ``(k, n, spec, core)`` when the k-th run of n starts,
#: ``(k, n, spec, outcome)`` when the k-th run finishes.
OnStart = Callable[[int, int, RunSpec, "int | None"], None]
OnDone = Callable[[int, int, RunSpec, RunOutcome], None]


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
    if spec.calib is not None:
        cmd += ["--calib", str(spec.calib)]
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


def last_line(text: str) -> str:
    """The last non-blank line of a process's output (its error message, usually)."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else ""


def launch_run(spec: RunSpec, core: int | None = None) -> RunOutcome:
    """Launch ``lite-vo run`` for ``spec`` as a child process and wait for it (the default launcher).

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
    return RunOutcome(proc.returncode, last_line(err_text or ""), time.perf_counter() - t0, core)


def available_cores() -> list[int]:
    """The cores this process may run on."""
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return list(range(os.cpu_count() or 1))


def default_workers() -> int:
    """Runs in parallel by default: two, or one on a single-core machine."""
    return max(1, min(2, len(available_cores())))


def launch_safely(launcher: RunLauncher, spec: RunSpec, core: int | None) -> RunOutcome:
    """``launcher(spec, core)``; a launcher that raises gives a crashed run instead."""
    try:
        return launcher(spec, core)
    except Exception as err:  # noqa: BLE001 - a broken launcher is a crashed run
        return RunOutcome(-1, f"launcher failed: {type(err).__name__}: {err}", 0.0, core)


def execute(specs: Sequence[RunSpec], launcher: RunLauncher | None = None, workers: int | None = None,
            pin_core: bool = False, on_start: OnStart | None = None,
            on_done: OnDone | None = None) -> list[RunOutcome]:
    """Run every spec with ``workers`` parallel launchers; returns outcomes in the order of ``specs``.

    With ``pin_core`` each running job holds one core of this process's affinity mask for its
    whole duration (so parallel runs never share a core; at most one job per core). A launcher
    that raises is turned into a crash outcome; nothing stops the sweep. ``on_start`` and
    ``on_done`` are called (one at a time) as runs start and finish.
    """
    launcher = launcher or launch_run
    workers = max(1, int(workers or default_workers()))
    cores: queue.Queue | None = None
    if pin_core:
        cores = queue.Queue()
        for c in available_cores():
            cores.put(c)
    n = len(specs)
    outcomes: list[RunOutcome] = [RunOutcome(-1)] * n
    counts = {"started": 0, "done": 0}
    lock = threading.Lock()

    def job(i: int) -> None:
        core = cores.get() if cores is not None else None
        try:
            with lock:
                counts["started"] += 1
                if on_start is not None:
                    on_start(counts["started"], n, specs[i], core)
            outcomes[i] = launch_safely(launcher, specs[i], core)
        finally:
            if cores is not None:
                cores.put(core)
        with lock:
            counts["done"] += 1
            if on_done is not None:
                on_done(counts["done"], n, specs[i], outcomes[i])

    if workers == 1:
        for i in range(n):
            job(i)
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(job, range(n)))
    return outcomes
