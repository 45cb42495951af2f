"""Direct SE(3) tracking: kernels vs numpy twins, reference building, convergence on synthetic pairs."""
import dataclasses

import numpy as np
import pytest

import naive_tracking as naive
from lite_vo.camera import PinholeIntrinsics
from lite_vo.geometry import exp_se3, inverse_se3, log_se3
from lite_vo.image import gradients, image_pyramid
from lite_vo.tracking import Tracker, TrackingConfig, TrackingReference, TrackingResult
from lite_vo.tracking import _kernels as kernels

INTR = PinholeIntrinsics(262.5, 262.5, 159.5, 119.5, 320, 240)     # phone profile mapping resolution
LEVELS, TRACK_LEVEL = 5, 1                                          # tracking at 160x120


# ----------------------------------------------------------------------------- kernels vs naive
def _random_points(rng, n, with_edge_cases=True):
    pts = np.empty((n, kernels.PTS_COLS), np.float32)
    d = rng.uniform(0.3, 1.2, n)
    xn = rng.uniform(-0.8, 0.8, n)
    yn = rng.uniform(-0.6, 0.6, n)
    pts[:, 0] = xn / d
    pts[:, 1] = yn / d
    pts[:, 2] = 1 / d
    pts[:, 3] = rng.uniform(0, 255, n)
    pts[:, 4] = rng.uniform(0, 0.05, n)
    if with_edge_cases:
        pts[0, 2] = -1.0                  # behind the camera
        pts[1, 0] = 50.0                  # far outside the image
        pts[2, :3] = [0.0, 0.0, 1e-4]     # (almost) at the camera centre
    return pts


def _args(fx, fy, cx, cy, sigma_i2, huber_k, aff_a, aff_b, with_affine, good_c2, good_g2, border, min_z):
    """``(cam, prm, aff_a, aff_b)``: the kernel arguments after the pose."""
    prm = np.zeros(kernels.TP_N)
    prm[kernels.TP_SIGMA_I2], prm[kernels.TP_HUBER] = sigma_i2, huber_k
    prm[kernels.TP_AFF_ENABLED] = float(with_affine)
    prm[kernels.TP_GOOD_C2], prm[kernels.TP_GOOD_G2] = good_c2, good_g2
    prm[kernels.TP_BORDER], prm[kernels.TP_MIN_Z] = border, min_z
    prm[kernels.TP_SATURATION] = 250.0
    return np.array([fx, fy, cx, cy], np.float64), prm, aff_a, aff_b


def _kernel_vs_naive(pts, img3, T, args, interp=kernels.INTERP_BILINEAR):
    acc = np.empty(kernels.ACC_SIZE)
    buf = np.empty((kernels.BUF_ROWS, max(len(pts), 1)))
    kernels.accumulate(pts, img3, interp, T, *args, buf, acc)
    ref = naive.accumulate(pts, img3, interp, T, *args)
    np.testing.assert_allclose(acc, ref, rtol=1e-6, atol=1e-6)
    return acc


@pytest.mark.parametrize("with_affine", [False, True])
@pytest.mark.parametrize("interp", [kernels.INTERP_BILINEAR, kernels.INTERP_BSPLINE])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_accumulate_matches_naive(seed, interp, with_affine):
    rng = np.random.default_rng(seed)
    h, w = 30, 40
    img = rng.uniform(0, 255, (h, w)).astype(np.float32)
    img3 = np.zeros((h, w, 3), np.float32)
    img3[:, :, 0] = img
    img3[:, :, 1:] = rng.normal(0, 20, (h, w, 2))
    img3[5:12, 5:12, 1:] = 0.0                              # zero-gradient patch
    img3[20, 30, :] = np.nan                                # NaN pixel
    pts = _random_points(rng, 300)
    T = exp_se3(rng.normal(0, [0.05, 0.05, 0.05, 0.05, 0.05, 0.05]))
    args = _args(35.0, 36.0, 19.5, 14.5, 16.0, 1.5, 1.1, -3.0, with_affine, 1600.0, 0.25, 1.0, 1e-3)
    acc = _kernel_vs_naive(pts, img3, T, args, interp)
    assert 0 < acc[kernels.ACC_N] < len(pts) - 2                  # some points skipped, most used
    assert acc[kernels.ACC_GOOD] + acc[kernels.ACC_BAD] == acc[kernels.ACC_N]


def test_accumulate_all_points_behind_or_outside_and_empty():
    rng = np.random.default_rng(4)
    img3 = rng.uniform(0, 255, (20, 20, 3)).astype(np.float32)
    pts = _random_points(rng, 50, with_edge_cases=False)
    pts[:, 2] *= -1                                         # everything behind the camera
    args = _args(20.0, 20.0, 9.5, 9.5, 16.0, 1.5, 1.0, 0.0, True, 1600.0, 0.25, 1.0, 1e-3)
    acc = _kernel_vs_naive(pts, img3, np.eye(4), args)
    assert acc[kernels.ACC_N] == 0 and np.all(acc == 0)
    acc = _kernel_vs_naive(pts[:0], img3, np.eye(4), args)
    assert np.all(acc == 0)


def test_accumulate_zero_gradient_gives_zero_hessian():
    rng = np.random.default_rng(5)
    img3 = np.zeros((20, 20, 3), np.float32)
    img3[:, :, 0] = 100.0
    pts = _random_points(rng, 40, with_edge_cases=False)
    args = _args(20.0, 20.0, 9.5, 9.5, 16.0, 1.5, 1.0, 0.0, True, 1600.0, 0.25, 1.0, 1e-3)
    acc = _kernel_vs_naive(pts, img3, np.eye(4), args)
    H, g = np.zeros((8, 8)), np.zeros(8)
    kernels.unpack_normal_equations(acc, H, g)
    assert acc[kernels.ACC_N] > 0 and np.all(H[:6] == 0) and np.all(g[:6] == 0)
    assert H[6, 6] > 0 and H[7, 7] > 0                      # brightness is still observable


def test_accumulate_jacobian_matches_finite_differences():
    """g = J^T W r: check J against numeric derivatives of the residual for a left increment."""
    rng = np.random.default_rng(6)
    ys, xs = np.mgrid[0:60, 0:80].astype(np.float64)
    img = 120 + 60 * np.sin(xs / 5.0) * np.cos(ys / 7.0) + 20 * np.sin((xs + 2 * ys) / 9.0)
    from lite_vo.image import intensity_gradient_stack
    img3 = intensity_gradient_stack(img.astype(np.float32))
    pts = _random_points(rng, 1, with_edge_cases=False)
    pts[0, :3] = [0.05, -0.03, 1.0]
    pts[0, 4] = 0.0
    T = exp_se3(np.array([0.01, 0.02, -0.01, 0.01, -0.02, 0.01]))
    intr = PinholeIntrinsics(70.0, 70.0, 39.5, 29.5, 80, 60)
    args = _args(intr.fx, intr.fy, intr.cx, intr.cy, 1.0, 1e9, 1.0, 0.0, True, 1600.0, 0.25, 1.0, 1e-3)
    acc = np.empty(kernels.ACC_SIZE)
    buf = np.empty((kernels.BUF_ROWS, 1))
    kernels.accumulate(pts, img3, kernels.INTERP_BILINEAR, T, *args, buf, acc)
    H = np.zeros((8, 8))
    g = np.zeros(8)
    kernels.unpack_normal_equations(acc, H, g)
    # single point, weight 1: g = J r, H = J J^T -> J = g / r
    r0 = naive.residuals(pts, img, T, intr)[0]
    J = g[:6] / r0
    # the affine columns: dr/dalpha = -a I_ref, dr/db = -1 (a = 1 here)
    np.testing.assert_allclose(g[6:] / r0, [-pts[0, 3], -1.0], rtol=1e-6)
    eps = 1e-6
    Jn = np.array([(naive.residuals(pts, img, exp_se3(eps * e) @ T, intr)[0]
                    - naive.residuals(pts, img, exp_se3(-eps * e) @ T, intr)[0]) / (2 * eps) for e in np.eye(6)])
    # the kernel uses interpolated central-difference gradients, not the exact bilinear slope: 10% agreement
    np.testing.assert_allclose(J, Jn, rtol=0.1, atol=0.1 * np.abs(Jn).max())
    np.testing.assert_allclose(H[:6, :6], np.outer(J, J), rtol=1e-6)


def test_solve_spd_and_exp_se3_nb():
    rng = np.random.default_rng(7)
    A = rng.normal(size=(6, 6))
    A = A @ A.T + 0.1 * np.eye(6)
    b = rng.normal(size=6)
    x = np.zeros(8)
    assert kernels.solve_spd(A, b, x, 6, 1e-12)
    np.testing.assert_allclose(x[:6], np.linalg.solve(A, b), rtol=1e-9)
    A8 = rng.normal(size=(8, 8))
    A8 = A8 @ A8.T + 0.1 * np.eye(8)
    b8 = rng.normal(size=8)
    assert kernels.solve_spd(A8, b8, x, 8, 1e-12)
    np.testing.assert_allclose(x, np.linalg.solve(A8, b8), rtol=1e-9)
    S = np.diag([1.0, 1, 1, 1, 1, 0])
    assert not kernels.solve_spd(S, b, x, 6, 1e-12)              # singular (zero-gradient direction)
    assert not kernels.solve_spd(np.full((6, 6), np.nan), b, x, 6, 1e-12)
    for xi in (rng.normal(size=6), 1e-7 * rng.normal(size=6), np.array([0.1, 0, 0, 0, 0, 0.0]),
               np.array([0, 0, 0, 3.0, 0, 0])):
        E = np.empty((4, 4))
        kernels.exp_se3_nb(xi, E)
        np.testing.assert_allclose(E, exp_se3(xi), atol=1e-12)


def test_kernels_warmup():
    kernels.warmup()


# ----------------------------------------------------------------------------- reference
def test_reference_build_levels_and_immutability():
    rng = np.random.default_rng(8)
    img = rng.uniform(0, 255, (240, 320)).astype(np.float32)
    idepth = rng.uniform(0.3, 1.0, (240, 320)).astype(np.float32)
    var = np.full((240, 320), 1e-3, np.float32)
    valid = rng.uniform(size=(240, 320)) < 0.3
    idepth[0, 0], valid[0, 0] = np.nan, True             # NaN is ignored
    pyr = image_pyramid(img, LEVELS)
    ref = TrackingReference.build(pyr, idepth, var, valid, INTR, frame_id=7)
    assert ref.frame_id == 7 and ref.num_levels == LEVELS
    assert ref.num_points(0) == valid.sum() - 1
    counts = [ref.num_points(lvl) for lvl in range(LEVELS)]
    densities = [c / ref.levels[lvl].num_pixels for lvl, c in enumerate(counts)]
    assert densities[0] < densities[1] < densities[2] <= densities[3] <= densities[4] <= 1.0
    lv = ref.levels[1]
    k1 = INTR.level(1)
    x, y, z = lv.points[:, 0], lv.points[:, 1], lv.points[:, 2]
    np.testing.assert_allclose(k1.fx * x / z + k1.cx, lv.x, atol=1e-3)
    np.testing.assert_allclose(k1.fy * y / z + k1.cy, lv.y, atol=1e-3)
    np.testing.assert_allclose(1 / z, lv.idepth, rtol=1e-5)
    from lite_vo.image import gaussian_blur
    assert ref.smooth_sigma == TrackingConfig().smooth_sigma > 0
    np.testing.assert_allclose(lv.intensity, gaussian_blur(pyr[1], ref.smooth_sigma)[lv.y.astype(int), lv.x.astype(int)],
                               atol=1e-3)
    raw = TrackingReference.build(pyr, idepth, var, valid, INTR, frame_id=7, smooth_sigma=0.0)
    np.testing.assert_array_equal(raw.levels[1].intensity, pyr[1][lv.y.astype(int), lv.x.astype(int)])
    for arr in (lv.x, lv.y, lv.intensity, lv.idepth, lv.idepth_var, lv.points):
        assert not arr.flags.writeable and arr.flags.c_contiguous
    with pytest.raises(AttributeError):
        ref.frame_id = 3
    with pytest.raises(ValueError):
        TrackingReference.build(pyr, idepth[:100], var, valid, INTR)


def _random_map(seed):
    """(image pyramid, idepth, var, valid) of a random 320x240 image with a random 30 % of valid depths."""
    rng = np.random.default_rng(seed)
    img = rng.uniform(0, 255, (240, 320)).astype(np.float32)
    idepth = rng.uniform(0.3, 1.0, (240, 320)).astype(np.float32)
    var = np.full((240, 320), 1e-3, np.float32)
    valid = rng.uniform(size=(240, 320)) < 0.3
    pyr = image_pyramid(img, LEVELS)
    return pyr, idepth, var, valid


@pytest.mark.parametrize("stride", [2, 3])
def test_reference_point_stride_thins_only_the_finest_tracked_level(stride):
    """``point_stride`` keeps the finest tracked level's points on the lattice (x + y) % stride == 0, the
    same points with the same values as without it; coarser levels keep all their points."""
    pyr, idepth, var, valid = _random_map(9)
    full = TrackingReference.build(pyr, idepth, var, valid, INTR, min_level=1)
    thin = TrackingReference.build(pyr, idepth, var, valid, INTR, min_level=1, point_stride=stride)
    a, b = full.levels[1], thin.levels[1]
    keep = (a.x.astype(int) + a.y.astype(int)) % stride == 0
    assert 0 < b.num_points == keep.sum() < a.num_points
    np.testing.assert_array_equal(b.points, a.points[keep])
    assert abs(b.num_points / a.num_points - 1 / stride) < 0.05
    assert thin.num_points(0) == full.num_points(0) == 0
    for lvl in range(2, LEVELS):
        np.testing.assert_array_equal(thin.levels[lvl].points, full.levels[lvl].points)


def test_reference_coarse_point_stride_thins_only_the_next_coarser_level():
    """``coarse_point_stride`` does to the level above the finest tracked one what ``point_stride`` does
    to the finest: the same points with the same values on the lattice, the other levels untouched."""
    pyr, idepth, var, valid = _random_map(10)
    full = TrackingReference.build(pyr, idepth, var, valid, INTR, min_level=1, point_stride=3)
    thin = TrackingReference.build(pyr, idepth, var, valid, INTR, min_level=1, point_stride=3, coarse_point_stride=2)
    a, b = full.levels[2], thin.levels[2]
    keep = (a.x.astype(int) + a.y.astype(int)) % 2 == 0
    assert 0 < b.num_points == keep.sum() < a.num_points
    np.testing.assert_array_equal(b.points, a.points[keep])
    for lvl in [1] + list(range(3, LEVELS)):
        np.testing.assert_array_equal(thin.levels[lvl].points, full.levels[lvl].points)


# ----------------------------------------------------------------------------- synthetic pairs
@pytest.fixture(scope="module")
def room_pair():
    room = naive.Room(seed=1, cell=0.05, depth=1.3, half_width=0.9, floor=0.5, ceiling=-0.6)
    img0, z0 = room.render(np.eye(4), INTR, supersample=2)
    gx, gy = gradients(img0)
    valid = np.hypot(gx, gy) >= 5
    ref = TrackingReference.build(image_pyramid(img0, LEVELS), 1 / z0, np.full_like(z0, 1e-6), valid, INTR, 0)
    return room, ref


def _pose_error(T_est, T_true):
    e = log_se3(inverse_se3(T_true) @ T_est)
    return np.linalg.norm(e[:3]), np.degrees(np.linalg.norm(e[3:]))


def test_small_motion_converges_to_1mm(room_pair):
    room, ref = room_pair
    T_ref_new = exp_se3(np.array([0.03, -0.01, 0.02, 0.01, -0.02, 0.005]))
    img1, _ = room.render(T_ref_new, INTR, supersample=2)
    # start 2 cm and 2 degrees away from the truth
    off = np.array([0.02 / np.sqrt(2), 0.0, 0.02 / np.sqrt(2), 0.0, np.radians(2.0), 0.0])
    guess = T_ref_new @ exp_se3(off)
    t0, r0 = _pose_error(guess, T_ref_new)
    assert t0 > 0.015 and r0 > 1.9
    tracker = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL)
    res = tracker.track(ref, image_pyramid(img1, LEVELS), guess)
    assert isinstance(res, TrackingResult)
    t_err, r_err = _pose_error(res.T_ref_new, T_ref_new)
    assert t_err < 1e-3 and r_err < 0.05, (t_err, r_err)
    assert not res.lost and res.good_ratio > 0.95 and res.points_used > 1000
    assert set(res.iterations) == {1, 2, 3, 4} and set(res.level_ms) == {1, 2, 3, 4}
    a, b = res.affine                     # gain and offset trade off: compare the mid-grey brightness
    assert res.residual < 2.0 and a == pytest.approx(1.0, abs=0.01) and a * 130 + b == pytest.approx(130, abs=0.5)


def test_large_motion_converges_thanks_to_pyramid(room_pair):
    room, ref = room_pair
    T_ref_new = exp_se3(np.array([0.1, 0.0, 0.0, 0.0, np.radians(5.0), 0.0]))
    img1, _ = room.render(T_ref_new, INTR, supersample=2)
    pyr1 = image_pyramid(img1, LEVELS)
    res = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL).track(ref, pyr1, np.eye(4))
    t_err, r_err = _pose_error(res.T_ref_new, T_ref_new)
    assert t_err < 3e-3 and r_err < 0.1, (t_err, r_err)
    assert not res.lost
    # the same motion from the finest level alone does not converge (the pyramid is what helps)
    cfg = dataclasses.replace(TrackingConfig(), coarsest_level=TRACK_LEVEL)
    res1 = Tracker(cfg, INTR, LEVELS, TRACK_LEVEL).track(ref, pyr1, np.eye(4))
    assert _pose_error(res1.T_ref_new, T_ref_new)[0] > 5 * max(t_err, 1e-3)


@pytest.mark.parametrize("gain,offset", [(0.8, 20.0), (1.3, -10.0), (0.6, 5.0)])
def test_joint_affine_brightness_recovers_gain_and_offset(room_pair, gain, offset):
    """The 8-unknown LM system recovers a known a*I + b together with the pose; with the brightness
    model off, the same pair is tracked worse (the exposure change is absorbed by the pose)."""
    room, ref = room_pair
    T_ref_new = exp_se3(np.array([0.01, 0.01, 0.0, 0.0, 0.01, 0.0]))
    img1, _ = room.render(T_ref_new, INTR, supersample=2)
    pyr1 = image_pyramid(gain * img1 + offset, LEVELS)
    on = TrackingConfig(affine_brightness=True)
    res = Tracker(on, INTR, LEVELS, TRACK_LEVEL).track(ref, pyr1, np.eye(4))
    t_err, r_err = _pose_error(res.T_ref_new, T_ref_new)
    assert t_err < 1e-3 and r_err < 0.05, (t_err, r_err)
    assert res.affine[0] == pytest.approx(gain, abs=0.01) and res.affine[1] == pytest.approx(offset, abs=1.5)
    # a starting guess near the truth converges to the same answer
    res2 = Tracker(on, INTR, LEVELS, TRACK_LEVEL).track(ref, pyr1, np.eye(4), affine_guess=(gain, offset))
    assert res2.affine == pytest.approx(res.affine, abs=0.02)
    off = Tracker(dataclasses.replace(TrackingConfig(), affine_brightness=False), INTR, LEVELS, TRACK_LEVEL)
    res_off = off.track(ref, pyr1, np.eye(4))
    assert res_off.affine == (1.0, 0.0)
    assert res_off.lost or res_off.mean_abs_residual > 3 * res.mean_abs_residual


def test_fixed_affine_is_held_for_one_call_only(room_pair):
    """``fix_affine``: a brightness measured elsewhere is held (the pose alone is solved, as accurate as
    with the joint estimate when the brightness is right); the next call estimates it again."""
    room, ref = room_pair
    T_ref_new = exp_se3(np.array([0.01, 0.01, 0.0, 0.0, 0.01, 0.0]))
    img1, _ = room.render(T_ref_new, INTR, supersample=2)
    pyr1 = image_pyramid(1.3 * img1 - 10.0, LEVELS)
    tracker = Tracker(TrackingConfig(affine_brightness=True), INTR, LEVELS, TRACK_LEVEL)
    held = tracker.track(ref, pyr1, np.eye(4), affine_guess=(1.3, -10.0), fix_affine=True)
    assert held.affine == (1.3, -10.0) and not held.lost
    t_err, r_err = _pose_error(held.T_ref_new, T_ref_new)
    assert t_err < 1e-3 and r_err < 0.05, (t_err, r_err)
    wrong = tracker.track(ref, pyr1, np.eye(4), affine_guess=(1.0, 0.0), fix_affine=True)
    assert wrong.affine == (1.0, 0.0) and wrong.mean_abs_residual > 3 * held.mean_abs_residual
    free = tracker.track(ref, pyr1, np.eye(4), affine_guess=(1.0, 0.0))
    assert free.affine[0] == pytest.approx(1.3, abs=0.01) and free.affine[1] == pytest.approx(-10.0, abs=1.5)


def test_affine_prior_pulls_towards_identity_when_brightness_is_unobservable():
    """A reference of one intensity only: gain and offset cannot be told apart; the weak prior keeps
    the system solvable and the estimate explains the new brightness."""
    intr = PinholeIntrinsics(40.0, 40.0, 19.5, 14.5, 40, 30)
    ys, xs = np.mgrid[0:30, 0:40]
    img = (100 + 40 * np.sin(xs / 3.0) * np.cos(ys / 4.0)).astype(np.float32)
    ref = TrackingReference.build(image_pyramid(img, 2), np.ones((30, 40)), np.full((30, 40), 1e-6),
                                  np.ones((30, 40), bool), intr, 0, smooth_sigma=0.0)
    res = Tracker(TrackingConfig(coarsest_level=0, affine_brightness=True), intr, 2, 0).track(ref, image_pyramid(img + 10.0, 2), np.eye(4))
    a, b = res.affine
    assert np.isfinite(a) and np.isfinite(b) and not res.lost
    assert a * 100.0 + b == pytest.approx(110.0, abs=1.0)          # the mean brightness change is explained


@pytest.mark.parametrize("kind", ["noise", "other_scene"])
def test_garbage_image_is_lost(room_pair, kind):
    _, ref = room_pair
    rng = np.random.default_rng(9)
    if kind == "noise":
        garbage = rng.uniform(0, 255, (240, 320)).astype(np.float32)
    else:
        garbage, _ = naive.Room(seed=5, cell=0.05).render(np.eye(4), INTR, supersample=1)
    tracker = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL)
    res = tracker.track(ref, image_pyramid(garbage, LEVELS), np.eye(4))
    # either the residual stays large, or the brightness model "explains" the garbage by a gain near 0
    assert res.lost and (res.residual_spread > TrackingConfig().max_abs_residual
                         or res.affine[0] < 1 / TrackingConfig().max_gain_change), res.quality()
    # with the residual test off, the paper's good/(good+bad) test alone is too lenient here (documented)
    lenient = Tracker(dataclasses.replace(TrackingConfig(), max_abs_residual=0.0), INTR, LEVELS, TRACK_LEVEL)
    assert lenient.track(ref, image_pyramid(garbage, LEVELS), np.eye(4)).good_ratio > 0.5


def test_residual_spread_ignores_a_common_offset():
    """The lost test measures the residuals' spread around their median: a common brightness offset
    (KITTI's exposure changes with affine brightness off; the alignment itself fine) does not count,
    a residual that differs from point to point (a wrong pose, another scene) does."""
    from lite_vo.tracking.tracker import _residual_spread
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 3.0, 4000)
    sigma0, spread0 = _residual_spread(noise)
    sigma1, spread1 = _residual_spread(noise + 20.0)
    assert sigma1 == pytest.approx(sigma0) and spread1 == pytest.approx(spread0)
    assert np.mean(np.abs(noise + 20.0)) > TrackingConfig().max_abs_residual > spread1   # offset: not lost
    assert sigma0 == pytest.approx(3.0, rel=0.1) and spread0 == pytest.approx(3.0 * np.sqrt(2 / np.pi), rel=0.1)
    wide = rng.uniform(-60.0, 60.0, 4000)                         # garbage: residuals all over the place
    assert _residual_spread(wide)[1] > TrackingConfig().max_abs_residual
    assert all(np.isnan(v) for v in _residual_spread(np.ones(20)))   # every 4th of 20: fewer than 8, unknown


def test_residual_spread_equals_numpys_median_and_mean():
    """The hot-path medians (sorted copies) give np.median's values bit for bit, odd and even sizes."""
    from lite_vo.tracking.tracker import _residual_spread
    rng = np.random.default_rng(5)
    for n in (32, 33, 34, 35, 4001, 9422):
        r = rng.standard_t(3, size=n) * 4.0
        q = r[::4]
        dev = np.abs(q - np.median(q))
        assert _residual_spread(r) == (float(1.4826 * np.median(dev)), float(np.mean(dev)))


@pytest.mark.parametrize("interp", [kernels.INTERP_BILINEAR, kernels.INTERP_BSPLINE])
@pytest.mark.parametrize("with_affine", [False, True])
@pytest.mark.parametrize("seed", [0, 1])
def test_track_level_matches_its_pieces(seed, with_affine, interp):
    """kernels.track_level = the image module's stack + lm_level + the hand-over of pose and brightness,
    bit for bit (the stack, pose, brightness, accumulator, stats and scratch rows)."""
    from lite_vo.image import bspline_horizon
    rng = np.random.default_rng(seed)
    h, w = 60, 80
    yy, xx = np.mgrid[0:h, 0:w]
    img = (120 + 60 * np.sin(xx / 5.0 + seed) * np.cos(yy / 7.0) + rng.normal(0, 2, (h, w))).astype(np.float32)
    cam, prm, _, _ = _args(70.0, 70.0, 39.5, 29.5, 4.0, 1.5, 1.0, 0.0, with_affine, 1600.0, 0.25, 1.0, 1e-3)
    for k, v in ((kernels.TP_CONV_RATIO, 0.999), (kernels.TP_CONV_EPS, 1e-8), (kernels.TP_LAMBDA_INIT, 0.2),
                 (kernels.TP_LAMBDA_ACCEPT_MAX, 0.2), (kernels.TP_LAMBDA_ACCEPT_FACTOR, 0.5),
                 (kernels.TP_LAMBDA_REJECT_FACTOR, 2.0), (kernels.TP_MIN_POINTS, 10), (kernels.TP_SOLVE_EPS, 1e-12),
                 (kernels.TP_MIN_HESSIAN_DIAG, 0.01), (kernels.TP_AFF_PRIOR_A, 0.01), (kernels.TP_AFF_PRIOR_B, 1e-5)):
        prm[k] = v
    pts = _random_points(rng, 400)
    T0 = exp_se3(np.array([0.01, -0.005, 0.02, 0.01, -0.02, 0.005]))
    channels = 1 if interp == kernels.INTERP_BSPLINE else 3
    for case in ("normal", "no points"):
        p = pts.copy()
        if case == "no points":
            p[:, 2] = -1.0                                        # all behind the camera: status 1, nothing handed on
        p.flags.writeable = False                                 # as a TrackingReference hands them
        outs = []
        for fn in ("kernel", "twin"):
            T, aff = T0.copy(), np.array([1.1, -3.0])
            img3 = np.full((h, w, channels), np.nan, np.float32)
            buf = np.zeros((kernels.BUF_ROWS, 512))
            T_out, acc, aff_out, stats = np.empty((4, 4)), np.empty(kernels.ACC_SIZE), np.empty(2), np.zeros(kernels.ST_SIZE)
            if fn == "kernel":
                status = kernels.track_level(p, img, interp, bspline_horizon(), img3, T, cam, prm, 20, aff, buf,
                                             T_out, acc, aff_out, stats)
            else:
                status = naive.track_level(p, img, interp, img3, T, cam, prm, 20, aff, buf, T_out, acc, aff_out, stats)
            outs.append((status, img3, T, aff, acc, stats, buf[:, :int(stats[kernels.ST_LAST_N])]))
        (s0, *a0), (s1, *a1) = outs
        assert s0 == s1 == (1 if case == "no points" else 0)
        for x0, x1 in zip(a0, a1):
            np.testing.assert_array_equal(x0, x1)
        if case == "no points":
            np.testing.assert_array_equal(a0[1], T0)
            np.testing.assert_array_equal(a0[2], [1.1, -3.0])
        else:
            assert not np.array_equal(a0[1], T0)


def test_bright_saturated_garbage_fails_good_ratio(room_pair):
    _, ref = room_pair
    white = image_pyramid(np.full((240, 320), 255.0, np.float32), LEVELS)
    res = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL).track(ref, white, np.eye(4))
    assert res.lost and res.points_used == 0 and "points" in res.lost_reason     # clipped pixels are not used
    lenient = Tracker(dataclasses.replace(TrackingConfig(), saturation=256.0), INTR, LEVELS, TRACK_LEVEL)
    res = lenient.track(ref, white, np.eye(4))
    assert res.lost and (res.good_ratio < 0.5 or res.affine[0] < 0.5)


def test_empty_map_and_out_of_view_are_lost_without_exception(room_pair):
    room, ref = room_pair
    img = image_pyramid(np.full((240, 320), 128, np.float32), LEVELS)
    empty = TrackingReference.build(img, np.ones((240, 320)), np.ones((240, 320)), np.zeros((240, 320), bool), INTR)
    tracker = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL)
    guess = exp_se3(np.array([0.01, 0, 0, 0, 0, 0]))
    res = tracker.track(empty, img, guess)
    assert res.lost and res.points_used == 0 and res.lost_reason
    np.testing.assert_allclose(res.T_ref_new, guess)
    # camera turned 180 degrees: nothing warps inside
    turned = exp_se3(np.array([0, 0, 0, 0, np.pi, 0]))
    res = tracker.track(ref, img, turned)
    assert res.lost and res.inside_ratio < 0.01


def test_flat_new_image_zero_gradient_does_not_crash(room_pair):
    _, ref = room_pair
    flat = image_pyramid(np.full((240, 320), 100, np.float32), LEVELS)
    res = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL).track(ref, flat, np.eye(4))
    assert np.all(np.isfinite(res.T_ref_new))
    np.testing.assert_allclose(res.T_ref_new, np.eye(4), atol=1e-9)    # singular system: no update


def test_nan_image_and_bad_guess():
    img = np.full((240, 320), np.nan, np.float32)
    pyr = image_pyramid(img, LEVELS)
    ref = TrackingReference.build(image_pyramid(np.full((240, 320), 100, np.float32), LEVELS),
                                  np.ones((240, 320)), np.full((240, 320), 1e-3), np.ones((240, 320), bool), INTR)
    res = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL).track(ref, pyr, np.eye(4))
    assert res.lost and res.points_used == 0
    with pytest.raises(ValueError):
        Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL).track(ref, pyr, np.full((4, 4), np.nan))


def test_bspline_jacobian_is_the_exact_derivative_of_the_spline():
    """In B-spline mode the residual is the spline itself: J must match its finite differences closely."""
    from scipy.ndimage import map_coordinates
    from lite_vo.image import bspline_coefficient_stack
    rng = np.random.default_rng(11)
    img = rng.uniform(0, 255, (40, 50)).astype(np.float32)
    coef3 = bspline_coefficient_stack(img)
    intr = PinholeIntrinsics(45.0, 45.0, 24.5, 19.5, 50, 40)
    pts = np.zeros((1, kernels.PTS_COLS), np.float32)
    pts[0, :3] = [0.07, -0.05, 1.2]
    pts[0, 3] = 100.0
    T = exp_se3(np.array([0.01, -0.02, 0.01, 0.02, 0.01, -0.01]))
    args = _args(intr.fx, intr.fy, intr.cx, intr.cy, 1.0, 1e9, 1.0, 0.0, True, 1600.0, 0.25, 1.0, 1e-3)
    acc = _kernel_vs_naive(pts, coef3, T, args, kernels.INTERP_BSPLINE)
    H, g = np.zeros((8, 8)), np.zeros(8)
    kernels.unpack_normal_equations(acc, H, g)

    def spline_residual(Tx):
        q = Tx[:3, :3] @ pts[0, :3].astype(np.float64) + Tx[:3, 3]
        u, v = intr.fx * q[0] / q[2] + intr.cx, intr.fy * q[1] / q[2] + intr.cy
        return map_coordinates(coef3[:, :, 0].astype(np.float64), [[v], [u]], order=3, prefilter=False)[0] - 100.0
    r0 = spline_residual(T)
    eps = 1e-6
    Jn = np.array([(spline_residual(exp_se3(eps * e) @ T) - spline_residual(exp_se3(-eps * e) @ T)) / (2 * eps)
                   for e in np.eye(6)])
    np.testing.assert_allclose(g[:6] / r0, Jn, rtol=1e-4, atol=1e-4 * np.abs(Jn).max())
    # the spline interpolates: evaluated at pixel centres it returns the image
    ys, xs = np.mgrid[2:38, 2:48]
    back = map_coordinates(coef3[:, :, 0].astype(np.float64), [ys.ravel(), xs.ravel()], order=3, prefilter=False)
    np.testing.assert_allclose(back, img[2:38, 2:48].ravel(), atol=1e-3)


@pytest.mark.parametrize("interpolation", ["bilinear", "bspline"])
def test_small_motion_both_interpolations(room_pair, interpolation):
    room, ref = room_pair
    T_ref_new = exp_se3(np.array([0.01, 0.005, -0.01, 0.005, 0.01, 0.0]))
    img1, _ = room.render(T_ref_new, INTR, supersample=2)
    cfg = dataclasses.replace(TrackingConfig(), interpolation=interpolation)
    res = Tracker(cfg, INTR, LEVELS, TRACK_LEVEL).track(ref, image_pyramid(img1, LEVELS), np.eye(4))
    t_err, r_err = _pose_error(res.T_ref_new, T_ref_new)
    assert t_err < 1.5e-3 and r_err < 0.06, (t_err, r_err)


def test_reference_min_level_skips_fine_levels():
    rng = np.random.default_rng(12)
    img = rng.uniform(0, 255, (240, 320)).astype(np.float32)
    valid = rng.uniform(size=(240, 320)) < 0.3
    pyr = image_pyramid(img, LEVELS)
    full = TrackingReference.build(pyr, np.ones((240, 320)), np.full((240, 320), 1e-3), valid, INTR)
    part = TrackingReference.build(pyr, np.ones((240, 320)), np.full((240, 320), 1e-3), valid, INTR, min_level=1)
    assert part.num_points(0) == 0 and full.num_points(0) == valid.sum()
    for lvl in range(1, LEVELS):
        np.testing.assert_array_equal(part.levels[lvl].points, full.levels[lvl].points)
    res = Tracker(TrackingConfig(), INTR, LEVELS, 0).track(part, pyr, np.eye(4))
    assert res.lost and "min_level" in res.lost_reason


def test_depth_image_mask_drops_edges_flat_and_invalid():
    from lite_vo.tracking import depth_image_mask
    ys, xs = np.mgrid[0:40, 0:60].astype(np.float32)
    img = (128 + 60 * np.sin(xs / 2.0)).astype(np.float32)
    img[:, 50:] = 100.0                                   # textureless strip
    depth = np.full((40, 60), 2.0, np.float32)
    depth[:, 20:] = 1.0                                   # occlusion boundary at x = 20
    depth[5, 5] = 0.0
    depth[6, 6] = np.nan
    cfg = TrackingConfig()
    m = depth_image_mask(img, depth, cfg)
    assert not m[:, 16:24].any()                          # within the 9x9 window of the step
    assert m[10:30, 8:14].all() and m[10:30, 26:45].all()
    assert not m[:, 52:].any()                            # no gradient
    assert not m[5, 5] and not m[6, 6]
    off = depth_image_mask(img, depth, dataclasses.replace(cfg, depth_image_max_step=0.0, depth_image_min_grad=0.0))
    assert off.sum() == 40 * 60 - 2


def test_non_rigid_guess_is_projected_and_result_is_rigid(room_pair):
    room, ref = room_pair
    T_ref_new = exp_se3(np.array([0.01, 0.0, 0.005, 0.0, 0.01, 0.0]))
    img1, _ = room.render(T_ref_new, INTR, supersample=2)
    guess = np.eye(4)
    guess[:3, :3] *= 1.01                                   # drifted, non-orthonormal composition
    guess[0, 1] = 0.003
    res = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL).track(ref, image_pyramid(img1, LEVELS), guess)
    R = res.T_ref_new[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_array_equal(res.T_ref_new[3], [0, 0, 0, 1])
    t_err, r_err = _pose_error(res.T_ref_new, T_ref_new)
    assert t_err < 1.5e-3 and r_err < 0.06


# ----------------------------------------------------------------------------- wide basin (motion hypotheses)
def test_motion_hypotheses_order_and_rotation_angle():
    from lite_vo.tracking.tracker import motion_hypotheses
    V = exp_se3(np.array([0.02, 0.0, 0.01, 0.0, np.radians(2.0), 0.0]))
    T_last = exp_se3(np.array([0.1, 0.0, 0.0, 0.0, 0.0, np.radians(3.0)]))
    hyps = motion_hypotheses(T_last, V, np.radians(2.0))
    names = [n for n, _ in hyps]
    assert names[:5] == ["velocity", "velocity_x2", "velocity_x0.5", "zero_motion", "keyframe"]
    assert len(names) == 5 + 26 and len(set(names)) == len(names)
    H = dict(hyps)
    np.testing.assert_allclose(H["velocity_x2"], T_last @ V @ V, atol=1e-12)
    np.testing.assert_allclose(log_se3(inverse_se3(T_last) @ H["velocity_x0.5"]), 0.5 * log_se3(V), atol=1e-12)
    for n, T in hyps[5:]:
        _, r = _pose_error(T, H["velocity"])
        assert r == pytest.approx(2.0, abs=1e-6), n


def _warm_up(tracker, room, ref, n=3):
    """Track ``n`` small motions (the recent frames the wide basin compares against)."""
    for k in range(1, n + 1):
        T = exp_se3(np.array([0.005 * k, 0.0, 0.0, 0.0, 0.0, 0.0]))
        img, _ = room.render(T, INTR, supersample=2)
        assert not tracker.track(ref, image_pyramid(img, LEVELS), np.eye(4), motion=(np.eye(4), np.eye(4))).lost


def test_hypotheses_rescue_a_start_where_the_single_guess_diverges(room_pair):
    """Two frames were dropped: the constant-velocity guess is one frame's motion (10 cm, 8 deg)
    short and diverges; a motion hypothesis (2x velocity or a rotation about it) converges."""
    room, ref = room_pair
    V = exp_se3(np.array([0.1, 0.0, 0.01, 0.0, np.radians(8.0), 0.0]))
    T_last = V
    truth = T_last @ V @ V
    img1, _ = room.render(truth, INTR, supersample=2)
    pyr = image_pyramid(img1, LEVELS)
    single = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL).track(ref, pyr, T_last @ V)
    assert single.lost or _pose_error(single.T_ref_new, truth)[0] > 0.05
    tracker = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL)
    _warm_up(tracker, room, ref)
    res = tracker.track(ref, pyr, T_last @ V, motion=(T_last, V))
    t_err, r_err = _pose_error(res.T_ref_new, truth)
    assert not res.lost and t_err < 5e-3 and r_err < 0.2, (t_err, r_err)
    assert res.hypothesis not in ("", "first")
    assert tracker.hypothesis_counts[res.hypothesis] == 1 and tracker.hypothesis_frames == 1
    # without recent frames (a new map) the hypotheses are not tried
    tracker.reset_motion_history()
    fresh = tracker.track(ref, pyr, T_last @ V, motion=(T_last, V))
    assert fresh.lost == single.lost and fresh.hypothesis == ""
    # switched off: the same call is the single guess
    off = Tracker(dataclasses.replace(TrackingConfig(), motion_hypotheses=False), INTR, LEVELS, TRACK_LEVEL)
    res_off = off.track(ref, pyr, T_last @ V, motion=(T_last, V))
    assert res_off.lost == single.lost and res_off.hypothesis == ""


def test_hypotheses_are_not_tried_when_the_first_guess_is_good(room_pair):
    room, ref = room_pair
    V = exp_se3(np.array([0.02, 0.0, 0.0, 0.0, np.radians(1.0), 0.0]))
    tracker = Tracker(TrackingConfig(), INTR, LEVELS, TRACK_LEVEL)
    for k in (1, 2, 3, 4, 5):
        truth = np.linalg.matrix_power(V, k)
        img, _ = room.render(truth, INTR, supersample=2)
        res = tracker.track(ref, image_pyramid(img, LEVELS), np.linalg.matrix_power(V, k - 1) @ V,
                            motion=(np.linalg.matrix_power(V, k - 1), V))
        assert not res.lost and res.hypothesis == ("first" if k > 3 else "")
        assert _pose_error(res.T_ref_new, truth)[0] < 2e-3
    assert dict(tracker.hypothesis_counts) == {"first": 2} and tracker.hypothesis_frames == 0
