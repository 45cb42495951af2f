"""Sequence readers: TUM RGB-D folders, EuRoC ``mav0`` folders, image folders, video files and
live cameras, all behind :func:`open_sequence`.

Index files (lists, CSVs, calibrations, ground truth, accelerometer) are read and validated when
the sequence is opened, with the first readable image (its size must match the calibration);
images are read lazily while iterating. Every problem at open time is an
:class:`~lite_vo.errors.InputError` with a one-line message naming the file (and line). A frame
that cannot be read later (unreadable, truncated, missing or wrong-size file) is yielded as a
bad :class:`Frame` (``image=None``, ``error="<file>: <reason>"``) and the iteration goes on.
Colour sources also give the decoded BGR image (``Frame.color``).

Imports numpy, cv2 (lazily), ``lite_vo.camera``, ``lite_vo.geometry`` and the io helpers only.
"""
from __future__ import annotations

import functools
import os
import re
import time
from pathlib import Path
from typing import Iterator, Optional, Union

import numpy as np

from ..camera import Camera
from ..errors import InputError
from ._text import check_increasing, parse_table, read_lines
from .calib import TUM_DEPTH_SCALE, Calibration, freiburg_camera, freiburg_number
from .calib_formats import load_calibration, read_calibration, read_euroc_camera_yaml, read_sensor_transform
from .base import Sequence
from .trajectory import read_euroc_groundtruth, read_trajectory
from .types import Accelerometer, Frame

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")
VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv")
DEFAULT_DEPTH_MAX_DT = 0.02
DEFAULT_FPS = 30.0


# ------------------------------------------------------------------------------------------------
# image loading
# ------------------------------------------------------------------------------------------------

#: a BGR image whose channels differ by at most this everywhere is grey (a grey video decoded
#: as BGR; lossy codecs' chroma rounding leaves a few levels)
GREY_TOLERANCE = 3


def _is_grey(img: np.ndarray) -> bool:
    # plain numpy on views (cv2.split raised a rare SystemError in the reader thread on long runs)
    for a in (img[::7, ::5], img):           # a strided sample decides quickly for colour images
        a16 = a.astype(np.int16)
        if max(np.abs(a16[..., 0] - a16[..., 1]).max(), np.abs(a16[..., 0] - a16[..., 2]).max()) > GREY_TOLERANCE:
            return False
    return True


def _grey_and_colour(img: np.ndarray) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(grey uint8, BGR uint8 or None) of a decoded 8-bit image; BGR images whose channels are
    (nearly) equal count as grey."""
    import cv2
    if img.ndim == 2:
        return img, None
    if img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    elif img.shape[2] == 1:
        return np.ascontiguousarray(img[..., 0]), None
    elif img.shape[2] != 3:
        return np.ascontiguousarray(img[..., 0]), None
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    return grey, (None if _is_grey(img) else img)


def _read_bytes(path: Path) -> np.ndarray:
    """The bytes of an image file; InputError naming the file when it is missing or unreadable."""
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as err:
        if not path.is_file():
            raise InputError(f"{path}: image not found") from None
        raise InputError(f"{path}: cannot read image ({err.strerror or err})") from None
    if data.size == 0:
        raise InputError(f"{path}: cannot read image (empty file)")
    return data


def _is_jpeg(data: np.ndarray) -> bool:
    return data.size >= 3 and data[0] == 0xFF and data[1] == 0xD8 and data[2] == 0xFF


def _imdecode(data: np.ndarray, path: Path, flags: int) -> np.ndarray:
    """``cv2.imdecode`` of the bytes of ``path``; InputError naming the file when they do not decode."""
    import cv2
    img = cv2.imdecode(data, flags)
    if img is None:
        raise InputError(f"{path}: cannot read image (corrupt, truncated or unsupported format)")
    return img


def _decode_grey_jpeg(data: np.ndarray, path: Path) -> np.ndarray:
    """The luma plane of a JPEG (no colour conversion: about a third of the time of a colour decode).
    EXIF orientation is ignored, as for colour (the calibration describes the sensor's layout)."""
    import cv2
    return _imdecode(data, path, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)


def _decode_unchanged(data: np.ndarray, path: Path) -> np.ndarray:
    import cv2
    img = _imdecode(data, path, cv2.IMREAD_UNCHANGED)
    if img.dtype == np.uint16:
        return (img.astype(np.float32) / 257.0 + 0.5).astype(np.uint8)
    if img.dtype != np.uint8:
        raise InputError(f"{path}: unsupported image type {img.dtype} (expected 8-bit grey or colour)")
    return img


def _decode_colour(data: np.ndarray, path: Path, reduce: int = 1) -> Optional[np.ndarray]:
    """The BGR uint8 image of JPEG bytes, None for a grey image; ``reduce`` 2, 4 or 8: decoded at that
    fraction of the size (the decoder's DCT scaling: about half the time at 1/2)."""
    import cv2
    flags = {2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4, 8: cv2.IMREAD_REDUCED_COLOR_8}
    if reduce in flags:
        img = _imdecode(data, path, flags[reduce] | cv2.IMREAD_IGNORE_ORIENTATION)
        return None if _is_grey(img) else img
    return _grey_and_colour(_decode_unchanged(data, path))[1]


def _given(value, reduce: int = 1):
    return value


def _imread(path: Path, defer_colour: bool = False):
    """(grey, colour) of an image file, read once; InputError naming the file. ``colour`` is the BGR
    image or None for grey files; with ``defer_colour`` it is a callable returning it (``reduce``
    argument: see :class:`~lite_vo.io.types.Frame`). A JPEG's grey
    image is its luma plane, and with ``defer_colour`` its colour is decoded (from the bytes already
    read) only when asked: only keyframes need colour. Other formats are decoded once and converted."""
    data = _read_bytes(path)
    if _is_jpeg(data):
        colour = functools.partial(_decode_colour, data, path)
        grey = _decode_grey_jpeg(data, path)
    else:
        grey, c = _grey_and_colour(_decode_unchanged(data, path))
        colour = functools.partial(_given, c)
    return grey, (colour if defer_colour else colour())


def _check_size(path, img: np.ndarray, camera: Camera, what: str, calib_source: str = "") -> None:
    h, w = img.shape[:2]
    if (w, h) != (camera.width, camera.height):
        src = f" ({calib_source})" if calib_source else ""
        raise InputError(f"{path}: {what} is {w}x{h} but the calibration says {camera.width}x{camera.height}{src}")


def _imread_depth(path: Path, camera: Camera, depth_scale: float) -> np.ndarray:
    import cv2
    d = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if d is None:
        if not path.is_file():
            raise InputError(f"{path}: depth image not found")
        raise InputError(f"{path}: cannot read depth image (corrupt, truncated or unsupported format)")
    if d.ndim != 2 or d.dtype not in (np.uint16, np.float32):
        raise InputError(f"{path}: depth image must be single-channel 16-bit (or float32), got "
                         f"{d.dtype} with shape {d.shape}")
    _check_size(path, d, camera, "depth image")
    out = d.astype(np.float32) / np.float32(depth_scale)
    out[~np.isfinite(out) | (out < 0)] = 0.0
    return out


def natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


# ------------------------------------------------------------------------------------------------
# sequences
# ------------------------------------------------------------------------------------------------

class FileSequence(Sequence):
    """A sequence of image files with known timestamps (TUM, EuRoC, image folders).

    ``listed_in``: optional ``{frame index: "rgb.txt line N"}`` for files named in an index file,
    quoted when such a file turns out to be missing."""

    def __init__(self, name: str, camera: Camera, path: Path, timestamps: np.ndarray, image_paths: list,
                 depth_paths: Optional[list] = None, depth_scale: Optional[float] = None,
                 calib_source: str = "", listed_in: Optional[dict] = None):
        super().__init__(name, camera, path, calib_source)
        self.timestamps = np.asarray(timestamps, dtype=np.float64)
        self.timestamps.setflags(write=False)
        self.image_paths = list(image_paths)
        self.depth_paths = depth_paths
        self.depth_scale = depth_scale
        self.has_depth = depth_paths is not None and any(p is not None for p in depth_paths)
        self._listed_in = dict(listed_in or {})

    def __len__(self) -> int:
        return len(self.image_paths)

    def _read(self, i: int, defer_depth: bool = False, defer_color: bool = False) -> Frame:
        """Frame ``i``; InputError (naming the file) when it cannot be read."""
        img, colour = _imread(self.image_paths[i], defer_color)
        reader_c = None
        if defer_color:
            colour, reader_c = None, colour
        _check_size(self.image_paths[i], img, self.camera, "image", self.calib_source)
        depth, reader = None, None
        if self.depth_paths is not None and self.depth_paths[i] is not None:
            args = (self.depth_paths[i], self.camera, self.depth_scale or TUM_DEPTH_SCALE)
            if defer_depth:
                reader = functools.partial(_imread_depth, *args)
            else:
                depth = _imread_depth(*args)
        return Frame(i, float(self.timestamps[i]), img, depth, colour, depth_reader=reader, color_reader=reader_c)

    def frame(self, i: int, defer_depth: bool = False, defer_color: bool = False) -> Frame:
        """Frame ``i`` (random access; reads the files now). A file that cannot be read gives a
        frame with ``image=None`` and ``error`` set. ``defer_depth``: do not decode the depth
        image now; ``Frame.depth_reader`` reads it when called (most frames of a run never need it).
        ``defer_color``: do not decode the colour image now; ``Frame.color_reader`` decodes it from
        the bytes already read when called (None for a grey file). The grey image is the same either way."""
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range for {n} frames")
        i %= n
        try:
            return self._read(i, defer_depth, defer_color)
        except InputError as err:
            msg = str(err)
            if i in self._listed_in and "not found" in msg:
                msg += f" (listed in {self._listed_in[i]})"
            return Frame(i, float(self.timestamps[i]), None, error=msg)

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)

    def frames(self, start: int = 0, defer_depth: bool = False, defer_color: bool = False) -> Iterator[Frame]:
        """Frames ``start ..`` in order (see :meth:`frame` for ``defer_depth`` and ``defer_color``)."""
        for i in range(start, len(self)):
            yield self.frame(i, defer_depth, defer_color)

    def check_first_frame(self, scan: int = 30) -> None:
        """Open-time check: the first readable frame (among the first ``scan``) must match the
        calibration's size; none readable is an error naming the first problem."""
        first_error = None
        for i in range(min(scan, len(self))):
            try:
                self._read(i, defer_color=True)      # the sizes matter here, not the colour
                return
            except InputError as err:
                if "calibration says" in str(err):
                    raise
                first_error = first_error or str(err)
        n = min(scan, len(self))
        raise InputError(f"{self.path}: none of the first {n} images can be read (first: {first_error})")


class TumSequence(FileSequence):
    kind = "tum"


class EurocSequence(FileSequence):
    kind = "euroc"


class ImageFolderSequence(FileSequence):
    kind = "images"


#: a video that fails to decode tries this many further frames before it counts as ended
VIDEO_MAX_UNDECODABLE = 5


class VideoSequence(Sequence):
    """Frames of a video file (timestamps ``index / fps``). Frames that do not decode in the middle
    of the file, or have the wrong size, are yielded as bad frames (``error`` set)."""

    kind = "video"

    def __init__(self, path: Path, camera: Camera, fps: Optional[float] = None, calib_source: str = ""):
        import cv2
        super().__init__(path.stem, camera, path, calib_source)
        cap = cv2.VideoCapture(str(path))
        if not cap.isOpened():
            raise InputError(f"{path}: cannot open video (unsupported codec or not a video)")
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        vfps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        ok, img = cap.read()
        cap.release()
        if not ok or img is None:
            raise InputError(f"{path}: video contains no readable frame")
        _check_size(path, img, camera, "video frame", calib_source)
        self.fps = float(fps) if fps else (vfps if vfps > 0 else DEFAULT_FPS)
        self._count = max(n, 1)
        self.timestamps = np.arange(self._count) / self.fps   # nominal; iteration may end earlier
        self._cap = None

    def __len__(self) -> int:
        return self._count

    def __iter__(self) -> Iterator[Frame]:
        import cv2
        cap = cv2.VideoCapture(str(self.path))
        self._cap = cap
        try:
            i = 0
            failed: list[int] = []        # indices that did not decode, pending a later good frame
            while True:
                ok, img = cap.read()
                if not ok or img is None:
                    failed.append(i)
                    i += 1
                    if len(failed) > VIDEO_MAX_UNDECODABLE:
                        break             # the end of the file (or nothing more decodes)
                    continue
                for j in failed:          # a frame decoded after some did not: those were bad
                    yield Frame(j, j / self.fps, None, error=f"{self.path}: video frame {j} cannot be decoded")
                failed = []
                grey, colour = _grey_and_colour(img)
                try:
                    _check_size(self.path, grey, self.camera, f"video frame {i}", self.calib_source)
                except InputError as err:
                    yield Frame(i, i / self.fps, None, error=str(err))
                else:
                    yield Frame(i, i / self.fps, grey, None, colour)
                i += 1
        finally:
            cap.release()
            self._cap = None

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()


class LiveCameraSequence(Sequence):
    """A live camera (``cv2.VideoCapture(index)``); timestamps from ``time.monotonic()``;
    ``len()`` raises TypeError. The first frame is read when opening (its size must match the
    calibration); iteration ends when the camera stops delivering frames."""

    kind = "camera"

    def __init__(self, index: int, camera: Camera, calib_source: str = ""):
        import cv2
        super().__init__(f"camera{index}", camera, None, calib_source)
        self.index = index
        cap = cv2.VideoCapture(index)
        if not cap.isOpened():
            raise InputError(f"camera {index}: cannot open (no such device or it is busy)")
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, camera.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, camera.height)
        ok, img = cap.read()
        if not ok or img is None:
            cap.release()
            raise InputError(f"camera {index}: delivers no frame")
        try:
            _check_size(f"camera {index}", img, camera, "frame", calib_source)
        except InputError:
            cap.release()
            raise
        self._first = (time.monotonic(), img)
        self._cap = cap

    def __len__(self) -> int:
        raise TypeError("a live camera has no length")

    def __iter__(self) -> Iterator[Frame]:
        i = 0
        while self._cap is not None:
            if self._first is not None:
                (t, img), self._first = self._first, None
            else:
                ok, img = self._cap.read()
                t = time.monotonic()
                if not ok or img is None:
                    break
            grey, colour = _grey_and_colour(img)
            try:
                _check_size(f"camera {self.index}", grey, self.camera, "frame", self.calib_source)
            except InputError as err:
                yield Frame(i, t, None, error=str(err))
            else:
                yield Frame(i, t, grey, None, colour)
            i += 1

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


# ------------------------------------------------------------------------------------------------
# readers
# ------------------------------------------------------------------------------------------------

def _read_file_list(path: Path, base: Path, what: str, sep: str | None = None,
                    ts_scale: float = 1.0) -> tuple[np.ndarray, list[Path], dict]:
    """(timestamps, paths, {index: "<list> line N"} of the listed files that do not exist) of a
    ``timestamp filename`` list; checks fields and order. Missing files are read as bad frames
    later; a list whose files are all missing is an error."""
    ts, files, numbers, missing = [], [], [], {}
    for n, s in read_lines(path, what):
        f = s.split(sep) if sep else s.split()
        f = [x.strip() for x in f]
        if len(f) != 2 or not f[1]:
            raise InputError(f"{path} line {n}: expected 'timestamp{',' if sep else ''} filename', got {s!r}")
        try:
            t = float(f[0]) * ts_scale if ts_scale == 1.0 else int(f[0]) * ts_scale
        except ValueError:
            raise InputError(f"{path} line {n}: timestamp {f[0]!r} is not a number") from None
        if not np.isfinite(t):
            raise InputError(f"{path} line {n}: timestamp {f[0]!r} is not finite")
        p = base / f[1]
        if not p.is_file():
            missing[len(files)] = f"{path.name} line {n}"
        ts.append(t)
        files.append(p)
        numbers.append(n)
    if not files:
        raise InputError(f"{path}: lists no images")
    if len(missing) == len(files):
        raise InputError(f"{path}: none of the {len(files)} listed files exists (first: {files[0]})")
    t = np.asarray(ts, dtype=np.float64)
    check_increasing(path, t, numbers)
    return t, files, missing


def associate_nearest(t_a: np.ndarray, t_b: np.ndarray, max_dt: float) -> np.ndarray:
    """For each time in ``t_a`` the index into ``t_b`` it is paired with, or -1.

    One-to-one greedy matching by smallest time difference (as TUM's ``associate.py``), only
    pairs within ``max_dt``. Both arrays must be sorted."""
    t_a = np.asarray(t_a, dtype=np.float64)
    t_b = np.asarray(t_b, dtype=np.float64)
    out = np.full(len(t_a), -1, dtype=np.int64)
    if len(t_a) == 0 or len(t_b) == 0:
        return out
    cand = []
    j = np.searchsorted(t_b, t_a)
    for off in (-2, -1, 0, 1):
        jj = j + off
        ok = (jj >= 0) & (jj < len(t_b))
        ia = np.nonzero(ok)[0]
        d = np.abs(t_b[jj[ok]] - t_a[ok])
        keep = d <= max_dt
        cand.append(np.stack([d[keep], ia[keep], jj[ok][keep]], axis=1))
    c = np.concatenate(cand)
    if len(c) == 0:
        return out
    c = c[np.lexsort((c[:, 2], c[:, 1], c[:, 0]))]
    used_b = np.zeros(len(t_b), dtype=bool)
    for d, ia, jb in c:
        ia, jb = int(ia), int(jb)
        if out[ia] < 0 and not used_b[jb]:
            out[ia] = jb
            used_b[jb] = True
    return out


def _read_accelerometer_txt(path: Path) -> Accelerometer:
    arr, numbers = parse_table(path, 4, 4, what="accelerometer file", layout="timestamp ax ay az")
    if len(arr) == 0:
        raise InputError(f"{path}: contains no samples")
    check_increasing(path, arr[:, 0], numbers)
    return Accelerometer(arr[:, 0], arr[:, 1:4])


def open_tum(folder: Path, calib=None, depth_max_dt: float = DEFAULT_DEPTH_MAX_DT) -> TumSequence:
    """A TUM RGB-D layout folder (``rgb.txt`` + optional depth, ground truth, accelerometer).

    Calibration: ``calib`` argument, else ``calib.txt`` in the folder, else the published Freiburg
    N calibration for folders named ``rgbd_dataset_freiburgN_*``. Depth images are associated to
    rgb images one-to-one by nearest timestamp within ``depth_max_dt``; PNG values / depth_scale
    = metres (TUM default 5000). ``accelerometer.txt`` is used as recorded: the project's format
    (and ``lite-vo synth``) store it in the camera frame; original TUM recordings store the
    Kinect's own accelerometer axes, which this reader does not convert."""
    name = folder.name
    if calib is not None:
        cal = load_calibration(calib)
    elif (folder / "calib.txt").is_file():
        cal = read_calibration(folder / "calib.txt")
    elif freiburg_number(name) is not None:
        cal = Calibration(freiburg_camera(freiburg_number(name)), TUM_DEPTH_SCALE, f"Freiburg {freiburg_number(name)}")
    else:
        raise InputError(f"{folder}: no calib.txt (and the folder name is not rgbd_dataset_freiburgN_*, "
                         "so no published calibration applies)")
    t_rgb, rgb, missing = _read_file_list(folder / "rgb.txt", folder, "image list")
    depth_paths = None
    if (folder / "depth.txt").is_file():
        t_d, dfiles, _ = _read_file_list(folder / "depth.txt", folder, "depth list")
        match = associate_nearest(t_rgb, t_d, depth_max_dt)
        depth_paths = [dfiles[j] if j >= 0 else None for j in match]
    depth_scale = cal.depth_scale if cal.depth_scale is not None else TUM_DEPTH_SCALE
    seq = TumSequence(name, cal.camera, folder, t_rgb, rgb, depth_paths, depth_scale, cal.source, missing)
    if (folder / "groundtruth.txt").is_file():
        seq.groundtruth = read_trajectory(folder / "groundtruth.txt", "ground truth file")
    if (folder / "accelerometer.txt").is_file():
        seq.accelerometer = _read_accelerometer_txt(folder / "accelerometer.txt")
    seq.check_first_frame()  # fail early on a wrong calibration or unreadable images
    return seq


def open_euroc(mav0: Path, calib=None) -> EurocSequence:
    """An EuRoC MAV ``mav0`` folder: cam0 images, IMU accelerometer and ground truth converted into
    the camera frame with the sensor extrinsics (``T_world_cam = T_world_body @ T_body_cam``)."""
    name = mav0.parent.name if mav0.name == "mav0" else mav0.name
    cam_dir = mav0 / "cam0"
    if not cam_dir.is_dir():
        raise InputError(f"{cam_dir}: EuRoC camera folder not found")
    cam_yaml = cam_dir / "sensor.yaml"
    if calib is not None:
        cal = load_calibration(calib)
        camera, calib_source = cal.camera, cal.source
        T_body_cam = read_sensor_transform(cam_yaml) if cam_yaml.is_file() else np.eye(4)
    else:
        if not cam_yaml.is_file():
            raise InputError(f"{cam_yaml}: camera calibration not found")
        camera, T_body_cam = read_euroc_camera_yaml(cam_yaml)
        calib_source = str(cam_yaml)
    t, images, missing = _read_file_list(cam_dir / "data.csv", cam_dir / "data", "image list", sep=",",
                                         ts_scale=1e-9)
    seq = EurocSequence(name, camera, mav0, t, images, calib_source=calib_source, listed_in=missing)
    R_cam_body = T_body_cam[:3, :3].T

    imu_csv = mav0 / "imu0" / "data.csv"
    if imu_csv.is_file():
        arr, numbers = parse_table(imu_csv, 7, None, sep=",", what="IMU file",
                                   layout="timestamp [ns], w_x, w_y, w_z, a_x, a_y, a_z")
        if len(arr):
            ts = arr[:, 0] * 1e-9
            check_increasing(imu_csv, ts, numbers)
            imu_yaml = mav0 / "imu0" / "sensor.yaml"
            T_body_imu = read_sensor_transform(imu_yaml) if imu_yaml.is_file() else np.eye(4)
            acc_cam = arr[:, 4:7] @ (R_cam_body @ T_body_imu[:3, :3]).T
            seq.accelerometer = Accelerometer(ts, acc_cam)

    gt_csv = mav0 / "state_groundtruth_estimate0" / "data.csv"
    if gt_csv.is_file():
        seq.groundtruth, _ = read_euroc_groundtruth(gt_csv, T_body_cam=T_body_cam)
    seq.check_first_frame()
    return seq


def open_image_folder(folder: Path, calib=None, fps: Optional[float] = None) -> ImageFolderSequence:
    """A folder of images (sorted by name, natural order) with ``calib.txt`` (or ``calib``);
    timestamps from ``times.txt`` (one per image) if present, else ``index / fps``."""
    files = sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS),
                   key=lambda p: natural_key(p.name))
    if not files:
        raise InputError(f"{folder}: no image files")
    if calib is not None:
        cal = load_calibration(calib)
    elif (folder / "calib.txt").is_file():
        cal = read_calibration(folder / "calib.txt")
    else:
        raise InputError(f"{folder}: image folder without calib.txt (pass a calibration file)")
    times = folder / "times.txt"
    if times.is_file():
        arr, numbers = parse_table(times, 1, None, what="times file", layout="timestamp")
        if len(arr) != len(files):
            raise InputError(f"{times}: has {len(arr)} timestamps for {len(files)} images")
        check_increasing(times, arr[:, 0], numbers)
        t = arr[:, 0]
    else:
        f = float(fps) if fps else DEFAULT_FPS
        if not f > 0:
            raise InputError(f"fps must be positive, got {fps}")
        t = np.arange(len(files)) / f
    seq = ImageFolderSequence(folder.name, cal.camera, folder, t, files, calib_source=cal.source)
    if (folder / "groundtruth.txt").is_file():
        seq.groundtruth = read_trajectory(folder / "groundtruth.txt", "ground truth file")
    seq.check_first_frame()
    return seq


def _find_mav0(folder: Path) -> Optional[Path]:
    if (folder / "cam0" / "data.csv").is_file():
        return folder
    if (folder / "mav0").is_dir():
        return folder / "mav0"
    return None


def open_sequence(path: Union[str, os.PathLike, int], calib=None, *, fps: Optional[float] = None,
                  depth_max_dt: float = DEFAULT_DEPTH_MAX_DT, topic: Optional[str] = None) -> Sequence:
    """Open a sequence.

    ``path``: a TUM RGB-D layout folder (``rgb.txt``), an EuRoC folder (with ``mav0/``, or
    ``mav0`` itself), an image folder (+ ``calib.txt`` inside or ``calib``), a video file
    (+ ``calib`` or ``calib.txt`` beside it), or an ``int`` (or digit string) camera index for a
    live camera (``calib`` required).
    ``calib``: a calibration file in any format :func:`~lite_vo.io.calib_formats.read_calibration`
    reads (``calib.txt``, OpenCV, Kalibr, ROS ``camera_info`` or EuRoC YAML), a
    :class:`Calibration` or a :class:`Camera`, overriding the sequence's own.
    ``fps``: frame rate for image folders without ``times.txt`` and to override a video's rate.
    ``depth_max_dt``: TUM rgb/depth association tolerance in seconds.
    ``path`` may also be a ROS 1 ``.bag`` or a ROS 2 bag folder (``metadata.yaml``), read by
    :func:`lite_vo.io.rosbag.open_rosbag`; ``topic``: its image topic (needed when it has several).
    """
    if isinstance(path, (int, np.integer)) or (isinstance(path, str) and path.isdigit() and not Path(path).exists()):
        index = int(path)
        if calib is None:
            raise InputError(f"camera {index}: a calibration file is required for a live camera")
        cal = load_calibration(calib)
        return LiveCameraSequence(index, cal.camera, cal.source)
    p = Path(path).expanduser()
    if not p.exists():
        raise InputError(f"{p}: no such file or directory")
    from .rosbag import is_rosbag, open_rosbag
    if is_rosbag(p):
        return open_rosbag(p, calib, topic=topic)
    if topic is not None:
        raise InputError(f"{p}: topic= applies to ROS bags only")
    if p.is_file():
        if p.suffix.lower() in VIDEO_EXTENSIONS:
            if calib is None:
                beside = p.parent / "calib.txt"
                if not beside.is_file():
                    raise InputError(f"{p}: video needs a calibration file (calib.txt beside it or calib=)")
                calib = beside
            cal = load_calibration(calib)
            return VideoSequence(p, cal.camera, fps, cal.source)
        raise InputError(f"{p}: unknown sequence format (expected a folder or a video file "
                         f"{'/'.join(VIDEO_EXTENSIONS)})")
    if (p / "rgb.txt").is_file():
        return open_tum(p, calib, depth_max_dt)
    mav0 = _find_mav0(p)
    if mav0 is not None:
        return open_euroc(mav0, calib)
    if any(c.is_file() and c.suffix.lower() in IMAGE_EXTENSIONS for c in p.iterdir()):
        return open_image_folder(p, calib, fps)
    raise InputError(f"{p}: unknown sequence format (no rgb.txt (TUM), mav0/ (EuRoC) or image files)")
