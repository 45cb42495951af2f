"""Tests of the profiler (lite_vo/profiler.py, lite_vo/profiler_report.py) and the warm-up.

The sweep is tested against the run-folder contract with a fake runner that writes
trajectory.txt / timing.json / run.json directly (no VO run), a fake ground truth and, where the
numbers matter, a small fake evaluator; one test uses the real ``lite_vo.eval`` when present.
"""
from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from lite_vo import profiler as P
from lite_vo import profiler_report as R
from lite_vo.errors import InputError
from lite_vo.eval import associate
from lite_vo.geometry import exp_se3, tum_from_pose
from lite_vo.io import Trajectory
from lite_vo.warmup import warmup

FPS = 30.0


# ----------------------------------------------------------------------------------------------
# Fakes
# ----------------------------------------------------------------------------------------------

def gt_poses(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A smooth hand-held-like trajectory: timestamps and T_world_cam (n, 4, 4)."""
    t = 100.0 + np.arange(n) / FPS
    s = t - t[0]
    xi = np.zeros((n, 6))
    xi[:, 0] = 0.3 * np.sin(0.8 * s)
    xi[:, 1] = 0.1 * np.sin(1.3 * s + 0.5)
    xi[:, 2] = 0.05 * s
    xi[:, 3] = 0.1 * np.sin(0.7 * s)
    xi[:, 4] = 0.2 * np.sin(0.5 * s + 1.0)
    return t, exp_se3(xi)


def write_tum(path: Path, t: np.ndarray, poses: np.ndarray) -> None:
    rows = np.concatenate([t[:, None], tum_from_pose(poses)], axis=1)
    path.write_text("".join(" ".join(f"{v:.9f}" for v in r) + "\n" for r in rows))


def make_sequence(root: Path, name: str = "seqA", n: int = 150, depth: bool = True) -> Path:
    seq = root / name
    seq.mkdir(parents=True)
    t, poses = gt_poses(n)
    (seq / "rgb.txt").write_text("# timestamp filename\n" + "".join(f"{x:.6f} rgb/{i:04d}.png\n" for i, x in enumerate(t)))
    if depth:
        (seq / "depth.txt").write_text("".join(f"{x:.6f} depth/{i:04d}.png\n" for i, x in enumerate(t)))
    write_tum(seq / "groundtruth.txt", t, poses)
    return seq


def stats(values) -> dict:
    a = np.asarray(values, float)
    return {"count": len(a), "mean": float(a.mean()), "std": float(a.std()), "median": float(np.median(a)),
            "p95": float(np.percentile(a, 95))}


class FakeRunner:
    """Writes the run-folder contract; behaviour per profile label: ok, crash, missing, lost, status."""

    def __init__(self, behaviour: dict[str, str] | None = None, noise: dict[str, float] | None = None,
                 scale: float = 1.0, delay: float = 0.0):
        self.behaviour = behaviour or {}
        self.noise = noise or {}
        self.scale = scale
        self.delay = delay
        self.calls: list[tuple[P.RunSpec, int | None]] = []
        self.lock = threading.Lock()
        self.active_cores: set = set()
        self.core_clash = False

    def __call__(self, spec: P.RunSpec, core):
        with self.lock:
            self.calls.append((spec, core))
            if core is not None and core in self.active_cores:
                self.core_clash = True
            self.active_cores.add(core)
        try:
            if self.delay:
                time.sleep(self.delay)
            return self._run(spec, core)
        finally:
            with self.lock:
                self.active_cores.discard(core)

    def _run(self, spec: P.RunSpec, core):
        label = P.profile_label(spec.profile)
        mode = self.behaviour.get(label, "ok")
        if mode == "crash":
            return P.RunOutcome(1, "ValueError: boom in mapping", 0.5, core)
        out = spec.out_dir
        out.mkdir(parents=True)
        t, poses = gt_poses(150)
        lo = spec.start_frame or 0
        hi = lo + (spec.max_frames or 150)
        t, poses = t[lo:hi], poses[lo:hi].copy()
        rng = np.random.default_rng(abs(hash((label, spec.rep))) % 2**32)
        poses[:, :3, 3] += rng.normal(0.0, self.noise.get(label, 0.002), (len(t), 3)).cumsum(axis=0) * 0.1
        poses[:, :3, 3] /= self.scale
        write_tum(out / "trajectory.txt", t, poses)
        trk = {"phone": [4.0, 5.0, 6.0], "desktop": [20.0, 30.0, 25.0]}.get(label, [1.0, 2.0])
        timing = {"tracking": stats(trk), "mapping": stats([10.0 * x for x in trk]),
                  "stages": {"track_lvl1": stats(trk), "propagate": stats([1.0, 1.5])},
                  "frames": {"in": len(t), "tracked": len(t), "lost": 5 if mode == "lost" else 0, "dropped": 0},
                  "wall_s": 1.5}
        if mode != "missing":
            (out / "timing.json").write_text(json.dumps(timing))
        init = spec.init or "depth"
        series = [{"frame": i, "t": i / FPS, "median_abs_rel_error": 0.5 * np.exp(-i / 20.0) + 0.05,
                   "density": 0.3} for i in range(0, len(t), 5)]
        run = {"profile": label, "config": {"system": {"init": init}}, "versions": {}, "sequence": spec.seq_name,
               "status": "error" if mode == "status" else "ok",
               "depth_accuracy": {"density": 0.3, "median_abs_rel_error": series[-1]["median_abs_rel_error"],
                                  "within_5pct": 0.5, "within_10pct": 0.7, "frames": series}}
        (out / "run.json").write_text(json.dumps(run))
        return P.RunOutcome(0, "", 0.5, core)


class FakeResult:
    def __init__(self, d):
        self.d = d

    def to_dict(self):
        return dict(self.d)


class FakeEvaluator:
    """Mean position error (cm) and the alignment it was asked for; scale from the path lengths."""

    def __init__(self):
        self.aligns = []

    def __call__(self, gt, est, align="sim3", delta_s=1.0):
        self.aligns.append(align)
        ig, ie = associate(gt.timestamps, est.timestamps, 0.01)
        pg, pe = gt.poses[ig, :3, 3], est.poses[ie, :3, 3]
        scale = 1.0
        if align == "sim3":
            scale = float(np.linalg.norm(np.diff(pg, axis=0), axis=1).sum()
                          / np.linalg.norm(np.diff(pe, axis=0), axis=1).sum())
        err = float(np.linalg.norm(pg - scale * pe, axis=1).mean())
        return FakeResult({"rpe_trans_cm_per_s": 100 * err, "rpe_rot_deg_per_s": 0.1, "ate_rmse_m": err,
                           "scale": scale, "matched_poses": len(ig)})


def settings(tmp_path, seqs, **kw) -> P.ProfileSettings:
    base = dict(sequences=[str(s) for s in seqs], profiles=["phone", "desktop", "m160_t80"], repeat=1,
                out=tmp_path / "report", workers=2, warmup=False, startup=False)
    base.update(kw)
    return P.ProfileSettings(**base)


# ----------------------------------------------------------------------------------------------
# The sweep
# ----------------------------------------------------------------------------------------------

def test_sweep_with_crash_missing_and_lost_runs(tmp_path):
    seq_a = make_sequence(tmp_path / "data", "seqA")
    seq_b = make_sequence(tmp_path / "data", "seqB")
    runner = FakeRunner({"m160_t80": "crash"}, noise={"desktop": 0.001, "phone": 0.004})
    ev = FakeEvaluator()
    s = settings(tmp_path, [seq_a, seq_b], repeat=2)
    startup = {"sequence": str(seq_a), "profile": "phone", "n_frames": 2,
               "cold": {"ok": True, "import_s": 0.5, "setup_s": 0.1, "frame_ms": [9000.0, 4000.0], "process_s": 15.0},
               "warmup": {"ok": True, "warmup_s": 30.0, "process_s": 31.0},
               "warm": {"ok": True, "import_s": 0.5, "setup_s": 0.1, "frame_ms": [80.0, 20.0], "process_s": 2.0}}
    s.startup = True
    report = P.run_profile(s, runner=runner, evaluator=ev, startup_fn=lambda *a, **k: startup)
    out = tmp_path / "report"

    assert len(runner.calls) == 2 * 3 * 2
    assert report["counts"] == {"ok": 8, "fail": 0, "crash": 4}
    assert set(ev.aligns) == {"se3"}  # depth-initialised runs are evaluated without scale
    acc = report["accuracy"]
    assert acc["seqA"]["m160_t80"]["crashed"] == 2 and acc["seqA"]["m160_t80"]["ok"] == 0
    assert acc["seqA"]["phone"]["ok"] == 2
    # less noise -> less drift in the table
    assert acc["seqB"]["desktop"]["rpe_trans_cm_per_s"]["mean"] < acc["seqB"]["phone"]["rpe_trans_cm_per_s"]["mean"]
    # timing pooled over 4 runs of 3 tracked frames each
    trk = report["timing"]["phone"]["tracking"]
    assert trk["count"] == 12 and trk["mean"] == pytest.approx(5.0) and trk["std"] == pytest.approx(np.std([4, 5, 6]))
    assert report["timing"]["desktop"]["stages"]["propagate"]["count"] == 8
    assert report["timing"]["m160_t80"]["tracking"] is None

    md = (out / "report.md").read_text()
    js = json.loads((out / "report.json").read_text())
    assert js["machine"]["cpu_model"] and js["machine"]["python"] and "numba" in js["machine"]
    assert js["profiles"]["m160_t80"]["label"] == "160/80"
    assert "crash" in md and "ValueError: boom in mapping" in md
    assert "5.0 ± 0.8" in md  # phone tracking ms
    assert "| frame 0 (ms) |" in md and "9000" in md
    for png in ("accuracy_vs_resolution.png", "time_vs_resolution.png"):
        assert (out / png).stat().st_size > 1000
        assert f"({png})" in md
    # run folders follow DIR/runs/<seq>/<profile>/<rep>
    assert (out / "runs" / "seqB" / "desktop" / "1" / "timing.json").is_file()


def test_fail_when_lost_or_status_not_ok_and_missing_files_crash(tmp_path):
    seq = make_sequence(tmp_path / "data")
    runner = FakeRunner({"phone": "lost", "desktop": "status", "m160_t80": "missing"})
    report = P.run_profile(settings(tmp_path, [seq]), runner=runner, evaluator=FakeEvaluator())
    by = {r["profile"]: r for r in report["runs"]}
    assert by["phone"]["status"] == "fail" and "lost on 5/150" in by["phone"]["reason"]
    assert by["phone"]["eval"] is not None  # numbers are still kept in report.json
    assert by["desktop"]["status"] == "fail" and "'error'" in by["desktop"]["reason"]
    assert by["m160_t80"]["status"] == "crash" and "timing.json" in by["m160_t80"]["reason"]
    md = (tmp_path / "report" / "report.md").read_text()
    row = next(ln for ln in md.splitlines() if ln.startswith("| phone | 320 | 160 |"))
    assert row.count("fail") == 2
    # tolerated when the user allows lost frames
    rec = P.collect_run(runner.calls[0][0], P.RunOutcome(0), P.load_groundtruth(seq), FakeEvaluator(),
                        max_lost_ratio=0.1)
    assert rec["status"] == "ok"


def test_random_init_runs_use_sim3_and_recover_scale(tmp_path):
    seq = make_sequence(tmp_path / "data", depth=False)
    ev = FakeEvaluator()
    s = settings(tmp_path, [seq], profiles=["phone"], init="random")
    report = P.run_profile(s, runner=FakeRunner(scale=4.0, noise={"phone": 0.0}), evaluator=ev)
    assert ev.aligns == ["sim3"]
    assert report["accuracy"]["seqA"]["phone"]["scale"]["mean"] == pytest.approx(4.0, rel=1e-3)
    assert "--init" in P.build_run_command(report_spec(report, tmp_path))
    spec = P.RunSpec("s", "s", "phone", 0, tmp_path / "x", overrides=("tracking.huber=2",))
    assert "--set tracking.huber=2" in " ".join(P.build_run_command(spec))


def report_spec(report, tmp_path) -> P.RunSpec:
    r = report["runs"][0]
    return P.RunSpec(r["sequence"], r["seq_name"], r["profile"], r["rep"], Path(r["dir"]), init="random")


def test_real_evaluator_on_exact_trajectory(tmp_path):
    ev_mod = pytest.importorskip("lite_vo.eval", reason="lite_vo.eval not written yet")
    seq = make_sequence(tmp_path / "data")
    spec = P.RunSpec(str(seq), "seqA", "phone", 0, tmp_path / "run")
    FakeRunner(noise={"phone": 0.0})(spec, None)
    rec = P.collect_run(spec, P.RunOutcome(0), P.load_groundtruth(seq), ev_mod.evaluate)
    assert rec["status"] == "ok", rec["reason"]
    assert rec["eval"]["rpe_trans_cm_per_s"] == pytest.approx(0.0, abs=1e-3)
    assert rec["eval"]["matched_poses"] >= 140


def test_output_folder_is_never_overwritten_without_force(tmp_path):
    seq = make_sequence(tmp_path / "data")
    out = tmp_path / "report"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "report.md").write_text("old")
    with pytest.raises(InputError, match="--force"):
        P.run_profile(settings(tmp_path, [seq]), runner=FakeRunner(), evaluator=FakeEvaluator())
    assert (out / "report.md").read_text() == "old"
    P.run_profile(settings(tmp_path, [seq], force=True), runner=FakeRunner(), evaluator=FakeEvaluator())
    assert (out / "notes.txt").read_text() == "mine"  # only our own entries are replaced
    assert (out / "report.md").read_text().startswith("# lite-vo profile report")
    # the CLI says so in one line and exits 1
    from lite_vo.cli.main import main
    assert main(["profile", str(seq), "--out", str(out), "--profiles", "phone"]) == 1


def test_bad_profile_and_missing_sequence_are_input_errors(tmp_path):
    seq = make_sequence(tmp_path / "data")
    from lite_vo.errors import ConfigError
    with pytest.raises(ConfigError, match="nosuch"):
        P.run_profile(settings(tmp_path, [seq], profiles=["phone", "nosuch"]), runner=FakeRunner())
    with pytest.raises(InputError, match="not found"):
        P.run_profile(settings(tmp_path, [tmp_path / "nope"]), runner=FakeRunner())
    assert not (tmp_path / "report").exists()


# ----------------------------------------------------------------------------------------------
# Pieces
# ----------------------------------------------------------------------------------------------

def test_pool_stats_equals_stats_of_concatenation():
    rng = np.random.default_rng(3)
    parts = [rng.normal(10, 3, n) for n in (5, 17, 1)]
    pooled = P.pool_stats([stats(p) for p in parts] + [None, {"count": 0, "mean": None}])
    allv = np.concatenate(parts)
    assert pooled["count"] == 23 and pooled["runs"] == 3
    assert pooled["mean"] == pytest.approx(allv.mean())
    assert pooled["std"] == pytest.approx(allv.std())
    assert P.pool_stats([None]) is None


def test_run_command_and_pinned_environment(tmp_path):
    spec = P.RunSpec("seq", "seq", "board", 0, tmp_path / "o", init="random", max_frames=50, start_frame=7,
                     seed=3, pin_core=True)
    cmd = P.build_run_command(spec)
    assert cmd[:5] == [sys.executable, "-m", "lite_vo.cli.main", "run", "seq"]
    text = " ".join(cmd)
    for part in ("--profile board", "--quiet", "--mode sync", "--init random", "--max-frames 50",
                 "--start-frame 7", "--set system.seed=3", "--set system.numba_threads=1", f"--out {tmp_path / 'o'}"):
        assert part in text
    assert P.run_env(True, {})["NUMBA_NUM_THREADS"] == "1"
    assert "NUMBA_NUM_THREADS" not in P.run_env(False, {})


def test_execute_keeps_order_never_shares_a_core_and_survives_a_broken_runner(tmp_path, monkeypatch):
    monkeypatch.setattr(P, "available_cores", lambda: [0, 1])
    specs = [P.RunSpec("s", "s", "phone", i, tmp_path / str(i)) for i in range(6)]
    fake = FakeRunner(delay=0.02)

    def runner(spec, core):
        if spec.rep == 3:
            raise RuntimeError("launcher broke")
        return fake(spec, core)

    seen = []
    outs = P.execute(specs, runner, workers=3, pin_core=True, on_done=lambda i, n, s, o: seen.append(i))
    assert [o.returncode for o in outs] == [0, 0, 0, -1, 0, 0]
    assert "launcher broke" in outs[3].stderr_tail
    assert not fake.core_clash and {c for _, c in fake.calls} <= {0, 1}
    assert sorted(seen) == list(range(1, 7))


def test_subprocess_runner_reports_a_crash_with_its_last_stderr_line(tmp_path, monkeypatch):
    code = "import sys; print('working'); sys.stderr.write('Traceback\\nKeyError: frame 3\\n'); sys.exit(2)"
    monkeypatch.setattr(P, "build_run_command", lambda spec: [sys.executable, "-c", code])
    spec = P.RunSpec("s", "s", "phone", 0, tmp_path / "runs" / "s" / "phone" / "0")
    out = P.subprocess_runner(spec, core=P.available_cores()[0])
    assert out.returncode == 2 and out.stderr_tail == "KeyError: frame 3"
    log = spec.log_path.read_text()
    assert "working" in log and "KeyError" in log
    rec = P.collect_run(spec, out)
    assert rec["status"] == "crash" and "exit status 2: KeyError: frame 3" in rec["reason"]


def test_associate_and_relative_drift():
    t, poses = gt_poses(120)
    gt = Trajectory(t, poses)
    ia, ib = associate(t[::2] + 0.001, t, 0.005)
    assert np.array_equal(ib, np.arange(0, 120, 2)) and len(ia) == 60
    assert len(associate(t + 0.5, t[:10], 0.01)[0]) == 0
    half = poses.copy()
    half[:, :3, 3] *= 0.5
    est = Trajectory(t, half)
    ts, e = P.relative_drift(gt, est, scale=2.0)
    assert len(e) > 50 and np.allclose(e, 0.0, atol=1e-9) and ts[0] == pytest.approx(0.5, abs=0.02)
    _, e_wrong = P.relative_drift(gt, est, scale=1.0, window_frames=15)
    assert np.allclose(e_wrong, 0.5, atol=1e-9)  # half the motion -> 50% relative drift


def test_sequence_names_are_unique(tmp_path):
    a = tmp_path / "x" / "seq"
    b = tmp_path / "y" / "seq"
    c = tmp_path / "euroc" / "mav0"
    for p in (a, b, c):
        p.mkdir(parents=True)
    assert P.sequence_names([str(a), str(b), str(c)]) == ["seq_1", "seq_2", "euroc"]


def test_machine_info_describes_this_machine():
    m = P.machine_info()
    assert m["cpu_count"] >= 1 and m["cores_available"] >= 1
    assert m["python"].count(".") == 2 and m["numpy"] == np.__version__
    assert "CPU:" in R.machine_lines(m)[0]


def test_plots_missing_matplotlib_is_a_clear_note(tmp_path, monkeypatch):
    seq = make_sequence(tmp_path / "data")
    import builtins
    real_import = builtins.__import__

    def no_mpl(name, *a, **k):
        if name.startswith("matplotlib"):
            raise ImportError("no matplotlib")
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_mpl)
    msgs = []
    P.run_profile(settings(tmp_path, [seq], profiles=["phone"]), runner=FakeRunner(),
                  evaluator=FakeEvaluator(), log=msgs.append)
    md = (tmp_path / "report" / "report.md").read_text()
    assert "Plots skipped" in md and "lite-vo[plot]" in md
    assert not list((tmp_path / "report").glob("*.png"))
    assert any("matplotlib" in m for m in msgs)


# ----------------------------------------------------------------------------------------------
# Initialisation study
# ----------------------------------------------------------------------------------------------

def test_init_study_plan_spreads_start_frames_and_seeds(tmp_path):
    seq = make_sequence(tmp_path / "data", n=150)  # 5 s at 30 Hz
    specs = P.plan_init_study(str(seq), "seqA", 4, 3.0, tmp_path / "o")
    assert [s.seed for s in specs] == [1, 2, 3, 4]
    starts = [s.start_frame for s in specs]
    assert starts[0] == 0 and starts == sorted(starts) and len(set(starts)) == 4
    assert max(starts) + specs[-1].max_frames <= 150
    assert all(s.init == "random" and s.kind == "init" for s in specs)
    assert specs[0].max_frames == 91  # 3 s at 30 Hz, inclusive of both ends
    with pytest.raises(InputError, match="shorter"):
        P.plan_init_study(str(seq), "seqA", 2, 10.0, tmp_path / "o")


def test_init_study_success_rate_and_errors_over_time(tmp_path):
    seq = make_sequence(tmp_path / "data", n=150)

    class InitRunner(FakeRunner):
        def _run(self, spec, core):
            if spec.seed == 2:
                return P.RunOutcome(1, "RuntimeError: diverged", 0.1, core)
            out = super()._run(spec, core)
            if spec.seed == 3:  # wrong depth: fails the 16% criterion
                run = json.loads((spec.out_dir / "run.json").read_text())
                for x in run["depth_accuracy"]["frames"]:
                    x["median_abs_rel_error"] = 0.4
                (spec.out_dir / "run.json").write_text(json.dumps(run))
            return out

    s = settings(tmp_path, [seq], profiles=["phone"], init_study=4, init_study_len=3.5)
    report = P.run_profile(s, runner=InitRunner(scale=3.0, noise={"phone": 0.0}), evaluator=FakeEvaluator())
    study = report["init_study"]["seqA"]
    assert study["runs"] == 4 and study["successes"] == 2 and study["crashed"] == 1
    assert study["success_rate"] == pytest.approx(0.5)
    runs = {r["seed"]: r for r in report["runs"]}
    assert runs[1]["success"] and runs[1]["final_drift"] == pytest.approx(0.0, abs=1e-6)
    assert runs[1]["depth_error_at_s"] <= 3.0 and runs[1]["depth_error"] < 0.16
    assert "depth error 40%" in runs[3]["init_reason"]
    bins = study["depth_error_over_time"]["bins"]
    assert bins[0]["mean"] > bins[-1]["mean"]  # errors fall over time in the fake runs
    md = (tmp_path / "report" / "report.md").read_text()
    assert "Initialisation study" in md and "| seqA | 4 | 2 | 50% | 1 |" in md
    assert (tmp_path / "report" / "init_study.png").stat().st_size > 1000
    assert report.get("accuracy") is None


# ----------------------------------------------------------------------------------------------
# Warm-up
# ----------------------------------------------------------------------------------------------

def test_warmup_reports_each_module_and_skips_missing_ones(tmp_path, monkeypatch):
    pkg = tmp_path / "wpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "good.py").write_text("CALLS = []\ndef warmup():\n    CALLS.append(1)\n")
    (pkg / "bad.py").write_text("def warmup():\n    raise ValueError('kernel broke')\n")
    (pkg / "plain.py").write_text("X = 1\n")
    (pkg / "needs.py").write_text("import not_installed_dep_xyz\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    seen = []
    res = warmup(["wpkg.good", "wpkg.bad", "wpkg.plain", "wpkg.nothere", "nopkg_xyz.k", "wpkg.needs"],
                 on_result=seen.append)
    status = {r.module: r.status for r in res}
    assert status == {"wpkg.good": "ok", "wpkg.bad": "error", "wpkg.plain": "no_warmup",
                      "wpkg.nothere": "missing", "nopkg_xyz.k": "missing", "wpkg.needs": "error"}
    assert len(seen) == 6
    import wpkg.good
    assert wpkg.good.CALLS == [1]
    assert "kernel broke" in res[1].message
    assert "not_installed_dep_xyz" in res[5].message


def test_warmup_cli_prints_each_module_and_fails_on_errors(tmp_path, monkeypatch, capsys):
    import lite_vo.warmup as W
    from lite_vo.cli.main import main
    assert {"lite_vo.image", "lite_vo.tracking._kernels", "lite_vo.mapping._kernels",
            "lite_vo.synth._kernels"} <= set(W.KERNEL_MODULES)
    assert "ar_demo._kernels" in W.plugin_kernel_modules()            # registered by the plug-in
    assert not any(m.startswith("ar_demo") for m in W.KERNEL_MODULES)  # the core names no plug-in
    monkeypatch.setattr(W, "plugin_kernel_modules", lambda: ())
    pkg = tmp_path / "wpkg2"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "good.py").write_text("def warmup():\n    pass\n")
    (pkg / "bad.py").write_text("def warmup():\n    raise ValueError('kernel broke')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(W, "KERNEL_MODULES", ("wpkg2.good", "wpkg2.absent"))
    assert main(["warmup"]) == 0
    out = capsys.readouterr().out
    assert "wpkg2.good" in out and "wpkg2.absent" in out and "skipped" in out
    assert main(["warmup", "--quiet"]) == 0
    assert capsys.readouterr().out == ""
    monkeypatch.setattr(W, "KERNEL_MODULES", ("wpkg2.good", "wpkg2.bad"))
    assert main(["warmup", "--quiet"]) == 1
    assert "kernel broke" in capsys.readouterr().err


def test_depth_series_prefers_the_aligned_error_and_the_run_folder_file(tmp_path):
    (tmp_path / "depth_accuracy.json").write_text(json.dumps(
        [{"t": 0.5, "median_abs_rel_error": 0.6, "median_abs_rel_error_aligned": 0.1},
         {"t": 0.0, "median_abs_rel_error": 0.7, "median_abs_rel_error_aligned": None},
         {"t": 1.0, "median_abs_rel_error": None}]))
    s = P.depth_error_series({"depth_accuracy": {"frames": 3}}, tmp_path)
    assert [x["t"] for x in s] == [0.0, 0.5]
    assert s[1]["median_abs_rel_error"] == 0.1 and s[1]["median_abs_rel_error_raw"] == 0.6
    assert P.depth_error_series({"depth_accuracy": {"frames": 3}}) == []


def test_init_runs_are_random_init_lite_vo_runs_from_their_start_frame(tmp_path):
    spec = P.plan_init_study(str(make_sequence(tmp_path / "d")), "seqA", 2, 1.0, tmp_path / "o", pin_core=True)[1]
    cmd = " ".join(P.build_run_command(spec))
    assert "-m lite_vo.cli.main run" in cmd and "--init random" in cmd and f"--set system.seed={spec.seed}" in cmd
    assert f"--start-frame {spec.start_frame}" in cmd and f"--max-frames {spec.max_frames}" in cmd
    assert "--set system.numba_threads=1" in cmd


def test_cli_passes_its_options_to_the_profiler(tmp_path, monkeypatch, capsys):
    from lite_vo.cli.main import main
    seen = {}

    def fake_run_profile(settings, log=None, command=None):
        seen["s"] = settings
        return {"counts": {"ok": 1, "fail": 0, "crash": 0}}

    monkeypatch.setattr(P, "run_profile", fake_run_profile)
    seq = make_sequence(tmp_path / "d")
    rc = main(["profile", str(seq), "--profiles", "phone,board", "--repeat", "2", "--workers", "1", "--pin-core",
               "--max-frames", "40", "--init", "depth", "--out", str(tmp_path / "o"), "--no-startup", "--force",
               "--set", "tracking.huber=2", "--set", "system.map_every=2"])
    s = seen["s"]
    assert rc == 0 and "1 ok" in capsys.readouterr().out
    assert (s.profiles, s.repeat, s.workers, s.pin_core, s.max_frames, s.init, s.force, s.startup) == \
        (["phone", "board"], 2, 1, True, 40, "depth", True, False)
    assert s.overrides == ["tracking.huber=2", "system.map_every=2"]
    assert main(["profile", str(seq), "--set", "tracking.hubr=2"]) == 1
    assert "tracking.hubr" in capsys.readouterr().err
    assert main(["profile", str(seq), "--init-study", "3", "--out", str(tmp_path / "o2")]) == 0
    assert seen["s"].init_study == 3 and seen["s"].profiles == ["phone"]  # the paper's study used phone
    assert main(["profile", str(seq), "--workers", "0"]) == 1
    assert main(["profile", str(seq), "--profiles", "phone,nosuch"]) == 1
    assert "nosuch" in capsys.readouterr().err


def test_accuracy_cells():
    ok = {"runs": 2, "ok": 2, "failed": 0, "crashed": 0, "x": {"mean": 0.625, "std": 0.05, "n": 2}, "y": None}
    assert R._cell(ok, "x") == "0.62 ± 0.05" or R._cell(ok, "x") == "0.63 ± 0.05"
    assert R._cell(ok, "y") == "n/a"  # evaluated, but e.g. shorter than the 1-s RPE interval
    part = dict(ok, ok=1, failed=1, x={"mean": 1.0, "std": 0.0, "n": 1})
    assert R._cell(part, "x") == "1.00 (1/2 fail)"
    assert R._cell({"runs": 1, "ok": 0, "failed": 1, "crashed": 0}, "x") == "fail"
    assert R._cell({"runs": 1, "ok": 0, "failed": 1, "crashed": 1}, "x") == "crash"
    assert R._cell({"runs": 0}, "x") == "-"


def test_compiled_kernels_from_numba_debug_output():
    text = ("[cache] index saved to '/tmp/c/tracking_9eea/_kernels.accumulate-89.py311.nbi'\n"
            "[cache] data saved to '/tmp/c/tracking_9eea/_kernels.accumulate-89.py311.2.nbc'\n"
            "[cache] data loaded from '/tmp/c/mapping_12ab/_kernels.observe-10.py311.1.nbc'\n"
            "[cache] data saved to '/tmp/c/tracking_9eea/_kernels.lm_level-307.py311.2.nbc'\n"
            "[cache] data saved to '/tmp/c/lite_vo_77aa/image._blur_separable-151.py311.1.nbc'\n")
    assert P.compiled_kernels(text) == ["lite_vo/image._blur_separable", "tracking/_kernels.accumulate",
                                        "tracking/_kernels.lm_level"]
    assert P.compiled_kernels("") == []
