"""TUM trajectory files and PLY point clouds."""
from __future__ import annotations

import numpy as np
import pytest

from data_helpers import random_trajectory
from lite_vo.errors import InputError
from lite_vo.io import Accelerometer, Trajectory, read_ply, read_trajectory, write_ply, write_trajectory


def test_trajectory_round_trip(tmp_path):
    traj = random_trajectory(50, seed=3, dt=0.033, t0=1305031453.359684)
    p = tmp_path / "traj.txt"
    write_trajectory(p, traj, comment="made by a test\nsecond line")
    text = p.read_text().splitlines()
    assert text[0] == "# timestamp tx ty tz qx qy qz qw" and text[1] == "# made by a test"
    back = read_trajectory(p)
    assert len(back) == 50
    np.testing.assert_allclose(back.timestamps, traj.timestamps, atol=1e-6)
    np.testing.assert_allclose(back.poses, traj.poses, atol=1e-7)
    assert back.poses_T_world_cam is back.poses


def test_trajectory_with_gaps_and_comments(tmp_path):
    p = tmp_path / "t.txt"
    p.write_text("# a comment\n\n0.0 0 0 0 0 0 0 1\n# lost frames here\n5.0 1 2 3 0 0 0.7071068 0.7071068\n")
    t = read_trajectory(p)
    assert len(t) == 2 and t.timestamps.tolist() == [0.0, 5.0]
    np.testing.assert_allclose(t.poses[1][:3, 3], [1, 2, 3])
    np.testing.assert_allclose(t.poses[1][:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-6)
    assert t.path_length() == pytest.approx(np.sqrt(14))
    assert t.nearest(4.0) == 1 and t.nearest(4.0, max_dt=0.5) is None


@pytest.mark.parametrize("line, expect", [
    ("1.0 0 0 0 0 0 1", "line 3: expected 8 fields"),
    ("1.0 0 0 nan 0 0 0 1", "line 3: pose contains NaN"),
    ("1.0 0 0 0 0 0 0 0", "line 3: quaternion qx qy qz qw has zero length"),
    ("1.0 0 0 x 0 0 0 1", "line 3: 'x' is not a number"),
    ("0.0 0 0 0 0 0 0 1", "line 3: timestamp 0.0 is not after the previous one"),
])
def test_trajectory_errors(tmp_path, line, expect):
    p = tmp_path / "bad.txt"
    p.write_text("# header\n0.0 0 0 0 0 0 0 1\n" + line + "\n")
    with pytest.raises(InputError) as ei:
        read_trajectory(p)
    assert "bad.txt" in str(ei.value) and expect in str(ei.value)


def test_trajectory_missing_or_empty(tmp_path):
    with pytest.raises(InputError, match="nope.txt: trajectory file not found"):
        read_trajectory(tmp_path / "nope.txt")
    (tmp_path / "e.txt").write_text("# only a comment\n")
    with pytest.raises(InputError, match="e.txt: trajectory file contains no poses"):
        read_trajectory(tmp_path / "e.txt")


def test_pose_interpolation():
    from lite_vo.geometry import exp_so3, make_pose
    T0 = make_pose(np.eye(3), np.zeros(3))
    T1 = make_pose(exp_so3(np.array([0, 0, np.pi / 2])), np.array([2.0, 0, 0]))
    traj = Trajectory([1.0, 2.0], [T0, T1])
    mid = traj.pose_at(1.5, max_gap=2.0)
    np.testing.assert_allclose(mid[:3, 3], [1.0, 0, 0])
    np.testing.assert_allclose(mid[:3, :3], exp_so3(np.array([0, 0, np.pi / 4])), atol=1e-12)
    np.testing.assert_array_equal(traj.pose_at(2.0), T1)
    assert traj.pose_at(0.5) is None and traj.pose_at(2.5) is None
    assert traj.pose_at(1.5, max_gap=0.5) is None


def test_trajectory_and_accelerometer_validation():
    with pytest.raises(ValueError, match="strictly increasing"):
        Trajectory([0.0, 0.0], np.tile(np.eye(4), (2, 1, 1)))
    with pytest.raises(ValueError, match="NaN"):
        Trajectory([0.0], np.full((1, 4, 4), np.nan))
    with pytest.raises(ValueError, match="expected timestamps"):
        Trajectory([0.0, 1.0], np.eye(4)[None])
    acc = Accelerometer([0.0, 1.0], [[0, 0, 9], [0, 0, 11]])
    np.testing.assert_allclose(acc.at(0.25), [0, 0, 9.5])
    np.testing.assert_allclose(acc.mean_between(-1, 2), [0, 0, 10])
    assert acc.mean_between(5, 6) is None


@pytest.mark.parametrize("binary", [True, False])
def test_ply_round_trip(tmp_path, binary):
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(100, 3))
    var = rng.uniform(0, 1e-3, 100)
    grey = rng.integers(0, 256, 100)
    p = tmp_path / "map.ply"
    write_ply(p, pts, idepth_var=var, colors=grey, binary=binary)
    header = p.read_bytes().split(b"end_header\n")[0].decode()
    assert ("binary_little_endian" if binary else "ascii") in header
    assert "element vertex 100" in header and "property float idepth_var" in header
    d = read_ply(p)
    np.testing.assert_allclose(np.stack([d["x"], d["y"], d["z"]], 1), pts, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(d["idepth_var"], var, rtol=1e-6)
    np.testing.assert_array_equal(d["red"], grey)
    np.testing.assert_array_equal(d["blue"], grey)


def test_ply_xyz_only_rgb_and_errors(tmp_path):
    p = tmp_path / "a.ply"
    write_ply(p, np.zeros((0, 3)))
    assert read_ply(p)["x"].shape == (0,)
    rgb = np.array([[255, 0, 0], [0, 255, 0]])
    write_ply(p, np.ones((2, 3)), colors=rgb)
    d = read_ply(p)
    assert set(d) == {"x", "y", "z", "red", "green", "blue"} and d["green"].tolist() == [0, 255]
    with pytest.raises(ValueError, match="NaN"):
        write_ply(p, np.array([[0, 0, np.nan]]))
    with pytest.raises(ValueError, match="idepth_var has 1 values for 2 points"):
        write_ply(p, np.ones((2, 3)), idepth_var=[1.0])
    (tmp_path / "x.ply").write_text("not a ply")
    with pytest.raises(InputError, match="x.ply: not a PLY file"):
        read_ply(tmp_path / "x.ply")
