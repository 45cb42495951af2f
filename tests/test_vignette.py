"""Vignetting estimated from a run's own maps (lite_vo.vignette, ``lite-vo run --estimate-vignette``)."""
from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import shared_sequence

from lite_vo.camera import Camera, PinholeIntrinsics
from lite_vo.errors import InputError
from lite_vo.photometric import load_photometric
from lite_vo.session import PublishedMap
from lite_vo.vignette import (MAX_FRAME_GAP, PairSamples, correspondences, fit_problem, fit_vignette, radial_frame,
                              radius2, vignette_image, vignette_of, write_vignette)

W, H = 320, 240
MAP_CAM = PinholeIntrinsics(250.0, 250.0, 159.5, 119.5, W, H)     # the map of a 640x480 camera, f = 500
FRAME = radial_frame(MAP_CAM)


def _pairs(k_true, n_pairs=30, n=2000, seed=0, outliers=0.1):
    """Correspondences of a camera with vignette ``k_true`` moving over a random scene: every pair has
    its own exposure change (a, b), Gaussian noise of 3 grey levels and a share of gross outliers."""
    rng = np.random.default_rng(seed)
    pairs = []
    for _ in range(n_pairs):
        x, y = rng.uniform(2, W - 3, n), rng.uniform(2, H - 3, n)
        shift = rng.normal(0, 15, 2)
        xu, yu = np.clip(x + shift[0], 1, W - 2), np.clip(y + shift[1], 1, H - 2)
        radiance = rng.uniform(20, 200, n)
        a, b = rng.uniform(0.7, 1.3), rng.uniform(-10, 10)
        r2o, r2n = radius2(x, y, FRAME), radius2(xu, yu, FRAME)
        i_old = vignette_of(k_true, r2o) * radiance
        i_new = a * vignette_of(k_true, r2n) * radiance + b + rng.normal(0, 3, n)
        bad = rng.random(n) < outliers
        i_new[bad] += rng.normal(0, 50, int(bad.sum()))
        pairs.append(PairSamples(r2o, r2n, i_old, i_new, np.full(n, 1 / 9.0)))
    return pairs


@pytest.mark.parametrize("k_true, corner", [((-0.5, 0.0, 0.0), 0.5), ((-0.2, -0.2, 0.1), 0.7), ((0.0, 0.0, 0.0), 1.0)])
def test_fit_recovers_a_known_vignette_despite_exposure_changes_and_outliers(k_true, corner):
    fit = fit_vignette(_pairs(np.array(k_true)), FRAME)
    assert abs(fit.corner - corner) < 0.01
    assert fit.corner_std < 0.01
    r2 = np.linspace(0, 1, 11)
    np.testing.assert_allclose(vignette_of(fit.k, r2), vignette_of(np.array(k_true), r2), atol=0.015)
    assert fit.pairs == 30 and fit.samples == 60000
    assert 2.0 < fit.residual_rms < 4.0                   # the inliers' noise (3 grey levels), outliers left out


def test_radial_frame_is_centred_on_the_principal_point():
    cx, cy, r2max = radial_frame(PinholeIntrinsics(250.0, 250.0, 100.0, 119.5, W, H))
    assert (cx, cy) == (100.0, 119.5) and r2max == pytest.approx(219.0 ** 2 + 119.5 ** 2)   # farthest: the right corners
    assert radius2(np.array([100.0, 319.0]), np.array([119.5, 0.0]), (cx, cy, r2max)) == pytest.approx([0.0, 1.0])


def test_fit_leaves_out_pairs_whose_points_do_not_correspond():
    """A pair from a re-initialised map (another scale: its points land elsewhere) agrees with nothing."""
    pairs = _pairs(np.array([-0.5, 0.0, 0.0]))
    rng = np.random.default_rng(5)
    for p in pairs[:3]:
        p.i_new[:] = rng.permutation(p.i_new)
    fit = fit_vignette(pairs, FRAME)
    assert fit.pairs == 27 and abs(fit.corner - 0.5) < 0.01


def test_a_camera_that_does_not_move_across_the_image_gives_no_vignette():
    """Points that stay at their radius carry nothing about the vignette: the fit is too uncertain
    and is rejected; so is a fit whose corners come out brighter than the centre."""
    pairs = _pairs(np.array([-0.5, 0.0, 0.0]))
    for p in pairs:
        p.r2_new[:] = p.r2_old * (1 + 1e-4)                # hardly any motion
        p.i_new[:] = p.i_old * 1.1 + 3.0 + np.random.default_rng(0).normal(0, 3, len(p.i_old))
    assert "too uncertain" in fit_problem(fit_vignette(pairs, FRAME))
    bright = fit_vignette(_pairs(np.array([0.3, 0.0, 0.0])), FRAME)
    assert bright.corner > 1.2 and "do not fit a lens vignette" in fit_problem(bright)
    assert fit_problem(fit_vignette(_pairs(np.array([-0.5, 0.0, 0.0])), FRAME)) is None


def test_fit_needs_enough_pairs():
    with pytest.raises(InputError, match="usable pairs"):
        fit_vignette(_pairs(np.array([-0.5, 0.0, 0.0]), n_pairs=2), FRAME)


def _published(index, T_world_cam, image, idepth):
    cam = PinholeIntrinsics(250.0, 250.0, 159.5, 119.5, W, H)
    valid = np.isfinite(idepth)
    return PublishedMap(index, index / 30.0, T_world_cam, cam, image.astype(np.float32),
                        np.where(valid, idepth, 0).astype(np.float32), np.full((H, W), 1e-3, np.float32), valid)


def test_correspondences_follow_the_geometry_and_skip_unusable_pairs():
    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur(rng.uniform(20, 230, (H, W)), (0, 0), 3.0)
    idepth = np.full((H, W), np.nan)
    idepth[::4, ::4] = 0.5                                # a fronto-parallel plane 2 m away
    old = _published(10, np.eye(4), image, idepth)
    T = np.eye(4)
    T[0, 3] = 0.04                                        # the camera moves 4 cm to the right
    # the scene moves 250 * 0.04 * 0.5 = 5 px to the left in the new image: shift the image with it
    shifted = np.roll(image, -5, axis=1)
    new = _published(14, T, shifted, idepth)
    p = correspondences(old, new)
    assert p is not None and len(p.i_old) > 1000
    v, u = np.nonzero(np.isfinite(idepth))
    inside = (u - 5 >= 1) & (u - 5 < W - 2) & (v >= 1) & (v < H - 2)
    np.testing.assert_allclose(np.sort(p.r2_new), np.sort(radius2(u[inside] - 5.0, v[inside] * 1.0, FRAME)[
        (image[v[inside], u[inside]] < 250)]), atol=1e-9)
    np.testing.assert_allclose(p.i_new, p.i_old, atol=1e-3)      # the same scene point, the same brightness
    assert np.all(p.weight > 0) and np.all(p.weight <= 1 / 9.0 + 1e-12)
    # pairs that are not consecutive maps of one run: too far apart, backwards, or other image sizes
    assert correspondences(old, _published(10 + MAX_FRAME_GAP, T, shifted, idepth)) is None
    assert correspondences(new, old) is None
    few = np.full((H, W), np.nan)
    few[100, 100:110] = 0.5
    assert correspondences(_published(10, np.eye(4), image, few), _published(11, T, shifted, few)) is None


def test_vignette_image_at_native_resolution_and_roundtrip_through_dsos_format(tmp_path):
    fit = fit_vignette(_pairs(np.array([-0.5, 0.0, 0.0])), FRAME)
    cam = Camera.pinhole(500.0, 500.0, 319.5, 239.5, 640, 480)
    v = vignette_image(fit, cam, MAP_CAM)
    assert v.shape == (480, 640) and abs(v.max() - 1.0) < 1e-12
    assert abs(v[240, 320] - 1.0) < 1e-3 and abs(v[0, 0] - fit.corner) < 0.01
    path = write_vignette(tmp_path, fit, cam, MAP_CAM)
    cal = load_photometric(tmp_path)                      # what --photometric DIR reads
    np.testing.assert_allclose(cal.vignette, v, atol=2e-5)
    assert json.loads((tmp_path / "vignette.json").read_text())["corner"] == pytest.approx(fit.corner)
    # a vignette the run already corrected with is multiplied in
    given = np.full((480, 640), 1.0)
    given[:, :320] = 0.8
    write_vignette(tmp_path, fit, cam, MAP_CAM, given)
    both = load_photometric(tmp_path).vignette
    np.testing.assert_allclose(both[240, 320], 1.0, atol=1e-3)
    np.testing.assert_allclose(both[240, 160] / both[240, 480], 0.8 * v[240, 160] / v[240, 480], atol=1e-3)
    assert path.name == "vignette.png"


def test_vignette_image_follows_the_lens_model():
    """With lens distortion a native pixel is undistorted and projected with the map's intrinsics:
    the vignette of a native pixel is the fit's value at that rectified position."""
    fit = fit_vignette(_pairs(np.array([-0.5, 0.0, 0.0])), FRAME)
    cam = Camera.radtan(500.0, 500.0, 319.5, 239.5, 640, 480, -0.2, 0.05, 0.0, 0.0)
    map_cam = PinholeIntrinsics(230.0, 230.0, 159.5, 119.5, W, H)       # as a rectifier that crops would choose
    v = vignette_image(fit, cam, map_cam)
    peak = vignette_of(fit.k, np.array(0.0))
    for x, y in ((0, 0), (639, 0), (100, 300), (319, 239), (600, 470)):
        ray = cam.unproject(np.array([[x, y]], np.float64))[0]
        r2 = radius2(map_cam.fx * ray[0] + map_cam.cx, map_cam.fy * ray[1] + map_cam.cy, FRAME)
        assert v[y, x] == pytest.approx(vignette_of(fit.k, r2) / peak, abs=1e-5)   # peak: between pixels
    diag = v[np.arange(239, 0, -10), np.arange(319, 0, -(320 // 24))[:24]]
    assert np.all(np.diff(diag) < 0)                     # darker towards the corner
    assert not np.allclose(v, vignette_image(fit, Camera.pinhole(500.0, 500.0, 319.5, 239.5, 640, 480), MAP_CAM),
                           atol=0.01)                     # the lens model matters


def _vignetted_copy(src: Path, dst: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
    from augment import vignette_map
    shutil.copytree(src, dst)
    for f in sorted((dst / "rgb").iterdir()):
        img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        v = vignette_map(*img.shape[:2])
        cv2.imwrite(str(f), np.clip(np.rint(img * (v[..., None] if img.ndim == 3 else v)), 0, 255).astype(np.uint8))


def test_run_estimates_the_vignette_of_a_vignetted_sequence(synth_small, tmp_path, capsys):
    """``lite-vo run --estimate-vignette`` on the synthetic room darkened to 50 % in the corners
    writes a vignette.png that --photometric reads; a run too short for an estimate writes none."""
    from lite_vo.cli.main import main
    seq = tmp_path / "vig"
    _vignetted_copy(synth_small, seq)
    out = tmp_path / "out"
    assert main(["run", str(seq), "--out", str(out), "--quiet", "--mode", "sync", "--estimate-vignette"]) == 0
    said = capsys.readouterr().out
    fit = json.loads((out / "vignette.json").read_text())
    assert abs(fit["corner"] - 0.5) < 0.08 and fit["pairs"] >= 8       # 0.54 here; 1.0 without the estimate
    assert f"--photometric {out}" in said
    cal = load_photometric(out)
    assert cal.vignette.shape == (240, 320) and abs(cal.vignette[0, 0] - fit["corner"]) < 0.02
    # the same from Python: the sink among a Session's sinks (a sync run is deterministic: the same fit)
    import lite_vo
    from lite_vo.vignette import VignetteSink
    opened = lite_vo.open_sequence(seq)
    sink = VignetteSink(tmp_path / "api", opened.camera)
    (tmp_path / "api").mkdir()
    lite_vo.Session(opened, lite_vo.load_profile("phone", ['system.mode="sync"']), sinks=[sink]).run()
    assert sink.fit.corner == pytest.approx(fit["corner"], abs=1e-12)
    assert (tmp_path / "api" / "vignette.png").exists()
    short = tmp_path / "short"
    assert main(["run", str(seq), "--out", str(short), "--quiet", "--mode", "sync", "--estimate-vignette",
                 "--max-frames", "8"]) == 0
    assert not (short / "vignette.png").exists() and "vignette: not written: " in capsys.readouterr().out
    assert json.loads((short / "vignette.json").read_text())["written"] is False
    # a run that had a calibration: the folder it writes is the whole calibration (response kept)
    cal_dir = tmp_path / "cal"
    cal_dir.mkdir()
    inverse = 255.0 * (np.arange(256) / 255.0) ** 1.5
    (cal_dir / "pcalib.txt").write_text(" ".join(f"{v:.6f}" for v in inverse))
    second = tmp_path / "second"
    assert main(["run", str(seq), "--out", str(second), "--quiet", "--mode", "sync", "--estimate-vignette",
                 "--photometric", str(cal_dir)]) == 0
    capsys.readouterr()
    both = load_photometric(second)
    np.testing.assert_allclose(both.inverse_response, load_photometric(cal_dir).inverse_response, atol=1e-4)
    assert both.vignette is not None and both.vignette[0, 0] < 0.7


def test_a_camera_standing_still_writes_no_vignette(tmp_path, capsys):
    """EuRoC V1_01's first 95 frames: the vehicle stands still, nothing crosses the image."""
    from lite_vo.cli.main import main
    seq = shared_sequence("euroc_v101_static95")
    out = tmp_path / "out"
    assert main(["run", str(seq), "--out", str(out), "--quiet", "--estimate-vignette"]) == 0
    said = capsys.readouterr().out
    record = json.loads((out / "vignette.json").read_text())
    assert not (out / "vignette.png").exists() and record["written"] is False
    assert "too uncertain" in record["reason"] and "vignette: not written: " in said
