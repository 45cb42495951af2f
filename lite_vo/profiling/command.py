"""The whole ``lite-vo profile`` command as a library call: :func:`run_profile` runs the sweep (or
the initialisation study), evaluates and aggregates the runs, measures the start-up and writes the
report. ``lite_vo/cli/profile.py`` parses the options into :class:`ProfileSettings` and calls it.

Progress goes to ``log`` (one plain line per step: the warm-up, every run as it starts and ends,
each start-up process), so a sweep piped to a file still says what it is doing.

Imports: the standard library and the other modules of ``lite_vo.profiling``; ``lite_vo.io``
lazily. Never imports matplotlib (see :mod:`lite_vo.profiling.plots`), numba kernels,
``ar_demo`` or any GL/physics package.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..errors import InputError
from . import report as report_writer
from .init_study import judge_init_run, plan_init_study, summarise_init_study
from .machine import machine_info
from .profiles import PAPER_PROFILES, parse_profiles, profile_label, profile_resolution
from .results import aggregate, collect_run, load_groundtruth
from .startup import measure_startup, run_warmup
from .sweep import RunLauncher, RunOutcome, RunSpec, default_workers, execute, sequence_names

Log = Callable[[str], None]


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
    calib: str | None = None

    def to_dict(self) -> dict:
        d = asdict(self)
        d["out"] = str(self.out)
        return d


#: What ``--force`` removes from an existing output folder (nothing else is ever deleted).
OUTPUT_ENTRIES = ("runs", "init_study", "report.md", "report.json", "accuracy_vs_resolution.png",
                  "time_vs_resolution.png", "init_study.png")


def prepare_out(out: Path, force: bool) -> None:
    """Refuse an existing, non-empty output folder unless ``force``; with it, remove our own entries."""
    from ..io import prepare_output_dir
    prepare_output_dir(out, force, clean=OUTPUT_ENTRIES)


def check_settings(s: ProfileSettings) -> None:
    """Raise InputError/ConfigError for settings the sweep cannot run; normalises ``s.profiles``."""
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


def load_groundtruths(s: ProfileSettings, seq_names: list[str], gt_loader: Callable, log: Log) -> dict:
    """Ground truth per sequence name (None, with a warning, where there is none)."""
    gts: dict[str, Any] = {}
    for name, seq in zip(seq_names, s.sequences):
        try:
            gts[name] = gt_loader(seq)
        except Exception as err:  # noqa: BLE001 - reported per run as "no ground truth"
            log(f"warning: {seq}: no ground truth ({err})")
            gts[name] = None
    return gts


def sweep_specs(s: ProfileSettings, seq_names: list[str], out: Path) -> list[RunSpec]:
    """Every (repetition, sequence, profile) run of the sweep."""
    return [RunSpec(sequence=seq, seq_name=name, profile=p, rep=k,
                    out_dir=out / "runs" / name / profile_label(p) / str(k), init=s.init,
                    max_frames=s.max_frames, pin_core=s.pin_core, overrides=tuple(s.overrides), calib=s.calib)
            for k in range(s.repeat) for name, seq in zip(seq_names, s.sequences) for p in s.profiles]


@dataclass
class Sweep:
    """What the runs of one ``lite-vo profile`` share: settings, output folder, ground truths,
    the launcher and its workers, the evaluator and the progress log."""
    settings: ProfileSettings
    out: Path
    seq_names: list[str]
    gts: dict
    workers: int
    launcher: RunLauncher | None
    evaluator: Callable | None
    log: Log

    def run(self, specs: list[RunSpec]) -> list[RunOutcome]:
        """:func:`execute` the specs with a progress line when each run starts and when it ends."""
        def started(k: int, n: int, spec: RunSpec, core: int | None) -> None:
            self.log(f"started {spec.key} ({k}/{n}" + (f", core {core}" if core is not None else "") + ")")

        def done(k: int, n: int, spec: RunSpec, o: RunOutcome) -> None:
            state = "ok" if o.returncode == 0 else f"exit {o.returncode}"
            self.log(f"[{k}/{n}] {spec.key}: {state} ({o.wall_s:.1f} s)")

        return execute(specs, self.launcher, self.workers, self.settings.pin_core, on_start=started, on_done=done)

    def collect(self, spec: RunSpec, outcome: RunOutcome, max_lost_ratio: float) -> dict:
        """:func:`collect_run` against the sequence's ground truth."""
        return collect_run(spec, outcome, self.gts.get(spec.seq_name), self.evaluator, max_lost_ratio,
                           self.settings.delta_s)

    def tables(self) -> dict:
        """The report entries of the sweep (runs, accuracy, timing, counts)."""
        s = self.settings
        specs = sweep_specs(s, self.seq_names, self.out)
        self.log(f"{len(specs)} runs ({len(s.sequences)} sequence(s) x {len(s.profiles)} profile(s) x "
                 f"{s.repeat}) on {self.workers} worker(s)" + (", each pinned to one core" if s.pin_core else ""))
        records = [self.collect(spec, o, s.max_lost_ratio) for spec, o in zip(specs, self.run(specs))]
        return {"runs": records, **aggregate(records, s.profiles, self.seq_names)}

    def init_study(self) -> dict:
        """The report entries of the initialisation study (runs, summary per sequence, profile)."""
        s = self.settings
        prof = s.profiles[0]
        specs = []
        for name, seq in zip(self.seq_names, s.sequences):
            specs += plan_init_study(seq, name, s.init_study, s.init_study_len, self.out / "init_study",
                                     profile=prof, pin_core=s.pin_core, overrides=tuple(s.overrides),
                                     calib=s.calib)
        self.log(f"initialisation study: {len(specs)} runs on {self.workers} worker(s)")
        records = [judge_init_run(self.collect(spec, o, max_lost_ratio=1.0), self.gts.get(spec.seq_name))
                   for spec, o in zip(specs, self.run(specs))]
        return {"runs": records,
                "init_study": {name: summarise_init_study([r for r in records if r["seq_name"] == name])
                               for name in self.seq_names},
                "init_study_profile": profile_label(prof)}


def startup_report(s: ProfileSettings, startup_fn: Callable[..., dict] | None, log: Log) -> dict:
    """The cold vs warm start-up measurement (an error entry instead of an exception)."""
    log("measuring cold vs warm start-up (fresh processes, empty numba caches) ...")
    try:
        return (startup_fn or measure_startup)(s.sequences[0], s.profiles[0], log=log)
    except Exception as err:  # noqa: BLE001 - the sweep results matter more
        return {"error": f"{type(err).__name__}: {err}"}


def run_profile(settings: ProfileSettings, launcher: RunLauncher | None = None, evaluator: Callable | None = None,
                gt_loader: Callable | None = None, log: Log | None = None,
                startup_fn: Callable[..., dict] | None = None, command: str | None = None) -> dict:
    """Run the sweep (or the initialisation study), evaluate, aggregate and write the report.

    Returns the report dictionary (also written to ``report.json``). ``launcher``, ``evaluator``,
    ``gt_loader`` and ``startup_fn`` replace the real subprocess launcher, ``lite_vo.eval.evaluate``,
    :func:`load_groundtruth` and :func:`measure_startup` (tests).
    """
    log = log or (lambda msg: None)
    s = settings
    check_settings(s)
    out = Path(s.out)
    prepare_out(out, s.force)
    seq_names = sequence_names(s.sequences)
    started = time.time()
    report: dict[str, Any] = {
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(started)),
        "command": command,
        "machine": machine_info(), "settings": s.to_dict(),
        "profiles": {profile_label(p): profile_resolution(p) for p in s.profiles},
        "sequences": dict(zip(seq_names, map(str, s.sequences))),
    }
    gts = load_groundtruths(s, seq_names, gt_loader or load_groundtruth, log)
    sweep = Sweep(s, out, seq_names, gts, int(s.workers or default_workers()), launcher, evaluator, log)
    report["workers"] = sweep.workers
    if s.warmup and launcher is None:
        report["warmup"] = run_warmup(log=log)
    if s.init_study > 0:
        report.update(sweep.init_study())
    else:
        report.update(sweep.tables())
        if s.startup:
            report["startup"] = startup_report(s, startup_fn, log)
    report["elapsed_s"] = round(time.time() - started, 1)
    paths = report_writer.write_report(report, out, plots=s.plots, log=log)
    report["written"] = [str(p) for p in paths]
    return report
