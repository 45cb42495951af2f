"""EuRoC mav0 reader: sensor.yaml parsing, frame conversions of IMU and ground truth, errors."""
from __future__ import annotations

import numpy as np
import pytest

from data_helpers import write_euroc_folder
from lite_vo.errors import InputError
from lite_vo.geometry import exp_so3, make_pose
from lite_vo.io import EurocSequence, open_sequence
from lite_vo.io.calib_formats import load_yaml

T_BS = make_pose(exp_so3(np.array([0.3, -0.2, 1.2])), np.array([0.05, -0.02, 0.01]))


def test_euroc_folder_and_mav0_itself(tmp_path):
    folder = write_euroc_folder(tmp_path, n=5, T_BS=T_BS)
    for p in (folder, folder / "mav0"):
        seq = open_sequence(p)
        assert isinstance(seq, EurocSequence) and seq.name == "euroc_seq"
        assert len(seq) == 5
        frames = list(seq)
        t = np.array([f.timestamp for f in frames])
        np.testing.assert_allclose(t - t[0], 0.05 * np.arange(5), atol=1e-6)   # ns -> s
        assert t[0] == pytest.approx(1403715273.262142976, abs=1e-6)
        assert frames[0].image.shape == (48, 64) and frames[0].depth is None
    cam = seq.camera
    assert cam.model == "radtan" and cam.params == (-0.1, 0.01, 0.0, 0.0, 0.0)
    assert cam.intrinsics.fx == 50.0 and cam.intrinsics.cx == 31.5


def test_euroc_imu_and_groundtruth_in_camera_frame(tmp_path):
    folder = write_euroc_folder(tmp_path, n=5, T_BS=T_BS)
    seq = open_sequence(folder)
    # accelerometer: body measures +9.81 along x; in the camera frame that is R_cam_body @ a_body
    expected = T_BS[:3, :3].T @ np.array([9.81, 0.0, 0.0])
    np.testing.assert_allclose(seq.accelerometer.acc_xyz, np.tile(expected, (20, 1)), atol=1e-9)
    # ground truth: T_world_cam = T_world_body @ T_body_cam
    gt = seq.groundtruth
    assert len(gt) == 10
    for k in range(10):
        T_world_body = make_pose(np.eye(3), np.array([0.01 * k, 0.0, 0.0]))
        np.testing.assert_allclose(gt.poses[k], T_world_body @ T_BS, atol=1e-9)
    np.testing.assert_allclose(np.diff(gt.timestamps), 0.025, atol=1e-6)


def test_opencv_style_yaml_read_with_pyyaml(tmp_path):
    # EuRoC's sensor.yaml starts with OpenCV's "%YAML:1.0", which is not valid YAML: it is skipped
    p = tmp_path / "s.yaml"
    p.write_text("%YAML:1.0\n# comment\nname: 'cam # not a comment'\nrate_hz: 20\n"
                 "T_BS:\n  cols: 4\n  rows: 4\n  data: [1, 0, 0, 0,\n    0, 1, 0, 0,   # trailing\n"
                 "    0, 0, 1, 0, 0, 0, 0, 1]\nresolution: [752, 480]\nempty_list: []\n")
    d = load_yaml(p)
    assert d["name"] == "cam # not a comment" and d["rate_hz"] == 20
    assert d["T_BS"]["rows"] == 4 and len(d["T_BS"]["data"]) == 16
    assert d["resolution"] == [752, 480] and d["empty_list"] == []
    p.write_text("%YAML:1.0\nresolution: [752, 480\nrate_hz: 20\n")
    with pytest.raises(InputError, match=r"s.yaml line \d+: not valid YAML"):
        load_yaml(p)


def _err(path) -> str:
    with pytest.raises(InputError) as ei:
        list(open_sequence(path))
    assert "\n" not in str(ei.value)
    return str(ei.value)


def test_euroc_missing_sensor_yaml(tmp_path):
    folder = write_euroc_folder(tmp_path)
    (folder / "mav0" / "cam0" / "sensor.yaml").unlink()
    msg = _err(folder)
    assert "sensor.yaml" in msg and "camera calibration not found" in msg


def test_euroc_distortion_models(tmp_path):
    folder = write_euroc_folder(tmp_path)
    y = folder / "mav0" / "cam0" / "sensor.yaml"
    text = y.read_text()
    y.write_text(text.replace("radial-tangential", "equidistant"))     # fisheye rigs: 4 coefficients
    cam = open_sequence(folder).camera
    assert cam.model == "equidistant" and cam.params == (-0.1, 0.01, 0.0, 0.0)
    y.write_text(text.replace("radial-tangential", "double-sphere"))
    msg = _err(folder)
    assert "sensor.yaml" in msg and "distortion_model 'double-sphere' is not supported" in msg


def test_euroc_bad_intrinsics(tmp_path):
    folder = write_euroc_folder(tmp_path)
    y = folder / "mav0" / "cam0" / "sensor.yaml"
    y.write_text(y.read_text().replace("intrinsics: [50.0, 50.0,", "intrinsics: [50.0,"))
    msg = _err(folder)
    assert "sensor.yaml" in msg and "intrinsics must have 4 values, got 3" in msg


def test_euroc_malformed_csv_line(tmp_path):
    folder = write_euroc_folder(tmp_path)
    csv = folder / "mav0" / "cam0" / "data.csv"
    lines = csv.read_text().splitlines()
    lines[2] = lines[2].replace(",", " ")
    csv.write_text("\n".join(lines) + "\n")
    msg = _err(folder)
    assert "data.csv line 3" in msg and "expected 'timestamp, filename'" in msg


def test_euroc_nan_in_groundtruth(tmp_path):
    folder = write_euroc_folder(tmp_path)
    csv = folder / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    lines = csv.read_text().splitlines()
    f = lines[4].split(",")
    f[5] = "nan"
    lines[4] = ",".join(f)
    csv.write_text("\n".join(lines) + "\n")
    msg = _err(folder)
    assert "state_groundtruth_estimate0" in msg and "line 5" in msg and "not finite" in msg


def test_euroc_non_increasing_imu(tmp_path):
    folder = write_euroc_folder(tmp_path)
    csv = folder / "mav0" / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    lines[3], lines[4] = lines[4], lines[3]
    csv.write_text("\n".join(lines) + "\n")
    msg = _err(folder)
    assert "imu0" in msg and "line 5" in msg and "strictly increasing" in msg


def test_euroc_image_of_wrong_size(tmp_path):
    folder = write_euroc_folder(tmp_path, width=64, height=48)
    y = folder / "mav0" / "cam0" / "sensor.yaml"
    y.write_text(y.read_text().replace("resolution: [64, 48]", "resolution: [752, 480]"))
    msg = _err(folder)
    assert "is 64x48 but the calibration says 752x480" in msg
