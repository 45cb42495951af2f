"""Evaluation: hand-made cases with known answers, cross-checks against evo on the shared ground
truths, and the ``lite-vo eval`` command."""
from __future__ import annotations

import json

import numpy as np
import pytest

from data_helpers import random_trajectory, require_shared, write_tum_folder, write_tum_trajectory
from lite_vo.errors import InputError
from lite_vo.eval import associate, evaluate, relative_pairs, umeyama_alignment
from lite_vo.geometry import exp_so3, make_pose
from lite_vo.io import Trajectory, read_trajectory, write_trajectory

CONTRACT_KEYS = {"rpe_trans_cm_per_s", "rpe_rot_deg_per_s", "ate_rmse_m", "scale", "matched_poses"}
EXTRA_KEYS = {"motion_cm_per_s", "rpe_trans_pct", "path_length_m", "ate_pct_of_path", "rot_motion_deg_per_s"}


def _line(t, speed=1.0, rot_deg_per_s=0.0):
    """Poses moving along x at ``speed`` m/s and turning about z at ``rot_deg_per_s``."""
    R = exp_so3(np.stack([np.zeros_like(t), np.zeros_like(t), np.radians(rot_deg_per_s) * t], 1))
    p = np.stack([speed * t, np.zeros_like(t), np.zeros_like(t)], 1)
    return Trajectory(t, make_pose(R, p))


def test_identical_trajectories_have_zero_error():
    gt = random_trajectory(200, seed=1, dt=0.05)
    for align in ("none", "se3", "sim3"):
        r = evaluate(gt, gt, align=align)
        assert r.matched_poses == 200 and r.ate_rmse_m < 1e-12
        assert r.rpe_trans_cm_per_s < 1e-9 and r.rpe_rot_deg_per_s < 1e-9
        assert r.scale == pytest.approx(1.0)
    d = r.to_dict()
    assert CONTRACT_KEYS <= set(d) and EXTRA_KEYS <= set(d)
    json.dumps(d)


def test_constant_speed_error_known_answers():
    t = np.arange(0, 10.0001, 0.1)
    gt, est = _line(t, 1.0), _line(t, 1.1)
    r = evaluate(gt, est, align="none")
    assert r.rpe_trans_cm_per_s == pytest.approx(10.0)           # 0.1 m per second
    assert r.motion_cm_per_s == pytest.approx(100.0)
    assert r.rpe_trans_pct == pytest.approx(10.0)
    assert r.rpe_rot_deg_per_s == pytest.approx(0.0, abs=1e-9)
    assert r.rpe_pairs == len(t) - 10                            # every i with t_i + 1 s inside
    assert r.ate_rmse_m == pytest.approx(np.sqrt(np.mean((0.1 * t) ** 2)))
    assert r.path_length_m == pytest.approx(10.0)
    assert r.ate_pct_of_path == pytest.approx(100 * r.ate_rmse_m / 10.0)
    # Sim(3) alignment finds the scale and removes both errors; the scale also applies to RPE
    r = evaluate(gt, est, align="sim3")
    assert r.scale == pytest.approx(1 / 1.1) and r.ate_rmse_m < 1e-9
    assert r.rpe_trans_cm_per_s < 1e-7
    # SE(3) cannot fix the scale: RPE is unchanged, ATE smaller than without alignment
    r2 = evaluate(gt, est, align="se3")
    assert r2.scale == 1.0 and r2.rpe_trans_cm_per_s == pytest.approx(10.0)
    assert 0 < r2.ate_rmse_m < np.sqrt(np.mean((0.1 * t) ** 2))


def test_rotation_drift_known_answer():
    t = np.arange(0, 5.0001, 0.05)
    r = evaluate(_line(t, 0.5, 10.0), _line(t, 0.5, 12.0), align="none")
    assert r.rpe_rot_deg_per_s == pytest.approx(2.0, rel=1e-9)
    assert r.rot_motion_deg_per_s == pytest.approx(10.0, rel=1e-9)


def test_delta_and_time_normalisation():
    t = np.arange(0, 10.0001, 0.1)
    gt, est = _line(t, 1.0), _line(t, 1.1)
    r = evaluate(gt, est, align="none", delta_s=2.0)
    assert r.rpe_trans_cm_per_s == pytest.approx(10.0)            # still per second
    assert r.rpe_pairs == len(t) - 20


def test_gaps_in_the_estimate():
    t = np.arange(0, 10.0001, 0.1)
    keep = (t < 3.0) | (t > 5.5)                                  # 2.5 s lost
    gt, est = _line(t, 1.0), _line(t, 1.1)[np.nonzero(keep)[0]]
    r = evaluate(gt, est, align="none")
    assert r.matched_poses == keep.sum()
    assert r.rpe_trans_cm_per_s == pytest.approx(10.0)            # per actual time delta
    assert r.rpe_pairs < keep.sum() - 10
    i, j = relative_pairs(est.timestamps, 1.0)
    dt = est.timestamps[j] - est.timestamps[i]
    assert np.all(np.abs(dt - 1.0) <= 0.5 + 1e-9)


def test_association_tolerance_and_messages():
    t = np.arange(0, 3.0, 0.1)
    gt = _line(t)
    est = _line(t + 0.01)
    i_est, i_gt = associate(est.timestamps, gt.timestamps, 0.02)
    assert len(i_est) == len(t) and np.all(i_est == i_gt)
    r = evaluate(gt, est, align="se3")
    assert r.matched_poses == len(t)
    with pytest.raises(InputError, match=r"only 0 estimated poses match the ground truth within 0.02 s"):
        evaluate(gt, _line(t + 0.04), align="se3")
    assert evaluate(gt, _line(t + 0.04), align="se3", max_dt=0.045).matched_poses == len(t)
    with pytest.raises(InputError, match="unknown alignment"):
        evaluate(gt, est, align="sim2")


def test_short_trajectory_has_no_rpe_pairs():
    t = np.arange(0, 0.5, 0.1)
    r = evaluate(_line(t), _line(t, 1.2), align="none")
    assert r.rpe_pairs == 0 and np.isnan(r.rpe_trans_cm_per_s)
    d = r.to_dict()
    assert d["rpe_trans_cm_per_s"] is None and any("RPE undefined" in w for w in d["warnings"])
    json.dumps(d)
    assert "n/a" in r.table()


def test_umeyama_recovers_known_similarity():
    rng = np.random.default_rng(5)
    src = rng.normal(size=(50, 3))
    R = exp_so3(np.array([0.4, -1.0, 2.0]))
    dst = 2.5 * src @ R.T + np.array([1.0, -2.0, 3.0])
    s, R2, t2 = umeyama_alignment(src, dst, with_scale=True)
    assert s == pytest.approx(2.5) and np.allclose(R2, R) and np.allclose(t2, [1, -2, 3])
    s, R3, _ = umeyama_alignment(src, dst, with_scale=False)
    assert s == 1.0 and np.allclose(R3, R)                         # rotation is scale-independent
    # a reflection is never returned
    assert np.linalg.det(umeyama_alignment(src, -src, True)[1]) == pytest.approx(1.0)


def test_static_estimate_sim3_warns():
    t = np.arange(0, 2.0, 0.1)
    est = Trajectory(t, np.tile(np.eye(4), (len(t), 1, 1)))
    r = evaluate(_line(t), est, align="sim3")
    assert r.scale == 1.0 and any("does not move" in w for w in r.warnings)


# ------------------------------------------------------------------------------------------------
# cross-check against evo on the shared ground truths
# ------------------------------------------------------------------------------------------------

def _perturbed(gt: Trajectory, seed: int, scale: float | None, time_jitter: float = 0.0) -> Trajectory:
    """GT with seeded pose noise, expressed in a random Sim(3)-transformed world."""
    from lite_vo.geometry import exp_se3
    rng = np.random.default_rng(seed)
    n = len(gt)
    noise = exp_se3(np.concatenate([rng.normal(0, 0.01, (n, 3)), rng.normal(0, 0.01, (n, 3))], 1))
    poses = gt.poses @ noise
    R = exp_so3(rng.normal(size=3))
    s = 1.0 if scale is None else scale
    out = poses.copy()
    out[:, :3, :3] = R @ poses[:, :3, :3]
    out[:, :3, 3] = s * poses[:, :3, 3] @ R.T + rng.normal(size=3)
    t = gt.timestamps + (rng.uniform(-time_jitter, time_jitter, n) if time_jitter else 0.0)
    return Trajectory(t, out)


def _evo_traj(traj: Trajectory):
    from evo.core.trajectory import PoseTrajectory3D
    return PoseTrajectory3D(poses_se3=list(traj.poses), timestamps=traj.timestamps.copy())


def _evo_ape(gt, est, align, correct_scale, max_diff=0.02):
    import copy

    from evo.core import metrics, sync
    ref, e = sync.associate_trajectories(_evo_traj(gt), _evo_traj(est), max_diff=max_diff)
    e = copy.deepcopy(e)
    if align:
        e.align(ref, correct_scale=correct_scale)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, e))
    return ape.get_statistic(metrics.StatisticsType.rmse), len(ref.timestamps)


GT_FILES = [("icl_livingroom_211", None), ("kitti07_160", None), ("rgbd_dataset_freiburg1_desk_first9", 3)]


@pytest.mark.shared_data
@pytest.mark.parametrize("name, stride", GT_FILES, ids=[g[0].split("_")[0] for g in GT_FILES])
@pytest.mark.parametrize("align", ["none", "se3", "sim3"])
def test_ate_matches_evo(name, stride, align):
    pytest.importorskip("evo")
    gt = read_trajectory(require_shared(name) / "groundtruth.txt")
    if stride:
        gt = gt[::stride]
    if align == "none":   # same world frame: only pose noise and timestamp jitter
        rng = np.random.default_rng(3)
        p = gt.poses.copy()
        p[:, :3, 3] += rng.normal(0, 0.05, (len(gt), 3))
        est = Trajectory(gt.timestamps + rng.uniform(-0.004, 0.004, len(gt)), p)
    else:
        est = _perturbed(gt, seed=7, scale=None if align != "sim3" else 0.37, time_jitter=0.004)
    ours = evaluate(gt, est, align=align, max_dt=0.02)
    ref, n = _evo_ape(gt, est, align != "none", align == "sim3")
    assert ours.matched_poses == n
    assert ours.ate_rmse_m == pytest.approx(ref, rel=1e-6, abs=1e-9)
    if align == "sim3":
        assert ours.scale == pytest.approx(1 / 0.37, rel=0.05)


@pytest.mark.shared_data
@pytest.mark.parametrize("align", ["se3", "sim3"])
def test_rpe_matches_evo_on_icl(align):
    pytest.importorskip("evo")
    import copy

    from evo.core import metrics
    gt = read_trajectory(require_shared("icl_livingroom_211") / "groundtruth.txt")   # exactly 30 Hz
    est = _perturbed(gt, seed=11, scale=2.0 if align == "sim3" else None)
    ours = evaluate(gt, est, align=align, delta_s=1.0)
    ref, e = _evo_traj(gt), copy.deepcopy(_evo_traj(est))
    e.align(ref, correct_scale=(align == "sim3"))
    vals = {}
    for rel in (metrics.PoseRelation.translation_part, metrics.PoseRelation.rotation_angle_deg):
        rpe = metrics.RPE(rel, delta=30, delta_unit=metrics.Unit.frames, all_pairs=True)
        rpe.process_data((ref, e))
        vals[rel] = (rpe.get_statistic(metrics.StatisticsType.rmse), len(rpe.error))
    # evo reports per pair (delta = 30 frames = 1 s); ours per second of the actual delta (1 s +- 1e-5)
    assert ours.rpe_pairs == vals[metrics.PoseRelation.translation_part][1]
    assert ours.rpe_trans_cm_per_s / 100 == pytest.approx(vals[metrics.PoseRelation.translation_part][0], rel=1e-4)
    assert ours.rpe_rot_deg_per_s == pytest.approx(vals[metrics.PoseRelation.rotation_angle_deg][0], rel=1e-4)


# ------------------------------------------------------------------------------------------------
# lite-vo eval
# ------------------------------------------------------------------------------------------------

def test_cli_eval_writes_json_and_refuses_overwrite(tmp_path, capsys):
    from lite_vo.cli.main import main
    t = np.arange(0, 5.0001, 0.1)
    gt_p = write_tum_trajectory(tmp_path / "gt.txt", t, _line(t, 1.0).poses)
    est_p = tmp_path / "est.txt"
    write_trajectory(est_p, _line(t, 1.1))
    out = tmp_path / "res.json"
    rc = main(["eval", "--gt", str(gt_p), "--est", str(est_p), "--align", "none", "--json", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "RPE translation" in printed and "10.000 cm/s" in printed and "ATE RMSE" in printed
    d = json.loads(out.read_text())
    assert CONTRACT_KEYS <= set(d) and EXTRA_KEYS <= set(d)
    assert d["rpe_trans_cm_per_s"] == pytest.approx(10.0) and d["matched_poses"] == len(t)
    # no overwrite without --force
    before = out.read_text()
    rc = main(["eval", "--gt", str(gt_p), "--est", str(est_p), "--json", str(out)])
    err = capsys.readouterr().err
    assert rc == 1 and "res.json: already exists (use --force to overwrite)" in err
    assert out.read_text() == before
    rc = main(["eval", "--gt", str(gt_p), "--est", str(est_p), "--align", "sim3", "--json", str(out), "--force"])
    assert rc == 0 and json.loads(out.read_text())["scale"] == pytest.approx(1 / 1.1)


def test_cli_eval_sequence_folder_and_run_folder(tmp_path, capsys):
    from lite_vo.cli.main import main
    seq = write_tum_folder(tmp_path, n=3)
    gt = read_trajectory(seq / "groundtruth.txt")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    write_trajectory(run_dir / "trajectory.txt", gt)
    rc = main(["eval", "--gt", str(seq), "--est", str(run_dir), "--align", "se3", "--delta-s", "0.2"])
    assert rc == 0 and "matched poses" in capsys.readouterr().out


def test_cli_eval_bad_input(tmp_path, capsys):
    from lite_vo.cli.main import main
    t = np.arange(0, 2.0, 0.1)
    gt_p = write_tum_trajectory(tmp_path / "gt.txt", t, _line(t).poses)
    bad = tmp_path / "bad.txt"
    bad.write_text("0.0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0\n")
    assert main(["eval", "--gt", str(gt_p), "--est", str(bad)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad.txt line 2: expected 8 fields" in err
    assert main(["eval", "--gt", str(gt_p), "--est", str(tmp_path / "missing.txt")]) == 1
    assert "missing.txt: trajectory file not found" in capsys.readouterr().err
    far = tmp_path / "far.txt"
    write_trajectory(far, _line(t + 100.0))
    assert main(["eval", "--gt", str(gt_p), "--est", str(far)]) == 1
    assert "only 0 estimated poses match" in capsys.readouterr().err
    assert main(["eval", "--gt", str(gt_p), "--est", str(gt_p), "--delta-s", "-1"]) == 1
    assert "delta_s must be > 0" in capsys.readouterr().err


def test_no_rpe_pairs_for_a_run_shorter_than_delta_with_unix_timestamps():
    from lite_vo.eval import relative_pairs
    t = 1305031102.175304 + np.arange(9) / 30.0  # 0.27 s of TUM fr1/desk
    i, j = relative_pairs(t, 1.0)
    assert len(i) == 0
    i, j = relative_pairs(t, 0.1)
    assert len(i) > 0 and np.all(np.abs(t[j] - t[i] - 0.1) <= 0.05 + 1e-6)
