"""Image folders, video files and live cameras."""
from __future__ import annotations

import numpy as np
import pytest

from data_helpers import write_calib, write_image_folder, write_video
from lite_vo.camera import Camera
from lite_vo.errors import InputError
from lite_vo.io import ImageFolderSequence, VideoSequence, open_sequence


def test_image_folder_natural_order_and_fps(tmp_path):
    folder = write_image_folder(tmp_path, n=11)
    seq = open_sequence(folder, fps=20.0)
    assert isinstance(seq, ImageFolderSequence) and len(seq) == 11 and not seq.has_depth
    assert [p.name for p in seq.image_paths][:3] == ["img1.png", "img2.png", "img3.png"]
    assert seq.image_paths[-1].name == "img11.png"       # natural order, not img10 < img2
    np.testing.assert_allclose(seq.timestamps, np.arange(11) / 20.0)
    frames = list(seq)
    assert frames[0].image.shape == (48, 64) and frames[0].image.dtype == np.uint8
    # default rate is 30 fps
    np.testing.assert_allclose(open_sequence(folder).timestamps[1], 1 / 30)


def test_image_folder_times_txt(tmp_path):
    folder = write_image_folder(tmp_path, n=3, times=[0.5, 0.61, 0.9])
    seq = open_sequence(folder)
    np.testing.assert_allclose([f.timestamp for f in seq], [0.5, 0.61, 0.9])


def test_image_folder_errors(tmp_path):
    folder = write_image_folder(tmp_path, n=3, times=[0.5, 0.61])
    with pytest.raises(InputError, match=r"times.txt: has 2 timestamps for 3 images"):
        open_sequence(folder)
    folder = write_image_folder(tmp_path, n=3, times=[0.5, 0.4, 0.9], name="dec")
    with pytest.raises(InputError, match=r"times.txt line 2: .* strictly increasing"):
        open_sequence(folder)
    folder = write_image_folder(tmp_path, n=2, calib=False, name="nocalib")
    with pytest.raises(InputError, match=r"nocalib: image folder without calib.txt"):
        open_sequence(folder)
    # a calibration given explicitly works
    c = write_calib(tmp_path / "c.txt", 64, 48)
    assert len(open_sequence(folder, calib=c)) == 2
    # and a Camera object too
    assert len(open_sequence(folder, calib=Camera.pinhole(50, 50, 32, 24, 64, 48))) == 2


def test_video_file(tmp_path):
    video = write_video(tmp_path / "clip.avi", n=6, fps=10.0)
    if video is None:
        pytest.skip("this OpenCV build cannot write MJPG videos")
    with pytest.raises(InputError, match=r"clip.avi: video needs a calibration file"):
        open_sequence(video)
    write_calib(tmp_path / "calib.txt", 64, 48)
    seq = open_sequence(video)
    assert isinstance(seq, VideoSequence) and seq.name == "clip"
    frames = list(seq)
    assert len(frames) == len(seq) == 6
    assert frames[0].image.shape == (48, 64) and frames[0].image.dtype == np.uint8
    np.testing.assert_allclose([f.timestamp for f in frames], np.arange(6) / 10.0)
    # wrong calibration size
    bad = write_calib(tmp_path / "bad.txt", 640, 480)
    with pytest.raises(InputError, match=r"clip.avi: video frame is 64x48 but the calibration says 640x480"):
        open_sequence(video, calib=bad)


def test_corrupt_video(tmp_path):
    p = tmp_path / "broken.mp4"
    p.write_bytes(b"\x00" * 100)
    write_calib(tmp_path / "calib.txt", 64, 48)
    with pytest.raises(InputError, match=r"broken.mp4: (cannot open video|video contains no readable frame)"):
        open_sequence(p)


def test_live_camera_errors(tmp_path):
    with pytest.raises(InputError, match=r"camera 0: a calibration file is required"):
        open_sequence(0)
    c = write_calib(tmp_path / "c.txt", 64, 48)
    with pytest.raises(InputError, match=r"camera 97: cannot open"):
        open_sequence(97, calib=c)


def test_video_frame_that_does_not_decode_is_a_bad_frame(tmp_path):
    video = write_video(tmp_path / "clip.avi", n=6, fps=10.0)
    if video is None:
        pytest.skip("this OpenCV build cannot write MJPG videos")
    data = bytearray(video.read_bytes())
    starts = [i for i in range(len(data) - 3) if data[i:i + 3] == b"\xff\xd8\xff"]   # one JPEG per frame
    assert len(starts) == 6
    data[starts[2]:starts[2] + 400] = bytes(400)                # wipe frame 2's JPEG header
    video.write_bytes(data)
    write_calib(tmp_path / "calib.txt", 64, 48)
    frames = list(open_sequence(video))
    assert [f.index for f in frames] == list(range(6))         # the iteration goes past the bad frame
    assert [f.error is not None for f in frames] == [False, False, True, False, False, False]
    assert frames[2].image is None and "clip.avi: video frame 2 cannot be decoded" in frames[2].error
    np.testing.assert_allclose([f.timestamp for f in frames], np.arange(6) / 10.0)


def test_colour_video_and_image_folder_give_colour_frames(tmp_path):
    import cv2
    video = write_video(tmp_path / "clip.avi", n=2, fps=10.0)
    if video is None:
        pytest.skip("this OpenCV build cannot write MJPG videos")
    write_calib(tmp_path / "calib.txt", 64, 48)
    f = next(iter(open_sequence(video)))
    cap = cv2.VideoCapture(str(video))
    ok, first = cap.read()
    cap.release()
    if np.array_equal(first[..., 0], first[..., 1]) and np.array_equal(first[..., 0], first[..., 2]):
        assert f.color is None                                  # a grey video decodes as equal BGR planes
    else:
        np.testing.assert_array_equal(f.color, first)
        np.testing.assert_array_equal(f.image, cv2.cvtColor(first, cv2.COLOR_BGR2GRAY))
    # a grey video (equal BGR planes) has no colour image
    grey_video = tmp_path / "grey.avi"
    w = cv2.VideoWriter(str(grey_video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for k in range(2):
        w.write(cv2.cvtColor(np.full((48, 64), 60 * k + 40, np.uint8), cv2.COLOR_GRAY2BGR))
    w.release()
    g = next(iter(open_sequence(grey_video, calib=tmp_path / "calib.txt")))
    assert g.color is None and g.image.shape == (48, 64)
    folder = write_image_folder(tmp_path, n=2)                  # colour PNGs
    assert next(iter(open_sequence(folder))).color.shape == (48, 64, 3)
