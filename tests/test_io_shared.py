"""The four real sequences in ../shared/data open and iterate correctly (skipped when absent)."""
from __future__ import annotations

import numpy as np
import pytest

from data_helpers import require_shared
from lite_vo.io import open_sequence

pytestmark = pytest.mark.shared_data


def _iterate(seq, stride=1):
    frames = []
    for f in seq:
        if f.index % stride == 0:
            frames.append(f)
    return frames


def _check_common(seq, n, width, height):
    assert len(seq) == n
    assert (seq.camera.width, seq.camera.height) == (width, height)
    frames = _iterate(seq)
    assert len(frames) == n
    assert [f.index for f in frames] == list(range(n))
    t = np.array([f.timestamp for f in frames])
    assert np.all(np.diff(t) > 0)
    for f in frames[:: max(1, n // 5)]:
        assert f.image.shape == (height, width) and f.image.dtype == np.uint8
        assert 20 < f.image.mean() < 235 and f.image.std() > 10     # a real, non-blank picture
    return frames, t


def test_icl_livingroom():
    seq = open_sequence(require_shared("icl_livingroom_211"))
    frames, t = _check_common(seq, 211, 640, 480)
    np.testing.assert_allclose(np.diff(t), 1 / 30, atol=1e-5)
    assert seq.has_depth and seq.depth_scale == 1000.0
    for f in frames[::50]:
        d = f.depth
        assert d.dtype == np.float32 and d.shape == (480, 640)
        valid = d[d > 0]
        assert valid.size > 0.9 * d.size
        assert 0.3 < np.median(valid) < 6.0 and valid.max() < 15.0      # metres, indoor room
    gt = seq.groundtruth
    assert len(gt) == 211 and 3.0 < gt.path_length() < 4.5            # ~3.7 m
    assert seq.camera.model == "none"
    rect = seq.camera.rectifier(320)
    assert rect.size == (320, 240)
    assert rect.depth(frames[0].depth).max() < 15.0


def test_kitti07():
    seq = open_sequence(require_shared("kitti07_160"))
    frames, t = _check_common(seq, 160, 1226, 370)
    assert 0.09 < np.median(np.diff(t)) < 0.11                           # 10 Hz
    assert not seq.has_depth and all(f.depth is None for f in frames)
    gt = seq.groundtruth
    assert len(gt) == 160 and 80 < gt.path_length() < 100               # ~91 m
    rect = seq.camera.rectifier(320)
    out = rect(frames[0].image)
    assert out.shape == (96, 320) and out.dtype == np.float32


def test_tum_fr1_desk_first9():
    seq = open_sequence(require_shared("rgbd_dataset_freiburg1_desk_first9"))
    frames, t = _check_common(seq, 9, 640, 480)
    i = seq.camera.intrinsics
    assert (i.fx, i.fy, i.cx, i.cy) == (517.3, 516.5, 318.6, 255.3)     # Freiburg 1 from the folder name
    assert seq.camera.model == "radtan" and seq.camera.params[0] == 0.2624
    assert seq.depth_scale == 5000.0 and seq.has_depth
    assert all(f.depth is not None for f in frames)                     # every rgb has a depth within 0.02 s
    for f in frames:
        valid = f.depth[f.depth > 0]
        assert valid.size > 0.5 * f.depth.size
        assert 0.4 < np.median(valid) < 3.0 and valid.max() < 10.0
    gt = seq.groundtruth
    assert len(gt) == 2335
    assert gt.timestamps[0] < t[0] < t[-1] < gt.timestamps[-1]
    assert seq.accelerometer is None


def test_euroc_v101_static():
    seq = open_sequence(require_shared("euroc_v101_static95"))
    frames, t = _check_common(seq, 95, 752, 480)
    np.testing.assert_allclose(np.diff(t), 0.05, atol=1e-4)              # 20 Hz
    assert seq.camera.model == "radtan" and seq.camera.params[0] == pytest.approx(-0.28340811)
    gt = seq.groundtruth
    assert len(gt) == 933
    assert gt.timestamps[0] == pytest.approx(t[0] + 1.04, abs=0.05)    # starts ~1 s after the first image
    # the vehicle stands still while the images are taken: a few millimetres of motion
    during = (gt.timestamps >= t[0]) & (gt.timestamps <= t[-1])
    assert during.sum() > 500
    assert np.ptp(gt.positions_xyz[during], axis=0).max() < 0.01
    acc = seq.accelerometer
    assert acc is not None and len(acc) > 1000
    window = (acc.timestamps >= t[0]) & (acc.timestamps <= t[-1])
    a = acc.acc_xyz[window]
    assert abs(np.linalg.norm(a, axis=1).mean() - 9.81) < 0.15
    # in the camera frame, rotated into the world with the converted ground truth, the specific
    # force points up (+z in EuRoC's world): this checks T_world_cam = T_world_body @ T_body_cam
    # and the accelerometer conversion together
    R_world_cam = gt.poses[0][:3, :3]
    up = R_world_cam @ acc.at(gt.timestamps[0])
    assert up[2] > 9.5 and np.hypot(up[0], up[1]) < 1.0
    rect = seq.camera.rectifier(320)
    assert rect.size == (320, 192)
    out = rect(frames[0].image)
    assert out.min() >= 0 and out.max() <= 255 and out.std() > 10
