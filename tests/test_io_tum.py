"""TUM RGB-D layout reader on small folders written by the tests, and its error messages."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

import lite_vo
from data_helpers import textured_image, write_calib, write_tum_folder
from lite_vo.camera import Camera
from lite_vo.errors import InputError
from lite_vo.io import Frame, TumSequence, open_sequence


def test_tum_folder_basic(tmp_path):
    folder = write_tum_folder(tmp_path, n=5, width=64, height=48, depth_scale=1000.0, depth_value_m=2.0)
    seq = lite_vo.open_sequence(folder)
    assert isinstance(seq, TumSequence)
    assert seq.name == "seq" and len(seq) == 5 and seq.has_depth
    assert (seq.camera.width, seq.camera.height) == (64, 48)
    frames = list(seq)
    assert [f.index for f in frames] == list(range(5))
    assert all(isinstance(f, Frame) for f in frames)
    ts = np.array([f.timestamp for f in frames])
    np.testing.assert_allclose(ts, 100.0 + 0.1 * np.arange(5), atol=1e-9)
    f0 = frames[0]
    assert f0.image.dtype == np.uint8 and f0.image.shape == (48, 64)
    # colour PNGs become grey exactly as OpenCV converts them
    colour = cv2.imread(str(seq.image_paths[0]), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(f0.image, cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY))
    # depth in metres, 0 invalid
    assert f0.depth.dtype == np.float32 and f0.depth.shape == (48, 64)
    assert f0.depth[0, 0] == 0.0
    np.testing.assert_allclose(f0.depth[1:, 1:], 2.0)
    assert seq.groundtruth is not None and len(seq.groundtruth) == 15
    assert seq.accelerometer is not None and len(seq.accelerometer) == 50
    np.testing.assert_allclose(seq.accelerometer.acc_xyz[0], [0, -9.81, 0])
    # iterating twice gives the same frames; random access agrees
    again = next(iter(seq))
    np.testing.assert_array_equal(again.image, f0.image)
    np.testing.assert_array_equal(seq.frame(-1).image, frames[-1].image)


def test_depth_scale_default_is_tum_5000(tmp_path):
    folder = write_tum_folder(tmp_path, n=2, depth_scale=None, depth_value_m=1.5)
    calib = folder / "calib.txt"
    assert "depth_scale" not in calib.read_text()
    seq = open_sequence(folder)
    assert seq.depth_scale == 5000.0
    np.testing.assert_allclose(next(iter(seq)).depth[5, 5], 1.5, rtol=1e-6)


def test_depth_association_tolerance(tmp_path):
    near = write_tum_folder(tmp_path, n=4, name="near", depth_offset=0.015)
    assert open_sequence(near).has_depth
    assert all(f.depth is not None for f in open_sequence(near))
    far = write_tum_folder(tmp_path, n=4, name="far", depth_offset=0.03)
    seq = open_sequence(far)
    assert not seq.has_depth and all(f.depth is None for f in seq)
    # a larger tolerance associates them again
    assert open_sequence(far, depth_max_dt=0.05).has_depth


def test_association_is_one_to_one(tmp_path):
    from lite_vo.io import associate_nearest
    t_rgb = np.array([0.0, 0.01, 0.5])
    t_depth = np.array([0.004, 0.49])
    m = associate_nearest(t_rgb, t_depth, 0.02)
    # depth 0 is nearest to both rgb 0 (0.004) and rgb 1 (0.006): it goes to rgb 0 only
    assert m.tolist() == [0, -1, 1]


@pytest.mark.parametrize("n, expected", [
    (1, (517.3, 516.5, 318.6, 255.3, "radtan", (0.2624, -0.9531, -0.0054, 0.0026, 1.1633))),
    (2, (520.9, 521.0, 325.1, 249.7, "radtan", (0.2312, -0.7849, -0.0033, -0.0001, 0.9172))),
    (3, (535.4, 539.2, 320.1, 247.6, "none", ())),
])
def test_freiburg_folder_name_selects_published_calibration(tmp_path, n, expected):
    folder = write_tum_folder(tmp_path, n=2, width=640, height=480, name=f"rgbd_dataset_freiburg{n}_xyz",
                              calib=False, depth_scale=None)
    seq = open_sequence(folder)
    i = seq.camera.intrinsics
    assert (i.fx, i.fy, i.cx, i.cy) == expected[:4]
    assert seq.camera.model == expected[4] and seq.camera.params == expected[5]
    assert seq.depth_scale == 5000.0


def test_calib_argument_and_calib_file_override_freiburg(tmp_path):
    folder = write_tum_folder(tmp_path, n=2, width=64, height=48, name="rgbd_dataset_freiburg1_desk", calib=True)
    assert open_sequence(folder).camera.intrinsics.fx == 50.0   # calib.txt wins over the name
    other = write_calib(tmp_path / "other.txt", 64, 48, fx=70.0, fy=71.0)
    assert open_sequence(folder, calib=other).camera.intrinsics.fy == 71.0


def test_calib_txt_with_distortion_and_fov(tmp_path):
    from lite_vo.io import read_calib_txt
    p = tmp_path / "c.txt"
    p.write_text("# c\n500 501 320 240 0.1 -0.2 0.001 0.002 0.05\n640 480\ndepth_scale 1000 # mm\n")
    cal = read_calib_txt(p)
    assert cal.camera.model == "radtan" and cal.camera.params == (0.1, -0.2, 0.001, 0.002, 0.05)
    assert cal.depth_scale == 1000.0
    p.write_text("500 501 320 240 0.1 -0.2 0.001 0.002\n640 480\n")
    assert read_calib_txt(p).camera.params == (0.1, -0.2, 0.001, 0.002, 0.0)
    p.write_text("model fov\n300 300 320 240 0.9\n640 480\n")
    cal = read_calib_txt(p)
    assert cal.camera.model == "fov" and cal.camera.params == (0.9,)
    p.write_text("500 500 320 240 0 0 0 0\n640 480\n")
    assert read_calib_txt(p).camera.model == "none"


@pytest.mark.parametrize("camera", [
    Camera.radtan(517.3, 516.5, 318.6, 255.3, 640, 480, 0.2624, -0.9531, -0.0054, 0.0026, 1.1633),
    Camera.fov(300.0, 301.0, 319.5, 239.5, 640, 480, 0.91),
    Camera.pinhole(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370),
], ids=["radtan", "fov", "pinhole"])
def test_write_calib_txt_round_trip(tmp_path, camera):
    from lite_vo.io import read_calib_txt, write_calib_txt
    p = write_calib_txt(tmp_path / "calib.txt", camera, depth_scale=1000.0, comment="a test\ncamera")
    cal = read_calib_txt(p)
    assert cal.camera == camera and cal.depth_scale == 1000.0
    assert read_calib_txt(write_calib_txt(tmp_path / "c2.txt", camera)).depth_scale is None


# ------------------------------------------------------------------------------------------------
# bad input: one-line messages naming the file and the problem
# ------------------------------------------------------------------------------------------------

def _err(path, **kw) -> str:
    with pytest.raises(InputError) as ei:
        seq = open_sequence(path, **kw)
        for _ in seq:
            pass
    msg = str(ei.value)
    assert "\n" not in msg
    return msg


def test_missing_folder(tmp_path):
    msg = _err(tmp_path / "nope")
    assert "nope" in msg and "no such file or directory" in msg


def test_unknown_format(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.md").write_text("hello")
    msg = _err(tmp_path / "empty")
    assert "empty" in msg and "unknown sequence format" in msg
    (tmp_path / "file.xyz").write_text("x")
    assert "unknown sequence format" in _err(tmp_path / "file.xyz")


def test_missing_calibration(tmp_path):
    folder = write_tum_folder(tmp_path, n=2, calib=False)
    msg = _err(folder)
    assert "no calib.txt" in msg and "seq" in msg


def _bad_frames(seq) -> dict:
    """{index: error} of the bad frames of a whole iteration (which must reach the last frame)."""
    frames = list(seq)
    assert [f.index for f in frames] == list(range(len(seq)))
    for f in frames:
        assert (f.image is None) == (f.error is not None) and (f.error is None or "\n" not in f.error)
        assert f.error is None or (f.depth is None and f.color is None)
    return {f.index: f.error for f in frames if f.error is not None}


def test_rgb_list_references_missing_image(tmp_path):
    folder = write_tum_folder(tmp_path, n=3)
    (folder / "rgb.txt").write_text((folder / "rgb.txt").read_text() + "200.0 rgb/missing.png\n")
    seq = open_sequence(folder)              # a missing file is a bad frame, not fatal
    assert len(seq) == 4
    bad = _bad_frames(seq)
    assert list(bad) == [3]
    assert "missing.png: image not found" in bad[3] and "listed in rgb.txt line 6" in bad[3]
    # every listed file missing: nothing to read at all -> error when opening
    (folder / "rgb.txt").write_text("1.0 rgb/a.png\n2.0 rgb/b.png\n")
    msg = _err(folder)
    assert "rgb.txt" in msg and "none of the 2 listed files exists" in msg


def test_malformed_line_names_line_number(tmp_path):
    folder = write_tum_folder(tmp_path, n=3)
    lines = (folder / "rgb.txt").read_text().splitlines()
    lines[3] = "100.1"  # line 4: missing filename
    (folder / "rgb.txt").write_text("\n".join(lines) + "\n")
    msg = _err(folder)
    assert "rgb.txt line 4" in msg and "expected 'timestamp filename'" in msg
    lines[3] = "abc rgb/100.100000.png"
    (folder / "rgb.txt").write_text("\n".join(lines) + "\n")
    msg = _err(folder)
    assert "rgb.txt line 4" in msg and "'abc' is not a number" in msg


def test_non_increasing_timestamps(tmp_path):
    folder = write_tum_folder(tmp_path, n=3)
    lines = (folder / "rgb.txt").read_text().splitlines()
    lines[3], lines[4] = lines[4], lines[3]
    (folder / "rgb.txt").write_text("\n".join(lines) + "\n")
    msg = _err(folder)
    assert "rgb.txt line 5" in msg and "strictly increasing" in msg


def test_nan_in_groundtruth(tmp_path):
    folder = write_tum_folder(tmp_path, n=3)
    lines = (folder / "groundtruth.txt").read_text().splitlines()
    f = lines[2].split()
    f[3] = "nan"
    lines[2] = " ".join(f)
    (folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    msg = _err(folder)
    assert "groundtruth.txt line 3" in msg and "NaN" in msg


def test_malformed_accelerometer(tmp_path):
    folder = write_tum_folder(tmp_path, n=3)
    with open(folder / "accelerometer.txt", "a") as fh:
        fh.write("1000.0 1 2\n")
    msg = _err(folder)
    assert "accelerometer.txt line" in msg and "expected 4 fields" in msg


def test_image_of_wrong_size(tmp_path):
    folder = write_tum_folder(tmp_path, n=3, width=64, height=48)
    write_calib(folder / "calib.txt", 640, 480, cx=320, cy=240)
    msg = _err(folder)                       # the first frame: a wrong calibration, fatal at open
    assert ".png" in msg and "is 64x48 but the calibration says 640x480" in msg and "calib.txt" in msg
    # only a later frame is wrong: a bad frame, the iteration goes on
    folder2 = write_tum_folder(tmp_path, n=4, width=64, height=48, name="late")
    p = sorted((folder2 / "rgb").iterdir())[2]
    cv2.imwrite(str(p), textured_image(32, 24))
    bad = _bad_frames(open_sequence(folder2))
    assert list(bad) == [2] and p.name in bad[2] and "is 32x24 but the calibration says 64x48" in bad[2]


def test_unreadable_and_truncated_images_are_bad_frames(tmp_path):
    folder = write_tum_folder(tmp_path, n=5)
    files = sorted((folder / "rgb").iterdir())
    files[1].write_bytes(b"this is not a png")
    files[3].write_bytes(files[3].read_bytes()[:60])           # truncated PNG
    seq = open_sequence(folder)
    bad = _bad_frames(seq)
    assert sorted(bad) == [1, 3]
    assert files[1].name in bad[1] and "cannot read image" in bad[1]
    assert files[3].name in bad[3] and "cannot read image" in bad[3]
    assert seq.frame(1).error == bad[1] and seq.frame(2).error is None     # random access agrees
    # the first frame unreadable: the sequence still opens on the next readable one
    files[0].write_bytes(b"")
    assert 0 in _bad_frames(open_sequence(folder))
    for f in files:
        f.write_bytes(b"junk")
    msg = _err(folder)
    assert "none of the first 5 images can be read" in msg and "cannot read image" in msg


def test_unreadable_depth_image(tmp_path):
    folder = write_tum_folder(tmp_path, n=3)
    p = sorted((folder / "depth").iterdir())[1]
    cv2.imwrite(str(p), textured_image(64, 48, colour=True))   # 8-bit colour, not a depth image
    bad = _bad_frames(open_sequence(folder))
    assert list(bad) == [1] and p.name in bad[1] and "depth image must be single-channel 16-bit" in bad[1]
    p.unlink()                                                  # listed in depth.txt but missing
    bad = _bad_frames(open_sequence(folder))
    assert list(bad) == [1] and p.name in bad[1] and "depth image not found" in bad[1]


def test_colour_frames_keep_the_decoded_colour_image(tmp_path):
    folder = write_tum_folder(tmp_path, n=2, colour=True)
    f = open_sequence(folder).frame(0)
    colour = cv2.imread(str(sorted((folder / "rgb").iterdir())[0]), cv2.IMREAD_COLOR)
    assert f.color is not None and f.color.dtype == np.uint8 and f.color.shape == (48, 64, 3)
    np.testing.assert_array_equal(f.color, colour)
    np.testing.assert_array_equal(f.image, cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY))
    grey = write_tum_folder(tmp_path, n=2, colour=False, name="grey")
    g = open_sequence(grey).frame(0)
    assert g.color is None and g.image.shape == (48, 64)


@pytest.mark.parametrize("ext", [".png", ".jpg"])
def test_deferred_colour_decodes_the_same_image_on_demand(tmp_path, ext):
    """With ``defer_color`` a frame carries the grey image now and decodes its colour only when asked
    (keyframes): the same grey image and the same colour as an eager read, None for a grey file."""
    folder = write_tum_folder(tmp_path, n=3, colour=True)
    if ext == ".jpg":                                  # the same frames as JPEGs
        for p in sorted((folder / "rgb").iterdir()):
            cv2.imwrite(str(p.with_suffix(".jpg")), cv2.imread(str(p), cv2.IMREAD_COLOR))
            p.unlink()
        rgb_txt = folder / "rgb.txt"
        rgb_txt.write_text(rgb_txt.read_text().replace(".png", ".jpg"))
    seq = open_sequence(folder)
    eager, lazy = seq.frame(1), seq.frame(1, defer_color=True)
    assert lazy.color is None and callable(lazy.color_reader) and eager.color_reader is None
    np.testing.assert_array_equal(lazy.image, eager.image)
    np.testing.assert_array_equal(lazy.color_reader(), eager.color)
    path = str(seq.image_paths[1])
    if ext == ".jpg":                                  # a JPEG's grey image is its luma plane
        np.testing.assert_array_equal(lazy.image, cv2.imread(path, cv2.IMREAD_GRAYSCALE))
        assert np.abs(lazy.image.astype(int) - cv2.cvtColor(eager.color, cv2.COLOR_BGR2GRAY)).mean() < 1.0
    else:                                              # others: OpenCV's conversion of the colour
        np.testing.assert_array_equal(lazy.image, cv2.cvtColor(eager.color, cv2.COLOR_BGR2GRAY))
    half = lazy.color_reader(2)                        # JPEGs decode at half size when asked; others do not
    expect = (24, 32, 3) if ext == ".jpg" else (48, 64, 3)
    assert half.shape == expect and np.abs(cv2.resize(eager.color, expect[1::-1], interpolation=cv2.INTER_AREA)
                                           .astype(int) - half).mean() < 10.0   # the same picture, smaller
    assert [f.index for f in seq.frames(1, defer_color=True)] == [1, 2]
    grey = open_sequence(write_tum_folder(tmp_path, n=2, colour=False, name="grey")).frame(0, defer_color=True)
    assert grey.color is None and grey.color_reader() is None


@pytest.mark.parametrize("text, expect", [
    ("500 500 320\n640 480\n", "line 1: expected 'fx fy cx cy [k1 k2 p1 p2 [k3]]' (4, 8 or 9 values), got 3"),
    ("500 500 320 240\n640\n", "line 2: expected 'width height'"),
    ("500 500 320 240\n", "expected a line 'fx fy cx cy"),
    ("500 500 320 240\n640 480\nfocus 3\n", "line 3: unknown key 'focus'"),
    ("500 500 320 240\n640 480\ndepth_scale -3\n", "line 3: depth_scale must be a positive number"),
    ("500 500 320 x\n640 480\n", "line 1: value 'x' is not a number"),
    ("500 500 320 240\n640 480\n1 2\n", "line 3: unexpected extra line"),
    ("model fov\n500 500 320 240\n640 480\n", "line 2: model fov expects 'fx fy cx cy omega'"),
])
def test_bad_calib_txt(tmp_path, text, expect):
    folder = write_tum_folder(tmp_path, n=2)
    (folder / "calib.txt").write_text(text)
    msg = _err(folder)
    assert "calib.txt" in msg and expect in msg


def test_deferred_depth_reads_the_same_image_on_demand(tmp_path):
    folder = write_tum_folder(tmp_path, n=3, depth_scale=1000.0, depth_value_m=2.0)
    seq = open_sequence(folder)
    eager = seq.frame(1)
    lazy = seq.frame(1, defer_depth=True)
    assert lazy.depth is None and callable(lazy.depth_reader) and eager.depth_reader is None
    np.testing.assert_array_equal(lazy.depth_reader(), eager.depth)
    assert [f.index for f in seq.frames(1, defer_depth=True)] == [1, 2]
    p = sorted((folder / "depth").iterdir())[2]
    cv2.imwrite(str(p), textured_image(64, 48, colour=True))   # broken: found out only when read
    f = seq.frame(2, defer_depth=True)
    assert f.ok
    with pytest.raises(InputError, match="depth image must be single-channel 16-bit"):
        f.depth_reader()


def test_run_with_deferred_depth_skips_a_broken_depth_image_in_the_evaluation(tmp_path, caplog):
    """The session defers depth decoding: the frames map as usual; a depth image that cannot be read
    costs only its evaluation row (a warning naming the file), the same run as with good files."""
    from lite_vo.config import load_profile
    import dataclasses
    import json

    from lite_vo.runner import run_sequence
    folder = write_tum_folder(tmp_path, n=12, width=64, height=48, colour=False)
    cfg = load_profile("phone")
    cfg = dataclasses.replace(cfg, system=dataclasses.replace(cfg.system, depth_eval_every=1, map_every_startup=1))
    good = run_sequence(open_sequence(folder), cfg, tmp_path / "good", pose_source="gt")   # every frame maps
    p = sorted((folder / "depth").iterdir())[5]
    cv2.imwrite(str(p), textured_image(64, 48, colour=True))
    with caplog.at_level("WARNING"):
        bad = run_sequence(open_sequence(folder), cfg, tmp_path / "bad", pose_source="gt")
    assert bad.status == good.status and len(good.poses) == 12
    np.testing.assert_array_equal(np.array(bad.poses), np.array(good.poses))
    rows = lambda out: json.loads((out / "depth_accuracy.json").read_text())   # noqa: E731
    assert len(rows(tmp_path / "bad")) == len(rows(tmp_path / "good")) - 1 >= 3
    assert any("depth evaluation skips frame 5" in r.message and p.name in r.message for r in caplog.records)
