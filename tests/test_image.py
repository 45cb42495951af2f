"""Image and inverse-depth pyramids, gradients: kernels vs the numpy twins in naive_tracking.py."""
import numpy as np
import pytest

import naive_tracking as naive
from lite_vo import image
from lite_vo.camera import PinholeIntrinsics


@pytest.mark.parametrize("shape", [(8, 8), (7, 9), (15, 6), (2, 3), (121, 161)])
def test_image_pyramid_matches_naive_any_size(shape):
    rng = np.random.default_rng(1)
    img = rng.uniform(0, 255, shape).astype(np.float32)
    levels = 1
    while min(shape) >> levels >= 1 and levels < 4:
        levels += 1
    pyr = image.image_pyramid(img, levels)
    assert len(pyr) == levels
    np.testing.assert_array_equal(pyr[0], img)
    ref = img
    for lvl in range(1, levels):
        ref = naive.downsample_image(ref)
        assert pyr[lvl].shape == (shape[0] >> lvl, shape[1] >> lvl)
        assert pyr[lvl].dtype == np.float32 and pyr[lvl].flags.c_contiguous
        np.testing.assert_allclose(pyr[lvl], ref, rtol=0, atol=1e-4)


def test_pyramid_sizes_match_intrinsics_levels():
    intr = PinholeIntrinsics(200.0, 200.0, 160.0, 121.0, 321, 243)
    pyr = image.image_pyramid(np.zeros((243, 321), np.float32), 4)
    for lvl, im in enumerate(pyr):
        k = intr.level(lvl)
        assert im.shape == (k.height, k.width)


def test_image_pyramid_rejects_bad_input():
    with pytest.raises(ValueError):
        image.image_pyramid(np.zeros((4, 4, 3)), 2)
    with pytest.raises(ValueError):
        image.image_pyramid(np.zeros((1, 4)), 2)
    with pytest.raises(ValueError):
        image.image_pyramid(np.zeros((4, 4)), 0)


@pytest.mark.parametrize("seed,shape,density", [(0, (8, 8), 0.3), (1, (9, 7), 0.6), (2, (16, 20), 0.05),
                                                (3, (5, 5), 0.0)])
def test_idepth_pyramid_matches_naive(seed, shape, density):
    rng = np.random.default_rng(seed)
    d = rng.uniform(0.2, 2.0, shape).astype(np.float32)
    v = rng.uniform(1e-4, 1e-1, shape).astype(np.float32)
    m = rng.uniform(size=shape) < density
    ds, vs, ms = image.idepth_pyramid(d, v, m, 3)
    rd, rv, rm = np.where(m, d, np.nan), np.where(m, v, np.nan), m
    np.testing.assert_array_equal(ms[0], m)
    for lvl in range(1, 3):
        rd, rv, rm = naive.downsample_idepth(rd, rv, rm)
        np.testing.assert_array_equal(ms[lvl], rm)
        np.testing.assert_allclose(ds[lvl][rm], rd[rm], rtol=1e-5)
        np.testing.assert_allclose(vs[lvl][rm], rv[rm], rtol=1e-5)
        assert np.all(np.isnan(ds[lvl][~rm])) and np.all(np.isnan(vs[lvl][~rm]))


def test_idepth_pyramid_equations_5_2_5_3_by_hand():
    # one 2x2 block, three valid pixels with variances 1, 2, 4 and idepths 1, 2, 3
    d = np.array([[1.0, 2.0], [3.0, 9.0]], np.float32)
    v = np.array([[1.0, 2.0], [4.0, 1.0]], np.float32)
    m = np.array([[True, True], [True, False]])
    od, ov, om = image.downsample_idepth(d, v, m)
    info = 1 + 0.5 + 0.25
    assert om[0, 0]
    assert od[0, 0] == pytest.approx((1 / 1 + 2 / 2 + 3 / 4) / info, rel=1e-6)
    assert ov[0, 0] == pytest.approx(3 / info, rel=1e-6)     # n / sum(1/var): information averaged


def test_idepth_pyramid_becomes_denser():
    rng = np.random.default_rng(5)
    m = rng.uniform(size=(64, 64)) < 0.2
    _, _, ms = image.idepth_pyramid(np.ones((64, 64)), np.ones((64, 64)), m, 4)
    dens = [x.mean() for x in ms]
    assert dens[0] < dens[1] < dens[2] < dens[3]


def test_sanitize_drops_nan_nonpositive_and_zero_variance():
    d = np.array([[1.0, np.nan, -1.0, 0.5, 0.5, np.inf]], np.float32)
    v = np.array([[1.0, 1.0, 1.0, 0.0, np.nan, 1.0]], np.float32)
    m = np.ones_like(d, bool)
    sd, sv, sm = image.sanitize_idepth(d, v, m)
    np.testing.assert_array_equal(sm, [[True, False, False, False, False, False]])
    assert np.isnan(sd[0, 1:]).all() and np.isnan(sv[0, 1:]).all()


def test_gradients_match_naive_and_zero_border():
    rng = np.random.default_rng(3)
    img = rng.uniform(0, 255, (7, 11)).astype(np.float32)
    gx, gy = image.gradients(img)
    nx, ny = naive.gradients(img)
    np.testing.assert_allclose(gx, nx, atol=1e-4)
    np.testing.assert_allclose(gy, ny, atol=1e-4)
    stack = image.intensity_gradient_stack(img)
    assert stack.shape == (7, 11, 3)
    np.testing.assert_array_equal(stack[:, :, 0], img)
    assert np.all(gx[0] == 0) and np.all(gx[:, -1] == 0)


def test_gradient_of_linear_ramp_is_exact():
    ys, xs = np.mgrid[0:6, 0:8].astype(np.float32)
    gx, gy = image.gradients(3 * xs - 2 * ys)
    np.testing.assert_allclose(gx[1:-1, 1:-1], 3.0)
    np.testing.assert_allclose(gy[1:-1, 1:-1], -2.0)


def test_warmup_runs():
    image.warmup()


def _naive_blur(img, kern):
    """Separable convolution with mirror borders (the pixel at the edge not repeated), in float64."""
    r = len(kern) // 2
    h, w = img.shape

    def mirror(i, n):
        i = -i if i < 0 else i
        i = 2 * n - 2 - i if i >= n else i
        return min(max(i, 0), n - 1)

    tmp = np.array([[sum(kern[k + r] * img[y, mirror(x + k, w)] for k in range(-r, r + 1))
                     for x in range(w)] for y in range(h)])
    return np.array([[sum(kern[k + r] * tmp[mirror(y + k, h), x] for k in range(-r, r + 1))
                      for x in range(w)] for y in range(h)])


@pytest.mark.parametrize("shape", [(120, 160), (15, 20), (3, 7), (2, 9), (1, 1), (9, 2)])
@pytest.mark.parametrize("sigma", [0.7, 1.5])
def test_gaussian_blur_matches_naive_mirror_convolution(shape, sigma):
    from lite_vo.image import gaussian_blur, gaussian_kernel
    img = (np.random.default_rng(3).random(shape) * 255).astype(np.float32)
    out = gaussian_blur(img, sigma)
    assert out.dtype == np.float32 and out.shape == img.shape
    np.testing.assert_allclose(out, _naive_blur(img.astype(np.float64), gaussian_kernel(sigma)), atol=2e-4)
    assert not np.shares_memory(out, img)
    np.testing.assert_array_equal(gaussian_blur(img, 0.0), img)


@pytest.mark.parametrize("shape", [(120, 160), (15, 20), (2, 9)])
@pytest.mark.parametrize("sigma", [0.7, 0.0])
def test_gaussian_blur_into_out_equals_a_new_array(shape, sigma):
    from lite_vo.image import gaussian_blur
    img = (np.random.default_rng(4).random(shape) * 255).astype(np.float32)
    out = np.full(shape, np.nan, np.float32)
    got = gaussian_blur(img, sigma, out=out)
    assert got is out
    np.testing.assert_array_equal(out, gaussian_blur(img, sigma))
    for bad in (np.empty(shape, np.float64), np.empty((shape[0] + 1, shape[1]), np.float32),
                np.empty((shape[1], shape[0] * 2), np.float32)[:, ::2].T):
        with pytest.raises(ValueError):
            gaussian_blur(img, sigma, out=bad)


def test_bspline_horizon():
    from lite_vo.image import bspline_horizon
    z = abs(2.0 - np.sqrt(3.0))
    for precision in (1e-7, 1e-3, 1e-12):
        k = bspline_horizon(precision)
        assert z ** (k - 1) < precision <= z ** (k - 2)


def _prefilter_line_naive(c, horizon):
    """Row-by-row twin of the cubic B-spline prefilter (plain Python floats, one line at a time)."""
    n = len(c)
    if n < 2:
        return c
    z = np.sqrt(3.0) - 2.0
    c = [6.0 * v for v in c]
    zn, s = z, c[0]
    for k in range(1, min(horizon, n)):
        s += zn * c[k]
        zn *= z
    c[0] = s
    for k in range(1, n):
        c[k] += z * c[k - 1]
    c[n - 1] = (z / (z * z - 1.0)) * (c[n - 1] + z * c[n - 2])
    for k in range(n - 2, -1, -1):
        c[k] = z * (c[k + 1] - c[k])
    return c


@pytest.mark.parametrize("shape", [(120, 160), (37, 23), (9, 1), (1, 9), (2, 2), (17, 3)])
def test_bspline_coefficients_match_a_line_by_line_twin_bit_for_bit(shape):
    """The kernel runs eight rows' recursions interleaved; each value must get exactly the operations of a
    plain row pass then column pass (the same numbers bit for bit, any size, blocks of 8 rows and a rest)."""
    rng = np.random.default_rng(sum(shape))
    img = rng.uniform(0, 255, shape).astype(np.float32)
    horizon = int(np.ceil(np.log(1e-7) / np.log(2.0 - np.sqrt(3.0)))) + 1
    rows = [_prefilter_line_naive([float(v) for v in row], horizon) for row in img]
    cols = [_prefilter_line_naive([rows[y][x] for y in range(shape[0])], horizon) for x in range(shape[1])]
    twin = np.array([[cols[x][y] for x in range(shape[1])] for y in range(shape[0])], np.float32)
    got = image.bspline_coefficient_stack(img)[:, :, 0]
    assert np.array_equal(got, twin)


def test_box_average2_u8_is_opencvs_float_area_resize_bit_for_bit():
    import cv2
    from lite_vo.image import box_average2_u8
    rng = np.random.default_rng(11)
    for h, w in [(480, 640), (7, 9), (2, 2), (375, 1242)]:
        img = rng.integers(0, 256, (h, w), dtype=np.uint8)
        img[0, :] = 255                       # the extremes too
        img[-1, :] = 0
        even = img[: h // 2 * 2, : w // 2 * 2]
        expected = cv2.resize(even.astype(np.float32), (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        got = box_average2_u8(img)
        assert got.dtype == np.float32 and got.shape == (h // 2, w // 2)
        np.testing.assert_array_equal(got, expected)
    # read-only input (a reader's frame) and a strided view give the same values
    img = rng.integers(0, 256, (60, 80), dtype=np.uint8)
    ro = img.copy()
    ro.flags.writeable = False
    np.testing.assert_array_equal(box_average2_u8(ro), box_average2_u8(img))
    wide = np.repeat(img, 2, axis=1)[:, ::2]          # not contiguous
    np.testing.assert_array_equal(box_average2_u8(wide), box_average2_u8(img))
    with pytest.raises(ValueError, match="uint8"):
        box_average2_u8(img.astype(np.float32))
    with pytest.raises(ValueError, match="too small"):
        box_average2_u8(np.zeros((1, 5), np.uint8))
