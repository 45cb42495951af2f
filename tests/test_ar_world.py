"""AR world model: kernels vs naive twins, ground plane, in-painting, collision mesh."""
from __future__ import annotations

import numpy as np
import pytest

from ar_demo import _kernels
from ar_demo.config import ARConfig, ar_config
from ar_demo.ground import (GravityFilter, GroundPlane, estimate_ground_plane, lowest_supported_height,
                            map_points_world, up_from_accelerometer)
from ar_demo.inpaint import inpaint, reduce_idepth
from ar_demo.mesh import grid_faces, grid_mesh
from lite_vo.camera import PinholeIntrinsics
from lite_vo.errors import ConfigError
from naive_ar import (energy_naive, gradient_naive, idepth_from_depth, inpaint_naive, look_at, raycast_depth,
                      reduce_idepth_naive)

INTR = PinholeIntrinsics(260.0, 260.0, 159.5, 119.5, 320, 240)
BOX = (1.4, -0.35, 0.0, 2.0, 0.25, 0.4)


def _camera(roll_deg=0.0):
    T = look_at([0.0, 0.1, 1.0], [2.2, 0.0, 0.0])
    if roll_deg:
        c, s = np.cos(np.deg2rad(roll_deg)), np.sin(np.deg2rad(roll_deg))
        T[:3, :3] = T[:3, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return T


# ----------------------------------------------------------------------------- kernels
@pytest.mark.parametrize("shape,out", [((8, 12), (2, 3)), ((7, 9), (3, 4)), ((5, 5), (5, 5)), ((4, 4), (1, 1))])
def test_reduce_kernel_matches_naive(shape, out):
    rng = np.random.default_rng(1)
    d = rng.uniform(0.2, 2.0, shape)
    v = rng.uniform(1e-3, 1e-1, shape)
    d[rng.random(shape) < 0.5] = np.nan          # empty pixels
    v[rng.random(shape) < 0.1] = np.inf          # invalid variance
    v[0, 0] = 0.0
    D, V, C = reduce_idepth_naive(d, v, out)
    oD, oV, oC = np.empty(out), np.empty(out), np.empty(out, dtype=np.int64)
    _kernels.reduce_idepth_kernel(d, v, oD, oV, oC)
    np.testing.assert_array_equal(oC, C)
    np.testing.assert_allclose(oD, D, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(oV, V, rtol=1e-12, equal_nan=True)


def test_reduce_all_empty_gives_nan():
    d = np.full((16, 16), np.nan)
    D, V, C = reduce_idepth(d, np.ones_like(d), (2, 2))
    assert np.isnan(D).all() and np.isnan(V).all() and (C == 0).all()


def test_reduce_pyramid_equals_repeated_2x2():
    rng = np.random.default_rng(2)
    d = rng.uniform(0.2, 2.0, (16, 16))
    v = rng.uniform(1e-3, 1e-1, (16, 16))
    d[rng.random(d.shape) < 0.7] = np.nan
    D, V, _ = reduce_idepth(d, v, (4, 4))
    d1, v1, _ = reduce_idepth_naive(d, v, (8, 8))
    d2, v2, _ = reduce_idepth_naive(d1, v1, (4, 4))
    np.testing.assert_allclose(D, d2, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(V, v2, rtol=1e-12, equal_nan=True)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_inpaint_kernel_matches_naive_and_energy_decreases(seed):
    rng = np.random.default_rng(seed)
    shape = (6, 7) if seed else (1, 1)
    f = rng.uniform(0.5, 1.5, shape)
    w = rng.uniform(0.5, 1e3, shape)
    u0 = rng.uniform(0.0, 2.0, shape)
    alpha, delta = 0.3, 0.05
    np.testing.assert_allclose(_kernels.inpaint_energy_kernel(u0, f, w, alpha, delta),
                               energy_naive(u0, f, w, alpha, delta), rtol=1e-12)
    g = np.empty(shape)
    _kernels.inpaint_gradient_kernel(u0, f, w, alpha, delta, g)
    np.testing.assert_allclose(g, gradient_naive(u0, f, w, alpha, delta), rtol=1e-10, atol=1e-12)
    u = u0.copy()
    energies = np.empty(201)
    n = _kernels.inpaint_kernel(u, f, w, alpha, delta, 200, -1.0, energies)   # tol < 0: no early stop
    un, en = inpaint_naive(u0, f, w, alpha, delta, 200, -1.0)
    assert n == len(en) - 1
    np.testing.assert_allclose(u, un, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(energies[:n + 1], en, rtol=1e-9)
    assert np.all(np.diff(energies[:n + 1]) <= 1e-12 * energies[0])     # monotone decrease


def test_gradient_matches_finite_differences():
    rng = np.random.default_rng(5)
    u = rng.uniform(0, 1, (4, 5))
    f = rng.uniform(0, 1, (4, 5))
    w = rng.uniform(0.1, 2, (4, 5))
    g = gradient_naive(u, f, w, 0.7, 0.01)
    eps = 1e-7
    for idx in [(0, 0), (1, 2), (3, 4), (2, 0)]:
        up, dn = u.copy(), u.copy()
        up[idx] += eps
        dn[idx] -= eps
        num = (energy_naive(up, f, w, 0.7, 0.01) - energy_naive(dn, f, w, 0.7, 0.01)) / (2 * eps)
        assert abs(num - g[idx]) < 1e-5


def test_inpaint_energy_monotone_on_map_and_converges():
    rng = np.random.default_rng(3)
    D = rng.uniform(0.3, 0.6, (15, 20))
    V = np.full_like(D, 1e-3)
    D[rng.random(D.shape) < 0.6] = np.nan
    prior = np.full(D.shape, 0.4)
    res = inpaint(D, V, prior, alpha=0.05, huber_delta=0.05, ground_var=0.05, iterations=3000, tol=0.0)
    e = res.energies
    assert 3 < len(e) < 3001                    # stopped when the energy no longer decreases
    assert np.all(np.diff(e) <= 1e-12 * e[0])
    assert e[-1] < e[0]
    # at convergence the gradient vanishes (stationary point of the convex energy)
    u = res.idepth / res.scale
    f = np.where(res.data_mask, np.nan_to_num(D) / res.scale, prior / res.scale)
    w = np.where(res.data_mask, 1 / np.maximum(V / res.scale**2, 1e-4), 1 / 0.05)
    g = gradient_naive(u, f, w, 0.05, 0.05)
    assert np.abs(g).max() < 1e-4 * np.abs(gradient_naive(f, f, w, 0.05, 0.05)).max() + 1e-6


# ----------------------------------------------------------------------------- ground plane
def test_lowest_supported_height_rule():
    rng = np.random.default_rng(0)
    floor = rng.uniform(-0.004, 0.0, 500)
    table = 0.7 + rng.uniform(-0.004, 0.004, 800)
    outliers = np.array([-0.5, -0.3, -0.2])
    h = lowest_supported_height(np.concatenate([outliers, table, floor]), 100, 0.01)
    assert -0.0041 < h <= 0.0          # highest supporting floor sample, outliers ignored
    assert lowest_supported_height(np.zeros(5), 10, 0.01) is None


def test_gravity_filter_in_world_frame():
    rng = np.random.default_rng(0)
    f = GravityFilter(1.0)
    up_true = np.array([0.0, 0.0, 1.0])
    for k in range(300):
        ang = 0.3 * np.sin(k / 20)
        c, s = np.cos(ang), np.sin(ang)
        R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ _camera()[:3, :3]
        acc = R.T @ (9.81 * up_true) + rng.normal(0, 0.3, 3)
        f.update(acc, R, k / 100.0)
    assert np.degrees(np.arccos(f.up_world @ up_true)) < 1.0


@pytest.mark.parametrize("roll", [0.0, 12.0])
def test_ground_plane_from_imu_and_depth(roll):
    rng = np.random.default_rng(4)
    T = _camera(roll)
    depth, label = raycast_depth(T, INTR.K, 320, 240, boxes=[BOX])
    idepth = idepth_from_depth(depth, rng, 0.85)         # semi-dense
    idepth *= 1 + rng.normal(0, 0.003, idepth.shape)         # noisy
    points = map_points_world(idepth, INTR, T)
    acc_cam = (T[:3, :3].T @ np.array([0, 0, 9.81]))[None] + rng.normal(0, 0.2, (200, 3))
    up = up_from_accelerometer(acc_cam, 1.0, T[:3, :3])
    gp = estimate_ground_plane(points, ARConfig(), up_world=up, T_world_cam0=T)
    assert gp.source == "imu+map"
    assert np.degrees(np.arccos(gp.normal_world @ [0, 0, 1])) < 2.0
    assert abs(gp.height) < 0.02
    floor = points[np.abs(points[:, 2]) < 0.05]
    floor = floor[np.linalg.norm(floor - T[:3, 3], axis=1) < 4.0]
    assert np.median(np.abs(gp.signed_distance(floor))) < 0.02


def test_ground_plane_imu_only_when_refinement_disabled():
    rng = np.random.default_rng(4)
    T = _camera(5.0)
    depth, _ = raycast_depth(T, INTR.K, 320, 240, boxes=[BOX])
    idepth = idepth_from_depth(depth, rng, 0.85)
    up = np.array([0.0, np.sin(np.deg2rad(0.5)), np.cos(np.deg2rad(0.5))])
    gp = estimate_ground_plane(map_points_world(idepth, INTR, T), ARConfig(ground_refine_max_deg=0.0),
                               up_world=up, T_world_cam0=T)
    assert gp.source == "imu" and np.allclose(gp.normal_world, up)


def test_ground_plane_on_lite_vo_synth_room():
    """The synthetic room (floor z = 0, z up) with its accelerometer: hand-held motion biases the
    low-pass gravity; the refined plane is within 2 deg and 2 cm."""
    from ar_demo.world import semi_dense_from_depth
    from lite_vo.synth import default_intrinsics, iter_frames
    K = default_intrinsics(160, 120)
    f = GravityFilter(1.0)
    for fr in iter_frames("room", "handheld", n_frames=10, seed=3, width=160, height=120):
        f.update(fr.acc_cam, fr.T_world_cam[:3, :3], fr.timestamp)
    idepth, _ = semi_dense_from_depth(fr.image, fr.depth, 8.0, 1e-4)
    pts = map_points_world(idepth, K, fr.T_world_cam)
    gp = estimate_ground_plane(pts, ARConfig(), up_world=f.up_world, T_world_cam0=fr.T_world_cam)
    assert np.degrees(np.arccos(gp.normal_world[2])) < 2.0
    assert abs(gp.height) < 0.02
    floor = pts[np.abs(pts[:, 2]) < 0.01]
    assert np.median(np.abs(gp.signed_distance(floor))) < 0.02


def test_ground_plane_ransac_fallback_without_imu():
    rng = np.random.default_rng(6)
    T = _camera(8.0)
    depth, _ = raycast_depth(T, INTR.K, 320, 240, boxes=[BOX])
    idepth = idepth_from_depth(depth, rng, 0.9)
    idepth *= 1 + rng.normal(0, 0.002, idepth.shape)
    gp = estimate_ground_plane(map_points_world(idepth, INTR, T), ARConfig(), up_world=None, T_world_cam0=T)
    assert gp.source == "ransac"
    assert np.degrees(np.arccos(gp.normal_world @ [0, 0, 1])) < 2.0
    assert abs(gp.height) < 0.02


def test_ground_plane_idepth_matches_raycast():
    T = _camera(5.0)
    depth, label = raycast_depth(T, INTR.K, 320, 240)
    gp = GroundPlane(np.array([0.0, 0.0, 1.0]), 0.0)
    idg = gp.idepth_grid(T, INTR)
    hit = label == 1
    np.testing.assert_allclose(idg[hit], 1 / depth[hit], rtol=1e-9)
    assert np.all(idg[~hit] == 0)                 # above the horizon: no intersection


# ----------------------------------------------------------------------------- in-painting
def test_inpainting_recovers_piecewise_planar_depth():
    """Floor + box seen semi-densely at 320x240 -> 15x20 grid close to the true inverse depth."""
    rng = np.random.default_rng(7)
    T = _camera()
    cfg = ARConfig()
    depth, label = raycast_depth(T, INTR.K, 320, 240, boxes=[BOX])
    idepth = idepth_from_depth(depth)
    semi = idepth.copy()
    keep = rng.random(semi.shape) < 0.05
    keep[label == 0] = False
    semi[~keep] = np.nan
    semi[60:200, 20:90] = np.nan                  # a large empty floor region: the prior must fill it
    var = 1e-4 * np.nan_to_num(semi) ** 2 + 1e-8
    gi = INTR.scaled(20, 15)
    gp = GroundPlane(np.array([0.0, 0.0, 1.0]), 0.0)
    prior = gp.idepth_grid(T, gi)
    D, V, C = reduce_idepth(semi, var, (15, 20))
    res = inpaint(D, V, prior, cfg.alpha, cfg.huber_delta, cfg.ground_var, cfg.min_var, 2000, 1e-12)
    # ground truth: inverse depth at the grid cell centres (same cells as the reduction)
    truth, tlabel = raycast_depth(T, gi.K, 20, 15, boxes=[BOX])
    ok = truth > 0
    rel = np.abs(res.idepth[ok] * truth[ok] - 1)
    assert np.median(rel) < 0.03
    assert np.percentile(rel, 90) < 0.15
    # the empty block (no data) follows the ground prior
    empty = ~res.data_mask
    assert empty.sum() >= 6
    np.testing.assert_allclose(res.idepth[empty & (tlabel == 1)], prior[empty & (tlabel == 1)], rtol=0.05)
    assert np.all(np.diff(res.energies) <= 1e-12 * res.energies[0])


# ----------------------------------------------------------------------------- mesh
def test_grid_faces_and_mesh_of_plane(tmp_path):
    assert grid_faces(3, 4).shape == (12, 3)
    T = _camera()
    gi = INTR.scaled(20, 15)
    gp = GroundPlane(np.array([0.0, 0.0, 1.0]), 0.0)
    prior = gp.idepth_grid(T, gi)
    prior[prior == 0] = np.nan
    mesh = grid_mesh(prior, gi, T, max_depth_ratio=0.0, idepth_floor=0.01)
    ok = np.isfinite(prior).ravel()
    assert np.abs(mesh.vertices_world[ok, 2]).max() < 1e-9     # vertices lie on the floor
    # discontinuity filter drops the triangles at the far clamp
    mesh2 = grid_mesh(prior, gi, T, max_depth_ratio=1.6, idepth_floor=0.01)
    assert 0 < len(mesh2.faces) < len(mesh.faces)
    for ext in ("obj", "ply"):
        mesh2.export(tmp_path / f"m.{ext}")
        import trimesh
        m = trimesh.load(tmp_path / f"m.{ext}", process=False)
        assert len(m.faces) == len(mesh2.faces)


def test_ar_config_overrides():
    cfg = ar_config(["alpha=0.5", "ar.grid_width=40"])
    assert cfg.alpha == 0.5 and cfg.grid_width == 40
    with pytest.raises(ConfigError):
        ar_config(["nope=1"])
    with pytest.raises(ConfigError):
        ar_config(["grid_width=1"])
