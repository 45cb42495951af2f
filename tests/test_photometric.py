"""Real cameras: photometric calibration, the blur score, the noise estimate, the brightness chain."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

import naive_tracking
from lite_vo.camera import PinholeIntrinsics
from lite_vo.errors import InputError
from lite_vo.geometry import exp_se3
from lite_vo.image import gradients, image_pyramid, sharpness
from lite_vo.photometric import (PhotometricCalibration, PhotometricMonitor, affine_transfer, compose_affine,
                                 load_photometric)
from lite_vo.tracking import Tracker, TrackingConfig, TrackingReference

INTR = PinholeIntrinsics(262.5, 262.5, 159.5, 119.5, 320, 240)


def _scene(seed=0):
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (120, 160)), (0, 0), 2.0)
    return (img - img.min()) / (img.max() - img.min())          # radiance 0..1


def _camera(radiance, exposure, vignette, response):
    """What a camera records: response(exposure * vignette * radiance), 8 bit."""
    return np.clip(np.rint(response(np.clip(exposure * vignette * radiance, 0, 1)) * 255), 0, 255).astype(np.uint8)


def test_correction_inverts_a_known_response_and_vignette(tmp_path):
    gamma = 1 / 2.2
    def response(x):
        return x ** gamma
    inv = 255.0 * (np.arange(256) / 255.0) ** (1 / gamma)           # G^-1 in DSO's format
    ys, xs = np.mgrid[0:120, 0:160]
    vig = 1.0 - 0.5 * (((xs - 79.5) ** 2 + (ys - 59.5) ** 2) / (79.5 ** 2 + 59.5 ** 2))
    (tmp_path / "pcalib.txt").write_text(" ".join(f"{v:.6f}" for v in inv))
    cv2.imwrite(str(tmp_path / "vignette.png"), np.rint(vig * 65535).astype(np.uint16))
    (tmp_path / "times.txt").write_text("0 0.0 10.0\n1 0.033333 5.0\n")
    cal = load_photometric(tmp_path)
    assert cal is not None and cal.exposure_at(0.0333331) == 5.0 and cal.exposure_at(0.5) is None
    rad = _scene()
    raw0 = _camera(rad, 0.9, vig, response)
    raw1 = _camera(rad, 0.45, vig, response)                          # half the exposure time
    c0 = cal.correct(raw0, cal.exposure_at(0.0))
    c1 = cal.correct(raw1, cal.exposure_at(0.033333))
    assert c0.dtype == np.float32
    ok = (raw0 > 10) & (raw0 < 250) & (raw1 > 10)                    # away from clipping and quantisation
    # corrected: proportional to the radiance, the same for both exposures, no vignette left
    expected = 255.0 * 0.9 * rad * cal.reference_exposure / 10.0
    np.testing.assert_allclose(c0[ok], expected[ok], rtol=0.06, atol=1.5)
    np.testing.assert_allclose(c1[ok], c0[ok], rtol=0.1, atol=3.0)
    # the raw image is far from that: the test would fail without the correction
    assert np.median(np.abs(raw0[ok] - expected[ok]) / expected[ok]) > 0.2


def test_loader_finds_files_beside_calib_and_reports_bad_input(tmp_path):
    assert load_photometric(None, tmp_path) is None                  # nothing there: no calibration
    (tmp_path / "pcalib.txt").write_text(" ".join(str(v) for v in range(256)))
    cal = load_photometric(None, tmp_path)
    assert cal is not None and cal.vignette is None
    img = np.arange(256, dtype=np.uint8).reshape(16, 16)
    np.testing.assert_allclose(cal.correct(img), img)                # identity response
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "pcalib.txt").write_text("1 2 3")
    with pytest.raises(InputError, match="256"):
        load_photometric(bad)
    (bad / "pcalib.txt").write_text(" ".join(str(255 - v) for v in range(256)))
    with pytest.raises(InputError, match="increase"):
        load_photometric(bad)
    with pytest.raises(InputError, match="not found"):
        load_photometric(tmp_path / "missing")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="pcalib"):
        load_photometric(empty)
    (empty / "vignette.png").write_text("not a png")
    with pytest.raises(InputError, match="vignette"):
        load_photometric(empty)
    (bad / "pcalib.txt").write_text(" ".join(str(v) for v in range(256)))
    (bad / "times.txt").write_text("0 0.0 abc\n")
    with pytest.raises(InputError, match=r"times.txt:1"):
        load_photometric(bad)
    cal = PhotometricCalibration(vignette=np.ones((4, 4)))
    with pytest.raises(InputError, match="vignette"):
        cal.correct(np.zeros((5, 5), np.uint8))


def test_blur_score_ranks_a_blurred_copy_lower():
    img, _ = naive_tracking.Room(seed=2).render(np.eye(4), INTR, supersample=2)

    def blur(px):
        return cv2.filter2D(img, -1, np.ones((1, px), np.float32) / px, borderType=cv2.BORDER_REFLECT)
    scores = [sharpness(img)] + [sharpness(blur(px)) for px in (3, 5, 7)]
    assert scores[0] > scores[1] > scores[2] > scores[3]                # more blur, lower score
    assert scores[3] < 0.7 * scores[0]
    # an exposure change is not blur: gain and offset leave the score unchanged
    assert sharpness(np.clip(0.6 * img + 10, 0, 255)) == pytest.approx(scores[0], rel=0.02)
    mon = PhotometricMonitor(blur_window=5)
    assert [mon.sharpness(img) for _ in range(4)] == pytest.approx([1.0] * 4)
    assert mon.sharpness(blur(7)) < 0.75                                # relative to the recent median
    assert np.isnan(sharpness(np.full((20, 20), 7.0)))


def test_noise_estimate_tracks_the_injected_sigma():
    room = naive_tracking.Room(seed=1, cell=0.05, depth=1.3, half_width=0.9, floor=0.5, ceiling=-0.6)
    img0, z0 = room.render(np.eye(4), INTR, supersample=2)
    T = exp_se3(np.array([0.01, 0.005, 0.0, 0.0, 0.01, 0.0]))
    img1, _ = room.render(T, INTR, supersample=2)
    gx, gy = gradients(img0)
    valid = np.hypot(gx, gy) >= 5
    rng = np.random.default_rng(3)
    est = {}
    for sigma in (0.0, 4.0, 8.0, 16.0):
        n0 = img0 + rng.normal(0, sigma, img0.shape).astype(np.float32)
        n1 = img1 + rng.normal(0, sigma, img1.shape).astype(np.float32)
        ref = TrackingReference.build(image_pyramid(n0, 5), 1 / z0, np.full_like(z0, 1e-6), valid, INTR, 0)
        res = Tracker(TrackingConfig(), INTR, 5, 1).track(ref, image_pyramid(n1, 5), np.eye(4))
        assert not res.lost
        est[sigma] = res.noise_sigma
    assert est[0.0] < 2.0                                   # the model error of a clean pair is small
    for sigma in (4.0, 8.0, 16.0):
        assert est[sigma] == pytest.approx(sigma, rel=0.35), est
    assert est[4.0] < est[8.0] < est[16.0]


def test_brightness_chain_and_monitor():
    a, b = affine_transfer((0.8, 10.0), (1.2, -5.0))
    J = np.array([0.0, 50.0, 200.0])
    np.testing.assert_allclose(a * (0.8 * J + 10.0) + b, 1.2 * J - 5.0)
    assert compose_affine((0.8, 10.0), (a, b)) == pytest.approx((1.2, -5.0))
    mon = PhotometricMonitor(noise_smoothing=0.5)
    assert mon.affine_guess((1.0, 0.0)) == (1.0, 0.0)
    assert mon.accept((0.5, 2.0), (1.1, 3.0), 2.0, 6.0) == pytest.approx((0.55, 5.2))
    assert mon.affine_guess((0.55, 5.2)) == pytest.approx((1.0, 0.0))
    mon.accept((0.55, 5.2), (1.0, 0.0), 4.0, 10.0)
    assert mon.noise_sigma == pytest.approx(8.0) and mon.residual_sigma == pytest.approx(3.0)
    assert mon.tracking_sigma(2.0, 1.0, 1.0) == pytest.approx(3.0)
    assert mon.tracking_sigma(2.0, 0.0, 1.0) == pytest.approx(2.0)
    assert mon.tracking_sigma(2.0, 0.0, 0.5) == pytest.approx(4.0)     # a blurred frame gets wider weights
