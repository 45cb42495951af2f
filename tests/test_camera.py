"""Camera models (radtan, FOV, equidistant fisheye), rectification (remap + resize + crop), depth
resampling, levels."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from lite_vo.camera import Camera, PinholeIntrinsics
from lite_vo.errors import ConfigError, InputError

FR1 = Camera.radtan(517.3, 516.5, 318.6, 255.3, 640, 480, 0.2624, -0.9531, -0.0054, 0.0026, 1.1633)
EUROC = Camera.radtan(458.654, 457.296, 367.215, 248.375, 752, 480, -0.28340811, 0.07395907, 0.00019359,
                      1.76187114e-05)
FOV = Camera.fov(300.0, 300.0, 319.5, 239.5, 640, 480, 0.9)
KITTI = Camera.pinhole(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370)
# a fisheye that fills a 640x480 image (about 100 degrees horizontally)
FISHEYE = Camera.equidistant(370.0, 371.0, 322.5, 236.0, 640, 480, -0.0139, 0.0451, -0.0412, 0.0077)
# a T265-like wide fisheye (163 degrees): its border lies beyond 90 degrees from the axis
WIDE = Camera.equidistant(285.0, 286.0, 424.0, 400.0, 848, 800, -0.0073, 0.042, -0.040, 0.0077)


def _grid(cam: Camera, step: int = 16) -> np.ndarray:
    u, v = np.meshgrid(np.arange(0, cam.width, step, dtype=float), np.arange(0, cam.height, step, dtype=float))
    return np.stack([u.ravel(), v.ravel()], -1)


@pytest.mark.parametrize("cam", [FR1, EUROC, FOV, FISHEYE], ids=["fr1", "euroc", "fov", "fisheye"])
def test_distortion_round_trip_over_the_image(cam):
    uv = _grid(cam)
    xy = cam.unproject(uv)            # undistorted normalised
    assert np.isfinite(xy).all()
    uv2 = cam.project(np.concatenate([xy, np.ones((len(xy), 1))], 1))
    np.testing.assert_allclose(uv2, uv, atol=1e-6)
    # and the other way round, on undistorted points
    rng = np.random.default_rng(1)
    pts = rng.uniform(-0.4, 0.4, size=(500, 2))
    np.testing.assert_allclose(cam.undistort(cam.distort(pts)), pts, atol=1e-9)


@pytest.mark.parametrize("cam", [FR1, EUROC], ids=["fr1", "euroc"])
def test_radtan_matches_opencv_projection(cam):
    rng = np.random.default_rng(2)
    pts = np.concatenate([rng.uniform(-0.5, 0.5, (200, 2)), np.ones((200, 1))], 1) * rng.uniform(0.5, 4, (200, 1))
    i = cam.intrinsics
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), i.K, np.array(cam.params))
    np.testing.assert_allclose(cam.project(pts), ref.reshape(-1, 2), atol=1e-6)


@pytest.mark.parametrize("cam", [FISHEYE, WIDE], ids=["fisheye", "wide"])
def test_equidistant_matches_cv2_fisheye(cam):
    rng = np.random.default_rng(5)
    # directions up to 80 degrees off the axis, at several depths
    theta = rng.uniform(0, np.radians(80), 400)
    phi = rng.uniform(-np.pi, np.pi, 400)
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    pts = rays * rng.uniform(0.5, 5.0, (400, 1))
    K, D = cam.intrinsics.K, np.array(cam.params)
    ref, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
    uv = cam.project(pts)
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-8)
    # unprojection: the ray (x, y, 1) of each pixel, as cv2.fisheye.undistortPoints, to 1e-9
    xy = cam.unproject(uv)
    np.testing.assert_allclose(xy, pts[:, :2] / pts[:, 2:], rtol=1e-9, atol=1e-9)
    ref_xy = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2), K, D).reshape(-1, 2)
    np.testing.assert_allclose(xy, ref_xy, rtol=1e-6, atol=1e-6)
    # with all k = 0 it is still the equidistant projection r = f * theta, not a pinhole
    plain = Camera.equidistant(100.0, 100.0, 0.0, 0.0, 10, 10)
    assert plain.is_distorted
    np.testing.assert_allclose(plain.project(np.array([[1.0, 0.0, 1.0]]))[0, 0], 100.0 * np.pi / 4, atol=1e-12)


def test_equidistant_beyond_90_degrees_is_nan():
    # the wide lens sees past 90 degrees at its left border: such pixels have no undistorted
    # (pinhole) coordinates; pixels nearer the centre do
    assert np.isnan(WIDE.unproject(np.array([[0.0, 400.0]]))).all()
    assert np.isfinite(WIDE.unproject(np.array([[100.0, 400.0]]))).all()
    r90 = WIDE.distort(np.array([[1e9, 0.0]]))[0, 0]          # 90 degrees, as a distorted radius
    assert np.isfinite(WIDE.undistort(np.array([[r90 * 0.99, 0.0]]))).all()
    assert np.isnan(WIDE.undistort(np.array([[r90 * 1.01, 0.0]]))).all()
    with pytest.raises(ValueError, match="equidistant distortion needs"):
        Camera(PinholeIntrinsics(1, 1, 0, 0, 4, 4), "equidistant", (0.1, 0.2, 0.3))


def test_fov_model_known_values():
    omega = 0.9
    cam = Camera.fov(1.0, 1.0, 0.0, 0.0, 10, 10, omega)
    r_u = np.array([0.0, 0.1, 0.5, 1.0, 2.0])
    d = cam.distort(np.stack([r_u, np.zeros_like(r_u)], -1))
    # eq. 2.7: R(r) = atan(2 r tan(omega/2)) / omega
    expected = np.arctan(2 * r_u * np.tan(omega / 2)) / omega
    np.testing.assert_allclose(d[:, 0], expected, atol=1e-12)
    # eq. 2.9 closed-form inverse
    back = cam.undistort(d)
    np.testing.assert_allclose(back[:, 0], r_u, atol=1e-12)
    # FOV compresses the periphery: distorted radius grows slower than the undistorted one
    assert np.all(np.diff(d[1:, 0] / r_u[1:]) < 0)
    # direction is preserved (radially symmetric)
    xy = np.array([[0.3, -0.4]])
    dd = cam.distort(xy)
    np.testing.assert_allclose(dd[0] / np.linalg.norm(dd[0]), xy[0] / 0.5, atol=1e-12)


def test_fov_undistort_beyond_180_degrees_is_nan():
    cam = Camera.fov(1.0, 1.0, 0.0, 0.0, 10, 10, 1.5)
    r = np.pi / 2 / 1.5 + 0.1  # r_d * omega > pi/2
    assert np.isnan(cam.undistort(np.array([[r, 0.0]]))).all()


def test_camera_validation():
    with pytest.raises(ValueError, match="radtan"):
        Camera(PinholeIntrinsics(1, 1, 0, 0, 4, 4), "radtan", (0.1, 0.2))
    with pytest.raises(ValueError, match="unknown distortion model"):
        Camera(PinholeIntrinsics(1, 1, 0, 0, 4, 4), "kannala", ())
    with pytest.raises(ValueError, match="omega"):
        Camera.fov(1, 1, 0, 0, 4, 4, 4.0)
    assert not Camera.radtan(1, 1, 0, 0, 4, 4, 0, 0, 0, 0).is_distorted
    assert FR1.is_distorted and FOV.is_distorted


# ------------------------------------------------------------------------------------------------
# rectification
# ------------------------------------------------------------------------------------------------

def _pattern(x: np.ndarray, y: np.ndarray, period: float = 0.12) -> np.ndarray:
    """A smooth checkerboard in normalised image coordinates (band-limited, so resampling is fair)."""
    a = 2 * np.pi / period
    return 127.5 + 110.0 * np.tanh(2.0 * np.sin(a * x) * np.sin(a * y))


def _render_native(cam: Camera, intensity, supersample: int = 2) -> np.ndarray:
    """Native image of ``intensity(x, y)`` (normalised undistorted coordinates) seen through the
    distorted camera, pixel-area averaged over ``supersample`` x ``supersample`` samples."""
    s = supersample
    off = (np.arange(s) + 0.5) / s - 0.5
    acc = np.zeros((cam.height, cam.width))
    u, v = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
    for du in off:
        for dv in off:
            xy = cam.unproject(np.stack([u + du, v + dv], -1))
            acc += intensity(xy[..., 0], xy[..., 1])
    return acc / (s * s)


def _render_distorted(cam: Camera, supersample: int = 2) -> np.ndarray:
    """Native image of the pattern seen through the distorted camera (pixel-area averaged)."""
    return _render_native(cam, _pattern, supersample)


def _render_pinhole(k: PinholeIntrinsics, period: float = 0.12) -> np.ndarray:
    u, v = np.meshgrid(np.arange(k.width, dtype=float), np.arange(k.height, dtype=float))
    return _pattern((u - k.cx) / k.fx, (v - k.cy) / k.fy, period)


@pytest.mark.parametrize("cam", [FR1, EUROC, FOV, FISHEYE], ids=["fr1", "euroc", "fov", "fisheye"])
def test_rectified_checkerboard_matches_ideal_pinhole(cam):
    img = np.clip(np.rint(_render_distorted(cam)), 0, 255).astype(np.uint8)
    rect = cam.rectifier(320, multiple_of=16)
    out = rect(img)
    k = rect.intrinsics
    assert out.dtype == np.float32 and out.shape == (k.height, k.width)
    assert k.width == 320 and k.height % 16 == 0
    ideal = _render_pinhole(k)
    err = np.abs(out - ideal)
    assert np.median(err) < 2.0 and np.mean(err) < 3.0, (np.median(err), np.mean(err))
    # the test can fail: ignoring the distortion (plain resize) is far off
    naive = cv2.resize(img.astype(np.float32), (k.width, k.height), interpolation=cv2.INTER_AREA)
    assert np.mean(np.abs(naive - ideal)) > 5 * np.mean(err)


@pytest.mark.parametrize("cam", [FR1, EUROC, FOV, KITTI, FISHEYE, WIDE],
                         ids=["fr1", "euroc", "fov", "kitti", "fisheye", "wide"])
def test_rectified_image_has_no_undefined_border(cam):
    rect = cam.rectifier(320)
    # every output pixel samples inside the native image: a bright image with a dark frame
    # of 1 pixel around it must come out bright everywhere except possibly the outermost ring
    img = np.full((cam.height, cam.width), 200, np.uint8)
    img[:, 0] = img[:, -1] = img[0, :] = img[-1, :] = 0
    out = rect(img)
    assert out[2:-2, 2:-2].min() > 199.0
    # and the chosen region is not wastefully small: the four border rows/columns come close
    # to the native image edges (within 3 % of the field of view)
    mx, my = rect._source_coords(rect.intrinsics)
    assert mx.min() > -0.5 - 1e-6 and mx.max() < cam.width - 0.5 + 1e-6
    assert my.min() > -0.5 - 1e-6 and my.max() < cam.height - 0.5 + 1e-6


def _line_image(cam: Camera, line: tuple, width: float = 0.004, supersample: int = 2) -> np.ndarray:
    """Native image of a dark straight 3D line on a bright background: the line projects to
    ``a x + b y + c = 0`` in undistorted normalised coordinates (a pinhole sees it straight)."""
    a, b, c = line

    def intensity(x, y):
        dist = np.abs(a * x + b * y + c) / np.hypot(a, b)
        return 230.0 - 200.0 * np.exp(-0.5 * (dist / width) ** 2)
    return np.clip(np.rint(_render_native(cam, intensity, supersample)), 0, 255).astype(np.uint8)


def _line_centres(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column, the darkness-weighted row of the line (columns where it is clearly present)."""
    dark = np.clip(img.max() - img.astype(np.float64) - 20.0, 0, None)
    w = dark.sum(0)
    cols = np.nonzero(w > 0.5 * np.median(w[w > 0]))[0]
    rows = (dark[:, cols] * np.arange(img.shape[0])[:, None]).sum(0) / w[cols]
    return cols.astype(float), rows


def _straightness(cols, rows) -> float:
    fit = np.polyval(np.polyfit(cols, rows, 1), cols)
    return float(np.abs(rows - fit).max())


@pytest.mark.parametrize("line", [(0.25, 1.0, -0.45), (-0.1, 1.0, 0.3)])
def test_fisheye_straight_line_is_straight_after_rectification(line):
    cam = FISHEYE
    img = _line_image(cam, line)
    c0, r0 = _line_centres(img)
    assert _straightness(c0, r0) > 8.0          # through the fisheye the line is clearly bent
    rect = cam.rectifier(320)
    out = rect(img)
    k = rect.intrinsics
    cols, rows = _line_centres(out[2:-2, 2:-2])
    cols, rows = cols + 2, rows + 2
    assert len(cols) > 0.9 * (k.width - 4)      # it crosses the whole rectified image
    assert _straightness(cols, rows) < 0.3      # and is straight there (sub-pixel)
    # where the geometry says: a x + b y + c = 0 with x = (u - cx) / fx
    a, b, c = line
    expect = k.cy - k.fy * (a * (cols - k.cx) / k.fx + c) / b
    assert np.abs(rows - expect).max() < 0.3


def test_wide_fisheye_rectified_view_is_capped():
    from lite_vo.camera import MAX_RECTIFIED_HALF_ANGLE_DEG
    for cam, lo in ((WIDE, MAX_RECTIFIED_HALF_ANGLE_DEG - 3), (FISHEYE, 45.0)):
        k = cam.rectifier(320).intrinsics
        corner = np.degrees(np.arctan(np.hypot((k.width / 2) / k.fx, (k.height / 2) / k.fy)))
        assert lo < corner <= MAX_RECTIFIED_HALF_ANGLE_DEG + 1e-6, (cam.describe(), corner)
    # the FISHEYE's view is limited by its image edges (widest without a border), not by the cap:
    # with the native 4:3 aspect kept, the top and bottom edges are reached
    k = FISHEYE.rectifier(320, multiple_of=1).intrinsics
    i = FISHEYE.intrinsics
    y_top, y_bottom = FISHEYE.unproject(np.array([[i.cx, -0.5], [i.cx, i.height - 0.5]]))[:, 1]
    assert (-0.5 - k.cy) / k.fy == pytest.approx(y_top, rel=0.02)
    assert (k.height - 0.5 - k.cy) / k.fy == pytest.approx(y_bottom, rel=0.02)


def test_pinhole_without_distortion_is_a_plain_area_resize():
    cam = Camera.pinhole(525.0, 525.0, 319.5, 239.5, 640, 480)
    rect = cam.rectifier(320)
    assert rect.intrinsics == cam.intrinsics.scaled(320, 240)
    img = (np.random.default_rng(3).uniform(0, 255, (480, 640))).astype(np.uint8)
    expected = cv2.resize(img.astype(np.float32), (320, 240), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(rect(img), expected)
    # an odd multiple keeps the aspect ratio and crops symmetrically
    r2 = cam.rectifier(200, multiple_of=16)     # 200x150 -> 192x144
    k = r2.intrinsics
    assert (k.width, k.height) == (192, 144)
    assert k.cx == pytest.approx(cam.intrinsics.scaled(200, 150).cx - 4.0)
    assert k.cy == pytest.approx(cam.intrinsics.scaled(200, 150).cy - 3.0)


@pytest.mark.parametrize("multiple, size", [(16, (320, 96)), (8, (320, 96)), (1, (320, 97)), (32, (320, 96))])
def test_kitti_aspect_ratio_resize_and_crop(multiple, size):
    rect = KITTI.rectifier(320, multiple_of=multiple)
    k = rect.intrinsics
    assert (k.width, k.height) == size
    assert k.fx == pytest.approx(k.fy)          # square pixels stay square
    # uncropped output keeps the native aspect ratio
    w0, h0 = rect.uncropped_size
    assert abs(w0 / h0 - 1226 / 370) < 0.02
    # the field of view is (almost) the native one: within 2 % horizontally
    native_fov = 1226 / 707.0912
    assert k.width / k.fx == pytest.approx(native_fov, rel=0.02)
    assert k.width / k.fx <= native_fov + 1e-9
    # image content: the pattern rendered by the native pinhole comes out as rendered by k
    img = np.clip(np.rint(_render_pinhole(KITTI.intrinsics)), 0, 255).astype(np.uint8)
    out = rect(img)
    assert np.mean(np.abs(out - _render_pinhole(k))) < 3.0


def test_level_intrinsics_match_box_downsampling():
    rect = FR1.rectifier(320)
    k0 = rect.intrinsics
    period = 0.3  # coarse enough that 4x4 box averaging barely blurs it
    img0 = _render_pinhole(PinholeIntrinsics(k0.fx * 2, k0.fy * 2, (k0.cx + 0.5) * 2 - 0.5,
                                             (k0.cy + 0.5) * 2 - 0.5, k0.width * 2, k0.height * 2), period)
    lvl0 = cv2.resize(img0.astype(np.float32), (k0.width, k0.height), interpolation=cv2.INTER_AREA)
    assert np.mean(np.abs(lvl0 - _render_pinhole(k0, period))) < 2.5
    for lvl in (1, 2):
        kl = k0.level(lvl)
        f = 2 ** lvl
        assert (kl.width, kl.height) == (k0.width // f, k0.height // f)
        down = cv2.resize(lvl0, (kl.width, kl.height), interpolation=cv2.INTER_AREA)
        err_right = np.mean(np.abs(down - _render_pinhole(kl, period)))
        # a half-pixel convention error would be clearly worse
        wrong = PinholeIntrinsics(kl.fx, kl.fy, k0.cx / f, k0.cy / f, kl.width, kl.height)
        err_wrong = np.mean(np.abs(down - _render_pinhole(wrong, period)))
        assert err_right < 3.0 and err_right < err_wrong, (lvl, err_right, err_wrong)


@pytest.mark.parametrize("cam", [FR1, Camera.pinhole(525.0, 525.0, 319.5, 239.5, 640, 480)], ids=["fr1", "pinhole"])
def test_depth_resampling_nearest_valid_without_blending(cam):
    rect = cam.rectifier(320)
    k = rect.intrinsics
    depth = np.full((cam.height, cam.width), 1.0, np.float32)
    depth[:, cam.width // 2:] = 3.0                       # a depth edge
    rng = np.random.default_rng(4)
    holes = rng.random(depth.shape) < 0.3                 # 30 % invalid pixels
    depth[holes] = 0.0
    depth[100:140, 100:140] = np.nan                      # NaN counts as invalid
    out = rect.depth(depth)
    assert out.dtype == np.float32 and out.shape == (k.height, k.width)
    vals = np.unique(out)
    assert set(vals.tolist()) <= {0.0, 1.0, 3.0}           # never a blend across the edge
    assert (out > 0).mean() > 0.95                          # holes are filled from valid neighbours
    # the edge lands where the geometry says: the column of the native edge, undistorted
    xy = cam.unproject(np.array([[cam.width // 2 - 0.5, cam.intrinsics.cy]]))
    u_edge = k.fx * xy[0, 0] + k.cx
    row = out[k.height // 2]
    cols = np.arange(k.width)
    assert np.all(row[(cols < u_edge - 1.5) & (row > 0)] == 1.0)
    assert np.all(row[(cols > u_edge + 1.5) & (row > 0)] == 3.0)
    # an all-invalid depth map stays invalid
    assert not rect.depth(np.zeros_like(depth)).any()


@pytest.mark.parametrize("cam", [FR1, EUROC, FISHEYE], ids=["fr1", "euroc", "fisheye"])
def test_colour_rectification_matches_the_grey_one_channel_by_channel(cam):
    """Keyframe colours are rectified in one uint8 pass; each channel must land where the grey image
    does (same geometry), within rounding."""
    grey = np.clip(np.rint(_render_distorted(cam)), 0, 255).astype(np.uint8)
    bgr = np.dstack([grey, 255 - grey, grey // 2])
    rect = cam.rectifier(320, multiple_of=16)
    out = rect.color(bgr)
    k = rect.intrinsics
    assert out.dtype == np.uint8 and out.shape == (k.height, k.width, 3)
    for c in range(3):
        ref = rect(np.ascontiguousarray(bgr[..., c]))
        assert np.abs(out[..., c].astype(np.float32) - ref).max() <= 1.0
    # the test can fail: a plain resize (ignoring the distortion) is far off
    naive = cv2.resize(bgr, (k.width, k.height), interpolation=cv2.INTER_AREA)
    assert np.abs(naive[..., 0].astype(np.float32) - rect(grey)).mean() > 5.0
    with pytest.raises(InputError, match="colour image of shape"):
        rect.color(bgr[:-1])


def test_colour_may_come_at_a_reduced_size_when_no_remap_is_needed(tmp_path):
    """Without distortion the keyframe colour can be a JPEG decoded at 1/2 (or 1/4) size: the result has
    the output size and matches the full-size path within a few grey levels; with distortion (a remap)
    or at a size that is not 1/r, the native size is required."""
    icl = Camera.pinhole(481.2, 480.0, 319.5, 239.5, 640, 480)
    rect = icl.rectifier(320, multiple_of=16)
    assert rect.color_reduction == 2 and FR1.rectifier(320).color_reduction == 1
    assert icl.rectifier(160, multiple_of=8).color_reduction == 4
    bgr = cv2.GaussianBlur((np.random.default_rng(4).random((480, 640, 3)) * 255).astype(np.uint8), (0, 0), 3)
    path = str(tmp_path / "f.jpg")
    cv2.imwrite(path, bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    full = rect.color(cv2.imread(path, cv2.IMREAD_COLOR))
    half = rect.color(cv2.imread(path, cv2.IMREAD_REDUCED_COLOR_2))
    assert half.shape == full.shape == (240, 320, 3) and half.dtype == np.uint8
    assert np.abs(half.astype(int) - full).mean() < 1.0
    quarter = icl.rectifier(160, multiple_of=8).color(cv2.imread(path, cv2.IMREAD_REDUCED_COLOR_2))
    assert quarter.shape == (120, 160, 3)
    with pytest.raises(InputError, match="colour image of shape"):
        rect.color(bgr[::3, ::3])
    with pytest.raises(InputError, match="colour image of shape"):
        FR1.rectifier(320).color(bgr[::2, ::2])


def test_rectifier_rejects_wrong_image_size():
    rect = FR1.rectifier(320)
    with pytest.raises(InputError, match="does not match the camera's 640x480"):
        rect(np.zeros((240, 320), np.uint8))
    with pytest.raises(InputError, match="depth image"):
        rect.depth(np.zeros((480, 641), np.float32))
    with pytest.raises(ConfigError, match="map_width 4 is too small"):
        FR1.rectifier(4)
    with pytest.raises(ConfigError, match="map_width 40 is too small for the 1226x370 camera: the 40x12 image"):
        KITTI.rectifier(40, multiple_of=16)
