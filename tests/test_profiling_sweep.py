"""Tests of lite_vo.profiling.sweep and .results: run commands, worker processes pinned to cores,
judging one run folder, pooling timings."""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from lite_vo.eval import evaluate
from lite_vo.profiling import results as Res
from lite_vo.profiling import sweep as S
from profiling_fakes import FakeLauncher, make_sequence, stats


def test_real_evaluator_on_exact_trajectory(tmp_path):
    seq = make_sequence(tmp_path / "data")
    spec = S.RunSpec(str(seq), "seqA", "phone", 0, tmp_path / "run")
    FakeLauncher(noise={"phone": 0.0})(spec, None)
    rec = Res.collect_run(spec, S.RunOutcome(0), Res.load_groundtruth(seq), evaluate)
    assert rec["status"] == "ok", rec["reason"]
    assert rec["eval"]["rpe_trans_cm_per_s"] == pytest.approx(0.0, abs=1e-3)
    assert rec["eval"]["matched_poses"] >= 140


def test_pool_stats_equals_stats_of_concatenation():
    rng = np.random.default_rng(3)
    parts = [rng.normal(10, 3, n) for n in (5, 17, 1)]
    pooled = Res.pool_stats([stats(p) for p in parts] + [None, {"count": 0, "mean": None}])
    allv = np.concatenate(parts)
    assert pooled["count"] == 23 and pooled["runs"] == 3
    assert pooled["mean"] == pytest.approx(allv.mean())
    assert pooled["std"] == pytest.approx(allv.std())
    assert Res.pool_stats([None]) is None


def test_run_command_and_pinned_environment(tmp_path):
    spec = S.RunSpec("seq", "seq", "board", 0, tmp_path / "o", init="random", max_frames=50, start_frame=7,
                     seed=3, pin_core=True)
    cmd = S.build_run_command(spec)
    assert cmd[:5] == [sys.executable, "-m", "lite_vo.cli.main", "run", "seq"]
    text = " ".join(cmd)
    for part in ("--profile board", "--quiet", "--mode sync", "--init random", "--max-frames 50",
                 "--start-frame 7", "--set system.seed=3", "--set system.numba_threads=1", f"--out {tmp_path / 'o'}"):
        assert part in text
    assert S.run_env(True, {})["NUMBA_NUM_THREADS"] == "1"
    assert "NUMBA_NUM_THREADS" not in S.run_env(False, {})


def test_execute_keeps_order_never_shares_a_core_and_survives_a_broken_launcher(tmp_path, monkeypatch):
    monkeypatch.setattr(S, "available_cores", lambda: [0, 1])
    specs = [S.RunSpec("s", "s", "phone", i, tmp_path / str(i)) for i in range(6)]
    fake = FakeLauncher(delay=0.02)

    def launcher(spec, core):
        if spec.rep == 3:
            raise RuntimeError("launcher broke")
        return fake(spec, core)

    started, done = [], []
    outs = S.execute(specs, launcher, workers=3, pin_core=True,
                     on_start=lambda i, n, s, c: started.append((i, c)), on_done=lambda i, n, s, o: done.append(i))
    assert [o.returncode for o in outs] == [0, 0, 0, -1, 0, 0]
    assert "launcher broke" in outs[3].stderr_tail
    assert not fake.core_clash and {c for _, c in fake.calls} <= {0, 1}
    assert sorted(done) == list(range(1, 7)) and sorted(i for i, _ in started) == list(range(1, 7))
    assert {c for _, c in started} <= {0, 1}  # a run is announced with the core it holds


def test_launch_run_reports_a_crash_with_its_last_stderr_line(tmp_path, monkeypatch):
    code = "import sys; print('working'); sys.stderr.write('Traceback\\nKeyError: frame 3\\n'); sys.exit(2)"
    monkeypatch.setattr(S, "build_run_command", lambda spec: [sys.executable, "-c", code])
    spec = S.RunSpec("s", "s", "phone", 0, tmp_path / "runs" / "s" / "phone" / "0")
    out = S.launch_run(spec, core=S.available_cores()[0])
    assert out.returncode == 2 and out.stderr_tail == "KeyError: frame 3"
    log = spec.log_path.read_text()
    assert "working" in log and "KeyError" in log
    rec = Res.collect_run(spec, out)
    assert rec["status"] == "crash" and "exit status 2: KeyError: frame 3" in rec["reason"]


def test_sequence_names_are_unique(tmp_path):
    a = tmp_path / "x" / "seq"
    b = tmp_path / "y" / "seq"
    c = tmp_path / "euroc" / "mav0"
    for p in (a, b, c):
        p.mkdir(parents=True)
    assert S.sequence_names([str(a), str(b), str(c)]) == ["seq_1", "seq_2", "euroc"]


def test_depth_series_prefers_the_aligned_error_and_the_run_folder_file(tmp_path):
    (tmp_path / "depth_accuracy.json").write_text(json.dumps(
        [{"t": 0.5, "median_abs_rel_error": 0.6, "median_abs_rel_error_aligned": 0.1},
         {"t": 0.0, "median_abs_rel_error": 0.7, "median_abs_rel_error_aligned": None},
         {"t": 1.0, "median_abs_rel_error": None}]))
    s = Res.depth_error_series({"depth_accuracy": {"frames": 3}}, tmp_path)
    assert [x["t"] for x in s] == [0.0, 0.5]
    assert s[1]["median_abs_rel_error"] == 0.1 and s[1]["median_abs_rel_error_raw"] == 0.6
    assert Res.depth_error_series({"depth_accuracy": {"frames": 3}}) == []


def test_the_run_command_passes_the_calibration_on():
    from pathlib import Path
    from lite_vo.profiling.sweep import RunSpec, build_run_command
    spec = RunSpec("clip.mp4", "clip", "phone", 0, Path("out"), calib="cam.yaml")
    cmd = build_run_command(spec)
    assert cmd[cmd.index("--calib") + 1] == "cam.yaml"
    assert "--calib" not in build_run_command(RunSpec("seq", "seq", "phone", 0, Path("out")))
