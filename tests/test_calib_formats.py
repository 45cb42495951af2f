"""Calibration formats: calib.txt, OpenCV FileStorage YAML, Kalibr camchain, ROS camera_info YAML
(and EuRoC sensor.yaml) parse to the same camera; errors name the file and the field."""
from __future__ import annotations

import re

import cv2
import numpy as np
import pytest

from data_helpers import write_image_folder
from lite_vo.camera import Camera
from lite_vo.errors import InputError
from lite_vo.io import Calibration, camera_from_ros, open_sequence, read_calibration, write_calib_txt

RADTAN = Camera.radtan(512.25, 509.5, 318.75, 241.125, 640, 480, -0.281, 0.0739, 0.00019, 1.76e-05, 0.0121)
FISHEYE = Camera.equidistant(380.5, 381.25, 322.0, 236.5, 640, 480, -0.0139, 0.0451, -0.0412, 0.0077)
PINHOLE = Camera.pinhole(525.0, 525.0, 319.5, 239.5, 640, 480)


def _ros_name(cam: Camera) -> str:
    return {"radtan": "plumb_bob", "equidistant": "equidistant", "none": "plumb_bob"}[cam.model]


def _kalibr_name(cam: Camera) -> str:
    return {"radtan": "radtan", "equidistant": "equidistant", "none": "none"}[cam.model]


def _list(vals) -> str:
    return "[" + ", ".join(repr(float(v)) for v in vals) + "]"


def write_opencv(path, cam: Camera):
    """As OpenCV's calibration sample writes it (cv2.FileStorage, !!opencv-matrix nodes)."""
    i = cam.intrinsics
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("calibration_time", "today")
    fs.write("image_width", i.width)
    fs.write("image_height", i.height)
    fs.write("camera_matrix", i.K)
    fs.write("distortion_coefficients", np.array([cam.params], dtype=np.float64).reshape(1, -1)
             if cam.params else np.zeros((1, 5)))
    if cam.model == "equidistant":
        fs.write("distortion_model", "equidistant")
    fs.write("avg_reprojection_error", 0.21)
    fs.release()
    return path


def write_kalibr(path, cam: Camera):
    i = cam.intrinsics
    path.write_text(
        "cam0:\n"
        "  cam_overlaps: [1]\n"
        "  camera_model: pinhole\n"
        f"  distortion_coeffs: {_list(cam.params[:4] if cam.model == 'radtan' else cam.params)}\n"
        f"  distortion_model: {_kalibr_name(cam)}\n"
        f"  intrinsics: {_list([i.fx, i.fy, i.cx, i.cy])}\n"
        f"  resolution: [{i.width}, {i.height}]\n"
        "  rostopic: /cam0/image_raw\n"
        "cam1:\n"
        "  camera_model: pinhole\n"
        "  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]\n"
        "  distortion_model: radtan\n"
        "  intrinsics: [100.0, 100.0, 50.0, 50.0]\n"
        "  resolution: [100, 100]\n"
        "  T_cn_cnm1:\n"
        "  - [1.0, 0.0, 0.0, 0.1]\n  - [0.0, 1.0, 0.0, 0.0]\n  - [0.0, 0.0, 1.0, 0.0]\n  - [0.0, 0.0, 0.0, 1.0]\n")
    return path


def write_ros(path, cam: Camera):
    """As ROS camera_calibration_parsers writes camera_info YAML."""
    i = cam.intrinsics
    d = list(cam.params) if cam.params else [0.0] * 5
    P = [i.fx, 0, i.cx, 0, 0, i.fy, i.cy, 0, 0, 0, 1, 0]
    path.write_text(
        f"image_width: {i.width}\nimage_height: {i.height}\ncamera_name: narrow_stereo\n"
        f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: {_list(i.K.ravel())}\n"
        f"distortion_model: {_ros_name(cam)}\n"
        f"distortion_coefficients:\n  rows: 1\n  cols: {len(d)}\n  data: {_list(d)}\n"
        "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
        f"projection_matrix:\n  rows: 3\n  cols: 4\n  data: {_list(P)}\n")
    return path


WRITERS = {"calib.txt": lambda p, c: write_calib_txt(p.with_suffix(".txt"), c), "opencv": write_opencv,
           "kalibr": write_kalibr, "ros": write_ros}


@pytest.mark.parametrize("cam", [RADTAN, FISHEYE, PINHOLE], ids=["radtan", "equidistant", "pinhole"])
def test_the_four_formats_parse_to_the_same_camera(tmp_path, cam):
    if cam.model == "radtan":           # Kalibr's radtan has no k3: write the camera without it
        cam = Camera(cam.intrinsics, "radtan", cam.params[:4])
    cams = {}
    for name, write in WRITERS.items():
        path = write(tmp_path / f"{name.replace('.', '_')}.yaml", cam)
        cal = read_calibration(path)
        assert isinstance(cal, Calibration) and str(path) in cal.source
        cams[name] = cal.camera
    for name, c in cams.items():
        assert c.model == cam.model, name
        assert c.intrinsics == cam.intrinsics, name
        np.testing.assert_allclose(c.params, cam.params, rtol=0, atol=1e-15, err_msg=name)
    # the cameras are the same lens: same projections
    pts = np.random.default_rng(0).uniform([-0.6, -0.45, 1.0], [0.6, 0.45, 3.0], (50, 3))
    ref = cam.project(pts)
    for c in cams.values():
        np.testing.assert_allclose(c.project(pts), ref, atol=1e-9)


def test_kalibr_uses_cam0_and_ros_message_dumps(tmp_path):
    cal = read_calibration(write_kalibr(tmp_path / "camchain-imucam.yaml", FISHEYE))
    assert cal.camera == FISHEYE and "cam0" in cal.source
    # `rostopic echo` (ROS 1: K, D, width) and ROS 2 (k, d) message dumps
    i = RADTAN.intrinsics
    p = tmp_path / "info.yaml"
    p.write_text(f"header:\n  frame_id: cam\nheight: {i.height}\nwidth: {i.width}\ndistortion_model: plumb_bob\n"
                 f"D: {_list(RADTAN.params)}\nK: {_list(i.K.ravel())}\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n")
    assert read_calibration(p).camera == RADTAN
    p.write_text(f"height: {i.height}\nwidth: {i.width}\ndistortion_model: rational_polynomial\n"
                 f"d: {_list(list(RADTAN.params) + [0, 0, 0])}\nk: {_list(i.K.ravel())}\n")
    assert read_calibration(p).camera == RADTAN


def test_euroc_sensor_yaml_reads_as_a_calibration(tmp_path):
    p = tmp_path / "sensor.yaml"
    p.write_text("%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n"
                 "  data: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]\n"
                 "resolution: [752, 480]\ncamera_model: pinhole\n"
                 "intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv\n"
                 "distortion_model: radial-tangential\n"
                 "distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n")
    cam = read_calibration(p).camera
    assert cam == Camera.radtan(458.654, 457.296, 367.215, 248.375, 752, 480,
                                -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)


def test_camera_from_ros():
    K = RADTAN.intrinsics.K.ravel().tolist()
    assert camera_from_ros(640, 480, "plumb_bob", K, RADTAN.params, "bag /cam/info") == RADTAN
    assert camera_from_ros(640, 480, "rational_polynomial", K, list(RADTAN.params) + [0.0] * 3, "b") == RADTAN
    assert camera_from_ros(640, 480, "equidistant", FISHEYE.intrinsics.K, FISHEYE.params, "b") == FISHEYE
    assert camera_from_ros(640, 480, "", PINHOLE.intrinsics.K.ravel(), [], "b") == PINHOLE
    assert camera_from_ros(640, 480, "plumb_bob", PINHOLE.intrinsics.K.ravel(), [0.0] * 5, "b") == PINHOLE
    with pytest.raises(InputError, match=r"^bag /cam/info: D: rational_polynomial with k4..k6 = 0.5, 0, 0 is not"):
        camera_from_ros(640, 480, "rational_polynomial", K, [0.1, 0, 0, 0, 0, 0.5, 0, 0], "bag /cam/info")
    with pytest.raises(InputError, match=r"^b: distortion_model 'omni' is not supported"):
        camera_from_ros(640, 480, "omni", K, [0.1], "b")
    with pytest.raises(InputError, match=r"^b: D: equidistant \(fisheye\) needs 4 coefficients"):
        camera_from_ros(640, 480, "equidistant", K, [0.1, 0.2, 0.0, 0.0, 0.0], "b")
    with pytest.raises(InputError, match=r"^b: width must be a positive integer"):
        camera_from_ros(0, 480, "plumb_bob", K, [], "b")


@pytest.mark.parametrize("fmt, edit, expect", [
    ("ros", ("data: [512.25", "data: [.nan"), r"ros.yaml: camera_matrix value 1 is nan"),
    ("ros", ("data: [512.25", "data: [-512.25"), r"ros.yaml: camera_matrix: focal length fx = -512.25 must be positive"),
    ("ros", ("image_width: 640", "image_width: 300"),
     r"ros.yaml: camera_matrix: principal point cx = 318.75 lies outside the image \(300x480"),
    ("ros", ("cols: 3\n  data: [512.25, 0.0, 318.75, 0.0, 509.5, 241.125, 0.0, 0.0, 1.0]",
             "cols: 3\n  data: [512.25, 0.0, 318.75, 0.0, 509.5, 241.125, 0.0, 0.0]"),
     r"ros.yaml: camera_matrix says 3x3 but has 8 values"),
    ("ros", ("distortion_model: plumb_bob", "distortion_model: omni"), r"ros.yaml: distortion_model 'omni' is not"),
    ("kalibr", ("camera_model: pinhole\n  distortion_coeffs", "camera_model: omni\n  distortion_coeffs"),
     r"kalibr.yaml cam0: camera_model 'omni' is not supported"),
    ("kalibr", ("resolution: [640, 480]", "resolution: [640]"), r"kalibr.yaml cam0: resolution must have 2 values"),
    ("kalibr", ("intrinsics: [512.25", "intrinsics: [nan"), r"kalibr.yaml cam0: intrinsics value 1 is nan"),
    ("kalibr", ("cam0:", "cam0: [1\n"), r"kalibr.yaml line \d+: not valid YAML"),
])
def test_bad_calibration_yaml_names_file_and_field(tmp_path, fmt, edit, expect):
    cam = Camera(RADTAN.intrinsics, "radtan", RADTAN.params[:4])
    path = WRITERS[fmt](tmp_path / f"{fmt}.yaml", cam)
    text = path.read_text()
    assert edit[0] in text
    path.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(InputError) as ei:
        read_calibration(path)
    msg = str(ei.value)
    assert "\n" not in msg
    assert re.search(expect, msg), msg


def test_bad_opencv_yaml_and_unknown_layouts(tmp_path):
    p = write_opencv(tmp_path / "cv.yaml", RADTAN)
    p.write_text(p.read_text().replace("image_width: 640", "image_width: -640"))
    with pytest.raises(InputError, match=r"cv.yaml: image_width must be a positive integer, got -640"):
        read_calibration(p)
    p.write_text("%YAML:1.0\ncamera_matrix: !!opencv-matrix\n  rows: 3\n cols: 3\n")
    with pytest.raises(InputError, match=r"cv.yaml: OpenCV cannot parse this YAML"):
        read_calibration(p)
    q = tmp_path / "other.yaml"
    q.write_text("fx: 500\nfy: 500\n")
    with pytest.raises(InputError, match=r"other.yaml: not a calibration file this reader knows"):
        read_calibration(q)
    with pytest.raises(InputError, match=r"nope.yaml: calibration file not found"):
        read_calibration(tmp_path / "nope.yaml")


def test_calib_txt_equidistant_and_errors(tmp_path):
    p = write_calib_txt(tmp_path / "calib.txt", FISHEYE)
    assert "model equidistant" in p.read_text()
    assert read_calibration(p).camera == FISHEYE
    p.write_text("model equidistant\n380 380 320 240 0.1 0.2 0.3\n640 480\n")
    with pytest.raises(InputError, match=r"calib.txt line 2: model equidistant expects 'fx fy cx cy k1 k2 k3 k4'"):
        read_calibration(p)
    p.write_text("500 500 900 240\n640 480\n")
    with pytest.raises(InputError, match=r"calib.txt line 1: principal point cx = 900 lies outside the 640x480"):
        read_calibration(p)


@pytest.mark.parametrize("fmt", list(WRITERS))
def test_open_sequence_takes_any_format_for_a_folder_without_calib_txt(tmp_path, fmt):
    folder = write_image_folder(tmp_path, n=3, width=64, height=48, calib=False)
    cam = Camera.radtan(50.0, 50.0, 31.5, 23.5, 64, 48, -0.1, 0.01, 0.0, 0.0)
    path = WRITERS[fmt](tmp_path / f"c_{fmt.replace('.', '_')}.yaml", cam)
    seq = open_sequence(folder, calib=path)
    assert seq.camera == cam and len(list(seq)) == 3
    # a calibration of another size is an error at open time naming both files
    big = WRITERS[fmt](tmp_path / f"big_{fmt.replace('.', '_')}.yaml",
                       Camera.radtan(500.0, 500.0, 319.5, 239.5, 640, 480, -0.1, 0.01, 0.0, 0.0))
    with pytest.raises(InputError) as ei:
        open_sequence(folder, calib=big)
    msg = str(ei.value)
    assert "img1.png: image is 64x48 but the calibration says 640x480" in msg and big.stem in msg
