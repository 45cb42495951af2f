"""Trajectory plots (lite_vo.plots) and ``lite-vo eval --plot``: pixel size, content, the per-pose
errors they draw, and the one-line error without matplotlib."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from data_helpers import random_trajectory
from lite_vo.errors import MissingExtraError
from lite_vo.eval import evaluate, pose_errors
from lite_vo.geometry import exp_so3, make_pose
from lite_vo.io import Trajectory, write_trajectory

pytest.importorskip("matplotlib", reason="plots need the [plot] extra (matplotlib)")

from lite_vo.plots import EST_COLOUR, GT_COLOUR, plot_trajectory, top_view_plane  # noqa: E402


def _sim3(traj: Trajectory, s: float, seed: int = 0) -> Trajectory:
    """``traj`` seen in another frame and scale (what a monocular estimate looks like)."""
    R = exp_so3(np.random.default_rng(seed).normal(size=3))
    S = make_pose(R, np.array([0.3, -1.0, 2.0]))
    P = traj.poses.copy()
    P[:, :3, 3] *= s
    return Trajectory(traj.timestamps, S @ P)


def _pixels_near(img_bgr: np.ndarray, hex_colour: str, tol: int = 12) -> np.ndarray:
    rgb = np.array([int(hex_colour[k:k + 2], 16) for k in (1, 3, 5)])
    return np.all(np.abs(img_bgr[..., ::-1].astype(int) - rgb) <= tol, axis=-1)


def test_pose_errors_after_alignment_known_answers():
    gt = random_trajectory(60, seed=1, dt=0.05)
    # pose 10 turned by 2 degrees, the whole estimate in another frame and scale: Sim(3) removes the
    # frame and scale, the rotation error of pose 10 remains
    P = gt.poses.copy()
    P[10, :3, :3] = P[10, :3, :3] @ exp_so3(np.radians([0.0, 2.0, 0.0]))
    est = _sim3(Trajectory(gt.timestamps, P), 0.5)
    r = evaluate(gt, est, align="sim3")
    e = pose_errors(gt, est, r)
    assert len(e.timestamps) == 60 and np.allclose(e.trans_err_m, r.ate_errors_m)
    assert e.rot_err_deg[10] == pytest.approx(2.0, abs=1e-6)
    assert np.delete(e.rot_err_deg, 10).max() < 1e-6 and e.trans_err_m.max() < 1e-9
    np.testing.assert_allclose(e.gt_xyz, gt.positions_xyz)
    np.testing.assert_allclose(e.est_xyz, gt.positions_xyz, atol=1e-9)
    # without alignment a 3 cm shift of pose 30 is exactly its translation error
    P = gt.poses.copy()
    P[30, :3, 3] += [0.0, 0.03, 0.0]
    shifted = Trajectory(gt.timestamps, P)
    e = pose_errors(gt, shifted, evaluate(gt, shifted, align="none"))
    assert e.trans_err_m[30] == pytest.approx(0.03) and np.delete(e.trans_err_m, 30).max() < 1e-12


def test_top_view_plane_follows_the_spread():
    t = np.arange(50) * 0.1
    xyz = np.stack([np.sin(t), 0.01 * t, 3 * np.cos(t)], 1)        # camera frame: y down, moves in x-z
    assert top_view_plane(xyz) == "xz"
    assert top_view_plane(xyz[:, [0, 2, 1]]) == "xy"


def test_plot_with_ground_truth_has_the_size_and_both_trajectories(tmp_path):
    import cv2
    gt = random_trajectory(120, seed=2, dt=0.05, speed=0.5)
    est = _sim3(gt[np.r_[0:50, 60:120]], 2.0)                       # a gap of lost frames
    out = plot_trajectory(gt, est, tmp_path / "p.png", size_px=(1200, 800), name="test")
    img = cv2.imread(str(out))
    assert img.shape == (800, 1200, 3)
    left, right = img[:, :600], img[:, 650:]
    est_left, est_right = _pixels_near(left, EST_COLOUR).sum(), _pixels_near(right, EST_COLOUR).sum()
    assert est_left > 300 and est_right > 300                        # trajectory and error curves
    assert _pixels_near(left, GT_COLOUR).sum() > 100
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 50


def test_plot_without_ground_truth(tmp_path):
    import cv2
    est = random_trajectory(40, seed=3)
    out = plot_trajectory(None, est, tmp_path / "e.png", size_px=(640, 480), dpi=80)
    img = cv2.imread(str(out))
    assert img.shape == (480, 640, 3)
    assert _pixels_near(img, EST_COLOUR).sum() > 200


def test_cli_eval_plot(tmp_path, capsys):
    import cv2

    from lite_vo.cli.main import main
    gt = random_trajectory(60, seed=4, dt=0.05)
    gt_p, est_p, png = tmp_path / "gt.txt", tmp_path / "est.txt", tmp_path / "plot.png"
    write_trajectory(gt_p, gt)
    write_trajectory(est_p, _sim3(gt, 3.0))
    assert main(["eval", "--gt", str(gt_p), "--est", str(est_p), "--plot", str(png)]) == 0
    assert f"plot: {png}" in capsys.readouterr().out
    assert cv2.imread(str(png)).shape == (1000, 1500, 3)
    assert main(["eval", "--gt", str(gt_p), "--est", str(est_p), "--plot", str(png)]) == 1
    assert "plot.png: already exists (use --force to overwrite)" in capsys.readouterr().err


def test_without_matplotlib_plot_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    from lite_vo.cli.main import main
    gt = random_trajectory(20, seed=5)
    gt_p = tmp_path / "gt.txt"
    write_trajectory(gt_p, gt)
    for mod in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.setitem(sys.modules, mod, None)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(MissingExtraError, match=r"pip install 'lite-vo\[plot\]'"):
        plot_trajectory(gt, gt, tmp_path / "x.png")
    assert main(["eval", "--gt", str(gt_p), "--est", str(gt_p), "--plot", str(tmp_path / "y.png")]) == 1
    captured = capsys.readouterr()
    assert captured.err.strip().count("\n") == 0 and "[plot]" in captured.err and "ATE" not in captured.out
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "y.png").exists()
