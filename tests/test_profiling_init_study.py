"""Tests of lite_vo.profiling.init_study (thesis Fig. 5.8) and the relative drift it uses
(lite_vo.eval.relative_drift)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from lite_vo.errors import InputError
from lite_vo.eval import associate, relative_drift, window_pairs
from lite_vo.io import Trajectory
from lite_vo.profiling import command as C
from lite_vo.profiling import init_study as I
from lite_vo.profiling import sweep as S
from profiling_fakes import FakeEvaluator, FakeLauncher, gt_poses, make_sequence, settings


def test_associate_and_relative_drift():
    t, poses = gt_poses(120)
    gt = Trajectory(t, poses)
    ia, ib = associate(t[::2] + 0.001, t, 0.005)
    assert np.array_equal(ib, np.arange(0, 120, 2)) and len(ia) == 60
    assert len(associate(t + 0.5, t[:10], 0.01)[0]) == 0
    half = poses.copy()
    half[:, :3, 3] *= 0.5
    est = Trajectory(t, half)
    ts, e = relative_drift(gt, est, scale=2.0)
    assert len(e) > 50 and np.allclose(e, 0.0, atol=1e-9) and ts[0] == pytest.approx(0.5, abs=0.02)
    _, e_wrong = relative_drift(gt, est, scale=1.0, window_frames=15)
    assert np.allclose(e_wrong, 0.5, atol=1e-9)  # half the motion -> 50% relative drift


def test_init_study_plan_spreads_start_frames_and_seeds(tmp_path):
    seq = make_sequence(tmp_path / "data", n=150)  # 5 s at 30 Hz
    specs = I.plan_init_study(str(seq), "seqA", 4, 3.0, tmp_path / "o")
    assert [s.seed for s in specs] == [1, 2, 3, 4]
    starts = [s.start_frame for s in specs]
    assert starts[0] == 0 and starts == sorted(starts) and len(set(starts)) == 4
    assert max(starts) + specs[-1].max_frames <= 150
    assert all(s.init == "random" and s.kind == "init" for s in specs)
    assert specs[0].max_frames == 91  # 3 s at 30 Hz, inclusive of both ends
    with pytest.raises(InputError, match="shorter"):
        I.plan_init_study(str(seq), "seqA", 2, 10.0, tmp_path / "o")


def test_init_study_success_rate_and_errors_over_time(tmp_path):
    seq = make_sequence(tmp_path / "data", n=150)

    class InitLauncher(FakeLauncher):
        def _run(self, spec, core):
            if spec.seed == 2:
                return S.RunOutcome(1, "RuntimeError: diverged", 0.1, core)
            out = super()._run(spec, core)
            if spec.seed == 3:  # wrong depth: fails the 16% criterion
                run = json.loads((spec.out_dir / "run.json").read_text())
                for x in run["depth_accuracy"]["frames"]:
                    x["median_abs_rel_error"] = 0.4
                (spec.out_dir / "run.json").write_text(json.dumps(run))
            return out

    s = settings(tmp_path, [seq], profiles=["phone"], init_study=4, init_study_len=3.5)
    report = C.run_profile(s, launcher=InitLauncher(scale=3.0, noise={"phone": 0.0}), evaluator=FakeEvaluator())
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


def test_init_runs_are_random_init_lite_vo_runs_from_their_start_frame(tmp_path):
    spec = I.plan_init_study(str(make_sequence(tmp_path / "d")), "seqA", 2, 1.0, tmp_path / "o", pin_core=True)[1]
    cmd = " ".join(S.build_run_command(spec))
    assert "-m lite_vo.cli.main run" in cmd and "--init random" in cmd and f"--set system.seed={spec.seed}" in cmd
    assert f"--start-frame {spec.start_frame}" in cmd and f"--max-frames {spec.max_frames}" in cmd
    assert "--set system.numba_threads=1" in cmd


def test_window_pairs_pick_the_pose_one_window_earlier():
    t = np.array([0.0, 0.1, 0.2, 0.35, 0.4, 0.5, 0.9])
    k, j = window_pairs(t, window_s=0.3)
    # t_k - 0.3 must not reach before t_0; j is the nearest pose to that time (earlier one on a tie)
    assert k.tolist() == [3, 4, 5, 6] and j.tolist() == [0, 1, 2, 5]
    k, j = window_pairs(t, window_frames=2)
    assert k.tolist() == [2, 3, 4, 5, 6] and (k - j == 2).all()
    assert window_pairs(t[:1], window_s=0.3)[0].size == 0
