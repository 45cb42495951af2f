"""Trajectory formats of ``lite-vo eval``: KITTI (with times.txt or by index), EuRoC CSV ground
truth, detection by content, ``write_trajectory_kitti`` and the errors naming file and line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from data_helpers import random_trajectory, require_shared, write_euroc_folder
from lite_vo.errors import InputError
from lite_vo.eval import evaluate
from lite_vo.io import open_sequence, read_trajectory, write_trajectory
from lite_vo.io.trajectory import (read_kitti_poses, read_pose_file, trajectory_format,
                                   write_trajectory_kitti)


def _kitti_text(poses) -> str:
    return "".join(" ".join(f"{v:.12e}" for v in T[:3, :].reshape(-1)) + "\n" for T in poses)


def test_detection_by_content(tmp_path):
    tr = random_trajectory(5, seed=1)
    write_trajectory(tmp_path / "tum.txt", tr)
    (tmp_path / "tum_commas.txt").write_text("1.0,0,0,0,0,0,0,1\n")
    (tmp_path / "kitti.txt").write_text(_kitti_text(tr.poses))
    (tmp_path / "euroc.csv").write_text("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
                                        "q_RS_y [], q_RS_z []\n1403715274302139904,1,2,3,1,0,0,0\n")
    (tmp_path / "euroc_noheader.csv").write_text("1403715274302139904,1,2,3,1,0,0,0,0,0,0\n")
    (tmp_path / "odd.txt").write_text("# comment\n1 2 3 4 5\n")
    assert [trajectory_format(tmp_path / n) for n in ("tum.txt", "tum_commas.txt", "kitti.txt", "euroc.csv",
                                                      "euroc_noheader.csv")] == ["tum", "tum", "kitti", "euroc", "euroc"]
    with pytest.raises(InputError, match=r"odd\.txt line 2: 5 fields: not a TUM .* KITTI .* EuRoC"):
        trajectory_format(tmp_path / "odd.txt")
    (tmp_path / "empty.txt").write_text("# nothing\n")
    with pytest.raises(InputError, match="contains no poses"):
        trajectory_format(tmp_path / "empty.txt")


def test_kitti_round_trip_with_times_and_gaps(tmp_path):
    tr = random_trajectory(30, seed=2, dt=0.1, t0=3.0)
    gappy = tr[np.r_[0:10, 15:30]]                      # frames 10..14 lost
    run = tmp_path / "run"
    run.mkdir()
    write_trajectory_kitti(run / "trajectory_kitti.txt", gappy)
    lines = (run / "trajectory_kitti.txt").read_text().splitlines()
    assert len(lines) == 25 and all(len(s.split()) == 12 for s in lines)
    assert (run / "times.txt").read_text().splitlines()[10] == f"{gappy.timestamps[10]:.9f}"
    pf = read_pose_file(run / "trajectory_kitti.txt")
    back, note = pf.trajectory()
    assert pf.format == "kitti" and "times.txt" in note
    np.testing.assert_allclose(back.timestamps, gappy.timestamps)
    np.testing.assert_allclose(back.poses, gappy.poses, atol=1e-8)
    assert evaluate(tr, back, align="none").ate_rmse_m < 1e-7
    # times.txt with the wrong count names both files
    (run / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(InputError, match=r"times\.txt: has 2 timestamps for the 25 poses"):
        read_pose_file(run / "trajectory_kitti.txt")


def test_kitti_without_times_takes_the_other_trajectory_by_index(tmp_path):
    tr = random_trajectory(20, seed=3, dt=0.1, t0=50.0)
    (tmp_path / "07.txt").write_text(_kitti_text(tr.poses))
    pf = read_pose_file(tmp_path / "07.txt")
    assert pf.timestamps is None
    by_index, note = pf.trajectory(tr)
    assert "by index" in note and np.array_equal(by_index.timestamps, tr.timestamps)
    alone, note = pf.trajectory()
    assert "10 Hz" in note and np.allclose(alone.timestamps, np.arange(20) / 10.0)
    with pytest.raises(InputError, match=r"07\.txt: KITTI poses have no timestamps .* count 20 differs from the 19"):
        pf.trajectory(tr[1:])


def test_kitti_errors_name_file_and_line(tmp_path):
    good = " ".join(["1", "0", "0", "0", "0", "1", "0", "0", "0", "0", "1", "0"])
    cases = {
        "short.txt": (f"{good}\n1 0 0 0 0 1 0 0 0 0 1\n", r"short\.txt line 2: expected 12 numbers"),
        "word.txt": (f"{good}\n{good.replace('0', 'x', 1)}\n", r"word\.txt line 2: 'x' is not a number"),
        "nan.txt": (f"# header\n{good.replace('0', 'nan', 1)}\n", r"nan\.txt line 2: pose contains NaN"),
        "scaled.txt": (f"{good}\n2 0 0 0 0 2 0 0 0 0 2 0\n", r"scaled\.txt line 2: the 3x3 part is not a rotation"),
    }
    for name, (text, pattern) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(InputError, match=pattern):
            read_kitti_poses(tmp_path / name)


def test_euroc_csv_inside_mav0_is_converted_to_the_camera(tmp_path):
    T_BS = np.array([[0, -1, 0, 0.1], [1, 0, 0, -0.02], [0, 0, 1, 0.03], [0, 0, 0, 1.0]])
    folder = write_euroc_folder(tmp_path, n=6, T_BS=T_BS)
    csv = folder / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    tr, note = read_pose_file(csv, "ground truth file").trajectory()
    seq_gt = open_sequence(folder).groundtruth
    assert "converted to cam0" in note and len(tr) == 12
    np.testing.assert_allclose(tr.poses, seq_gt.poses, atol=1e-12)
    np.testing.assert_allclose(tr.timestamps, seq_gt.timestamps, atol=1e-6)
    # outside a mav0 folder: the body poses, said so
    lone = tmp_path / "data.csv"
    lone.write_text(csv.read_text())
    tr2, note2 = read_pose_file(lone).trajectory()
    assert "not converted" in note2
    np.testing.assert_allclose(tr2.positions_xyz[:, 0], 0.01 * np.arange(12))
    lone.write_text(csv.read_text() + "1403715279262142976,0,0,0,0,0,0,0\n")
    with pytest.raises(InputError, match=r"data\.csv line 14: quaternion .* zero length"):
        read_pose_file(lone)


def test_cli_eval_kitti_and_euroc(tmp_path, capsys):
    from lite_vo.cli.main import main
    tr = random_trajectory(40, seed=4, dt=0.1, t0=0.0)
    gt_k = tmp_path / "gt" / "07.txt"
    gt_k.parent.mkdir()
    gt_k.write_text(_kitti_text(tr.poses))
    est = tmp_path / "est.txt"
    write_trajectory(est, tr)
    out = tmp_path / "r.json"
    assert main(["eval", "--gt", str(gt_k), "--est", str(est), "--align", "none", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "timestamps of the other trajectory, by index" in printed
    d = json.loads(out.read_text())
    assert d["matched_poses"] == 40 and d["ate_rmse_m"] < 1e-8 and "by index" in d["notes"][0]
    # an estimate with a lost frame cannot be paired by index: a one-line error
    write_trajectory(est, tr[np.r_[0:20, 21:40]])
    assert main(["eval", "--gt", str(gt_k), "--est", str(est)]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "cannot be paired by index; put the frame timestamps into a times.txt" in err
    # EuRoC ground truth straight from its data.csv
    folder = write_euroc_folder(tmp_path, n=6)
    csv = folder / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    write_trajectory(est, open_sequence(folder).groundtruth)
    assert main(["eval", "--gt", str(csv), "--est", str(est), "--align", "none", "--delta-s", "0.2"]) == 0
    printed = capsys.readouterr().out
    assert "EuRoC ground truth, converted to cam0" in printed and "matched poses    12" in printed


def test_shared_kitti_ground_truth_as_kitti_file_matches_tum(tmp_path):
    seq = require_shared("kitti07_160")
    gt = read_trajectory(seq / "groundtruth.txt")
    write_trajectory_kitti(tmp_path / "07.txt", gt, times=False)
    back, note = read_pose_file(tmp_path / "07.txt").trajectory(gt)
    assert "by index" in note
    r = evaluate(gt, back, align="none")
    assert r.matched_poses == 160 and r.ate_rmse_m < 1e-6 and r.rpe_rot_deg_per_s < 1e-5

