"""Mapping: kernels against their naive twins, and properties of the inverse-depth filter."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import naive_mapping as naive
from mapping_synth_plane import make_texture, render_plane
from lite_vo.camera import PinholeIntrinsics
from lite_vo.errors import InputError
from lite_vo.geometry import exp_se3
from lite_vo.mapping import MapFrame, Mapper, MappingConfig, depth_accuracy, image_gradients
from lite_vo.mapping import _kernels as kernels
from lite_vo.mapping._kernels import MapState, RefFrames
from lite_vo.mapping.mapper import mapping_params

K_SMALL = PinholeIntrinsics(60.0, 60.0, 31.5, 23.5, 64, 48)
K_MAP = PinholeIntrinsics(131.25, 131.25, 79.5, 59.5, 160, 120)


def pose(tx=0.0, ty=0.0, tz=0.0, rot=(0.0, 0.0, 0.0)):
    T = exp_se3(np.array([0, 0, 0, *rot], float))
    T[:3, 3] = (tx, ty, tz)
    return T


def _ms(d):
    """A kernels.MapState of the arrays in the dict ``d`` (shared, not copied)."""
    return MapState(**{k: d[k] for k in MapState._fields})


def _cam(Kc):
    return np.array([Kc.fx, Kc.fy, Kc.cx, Kc.cy])


@pytest.fixture(scope="module")
def tex():
    return make_texture(3, size=512, cells=64)


# ----------------------------------------------------------------------------- gradients
@pytest.mark.parametrize("shape", [(1, 1), (2, 3), (7, 9), (30, 41)])
def test_gradients_match_naive(shape):
    rng = np.random.default_rng(1)
    img = (rng.random(shape) * 255).astype(np.float32)
    gx, gy, mg = image_gradients(img)
    ngx, ngy, nmg = naive.gradients(img)
    np.testing.assert_allclose(gx, ngx, atol=1e-4)
    np.testing.assert_allclose(gy, ngy, atol=1e-4)
    np.testing.assert_allclose(mg, nmg, atol=1e-4)


def test_gradients_zero_on_flat_image():
    gx, gy, mg = image_gradients(np.full((10, 12), 77.0, np.float32))
    assert not gx.any() and not gy.any() and not mg.any()


# ----------------------------------------------------------------------------- line stereo
def _stereo_case(tex, T_world_ref, T_world_cur, Kc, plane_z=2.0):
    img_ref, _ = render_plane(tex, T_world_ref, Kc, plane_z)
    img_cur, depth_cur = render_plane(tex, T_world_cur, Kc, plane_z)
    T_ref_cur = np.linalg.inv(T_world_ref) @ T_world_cur
    return img_ref, img_cur, depth_cur, T_ref_cur


def _run_line(cur, ref, gx, gy, T_ref_cur, Kc, x, y, lo, prior, hi, prm, impl, residual=0.0, allow_long=True,
              ref_a=1.0, ref_b=0.0):
    R = np.ascontiguousarray(T_ref_cur[:3, :3])
    t = np.ascontiguousarray(T_ref_cur[:3, 3])
    c = -R.T @ t
    fx, fy, cx, cy = Kc.fx, Kc.fy, Kc.cx, Kc.cy
    ok, ex, ey = (kernels.epipolar_direction if impl == "kernel" else naive.epipolar_direction)(
        cur, x, y, float(x), float(y), c, fx, fy, cx, cy, prm)
    if not ok:
        return None
    gxi, gyi = float(gx[y, x]), float(gy[y, x])
    if impl == "kernel":
        return kernels.line_stereo(cur, ref, float(x), float(y), ex, ey, lo, prior, hi, R, t, fx, fy, cx, cy, gxi, gyi,
                                   residual, prm, allow_long, ref_a, ref_b, np.empty(64), np.empty(64),
                                   np.empty(64), np.empty(64, np.uint64))
    return naive.line_stereo(cur, ref, float(x), float(y), ex, ey, lo, prior, hi, R, t, fx, fy, cx, cy, gxi, gyi,
                             residual, prm, allow_long, ref_a, ref_b, 64)


@pytest.mark.parametrize("motion", [
    dict(tx=0.05), dict(tx=-0.04, ty=0.02), dict(ty=0.05, rot=(0.01, -0.02, 0.005)),
    dict(tx=0.03, tz=0.05), dict(tx=0.02, tz=-0.08, rot=(0.0, 0.03, 0.0))])
def test_line_stereo_matches_naive(tex, motion):
    img_ref, cur, _, T_ref_cur = _stereo_case(tex, pose(), pose(**motion), K_SMALL)
    gx, gy, _ = image_gradients(cur)
    rng = np.random.default_rng(2)
    cfg = MappingConfig()
    for subpixel in (True, False):
        prm = mapping_params(dataclasses.replace(cfg, subpixel=subpixel))
        n_ok = 0
        for _ in range(60):
            x, y = int(rng.integers(1, 63)), int(rng.integers(1, 47))
            prior = float(rng.uniform(0.2, 1.0))
            lo, hi = (0.0, 20.0) if rng.random() < 0.4 else (max(prior - 0.2, 0.0), prior + 0.2)
            a = _run_line(cur, img_ref, gx, gy, T_ref_cur, K_SMALL, x, y, lo, prior, hi, prm, "kernel", 0.3)
            b = _run_line(cur, img_ref, gx, gy, T_ref_cur, K_SMALL, x, y, lo, prior, hi, prm, "naive", 0.3)
            assert (a is None) == (b is None)
            if a is None:
                continue
            assert a[0] == b[0], (x, y, a, b)
            np.testing.assert_allclose(a[1:], b[1:], rtol=1e-6, atol=1e-9)
            n_ok += a[0] == kernels.OK
        assert n_ok > 3   # the comparison exercised successful matches too


def test_min_in_is_a_plain_scan():
    """The stereo pass's interleaved minimum equals one scan with ``<`` from 1e50 on every range:
    NaN never counts, 1e50 and above never win, ties, ranges shorter than the four scans, empty ranges."""
    rng = np.random.default_rng(7)

    def scan(a, lo, hi):
        m = 1e50
        for k in range(lo, hi):
            if a[k] < m:
                m = a[k]
        return m

    for trial in range(400):
        n = int(rng.integers(0, 40))
        a = rng.integers(0, 6, n).astype(np.float64)       # few values: many ties
        if trial % 3 == 0 and n:
            a[rng.integers(0, n, max(1, n // 4))] = np.nan
        if trial % 5 == 0 and n:
            a[rng.integers(0, n, max(1, n // 3))] = rng.choice([1e50, 2e50, np.inf])
        if trial % 7 == 0:
            a[:] = np.nan
        lo = int(rng.integers(-2, n + 2))
        hi = int(rng.integers(-2, n + 2))
        lo, hi = max(lo, 0), min(hi, n)
        assert kernels._min_in(a, lo, hi) == scan(a, lo, hi), (a, lo, hi)


def test_min2_max2_are_the_builtins():
    """The kernels' selects give what ``min`` / ``max`` give for every pair, NaN on either side
    included (Python returns the first argument unless the second compares smaller / larger), for
    floats (float32 and float64) and integers."""
    from numba import njit

    @njit
    def both(a, b):
        return kernels._min2(a, b), kernels._max2(a, b)

    vals = [-2.5, -0.0, 0.0, 1.0, 3.25, np.inf, -np.inf, np.nan]
    for a in vals:
        for b in vals:
            for cast in (np.float64, np.float32):
                got = both(cast(a), cast(b))
                want = (min(cast(a), cast(b)), max(cast(a), cast(b)))
                for g, w in zip(got, want):
                    same = g == w and math.copysign(1, g) == math.copysign(1, w)
                    assert (math.isnan(g) and math.isnan(w)) or same, (a, b, cast, got, want)
    for a in range(-3, 4):
        for b in range(-3, 4):
            assert both(a, b) == (min(a, b), max(a, b))


def test_line_stereo_edge_cases(tex):
    img_ref, cur, _, T_ref_cur = _stereo_case(tex, pose(), pose(tx=0.05), K_SMALL)
    gx, gy, _ = image_gradients(cur)
    prm = mapping_params(MappingConfig())
    R, t = np.ascontiguousarray(T_ref_cur[:3, :3]), np.ascontiguousarray(T_ref_cur[:3, 3])
    args = (K_SMALL.fx, K_SMALL.fy, K_SMALL.cx, K_SMALL.cy, 1.0, 1.0, 0.0, prm, True, 1.0, 0.0)
    for impl in ("kernel", "naive"):
        f = kernels.line_stereo if impl == "kernel" else naive.line_stereo
        extra = (np.empty(64), np.empty(64), np.empty(64), np.empty(64, np.uint64)) if impl == "kernel" else (64,)
        # five samples leave the image at the border
        assert f(cur, img_ref, 1.0, 20.0, 1.0, 0.0, 0.0, 0.5, 2.0, R, t, *args, *extra)[0] == kernels.OUT_OF_IMAGE
        # NaN pose
        Rn = R.copy()
        Rn[0, 0] = np.nan
        assert f(cur, img_ref, 30.0, 20.0, 1.0, 0.0, 0.0, 0.5, 2.0, Rn, t, *args, *extra)[0] in (kernels.OUT_OF_IMAGE, kernels.NUMERIC)
        # the whole interval behind the reference camera (reference far in front)
        tb = np.array([0.0, 0.0, -50.0])
        assert f(cur, img_ref, 30.0, 20.0, 1.0, 0.0, 0.0, 0.01, 2.0, R, tb, *args, *extra)[0] == kernels.OUT_OF_IMAGE
        # scale change outside [0.7, 1.4]
        ts = np.array([0.05, 0.0, 1.0])
        assert f(cur, img_ref, 30.0, 20.0, 1.0, 0.0, 0.0, 0.5, 2.0, R, ts, *args, *extra)[0] == kernels.OUT_OF_IMAGE
    # NaN / too short epipolar line and zero gradient are rejected before the search
    c_nan = np.array([np.nan, 0.0, 0.0])
    flat = np.full((48, 64), 100.0, np.float32)
    for f in (kernels.epipolar_direction, naive.epipolar_direction):
        assert not f(cur, 30, 20, 30.0, 20.0, c_nan, 60.0, 60.0, 31.5, 23.5, prm)[0]
        assert not f(cur, 30, 20, 30.0, 20.0, np.zeros(3), 60.0, 60.0, 31.5, 23.5, prm)[0]
        assert not f(flat, 30, 20, 30.0, 20.0, np.array([-0.05, 0, 0]), 60.0, 60.0, 31.5, 23.5, prm)[0]


def test_observation_on_epipolar_line_recovers_known_depth(tex):
    """Stereo against a reference with a known pose returns the true inverse depth within 2 sigma
    and 1%, for a full-range search (no prior) and for a +-2 sigma search around a wrong prior."""
    T_ref, T_cur = pose(), pose(tx=0.06, ty=0.02)
    img_ref, cur, depth, T_ref_cur = _stereo_case(tex, T_ref, T_cur, K_MAP)
    gx, gy, mg = image_gradients(cur)
    prm = mapping_params(MappingConfig())
    rng = np.random.default_rng(5)
    errs = []
    for _ in range(200):
        x, y = int(rng.integers(10, 150)), int(rng.integers(10, 110))
        true = 1.0 / depth[y, x]
        for lo, prior, hi in ((0.0, 1.0, 20.0), (true - 0.1, true + 0.05, true + 0.2)):
            r = _run_line(cur, img_ref, gx, gy, T_ref_cur, K_MAP, x, y, lo, prior, hi, prm, "kernel")
            if r is None or r[0] != kernels.OK:
                continue
            _, idepth, var, _, _ = r
            errs.append(abs(idepth - true) / true)
            assert abs(idepth - true) <= max(2.5 * math.sqrt(var), 0.01 * true), (x, y, idepth, true, var)
    assert len(errs) > 100
    assert np.median(errs) < 0.01


# ----------------------------------------------------------------------------- observe
def _random_state(rng, h, w, frac_valid=0.6):
    valid = (rng.random((h, w)) < frac_valid).astype(np.uint8)
    idepth = rng.uniform(0.3, 0.8, (h, w)).astype(np.float32)
    var = rng.uniform(1e-4, 0.05, (h, w)).astype(np.float32)
    yy, xx = np.mgrid[0:h, 0:w]
    return {
        "idepth": idepth, "idepth_var": var, "idepth_s": (idepth + rng.normal(0, 0.01, (h, w))).astype(np.float32),
        "var_s": var.copy(), "valid": valid, "validity": rng.uniform(0, 60, (h, w)).astype(np.float32),
        "pos_x": (xx + rng.uniform(-0.5, 0.5, (h, w))).astype(np.float32),
        "pos_y": (yy + rng.uniform(-0.5, 0.5, (h, w))).astype(np.float32),
        "ref_id": rng.integers(0, 4, (h, w)).astype(np.int64),
        "blacklist": rng.integers(-3, 1, (h, w)).astype(np.int32),
        "skip": rng.integers(0, 3, (h, w)).astype(np.int32),
    }


@pytest.mark.parametrize("stride,row_groups", [(1, 1), (3, 1), (1, 3)])
def test_observe_kernel_matches_naive(tex, stride, row_groups):
    rng = np.random.default_rng(7)
    Kc = K_SMALL
    T_cur = pose(tx=0.08, ty=0.02, rot=(0.0, 0.01, 0.0))
    poses = [pose(), pose(tx=0.04), pose(tx=0.07, ty=0.01)]
    ids = np.array([0, 2, 3], np.int64)
    cur, _ = render_plane(tex, T_cur, Kc, 1.8)
    cur[10:20, 20:34] = 100.0                         # a flat patch: gradient too low
    refs = np.stack([render_plane(tex, T, Kc, 1.8)[0] for T in poses] + [np.zeros((48, 64), np.float32)])
    slots = np.array([3, 0, 1], np.int64)             # buffer order != slot order
    refs = refs[[1, 2, 3, 0]]
    # the references were taken at other exposures: stored as (I - b) / a, mapped back by (a, b)
    aff = np.array([[1.2, -8.0], [0.85, 6.0], [1.0, 0.0]])
    for k, slot in enumerate(slots):
        refs[slot] = (refs[slot] - aff[k, 1]) / aff[k, 0]
    Rs = np.stack([(np.linalg.inv(T) @ T_cur)[:3, :3] for T in poses])
    ts = np.stack([(np.linalg.inv(T) @ T_cur)[:3, 3] for T in poses])
    cs = np.stack([-R.T @ t for R, t in zip(Rs, ts)])
    res = np.array([0.0, 0.5, 1.0])
    gx, gy, mg = image_gradients(cur)
    st = _random_state(rng, 48, 64)
    st["idepth_s"][5, 5] = np.nan                        # NaN prior: must not crash or propagate
    prm = mapping_params(MappingConfig(min_depth=0.4, converged_skip=2))   # full-range searches fit the small image
    a = {k: v.copy() for k, v in st.items()}
    status = np.zeros((48, 64), np.int8)
    kernels.observe_kernel(cur, gx, gy, mg, RefFrames(refs, slots, ids, Rs, ts, cs, res, aff), _ms(a), _cam(Kc), prm,
                           stride, 1 if stride > 1 else 0, 64, status, row_groups)
    b = {k: v.copy() for k, v in st.items()}
    nstatus = naive.observe(cur, gx, gy, mg, refs, slots, ids, Rs, ts, cs, res, aff, b, Kc.fx, Kc.fy, Kc.cx, Kc.cy,
                            prm, stride, 1 if stride > 1 else 0, 64)
    np.testing.assert_array_equal(status, nstatus)
    for k in st:
        np.testing.assert_allclose(a[k], b[k], rtol=2e-5, atol=1e-6, err_msg=k)
    counts = np.bincount(status.ravel(), minlength=8)
    assert counts[1] > 20 and counts[2] > 5 and counts[6] > 0   # updates, creations, low-gradient removals
    assert counts[8] > 0 and np.any((status == 1) & (a["skip"] == 2))   # skipped and newly converged pixels


def test_observe_with_empty_buffer_changes_nothing(tex):
    cur, _ = render_plane(tex, pose(), K_SMALL)
    gx, gy, mg = image_gradients(cur)
    st = _random_state(np.random.default_rng(0), 48, 64)
    st["valid"][:] = 1
    a = {k: v.copy() for k, v in st.items()}
    status = np.zeros((48, 64), np.int8)
    empty = RefFrames(np.zeros((1, 48, 64), np.float32), np.zeros(0, np.int64), np.zeros(0, np.int64),
                      np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 2)))
    kernels.observe_kernel(cur, gx, gy, np.full_like(mg, 50.0), empty, _ms(a), np.array([60.0, 60.0, 31.5, 23.5]),
                           mapping_params(MappingConfig()), 1, 0, 64, status)
    for k in st:
        np.testing.assert_array_equal(a[k], st[k])


def test_fusion_lowers_variance_and_lands_between(tex):
    """Successful updates (status 1) never raise the variance and put the mean between the prior
    and the observation (a convex combination, eq. 3.13)."""
    Kc = K_MAP
    T_ref, T_cur = pose(), pose(tx=0.05)
    img_ref, cur, depth, _ = _stereo_case(tex, T_ref, T_cur, Kc)
    gx, gy, mg = image_gradients(cur)
    rng = np.random.default_rng(11)
    h, w = cur.shape
    true = 1.0 / depth
    st = _random_state(rng, h, w, 1.0)
    st["idepth"][:] = (true * rng.uniform(0.97, 1.03, (h, w))).astype(np.float32)
    st["idepth_s"][:] = st["idepth"]
    st["var_s"][:] = st["idepth_var"]
    st["ref_id"][:] = 0
    st["blacklist"][:] = 0
    st["validity"][:] = 5.0
    st["skip"][:] = 0
    before = {k: v.copy() for k, v in st.items()}
    T_ref_cur = np.linalg.inv(T_ref) @ T_cur
    status = np.zeros((h, w), np.int8)
    refs = RefFrames(img_ref[None], np.zeros(1, np.int64), np.zeros(1, np.int64), T_ref_cur[None, :3, :3].copy(),
                     T_ref_cur[None, :3, 3].copy(), (-T_ref_cur[:3, :3].T @ T_ref_cur[:3, 3])[None], np.zeros(1),
                     np.array([[1.0, 0.0]]))
    kernels.observe_kernel(cur, gx, gy, mg, refs, _ms(st), _cam(Kc), mapping_params(MappingConfig()), 1, 0, 64, status)
    upd = status == 1
    assert upd.sum() > 500
    assert np.all(st["idepth_var"][upd] <= before["idepth_var"][upd])
    assert np.mean(st["idepth_var"][upd] < before["idepth_var"][upd]) > 0.99
    # fused values got closer to the truth on average
    e_before = np.abs(before["idepth"][upd] - true[upd])
    e_after = np.abs(st["idepth"][upd] - true[upd])
    assert np.median(e_after) < 0.5 * np.median(e_before)
    assert np.all(st["validity"][upd] > before["validity"][upd])


# ----------------------------------------------------------------------------- propagate
def _prop_args(cfg):
    return (float(cfg.border), float(cfg.min_grad), float(cfg.prop_diff_const) ** 2, float(cfg.prop_diff_grad_fac),
            float(cfg.prop_merge_fac), float(cfg.propagation_sigma), float(cfg.validity_max + cfg.validity_max_grad))


def _run_propagate(st, img_old, img_new, mg_new, T_new_old, Kc, cfg, aff=(1.0, 0.0), bands=1):
    h, w = img_old.shape
    # the new map starts as garbage (the Mapper hands in the map of two frames ago): the kernel resets
    # valid, positions and blacklist itself; the rest only matters where a hypothesis lands
    garbage = np.random.default_rng(11)
    out = {k: (garbage.random((h, w)) * 9).astype(st[k].dtype) for k in (
        "idepth", "idepth_var", "idepth_s", "var_s", "valid", "validity", "pos_x", "pos_y", "ref_id", "skip",
        "blacklist")}
    R, t = np.ascontiguousarray(T_new_old[:3, :3]), np.ascontiguousarray(T_new_old[:3, 3])
    res = kernels.propagate_kernel(_ms(st), img_old, img_new, mg_new, R, t, _cam(Kc), mapping_params(cfg),
                                   np.array(aff, np.float64), _ms(out), kernels.propagation_work(h, w), bands)
    for k in ("idepth", "idepth_var", "idepth_s", "var_s", "validity", "ref_id", "skip"):
        out[k][out["valid"] == 0] = 0             # left as they were: not part of the result
    return out, res


@pytest.mark.parametrize("bands", [1, 5])
@pytest.mark.parametrize("motion", [dict(tx=0.05), dict(tx=0.02, tz=0.3, rot=(0.02, 0.01, 0.1)), dict(tz=-1.5),
                                    dict(tx=2.0)])
def test_propagate_matches_naive(tex, motion, bands):
    rng = np.random.default_rng(3)
    cfg = dataclasses.replace(MappingConfig(), propagation_sigma=1e-4)
    T_old, T_new = pose(), pose(**motion)
    img_old, _ = render_plane(tex, T_old, K_SMALL)
    img_new, _ = render_plane(tex, T_new, K_SMALL)
    _, _, mg_new = image_gradients(img_new)
    st = _random_state(rng, 48, 64, 0.7)
    st["idepth_s"][0, 0] = np.nan
    st["valid"][0, 0] = 1
    st["idepth_s"][1, 1] = -0.5                    # negative inverse depth: behind the camera
    st["valid"][1, 1] = 1
    T_new_old = np.linalg.inv(T_new) @ T_old
    aff = (1.15, -9.0)                             # the new frame is brighter: compensated in the intensity check
    img_new = aff[0] * img_new + aff[1]
    out, res = _run_propagate(st, img_old, img_new, mg_new, T_new_old, K_SMALL, cfg, aff, bands)
    nout, counts = naive.propagate(st, img_old, img_new, mg_new, T_new_old[:3, :3], T_new_old[:3, 3], K_SMALL.fx,
                                   K_SMALL.fy, K_SMALL.cx, K_SMALL.cy, *_prop_args(cfg), aff=aff)
    assert tuple(res) == (counts["kept"], counts["border"], counts["intensity"], counts["occluded"], counts["fused"])
    for k in out:
        np.testing.assert_allclose(out[k], nout[k], rtol=2e-5, atol=1e-6, err_msg=k)


@pytest.mark.parametrize("bands", [1, 3])
@pytest.mark.parametrize("near_first", [True, False])
def test_propagation_occlusion_nearer_wins(near_first, bands):
    """Two hypotheses that land on the same pixel with inconsistent depths: the farther one is
    removed, whichever comes first in scan order; consistent ones are fused (variance drops)."""
    cfg = MappingConfig()
    h, w = 30, 40
    Kc = PinholeIntrinsics(50.0, 50.0, 19.5, 14.5, w, h)
    img = np.full((h, w), 100.0, np.float32)
    mg = np.full((h, w), 50.0, np.float32)
    st = _random_state(np.random.default_rng(0), h, w, 0.0)
    yy, xx = np.mgrid[0:h, 0:w]
    st["pos_x"][:], st["pos_y"][:] = xx, yy
    # camera moves by -0.2 m in x: a point at pixel u with idepth d moves to u + 50 * 0.2 * d = u + 10 d
    T_new_old = pose(tx=0.2)
    near_x, far_x = (5, 13) if near_first else (23, 15)
    d_near, d_far = 1.0, 0.2
    if not near_first:      # near point to the right of the far one: mirror the motion
        T_new_old = pose(tx=-0.2)
        d_near, d_far = 1.0, 0.2
    for x, d in ((near_x, d_near), (far_x, d_far)):
        st["valid"][10, x] = 1
        st["idepth_s"][10, x] = d
        st["idepth_var"][10, x] = 1e-4
    out, res = _run_propagate(st, img, img, mg, T_new_old, Kc, cfg, bands=bands)
    assert out["valid"].sum() == 1
    assert res[3] == 1                                  # one occlusion
    iy, ix = np.argwhere(out["valid"])[0]
    assert out["idepth"][iy, ix] == pytest.approx(d_near, rel=1e-6)
    # consistent collision: both survive as one fused hypothesis with a lower variance
    st["idepth_s"][10, far_x] = d_near * 1.001
    st["idepth_var"][10, far_x] = 1e-4
    st["pos_x"][10, far_x] = near_x                     # same position, same depth: same target pixel
    out, res = _run_propagate(st, img, img, mg, T_new_old, Kc, cfg, bands=bands)
    assert out["valid"].sum() == 1 and res[4] == 1
    assert out["idepth_var"][out["valid"] == 1][0] < 1e-4


def test_propagation_variance_inflation_and_subpixel():
    """var_new = (d_new/d_old)^4 var + sigma_p^2; the projected sub-pixel position is kept."""
    cfg = dataclasses.replace(MappingConfig(), propagation_sigma=1e-3)
    h, w = 30, 40
    Kc = PinholeIntrinsics(50.0, 50.0, 19.5, 14.5, w, h)
    img = np.full((h, w), 100.0, np.float32)
    mg = np.full((h, w), 50.0, np.float32)
    st = _random_state(np.random.default_rng(0), h, w, 0.0)
    st["valid"][14, 19] = 1
    st["pos_x"][14, 19], st["pos_y"][14, 19] = 19.3, 14.6
    st["idepth_s"][14, 19] = 0.5                       # depth 2
    st["idepth_var"][14, 19] = 0.01
    out, _ = _run_propagate(st, img, img, mg, pose(tz=-0.4, tx=0.013), Kc, cfg)   # point now at depth 1.6
    iy, ix = np.argwhere(out["valid"])[0]
    d_new = 1 / 1.6
    assert out["idepth"][iy, ix] == pytest.approx(d_new, rel=1e-6)
    assert out["idepth_var"][iy, ix] == pytest.approx((d_new / 0.5) ** 4 * 0.01 + 1e-3, rel=1e-5)
    X = np.array([(19.3 - 19.5) / 50 * 2, (14.6 - 14.5) / 50 * 2, 2.0]) + [0.013, 0, -0.4]
    assert out["pos_x"][iy, ix] == pytest.approx(50 * X[0] / X[2] + 19.5, abs=1e-4)
    assert out["pos_y"][iy, ix] == pytest.approx(50 * X[1] / X[2] + 14.5, abs=1e-4)
    assert (ix, iy) == (int(out["pos_x"][iy, ix] + 0.5), int(out["pos_y"][iy, ix] + 0.5))


def test_propagation_intensity_check_drops_changed_pixels():
    cfg = MappingConfig()
    h, w = 30, 40
    Kc = PinholeIntrinsics(50.0, 50.0, 19.5, 14.5, w, h)
    img_old = np.full((h, w), 100.0, np.float32)
    img_new = img_old.copy()
    img_new[:, 20:] = 200.0                              # right half changed by 100 > 40 grey levels
    mg = np.full((h, w), 5.0, np.float32)
    st = _random_state(np.random.default_rng(0), h, w, 0.0)
    yy, xx = np.mgrid[0:h, 0:w]
    st["pos_x"][:], st["pos_y"][:] = xx, yy
    st["valid"][5:25, 5:35] = 1
    st["idepth_s"][:] = 0.5
    out, res = _run_propagate(st, img_old, img_new, mg, np.eye(4), Kc, cfg)
    assert out["valid"][5:25, 5:19].all() and not out["valid"][:, 21:].any()
    assert res[2] > 0


# ----------------------------------------------------------------------------- regularize / fill
@pytest.mark.parametrize("var_mode", [0, 1, 2])
def test_regularize_matches_naive(var_mode):
    rng = np.random.default_rng(4)
    st = _random_state(rng, 25, 31, 0.7)
    st["idepth"][3, 3] = np.nan
    st["valid"][3, 3] = 1
    a_d = np.zeros((25, 31), np.float32)
    a_v = np.zeros((25, 31), np.float32)
    a_valid = np.zeros((25, 31), np.uint8)
    bl = st["blacklist"].copy()
    cfg = MappingConfig(reg_radius=2, reg_dist_var=0.005625, reg_diff_fac=1.0, reg_validity_sum=24.0,
                        reg_var_mode=("min", "own", "fused")[var_mode])
    kernels.regularize_kernel(_ms({**st, "blacklist": bl, "idepth_s": a_d, "var_s": a_v}), mapping_params(cfg), a_valid,
                              kernels.regularize_work(25, 31, 2))
    n_d, n_v, n_valid, n_bl = naive.regularize(st["idepth"], st["idepth_var"], st["valid"], st["validity"],
                                               st["blacklist"], 2, 0.005625, 1.0, 24.0, var_mode)
    np.testing.assert_array_equal(a_valid, n_valid)
    np.testing.assert_array_equal(bl, n_bl)
    m = n_valid == 1
    np.testing.assert_allclose(a_d[m], n_d[m], rtol=1e-5)
    np.testing.assert_allclose(a_v[m], n_v[m], rtol=1e-6)
    assert 0 < m.sum() < st["valid"].sum()


@pytest.mark.parametrize("radius", [1, 2, 3])
def test_regularize_sparse_spans_match_naive(radius):
    """The kernel accumulates only spans of 8-pixel chunks holding a hypothesis: a semi-dense map with
    empty rows, empty runs longer and shorter than a chunk, and hypotheses in the first and last
    columns (a width that is not a multiple of 8) gives what the naive twin gives."""
    rng = np.random.default_rng(11)
    h, w = 21, 45
    st = _random_state(rng, h, w, 0.0)
    valid = np.zeros((h, w), np.uint8)
    for y in range(h):
        if y % 5 == 3:
            continue                                  # empty rows
        for x0 in rng.integers(0, w, 3):              # clusters of a few pixels
            valid[y, x0:x0 + int(rng.integers(1, 6))] = 1
    valid[::2, 0] = 1
    valid[1::2, w - 1] = 1
    valid[7, 8:16] = 1                                 # exactly one chunk
    st["valid"] = valid
    st["validity"][:] = rng.uniform(5, 30, (h, w)).astype(np.float32)
    a_d = np.zeros((h, w), np.float32)
    a_v = np.zeros((h, w), np.float32)
    a_valid = np.zeros((h, w), np.uint8)
    bl = st["blacklist"].copy()
    cfg = MappingConfig(reg_radius=radius, reg_dist_var=0.005625, reg_diff_fac=1.0, reg_validity_sum=24.0)
    kernels.regularize_kernel(_ms({**st, "blacklist": bl, "idepth_s": a_d, "var_s": a_v}), mapping_params(cfg), a_valid,
                              kernels.regularize_work(h, w, radius))
    n_d, n_v, n_valid, n_bl = naive.regularize(st["idepth"], st["idepth_var"], st["valid"], st["validity"],
                                               st["blacklist"], radius, 0.005625, 1.0, 24.0, 0)
    np.testing.assert_array_equal(a_valid, n_valid)
    np.testing.assert_array_equal(bl, n_bl)
    m = n_valid == 1
    np.testing.assert_allclose(a_d[m], n_d[m], rtol=1e-5)
    np.testing.assert_allclose(a_v[m], n_v[m], rtol=1e-6)
    assert 0 < m.sum() < valid.sum() and valid[:, 0].any() and valid[:, w - 1].any()


def test_regularize_preserves_edges():
    """A depth step between two well-determined surfaces is not blurred."""
    h, w = 20, 20
    d = np.where(np.arange(w)[None, :] < 10, 0.5, 1.0).repeat(h, 0).astype(np.float32)
    var = np.full((h, w), 1e-4, np.float32)
    valid = np.ones((h, w), np.uint8)
    o_d = np.zeros((h, w), np.float32)
    o_v = np.zeros((h, w), np.float32)
    o_valid = np.zeros((h, w), np.uint8)
    st = _random_state(np.random.default_rng(0), h, w)
    st.update(idepth=d, idepth_var=var, valid=valid, validity=np.full((h, w), 20.0, np.float32),
              blacklist=np.zeros((h, w), np.int32), idepth_s=o_d, var_s=o_v)
    kernels.regularize_kernel(_ms(st), mapping_params(MappingConfig(reg_var_mode="min")), o_valid,
                              kernels.regularize_work(h, w, MappingConfig().reg_radius))
    np.testing.assert_allclose(o_d, d, rtol=1e-6)
    assert o_valid.all()


def test_fill_matches_naive():
    rng = np.random.default_rng(6)
    st = _random_state(rng, 26, 33, 0.5)
    mg = rng.uniform(0, 10, (26, 33)).astype(np.float32)
    names = ("idepth", "idepth_var", "idepth_s", "var_s", "valid", "validity", "pos_x", "pos_y", "ref_id")
    o = {k: st[k].copy() for k in names}
    flag = np.zeros_like(st["valid"])
    bl = st["blacklist"].copy()
    skip = st["skip"].copy()
    cfg = MappingConfig(min_grad=5.0, min_blacklist=-1, fill_validity_sum=30.0, unblacklist_validity_sum=100.0,
                        init_var=0.125, fill_validity=0.0)
    work = kernels.fill_work(26, 33)
    for a in work:
        a.fill(7)                                 # scratch from an earlier call: overwritten, never read
    kernels.fill_kernel(_ms({**o, "blacklist": bl, "skip": skip}), mg, mapping_params(cfg), flag, work)
    created = naive.fill(st["idepth"], st["idepth_var"], st["valid"], st["validity"], st["ref_id"], st["blacklist"],
                         mg, 5.0, -1, 30.0, 100.0, 0.125, 0.0)
    assert {tuple(p) for p in np.argwhere(flag)} == set(created)
    assert len(created) > 5
    np.testing.assert_array_equal(o["valid"], st["valid"])           # valid is left to the caller
    old = st["valid"] == 1
    for k in names:                                                   # existing hypotheses untouched
        np.testing.assert_array_equal(o[k][old], st[k][old])
    assert np.any(st["blacklist"][flag == 1] < -1)                     # unblacklisted by a strong neighbourhood
    assert np.all(bl[flag == 1] == 0) and np.array_equal(bl[flag == 0], st["blacklist"][flag == 0])
    assert np.all(skip[flag == 1] == 0) and np.array_equal(skip[flag == 0], st["skip"][flag == 0])
    for (y, x), (d, rid) in created.items():
        assert o["idepth"][y, x] == pytest.approx(d, rel=1e-5)
        assert o["idepth_s"][y, x] == pytest.approx(d, rel=1e-5)
        assert o["idepth_var"][y, x] == pytest.approx(0.125)
        assert o["ref_id"][y, x] == rid
        assert (o["pos_x"][y, x], o["pos_y"][y, x]) == (x, y)


# ----------------------------------------------------------------------------- Mapper
def _plane_frames(tex, n, Kc, step=(0.012, 0.004, 0.0), plane_z=2.0):
    out = []
    for i in range(n):
        T = pose(step[0] * i, step[1] * i, step[2] * i, rot=(0.0, 0.002 * math.sin(0.3 * i), 0.0))
        img, depth = render_plane(tex, T, Kc, plane_z, normal=(0.0, 0.15, 1.0))
        out.append((MapFrame(i, i / 30.0, img, T), depth))
    return out


def test_random_init_converges_on_synthetic_sequence(tex):
    frames = _plane_frames(tex, 24, K_MAP)
    m = Mapper(MappingConfig(), K_MAP, seed=1)
    m.initialize_random(frames[0][0])
    idp, var, valid = m.current()
    start = depth_accuracy(idp, valid, frames[0][1])
    assert start["median_abs_rel_error"] > 0.15
    assert np.all((idp[valid] >= 0.5) & (idp[valid] <= 1.5)) and np.all(var[valid] == pytest.approx(0.125))
    for f, depth in frames[1:]:
        st = m.update(f)
    assert set(st.stage_ms) == {"propagate", "observe", "regularize", "fill"}
    assert st.valid_count == int(m.current()[2].sum())
    idp, var, valid = m.current()
    acc = depth_accuracy(idp, valid, frames[-1][1])
    assert acc["median_abs_rel_error"] < 0.01
    assert acc["within_10pct"] > 0.9
    assert acc["density"] > 0.5
    assert m.frame.frame_id == frames[-1][0].frame_id


def test_random_init_is_seeded(tex):
    f = _plane_frames(tex, 1, K_SMALL)[0][0]
    a, b, c = (Mapper(MappingConfig(), K_SMALL, seed=s) for s in (3, 3, 4))
    for m in (a, b, c):
        m.initialize_random(f)
    assert np.array_equal(a.current()[0], b.current()[0])
    assert not np.array_equal(a.current()[0], c.current()[0])
    # only pixels with (3x3 max) gradient >= min_grad get a hypothesis (>=, not >)
    _, _, mg = image_gradients(f.image)
    valid = a.current()[2]
    assert not np.any(valid & (mg < 5.0))


def test_depth_init_and_accuracy(tex):
    (f, depth), (f1, depth1) = _plane_frames(tex, 2, K_SMALL)
    m = Mapper(MappingConfig(), K_SMALL)
    depth = depth.copy()
    depth[:5] = 0.0                                     # invalid depth: no hypothesis
    m.initialize_from_depth(f, depth)
    idp, var, valid = m.current()
    assert not valid[:5].any()
    np.testing.assert_allclose(1 / idp[valid], depth[valid], rtol=1e-5)
    assert np.allclose(var[valid], 1e-4)
    acc = depth_accuracy(idp, valid, depth)
    assert acc["median_abs_rel_error"] < 1e-5 and acc["within_5pct"] == 1.0
    m.update(f1)
    acc1 = depth_accuracy(*m.current()[::2], depth1)
    assert acc1["median_abs_rel_error"] < 0.01


def test_depth_accuracy_by_hand():
    idepth = np.array([[0.5, 1.0], [0.0, 2.0]])
    valid = np.array([[True, True], [False, True]])
    gt = np.array([[2.1, 1.0], [3.0, 0.0]])             # GT 0 = invalid: not compared
    acc = depth_accuracy(idepth, valid, gt)
    assert acc["density"] == 0.75
    assert acc["median_abs_rel_error"] == pytest.approx(np.median([0.1 / 2.1, 0.0]))
    assert acc["within_5pct"] == 1.0 and acc["within_10pct"] == 1.0
    empty = depth_accuracy(idepth, np.zeros((2, 2), bool), gt)
    assert empty["density"] == 0.0 and math.isnan(empty["median_abs_rel_error"])


def test_depth_accuracy_float32_maps_as_in_float64():
    """The map and depth images come as float32 with NaN, inf and negative values: the statistics
    equal those computed on float64 copies (the tests run in float32, the arithmetic in float64)."""
    rng = np.random.default_rng(3)
    gt = rng.uniform(0.5, 4.0, (60, 80)).astype(np.float32)
    gt[rng.random(gt.shape) < 0.1] = 0.0
    gt[rng.random(gt.shape) < 0.02] = np.nan
    idepth = (rng.uniform(0.9, 1.1, gt.shape) / np.maximum(gt, 0.5)).astype(np.float32)
    idepth[rng.random(gt.shape) < 0.05] = -1.0
    idepth[rng.random(gt.shape) < 0.02] = np.inf
    valid = rng.random(gt.shape) < 0.5
    d64, g64 = idepth.astype(np.float64), gt.astype(np.float64)
    m = valid & np.isfinite(g64) & (g64 > 0) & np.isfinite(d64) & (d64 > 0)
    rel = np.abs(1.0 / d64[m] - g64[m]) / g64[m]
    acc = depth_accuracy(idepth, valid, gt)
    assert acc["compared"] == int(m.sum()) > 1000
    assert acc["median_abs_rel_error"] == float(np.median(rel))
    assert acc["within_5pct"] == float(np.mean(rel <= 0.05)) and acc["within_10pct"] == float(np.mean(rel <= 0.10))


def test_budget_subsamples_candidates(tex):
    frames = _plane_frames(tex, 4, K_MAP)
    m = Mapper(dataclasses.replace(MappingConfig(), budget_ms=0.01), K_MAP)
    m.initialize_random(frames[0][0])
    strides = [m.update(f).stride for f, _ in frames[1:]]
    assert strides[0] == 1 and all(s > 1 for s in strides[1:])
    free = Mapper(MappingConfig(), K_MAP)
    free.initialize_random(frames[0][0])
    assert all(free.update(f).stride == 1 for f, _ in frames[1:])


def test_stereo_stride_searches_a_rotating_share_of_the_candidates(tex):
    """``stereo_stride = k``: every iteration searches about 1/k of what stride 1 searches, and the budget
    can only raise the stride further."""
    frames = _plane_frames(tex, 5, K_MAP)

    def searched(st):
        return st.updated + st.created + st.inconsistent + st.failed

    runs = {}
    for k in (1, 2):
        m = Mapper(dataclasses.replace(MappingConfig(), stereo_stride=k), K_MAP)
        m.initialize_random(frames[0][0])
        runs[k] = [m.update(f) for f, _ in frames[1:]]
    assert all(st.stride == 1 for st in runs[1]) and all(st.stride == 2 for st in runs[2])
    ratio = sum(searched(st) for st in runs[2]) / sum(searched(st) for st in runs[1])
    assert 0.35 < ratio < 0.65
    tight = Mapper(dataclasses.replace(MappingConfig(), stereo_stride=2, budget_ms=0.01), K_MAP)
    tight.initialize_random(frames[0][0])
    strides = [tight.update(f).stride for f, _ in frames[1:]]
    assert min(strides) >= 2 and max(strides) > 2


def test_stage_cpu_times_only_when_asked(tex):
    frames = _plane_frames(tex, 3, K_MAP)
    m = Mapper(MappingConfig(), K_MAP)
    m.initialize_random(frames[0][0])
    st = m.update(frames[1][0])
    assert st.stage_cpu_ms == {} and set(st.stage_ms) == {"propagate", "observe", "regularize", "fill"}
    m.measure_cpu = True
    st = m.update(frames[2][0])
    assert set(st.stage_cpu_ms) == set(st.stage_ms) and all(v >= 0 for v in st.stage_cpu_ms.values())
    assert sum(st.stage_cpu_ms.values()) > 0


@pytest.mark.parametrize("shape", [(23, 37), (6, 5), (1, 1)])
def test_any_image_size(shape):
    h, w = shape
    Kc = PinholeIntrinsics(20.0, 20.0, (w - 1) / 2, (h - 1) / 2, w, h)
    rng = np.random.default_rng(0)
    m = Mapper(MappingConfig(), Kc)
    m.initialize_random(MapFrame(0, 0.0, (rng.random((h, w)) * 255).astype(np.float32), pose()))
    st = m.update(MapFrame(1, 0.1, (rng.random((h, w)) * 255).astype(np.float32), pose(tx=0.01)))
    assert st.valid_count >= 0
    assert m.current()[0].shape == (h, w)


def test_input_errors(tex):
    m = Mapper(MappingConfig(), K_SMALL)
    f = MapFrame(0, 0.0, np.zeros((10, 10), np.float32), pose())
    with pytest.raises(InputError):
        m.update(f)                        # not initialised
    with pytest.raises(InputError, match="shape"):
        m.initialize_random(f)
    good = MapFrame(0, 0.0, np.zeros((48, 64), np.float32), pose())
    with pytest.raises(InputError):
        m.initialize_from_depth(good, np.ones((5, 5)))
    bad_pose = MapFrame(0, 0.0, np.zeros((48, 64), np.float32), np.full((4, 4), np.nan))
    with pytest.raises(InputError):
        m.initialize_random(bad_pose)


def test_warmup_runs():
    kernels.warmup()


def test_reference_buffer_is_bounded_and_ordered(tex):
    frames = _plane_frames(tex, 9, K_SMALL)
    m = Mapper(dataclasses.replace(MappingConfig(), buffer_size=3), K_SMALL)
    m.initialize_random(frames[0][0])
    m.add_reference(frames[0][0])                    # the current frame is not its own reference
    assert m.update(frames[0][0]).references == 0
    for i in range(1, 9):
        if i % 2:
            m.add_reference(frames[i][0])            # tracked but not mapped
        else:
            st = m.update(frames[i][0])
            assert st.references <= 3
    ids = [f.frame_id for f, _ in m._buffer]
    assert ids == sorted(ids) and len(ids) == 3 and 8 not in ids
    assert len({slot for _, slot in m._buffer}) == 3


@pytest.mark.parametrize("keep", [False, True])
def test_hypotheses_flattened_by_clipping_are_kept_only_when_asked(tex, keep):
    """``keep_clipped``: when an exposure change drives most of the image into saturation (flat 255, no
    gradient), the hypotheses there survive propagation and stereo and are right when the exposure comes
    back; without it they are removed (and must be rebuilt)."""
    frames = _plane_frames(tex, 7, K_SMALL)
    m = Mapper(dataclasses.replace(MappingConfig(), keep_clipped=keep), K_SMALL)
    m.initialize_from_depth(frames[0][0], frames[0][1])
    start = int(m.current()[2].sum())
    for i, (f, _) in enumerate(frames[1:], 1):
        gain = 1.0 if i in (1, 6) else 4.0                  # frames 2-5: four times the exposure
        img = np.minimum(np.asarray(f.image, np.float32) * gain, 255.0)
        m.update(MapFrame(f.frame_id, f.timestamp, img, f.T_world_cam, 0.0, (gain, 0.0)))
        if i == 5:
            held = int(m.current()[2].sum())
            clipped = float(np.mean(img >= 250.0))
    idp, _, valid = m.current()
    truth = 1.0 / frames[6][1]
    err = np.abs(idp[valid] - truth[valid]) / truth[valid]
    assert clipped > 0.9
    if keep:                                                # measured: 80 % held, 84 % after, 0.1 % error
        assert held > 0.75 * start                          # carried through the clipped frames
        assert valid.sum() > 0.75 * start and np.median(err) < 0.02   # and still right afterwards
    else:                                                   # measured: 42 % held
        assert held < 0.5 * start


def test_nan_tracking_residual_does_not_poison_the_map(tex):
    frames = _plane_frames(tex, 4, K_SMALL)
    m = Mapper(MappingConfig(), K_SMALL)
    m.initialize_from_depth(frames[0][0], frames[0][1])
    for f, _ in frames[1:]:
        m.update(MapFrame(f.frame_id, f.timestamp, f.image, f.T_world_cam, float("nan")))
    idp, var, valid = m.current()
    assert valid.sum() > 100
    assert np.all(np.isfinite(idp[valid])) and np.all(np.isfinite(var[valid])) and np.all(var[valid] > 0)


def test_exposure_changes_give_the_same_depth_when_compensated(tex):
    """The same sequence with per-frame gain/offset (auto-exposure), told to the mapper through
    MapFrame.affine, converges to the same depth as the unchanged one; without the brightness
    model the stereo matches degrade."""
    frames = _plane_frames(tex, 16, K_MAP)
    rng = np.random.default_rng(21)
    gains = rng.uniform(0.8, 1.25, len(frames))
    offsets = rng.uniform(-10, 10, len(frames))
    gains[0], offsets[0] = 1.0, 0.0
    runs = {}
    for name in ("clean", "compensated", "ignored"):
        m = Mapper(MappingConfig(), K_MAP, seed=3)
        for i, (f, depth) in enumerate(frames):
            img = f.image if name == "clean" else (gains[i] * f.image + offsets[i]).astype(np.float32)
            aff = (float(gains[i]), float(offsets[i])) if name == "compensated" else (1.0, 0.0)
            mf = MapFrame(f.frame_id, f.timestamp, img, f.T_world_cam, affine=aff)
            if i == 0:
                m.initialize_random(mf)
            else:
                st = m.update(mf)
        runs[name] = (m.current(), st)
    gt = frames[-1][1]
    acc = {k: depth_accuracy(v[0][0], v[0][2], gt) for k, v in runs.items()}
    assert acc["clean"]["median_abs_rel_error"] < 0.01
    assert acc["compensated"]["median_abs_rel_error"] < 0.01
    assert acc["compensated"]["density"] == pytest.approx(acc["clean"]["density"], rel=0.05)
    (d_c, _, v_c), _ = runs["clean"]
    (d_e, _, v_e), _ = runs["compensated"]
    both = v_c & v_e
    assert np.median(np.abs(d_e[both] - d_c[both]) / d_c[both]) < 0.002
    # uncompensated: fewer successful stereo updates in the last iteration
    assert runs["ignored"][1].updated < 0.8 * runs["compensated"][1].updated


def test_interleaved_rows_visit_every_row_once_spread_over_the_image():
    from lite_vo.mapping._kernels import interleaved_rows
    for lo, hi, block, groups in ((3, 237, 8, 2), (3, 117, 8, 3), (0, 10, 3, 2), (3, 4, 8, 2), (5, 5, 8, 2),
                                  (0, 17, 4, 4), (3, 20, 8, 1)):
        rows = interleaved_rows(lo, hi, block, groups)
        assert sorted(rows.tolist()) == list(range(lo, hi))
    np.testing.assert_array_equal(interleaved_rows(3, 40, 8, 1), np.arange(3, 40))   # one thread: top to bottom
    rows = interleaved_rows(3, 237, 8, 2)
    first_half, second_half = rows[:len(rows) // 2], rows[len(rows) // 2:]
    # each half of the order (what one of two threads gets) has a block from every 16 rows
    assert {int(y - 3) // 16 for y in first_half} == {int(y - 3) // 16 for y in second_half}
    assert np.all(np.diff(first_half[:8]) == 1)                   # rows inside a block stay consecutive


def test_count_codes_matches_bincount():
    rng = np.random.default_rng(12)
    codes = rng.integers(-2, 12, (37, 53)).astype(np.int8)
    want = np.bincount(codes[(codes >= 0) & (codes < 9)].astype(np.int64), minlength=9)
    np.testing.assert_array_equal(kernels.count_codes(codes, 9), want)


def test_published_map_is_zero_where_invalid(tex):
    """Mapper.current() (one kernel pass) equals the numpy expression it replaced, bit for bit."""
    m = Mapper(MappingConfig(), K_SMALL)
    frames = _plane_frames(tex, 4, K_SMALL)
    m.initialize_random(frames[0][0])
    for f, _ in frames[1:]:
        m.update(f)
    d, v, valid = m.current()
    s = m.state
    want_valid = s.valid != 0
    assert d.dtype == v.dtype == np.float32 and valid.dtype == np.bool_
    np.testing.assert_array_equal(valid, want_valid)
    np.testing.assert_array_equal(d, np.where(want_valid, s.idepth_s, 0.0).astype(np.float32))
    np.testing.assert_array_equal(v, np.where(want_valid, s.var_s, 0.0).astype(np.float32))
    assert 0 < valid.sum() < valid.size
    d[:] = -1.0                                   # a copy: the map itself is not touched
    assert np.all(m.current()[0][valid] == s.idepth_s[valid])
