"""Whole-scene point cloud: colours from the right pixels, consistency filter, voxels, map.ply."""
from __future__ import annotations

import numpy as np

from lite_vo.camera import PinholeIntrinsics
from lite_vo.geometry import make_pose
from lite_vo.keyframes import Keyframe, depth_jump, scene_cloud, voxel_downsample

CAM = PinholeIntrinsics(50.0, 50.0, 31.5, 23.5, 64, 48)


def _wall_kf(i, x, depth=2.0, outlier=False):
    """A keyframe looking at the plane z = depth (world) from (x, 0, 0); colour encodes the pixel."""
    v, u = np.mgrid[0:48, 0:64]
    color = np.dstack([u * 3, v * 5, np.full_like(u, 200)]).astype(np.uint8)  # B = u*3, G = v*5, R = 200
    d = np.full((48, 64), 1.0 / depth, np.float32)
    if outlier:
        d[10, 10] = 1.0 / (0.5 * depth)                   # one point far off the wall
    return Keyframe.make(i, i * 0.1, make_pose(np.eye(3), [x, 0, 0]), CAM, color.mean(axis=2), d,
                         np.full((48, 64), 1e-5, np.float32), color)


def test_colours_come_from_the_right_pixels():
    kfs = [_wall_kf(0, 0.0), _wall_kf(1, 0.05), _wall_kf(2, 0.1)]
    cloud = scene_cloud(kfs)
    assert len(cloud.points) > 3000
    u, v = cloud.pixel[:, 0], cloud.pixel[:, 1]
    # RGB order (R first); keyframe colours are stored as JPEG (a grey level or two off): a point
    # coloured from the neighbouring pixel would be off by 3 (u) or 5 (v) levels on average
    err = np.abs(cloud.colors.astype(np.int16) - np.stack([np.full(len(u), 200), v * 5, u * 3], 1))
    assert err.max() <= 3 and err.mean(axis=0).max() < 1.0, (err.max(axis=0), err.mean(axis=0))
    # and the point of that pixel is where the pixel looks (points are stored as float32: 1e-4 px, 1e-6 m)
    kf = {k.index: k for k in kfs}
    for j in (0, len(u) // 2, len(u) - 1):
        k = kf[int(cloud.keyframe[j])]
        p = cloud.points[j].astype(np.float64) - k.T_world_cam[:3, 3]
        assert abs(CAM.fx * p[0] / p[2] + CAM.cx - u[j]) < 1e-4 and abs(p[2] - 2.0) < 1e-6


def test_inconsistent_point_is_removed():
    kfs = [_wall_kf(0, 0.0, outlier=True), _wall_kf(1, 0.05), _wall_kf(2, 0.1)]
    cloud = scene_cloud(kfs, max_jump=np.inf)                                # the consistency filter alone
    assert np.all(np.abs(cloud.points[:, 2] - 2.0) < 1e-6)
    clean = [_wall_kf(0, 0.0), _wall_kf(1, 0.05), _wall_kf(2, 0.1)]
    assert len(scene_cloud(clean, max_jump=np.inf).points) == len(cloud.points) + 1   # only the outlier went
    assert np.any(np.abs(scene_cloud(kfs, min_support=0, max_jump=np.inf).points[:, 2] - 1.0) < 1e-6)


def test_points_at_a_depth_discontinuity_are_removed():
    """A step from 2 m (left) to 1 m (right) at column 32: the points within 2 pixels of the step go
    (depth_jump 1.0 > max_jump), the rest of both planes stays."""
    d = np.full((48, 64), 0.5, np.float32)
    d[:, 32:] = 1.0
    var = np.full((48, 64), 1e-5, np.float32)
    kf = Keyframe.make(0, 0.0, np.eye(4), CAM, np.full((48, 64), 100.0), d, var)
    jump = depth_jump(kf.idepth)
    assert np.allclose(jump[:, 30:32], 1.0) and np.allclose(jump[:, 32:34], 0.5)
    assert np.all(jump[:, :30] == 0) and np.all(jump[:, 34:] == 0)
    cloud = scene_cloud([kf], min_support=0)
    u = cloud.pixel[:, 0]
    assert len(u) == 48 * 60 and not np.any((u >= 30) & (u < 34))
    assert len(scene_cloud([kf], min_support=0, max_jump=np.inf).points) == 48 * 64


def test_points_kept_unobserved_through_clipping_are_left_out():
    """A clipped, flat patch (grey 255 over 10x10 pixels: hypotheses the filter kept unobserved,
    mapping.keep_clipped) gives no points except along its rim (8 neighbours not all clipped); a bright
    but textured patch and the rest of the image keep theirs; clipped=256 keeps everything."""
    img = np.full((48, 64), 100.0)
    img[10:20, 10:20] = 255.0                               # clipped flat
    img[30:40, 40:50] = 252.0                               # bright with texture: every other pixel 240
    img[30:40:2, 40:50] = 240.0
    d = np.full((48, 64), 0.5, np.float32)
    kf = Keyframe.make(0, 0.0, np.eye(4), CAM, img, d, np.full((48, 64), 1e-5, np.float32))
    cloud = scene_cloud([kf], min_support=0)
    u, v = cloud.pixel[:, 0], cloud.pixel[:, 1]
    inner = (u >= 11) & (u < 19) & (v >= 11) & (v < 19)
    assert not np.any(inner) and len(u) == 48 * 64 - 64
    assert np.sum((u >= 40) & (u < 50) & (v >= 30) & (v < 40)) == 100
    assert len(scene_cloud([kf], min_support=0, clipped=256).points) == 48 * 64


def test_voxel_downsample_averages():
    cloud = scene_cloud([_wall_kf(0, 0.0), _wall_kf(1, 0.05)])
    small = voxel_downsample(cloud, 0.2)
    assert 0 < len(small.points) < len(cloud.points) / 10
    assert np.allclose(small.points[:, 2], 2.0)


def test_map_ply_is_the_coloured_whole_scene_and_trimesh_reads_it(synth_small, tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    import trimesh

    from lite_vo.io import read_ply
    exe = Path(sys.executable).with_name("lite-vo")
    subprocess.run([str(exe), "run", str(synth_small), "--poses", "gt", "--out", str(tmp_path / "out"), "--quiet"],
                   check=True)
    ply = read_ply(tmp_path / "out" / "map.ply")
    assert "red" in ply and len(ply["x"]) > 1000
    pc = trimesh.load(tmp_path / "out" / "map.ply")
    assert len(pc.vertices) == len(ply["x"])


def test_map_voxel_option_thins_map_ply(synth_small, tmp_path, capsys):
    """`lite-vo run --map-voxel S`: map.ply holds one point per S-sized voxel (fewer points, no two in
    one voxel); a negative size is one error line naming the option."""
    from lite_vo.cli.main import main
    from lite_vo.io import read_ply
    args = ["run", str(synth_small), "--poses", "gt", "--quiet"]
    assert main(args + ["--out", str(tmp_path / "all")]) == 0
    assert main(args + ["--out", str(tmp_path / "vox"), "--map-voxel", "0.05"]) == 0
    full, vox = read_ply(tmp_path / "all" / "map.ply"), read_ply(tmp_path / "vox" / "map.ply")
    xyz = np.stack([vox["x"], vox["y"], vox["z"]], axis=1).astype(np.float64)
    assert 0 < len(xyz) < len(full["x"]) / 3
    # points are voxel means: each lies in its own voxel, so no two share one
    assert len(np.unique(np.floor(xyz / 0.05).astype(np.int64), axis=0)) == len(xyz)
    capsys.readouterr()
    assert main(args + ["--out", str(tmp_path / "bad"), "--map-voxel", "-1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--map-voxel" in err[0]


def _semi_dense(rng, h=48, w=64, density=0.4):
    """A semi-dense inverse-depth map: smooth depth with steps, NaN where there is no hypothesis."""
    v, u = np.mgrid[0:h, 0:w]
    d = (0.5 + 0.3 * np.sin(u / 7.0) + 0.2 * (v > h // 2)).astype(np.float32)
    d[rng.random((h, w)) > density] = np.nan
    return d


def test_the_consistency_kernel_matches_its_numpy_twin():
    """support_counts gives, point for point, what one numpy pass per window offset gives: points behind
    the camera, outside the image, at the border, on and off the map's depth, window 0 / 1 / 2."""
    import naive_cloud as naive

    from lite_vo._cloud_kernels import support_counts
    rng = np.random.default_rng(5)
    d = _semi_dense(rng)
    d.setflags(write=False)
    n = 4000
    uv = rng.uniform(-6, 70, (n, 2))
    z = 1.0 / np.nan_to_num(d[np.clip(uv[:, 1].astype(int), 0, 47), np.clip(uv[:, 0].astype(int), 0, 63)], nan=0.6)
    z *= rng.choice([1.0, 1.03, 1.2, -1.0], n)              # agree, within 7 %, off, behind
    z[:5] = 0.0
    p = np.stack([(uv[:, 0] - CAM.cx) / CAM.fx * z, (uv[:, 1] - CAM.cy) / CAM.fy * z, z], axis=1)
    p[5:25, :2] = np.round(uv[5:25] - [CAM.cx, CAM.cy]) + 0.5             # projections exactly half-way
    p[5:25, :2] /= [CAM.fx, CAM.fy]
    p[5:25, 2] = 1.0
    for win in (0, 1, 2):
        count = np.zeros(n, np.int64)
        seen_n = np.zeros(n, np.int64)
        for _ in range(2):                                  # counts add up over neighbours
            support_counts(p, CAM.fx, CAM.fy, CAM.cx, CAM.cy, 64, 48, d, 0.07, win, count, seen_n)
        seen, agree = naive.support(p, CAM.fx, CAM.fy, CAM.cx, CAM.cy, 64, 48, d, 0.07, win)
        np.testing.assert_array_equal(seen_n, 2 * seen)
        np.testing.assert_array_equal(count, 2 * agree)
        assert 100 < agree.sum() < seen.sum() < n           # every outcome occurs


def test_the_depth_jump_kernel_matches_its_numpy_twin():
    import naive_cloud as naive
    rng = np.random.default_rng(6)
    d = _semi_dense(rng).astype(np.float64)
    d[0, :8] = 0.0                                          # degenerate hypotheses: inf / NaN ratios
    d[5, 5] = np.inf
    for radius in (0, 1, 2, 3):
        got = depth_jump(d, radius)
        want = naive.depth_jump(d, radius)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        np.testing.assert_array_equal(got[~np.isnan(got)], want[~np.isnan(want)])
    assert np.nanmax(depth_jump(d, 2)) > 0.3
