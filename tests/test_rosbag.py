"""ROS bags (lite_vo.io.rosbag): bags written in the test with rosbags (ROS 1 and ROS 2, sqlite3
and MCAP) read back through ``open_sequence``: encodings, CompressedImage, CameraInfo -> camera,
topic selection, IMU -> accelerometer, header stamps."""
from __future__ import annotations

import sys

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="the [ros] extra (rosbags) is not installed")

from lite_vo.camera import Camera  # noqa: E402
from lite_vo.errors import InputError, MissingExtraError  # noqa: E402
from lite_vo.io import open_sequence  # noqa: E402
from lite_vo.io.rosbag import BagWriter, RosbagSequence  # noqa: E402

W, H = 64, 48
CAM = Camera.radtan(60.0, 61.0, 31.5, 23.5, W, H, -0.1, 0.02, 0.001, -0.002, 0.003)


def _images(n, seed=0, channels=None):
    rng = np.random.default_rng(seed)
    shape = (H, W) if channels is None else (H, W, channels)
    return [rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(n)]


def _grey_rgb(rgb):
    """ITU-R 601 luma, computed here independently of OpenCV's colour conversion."""
    r, g, b = (rgb[..., k].astype(np.float64) for k in range(3))
    return 0.299 * r + 0.587 * g + 0.114 * b


def _write(path, images, encoding="mono8", compressed=None, ros2=False, storage="sqlite3",
           topic="/cam/image_raw", times=None, camera=CAM):
    times = np.arange(len(images)) / 20.0 + 100.0 if times is None else times
    with BagWriter(path, ros2=ros2, storage=storage) as w:
        for t, img in zip(times, images):
            if camera is not None:
                w.camera_info(topic.rsplit("/", 1)[0] + "/camera_info", t, camera)
            w.image(topic + ("/compressed" if compressed else ""), t, img, encoding, compressed)
    return times


def _header(w, sec, nanosec, seq=0):
    T = w.typestore.types
    stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    if w.ros2:
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id="cam")
    return T["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id="cam")


def _raw_image(w, header, img_bytes, h, wd, encoding, step, bigendian=0):
    return w.typestore.types["sensor_msgs/msg/Image"](
        header=header, height=h, width=wd, encoding=encoding, is_bigendian=bigendian, step=step,
        data=np.frombuffer(bytes(img_bytes), np.uint8))


@pytest.mark.parametrize("ros2,storage", [(False, None), (True, "sqlite3"), (True, "mcap")])
def test_mono8_round_trip_with_camera_info(tmp_path, ros2, storage):
    imgs = _images(5)
    path = tmp_path / ("rec" if ros2 else "rec.bag")
    times = _write(path, imgs, ros2=ros2, storage=storage or "sqlite3")
    seq = open_sequence(path)
    assert isinstance(seq, RosbagSequence) and len(seq) == 5 and seq.name == "rec"
    assert seq.topic == "/cam/image_raw" and seq.camera_info_topic == "/cam/camera_info"
    assert seq.camera == CAM and seq.accelerometer is None and not seq.has_depth
    frames = list(seq)
    assert [f.index for f in frames] == list(range(5))
    assert [f.timestamp for f in frames] == list(times)
    for f, img in zip(frames, imgs):
        assert f.image.dtype == np.uint8 and np.array_equal(f.image, img)
    assert np.array_equal(seq.frame(3).image, imgs[3]) and seq.frame(-1).timestamp == times[-1]
    seq.close()


def test_ros2_folder_opened_through_its_storage_file(tmp_path):
    _write(tmp_path / "rec", _images(2), ros2=True, storage="mcap")
    storage_file = next((tmp_path / "rec").glob("*.mcap"))
    assert len(open_sequence(storage_file)) == 2


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8"])
def test_colour_encodings_become_luma(tmp_path, encoding):
    imgs = _images(2, seed=1, channels=3)
    _write(tmp_path / "c.bag", imgs, encoding=encoding)
    for f, img in zip(open_sequence(tmp_path / "c.bag"), imgs):
        rgb = img if encoding == "rgb8" else img[..., ::-1]
        assert np.abs(f.image - _grey_rgb(rgb)).max() <= 1.0


def test_mono16_little_and_big_endian_with_row_padding(tmp_path):
    imgs = _images(2, seed=2)
    path = tmp_path / "m16.bag"
    _write(path, [i.astype(np.uint16) * 257 for i in imgs], encoding="mono16")
    assert all(np.array_equal(f.image, i) for f, i in zip(open_sequence(path), imgs))
    # hand-made messages: big-endian 16-bit values and 6 padding bytes at the end of every row
    path = tmp_path / "m16be.bag"
    with BagWriter(path) as w:
        w.camera_info("/cam/camera_info", 1.0, CAM)
        for k, img in enumerate(imgs):
            rows = np.zeros((H, 2 * W + 6), np.uint8)
            rows[:, :2 * W] = (img.astype(np.uint16) * 257).astype(">u2").view(np.uint8).reshape(H, 2 * W)
            w.write_message("/cam/image_raw", _raw_image(w, _header(w, 1, k + 1), rows.tobytes(), H, W,
                                                         "mono16", 2 * W + 6, bigendian=1), 10 ** 9 + k)
    assert all(np.array_equal(f.image, i) for f, i in zip(open_sequence(path), imgs))


@pytest.mark.parametrize("fmt,ros2", [("png", False), ("jpeg", True)])
def test_compressed_images(tmp_path, fmt, ros2):
    rng = np.random.default_rng(3)
    # smooth images so that JPEG stays close to the original
    yy, xx = np.mgrid[0:H, 0:W]
    imgs = [np.clip(np.stack([xx * 3 + 10 * k, yy * 4, 255 - xx * 2], -1) + rng.integers(0, 3, (H, W, 3)), 0, 255
                    ).astype(np.uint8) for k in range(3)]
    path = tmp_path / ("z" if ros2 else "z.bag")
    _write(path, imgs, encoding="rgb8", compressed=fmt, ros2=ros2)
    seq = open_sequence(path)
    assert seq.topic == "/cam/image_raw/compressed" and seq.camera_info_topic == "/cam/camera_info"
    for f, img in zip(seq, imgs):
        err = np.abs(f.image - _grey_rgb(img))
        assert err.max() <= 1.0 if fmt == "png" else err.mean() < 3.0


def test_topic_auto_detection_skips_depth_and_lists_several_candidates(tmp_path):
    path = tmp_path / "rgbd.bag"
    imgs = _images(2, seed=4)
    with BagWriter(path) as w:
        for k, img in enumerate(imgs):
            w.camera_info("/cam/rgb/camera_info", 1.0 + k, CAM)
            w.image("/cam/rgb/image_mono", 1.0 + k, img, "mono8")
            w.write_message("/cam/depth/image", _raw_image(w, _header(w, 1 + k, 0), np.zeros(H * W * 2, np.uint8),
                                                           H, W, "16UC1", 2 * W), (1 + k) * 10 ** 9)
    seq = open_sequence(path)
    assert seq.topic == "/cam/rgb/image_mono" and seq.camera_info_topic == "/cam/rgb/camera_info"

    path = tmp_path / "two.bag"
    with BagWriter(path) as w:
        w.camera_info("/left/camera_info", 1.0, CAM)
        w.camera_info("/right/camera_info", 1.0, CAM)
        w.image("/left/image_raw", 1.0, imgs[0], "mono8")
        w.image("/right/image_raw", 1.0, imgs[1], "mono8")
    with pytest.raises(InputError, match=r"several image topics: /left/image_raw, /right/image_raw; .*topic="):
        open_sequence(path)
    right = open_sequence(path, topic="/right/image_raw")
    assert right.camera_info_topic == "/right/camera_info"
    assert np.array_equal(next(iter(right)).image, imgs[1])
    with pytest.raises(InputError, match=r"no topic '/nope'.*image topics: /left/image_raw, /right/image_raw"):
        open_sequence(path, topic="/nope")
    with pytest.raises(InputError, match="not an image"):
        open_sequence(path, topic="/left/camera_info")


def test_camera_info_matching_and_calib_override(tmp_path):
    path = tmp_path / "noinfo.bag"
    _write(path, _images(2), topic="/a/b/image_raw", camera=None)
    with pytest.raises(InputError, match=r"no sensor_msgs/CameraInfo for /a/b/image_raw.*/a/b/camera_info.*calib"):
        open_sequence(path)
    other = Camera.pinhole(50, 50, 32, 24, W, H)
    assert open_sequence(path, other).camera == other
    # a CameraInfo one namespace up is found; a wrong size is caught when opening
    path = tmp_path / "up.bag"
    with BagWriter(path) as w:
        w.camera_info("/a/camera_info", 1.0, Camera.pinhole(50, 50, 40, 30, 80, 60))
        w.image("/a/b/image_raw", 1.0, _images(1)[0], "mono8")
    with pytest.raises(InputError, match=r"image is 64x48 but the calibration says 80x60"):
        open_sequence(path)


def test_camera_info_conversion_errors(tmp_path):
    def bag_with_info(name, model, D, K=(60, 0, 31.5, 0, 61, 23.5, 0, 0, 1)):
        path = tmp_path / name
        with BagWriter(path) as w:
            T = w.typestore.types
            roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
            info = T["sensor_msgs/msg/CameraInfo"](
                header=_header(w, 1, 0), height=H, width=W, distortion_model=model, D=np.asarray(D, float),
                K=np.asarray(K, float), R=np.eye(3).ravel(), P=np.zeros(12), binning_x=0, binning_y=0, roi=roi)
            w.write_message("/cam/camera_info", info, 10 ** 9)
            w.image("/cam/image_raw", 1.0, _images(1)[0], "mono8")
        return path
    fish = open_sequence(bag_with_info("fish.bag", "equidistant", [0.1, 0.01, 0.0, 0.0])).camera
    assert fish.model == "equidistant" and fish.params == (0.1, 0.01, 0.0, 0.0)
    with pytest.raises(InputError, match="camera_info: K: not a camera matrix"):
        open_sequence(bag_with_info("zero.bag", "plumb_bob", [0] * 5, K=[0] * 9))
    cam = open_sequence(bag_with_info("rp.bag", "rational_polynomial", [-0.1, 0.02, 0.001, 0, 0.003, 0, 0, 0])).camera
    assert cam.model == "radtan" and cam.params == (-0.1, 0.02, 0.001, 0.0, 0.003)
    assert open_sequence(bag_with_info("pin.bag", "plumb_bob", [])).camera == Camera.pinhole(60, 61, 31.5, 23.5, W, H)


@pytest.mark.parametrize("ros2", [False, True])
def test_imu_becomes_the_accelerometer(tmp_path, ros2):
    path = tmp_path / ("imu" if ros2 else "imu.bag")
    rng = np.random.default_rng(5)
    t_imu = 100.0 + np.arange(30) / 200.0
    acc = rng.normal(0, 1, (30, 3)) + [0, -9.81, 0]
    with BagWriter(path, ros2=ros2) as w:
        for t, a in zip(t_imu, acc):
            if t in (100.0, 100.05):
                w.camera_info("/cam/camera_info", t, CAM)
                w.image("/cam/image_raw", t, _images(1)[0], "mono8")
            w.imu("/cam/imu", t, a)
    seq = open_sequence(path)
    assert seq.imu_topic == "/cam/imu" and len(seq.accelerometer) == 30
    np.testing.assert_allclose(seq.accelerometer.timestamps, t_imu, rtol=0, atol=1e-9)
    np.testing.assert_allclose(seq.accelerometer.acc_xyz, acc, rtol=0, atol=1e-12)


def test_header_stamps_and_bag_time_fallback(tmp_path):
    path = tmp_path / "stamps.bag"
    imgs = _images(3)
    with BagWriter(path) as w:
        w.camera_info("/cam/camera_info", 0.0, CAM)
        # header stamps 5.25 s and 5.5 s while the bag (receive) times are 7 s later; stamp 0 -> bag time
        for k, (sec, ns, bag) in enumerate([(5, 250_000_000, 12_250_000_000), (5, 500_000_000, 12_500_000_000),
                                            (0, 0, 12_750_000_000)]):
            w.write_message("/cam/image_raw", _raw_image(w, _header(w, sec, ns, k), imgs[k].tobytes(), H, W,
                                                         "mono8", W), bag)
    seq = open_sequence(path)
    assert list(seq.timestamps) == [5.25, 5.5, 12.75]
    assert [f.timestamp for f in seq] == [5.25, 5.5, 12.75]

    path = tmp_path / "backwards.bag"
    with BagWriter(path) as w:
        w.camera_info("/cam/camera_info", 0.0, CAM)
        for k, sec in enumerate([5, 4]):
            w.write_message("/cam/image_raw", _raw_image(w, _header(w, sec, 0, k), imgs[k].tobytes(), H, W,
                                                         "mono8", W), (10 + k) * 10 ** 9)
    with pytest.raises(InputError, match=r"/cam/image_raw frame 1: header stamp 4\.0+ s is not after"):
        open_sequence(path)


def test_bad_bags_are_one_line_errors(tmp_path):
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"this is not a bag\n" * 10)
    with pytest.raises(InputError, match=r"junk\.bag: cannot read ROS bag") as err:
        open_sequence(junk)
    assert "\n" not in str(err.value)
    path = tmp_path / "enc.bag"
    with BagWriter(path) as w:
        w.camera_info("/cam/camera_info", 1.0, CAM)
        w.write_message("/cam/image_raw", _raw_image(w, _header(w, 1, 0), bytes(H * W * 2), H, W, "yuv422", 2 * W),
                        10 ** 9)
    with pytest.raises(InputError, match=r"frame 0: unsupported image encoding 'yuv422'"):
        open_sequence(path)
    with pytest.raises(InputError, match="ROS bags only"):
        open_sequence(tmp_path, topic="/cam/image_raw")


def test_without_rosbags_opening_a_bag_names_the_extra(tmp_path, monkeypatch):
    path = tmp_path / "rec.bag"
    _write(path, _images(1))
    for mod in [m for m in sys.modules if m == "rosbags" or m.startswith("rosbags.")]:
        monkeypatch.setitem(sys.modules, mod, None)
    monkeypatch.setitem(sys.modules, "rosbags", None)
    with pytest.raises(MissingExtraError, match=r"pip install 'lite-vo\[ros\]'"):
        open_sequence(path)


def test_tum_to_bag_tool_round_trip(tmp_path, synth_small):
    import importlib.util
    from pathlib import Path
    spec = importlib.util.spec_from_file_location("tum_to_bag", Path(__file__).parents[1] / "tools" / "tum_to_bag.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    folder = open_sequence(synth_small)
    assert tool.main([str(synth_small), str(tmp_path / "s.bag"), "--max-frames", "4"]) == 0
    assert tool.main([str(synth_small), str(tmp_path / "s2"), "--max-frames", "3", "--storage", "mcap",
                      "--encoding", "rgb8", "--compressed", "png"]) == 0
    assert tool.main([str(synth_small), str(tmp_path / "s.bag")]) == 1        # never overwrites
    bag, bag2 = open_sequence(tmp_path / "s.bag"), open_sequence(tmp_path / "s2")
    assert len(bag) == 4 and len(bag2) == 3 and bag.camera == folder.camera == bag2.camera
    for a, b, c in zip(folder, bag, bag2):
        assert np.array_equal(a.image, b.image) and a.timestamp == b.timestamp == c.timestamp
        assert np.abs(c.image.astype(int) - a.image).max() <= 1
    assert folder.accelerometer is not None and bag.accelerometer is not None and bag.imu_topic == "/imu"
    k = np.searchsorted(folder.accelerometer.timestamps, bag.accelerometer.timestamps[-1], side="right")
    assert k > 0
    np.testing.assert_allclose(bag.accelerometer.timestamps, folder.accelerometer.timestamps[:k], atol=1e-9)
    np.testing.assert_allclose(bag.accelerometer.acc_xyz, folder.accelerometer.acc_xyz[:k])
