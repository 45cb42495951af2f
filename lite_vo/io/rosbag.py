"""ROS bags without ROS: ROS 1 ``.bag`` files and ROS 2 bag folders (``metadata.yaml`` with sqlite3
or MCAP storage) read with the pure-Python ``rosbags`` library (the ``[ros]`` extra).

What is read:

* images: ``sensor_msgs/Image`` (mono8, 8UC1, mono16, rgb8, bgr8, rgba8, bgra8) or
  ``sensor_msgs/CompressedImage`` (jpeg, png) on one topic, found automatically when the bag has
  exactly one image topic that is not a depth image (``topic=`` otherwise); converted to 8-bit grey
  while iterating, one message at a time (mono16 as the folder readers do: value / 257);
* calibration: the first ``sensor_msgs/CameraInfo`` of the image topic's namespace
  (``/cam/image_raw`` and ``/cam/image_raw/compressed`` -> ``/cam/camera_info``, then the parent
  namespaces), unless ``calib=`` is given; plumb_bob (radial-tangential) lenses;
* accelerometer: ``sensor_msgs/Imu`` ``linear_acceleration`` (the one IMU topic, or the one in the
  camera's namespace, or ``imu_topic=``). The IMU frame is assumed to be the camera frame (no
  transform is read from the bag), as for TUM's ``accelerometer.txt``;
* timestamps: the message header stamp; the bag (receive) time when the header stamp is 0.

Opening a bag reads the image topic once without decoding the pixels (header stamps, encodings:
validated up front like the index files of the folder readers) plus the CameraInfo and IMU
messages; pixels are decoded lazily while iterating.

:class:`BagWriter` writes the same message types (ROS 1 or ROS 2), for ``tools/tum_to_bag.py``
and the tests.

Imports numpy, cv2 and rosbags lazily, ``lite_vo.camera``, ``lite_vo.errors`` and the io types.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator, Optional, Union

import numpy as np

from ..camera import Camera
from ..errors import InputError, MissingExtraError
from .base import Sequence
from .calib_formats import camera_from_ros, load_calibration
from .types import Accelerometer, Frame

ROS_EXTRA_MESSAGE = "reading ROS bags needs the [ros] extra: pip install 'lite-vo[ros]'"

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMU = "sensor_msgs/msg/Imu"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)

#: raw encodings read as images: (channels, dtype, cv2 conversion to grey or None)
_ENCODINGS = {
    "mono8": (1, np.uint8, None), "8UC1": (1, np.uint8, None), "mono16": (1, np.uint16, None),
    "rgb8": (3, np.uint8, "COLOR_RGB2GRAY"), "bgr8": (3, np.uint8, "COLOR_BGR2GRAY"),
    "8UC3": (3, np.uint8, "COLOR_BGR2GRAY"),     # cv_bridge's convention: 8UC3 is BGR
    "rgba8": (4, np.uint8, "COLOR_RGBA2GRAY"), "bgra8": (4, np.uint8, "COLOR_BGRA2GRAY"),
}
#: encodings of depth images: never picked as the camera topic automatically
DEPTH_ENCODINGS = ("16UC1", "32FC1", "16SC1", "32SC1", "64FC1")
BAG_FILE_SUFFIXES = (".bag", ".db3", ".mcap")


def _rosbags():
    """The rosbags modules used here, or a one-line MissingExtraError."""
    try:
        from rosbags.highlevel import AnyReader, AnyReaderError
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise MissingExtraError(ROS_EXTRA_MESSAGE) from None
    return AnyReader, AnyReaderError, Stores, get_typestore


def is_rosbag(path: Path) -> bool:
    """True for a ROS 1 ``.bag`` file, a ROS 2 bag folder (``metadata.yaml``) or a ``.db3`` /
    ``.mcap`` file inside one (no rosbags needed to decide)."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    suffix = path.suffix.lower()
    return suffix == ".bag" or (suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file())


def _bag_location(path: Path) -> Path:
    """What rosbags opens: the ``.bag`` file or the ROS 2 folder."""
    if path.is_file() and path.suffix.lower() in (".db3", ".mcap"):
        return path.parent
    return path


class _Reader:
    """An open ``AnyReader`` whose errors (corrupt bag, unknown types) become InputError."""

    def __init__(self, location: Path):
        AnyReader, self._err, Stores, get_typestore = _rosbags()
        self.location = location
        try:
            self.reader = AnyReader([location], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            self.reader.open()
        except (self._err, OSError, ValueError, KeyError) as err:
            raise InputError(f"{location}: cannot read ROS bag ({_one_line(err)})") from None

    def close(self) -> None:
        if self.reader.stack is not None:
            self.reader.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def connections(self, topic: str) -> list:
        return [c for c in self.reader.connections if c.topic == topic]

    def messages(self, topic: str, start: Optional[int] = None, stop: Optional[int] = None):
        """(bag time ns, message type, deserialised message) of ``topic`` in bag-time order."""
        conns = self.connections(topic)
        try:
            for con, t, raw in self.reader.messages(connections=conns, start=start, stop=stop):
                yield t, con.msgtype, self.reader.deserialize(raw, con.msgtype)
        except (self._err, OSError, ValueError, KeyError, IndexError) as err:
            raise InputError(f"{self.location}: {topic}: cannot read message ({_one_line(err)})") from None


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


def _stamp_ns(msg, bag_time_ns: int) -> int:
    """Header stamp in ns, or the bag time when the header stamp is 0."""
    s = msg.header.stamp
    ns = int(s.sec) * 1_000_000_000 + int(s.nanosec)
    return ns if ns != 0 else int(bag_time_ns)


def _compressed_target(fmt: str) -> str:
    """Pixel order of a CompressedImage after decoding: image_transport writes formats such as
    ``"rgb8; jpeg compressed bgr8"`` (the part after ``compressed``); a bare ``"jpeg"`` is BGR."""
    f = fmt.lower()
    if "compressed " in f:
        return f.split("compressed ", 1)[1].strip()
    return "bgr8"


def image_from_message(msg, msgtype: str, where: str) -> np.ndarray:
    """uint8 grey (H, W) image of a ``sensor_msgs/Image`` or ``CompressedImage`` message."""
    import cv2
    if msgtype == COMPRESSED_IMAGE:
        if "compresseddepth" in msg.format.lower():
            raise InputError(f"{where}: is a compressed depth image ({msg.format!r}), not a camera image")
        img = cv2.imdecode(np.frombuffer(np.asarray(msg.data, dtype=np.uint8), np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError(f"{where}: cannot decode the compressed image (format {msg.format!r})")
        rgb = _compressed_target(msg.format).startswith("rgb")
        if img.ndim == 3:
            code = {3: cv2.COLOR_RGB2GRAY if rgb else cv2.COLOR_BGR2GRAY,
                    4: cv2.COLOR_RGBA2GRAY if rgb else cv2.COLOR_BGRA2GRAY}.get(img.shape[2])
            img = cv2.cvtColor(img, code) if code is not None else img[..., 0]
    else:
        enc = msg.encoding
        if enc not in _ENCODINGS:
            raise InputError(f"{where}: unsupported image encoding {enc!r} (supported: {', '.join(_ENCODINGS)})")
        ch, dtype, conversion = _ENCODINGS[enc]
        h, w, step = int(msg.height), int(msg.width), int(msg.step)
        row_bytes = w * ch * np.dtype(dtype).itemsize
        data = np.asarray(msg.data, dtype=np.uint8)
        if h <= 0 or w <= 0 or step < row_bytes or len(data) < h * step:
            raise InputError(f"{where}: {w}x{h} {enc} image needs {h} rows of at least {row_bytes} bytes, "
                             f"got step {step} and {len(data)} bytes")
        rows = data[:h * step].reshape(h, step)[:, :row_bytes]
        if dtype == np.uint16:
            rows = np.ascontiguousarray(rows).view(">u2" if msg.is_bigendian else "<u2").astype(np.uint16)
        img = rows.reshape(h, w, ch) if ch > 1 else rows.reshape(h, w)
        if conversion is not None:
            img = cv2.cvtColor(np.ascontiguousarray(img), getattr(cv2, conversion))
    if img.dtype == np.uint16:
        img = (img.astype(np.float32) / 257.0 + 0.5).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise InputError(f"{where}: unsupported image type {img.dtype} (expected 8- or 16-bit)")
    return np.ascontiguousarray(img)


def _is_depth(msg, msgtype: str) -> bool:
    if msgtype == COMPRESSED_IMAGE:
        return "compresseddepth" in msg.format.lower()
    return msg.encoding in DEPTH_ENCODINGS


def _field(msg, *names):
    """The first of ``names`` the message has (ROS 1 CameraInfo fields are ``K``, ROS 2 ``k``)."""
    for n in names:
        if hasattr(msg, n):
            return getattr(msg, n)
    raise AttributeError(names[0])


def _camera_from_info_message(msg, source: str) -> Camera:
    bx, by = int(getattr(msg, "binning_x", 0) or 0), int(getattr(msg, "binning_y", 0) or 0)
    roi = getattr(msg, "roi", None)
    if bx > 1 or by > 1 or (roi is not None and int(roi.width) not in (0, int(msg.width))):
        raise InputError(f"{source}: binning / region of interest is not supported; pass a calibration file")
    return camera_from_ros(int(msg.width), int(msg.height), msg.distortion_model,
                                    _field(msg, "k", "K"), _field(msg, "d", "D"), source)


def _namespaces(topic: str) -> list[str]:
    """Namespaces of an image topic, innermost first: ``/a/b/image_raw/compressed`` -> ``/a/b``, ``/a``, ``""``."""
    parts = [p for p in topic.split("/") if p]
    if parts and parts[-1] in ("compressed", "theora", "compressedDepth"):
        parts = parts[:-1]
    parts = parts[:-1]
    return ["/" + "/".join(parts[:k]) if k else "" for k in range(len(parts), -1, -1)]


def _choose_topic(path: Path, reader: _Reader, topics: dict) -> str:
    """The one image topic that is not a depth image, or an InputError listing the candidates."""
    image_topics = sorted(t for t, typ in topics.items() if typ in IMAGE_TYPES)
    if not image_topics:
        listing = ", ".join(f"{t} ({typ})" for t, typ in sorted(topics.items())) or "none"
        raise InputError(f"{path}: no sensor_msgs/Image or CompressedImage topic (topics: {listing})")
    candidates = []
    for t in image_topics:
        first = next(reader.messages(t), None)
        if first is None or not _is_depth(first[2], first[1]):
            candidates.append(t)
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        raise InputError(f"{path}: the only image topics hold depth images ({', '.join(image_topics)}); "
                         "choose one with topic= (--topic)")
    raise InputError(f"{path}: several image topics: {', '.join(candidates)}; choose one with topic= (--topic)")


def _choose_imu_topic(path: Path, topics: dict, image_topic: str, imu_topic: Optional[str]) -> Optional[str]:
    imus = sorted(t for t, typ in topics.items() if typ == IMU)
    if imu_topic is not None:
        if imu_topic not in imus:
            raise InputError(f"{path}: no sensor_msgs/Imu topic {imu_topic!r} (IMU topics: {', '.join(imus) or 'none'})")
        return imu_topic
    if len(imus) <= 1:
        return imus[0] if imus else None
    for ns in _namespaces(image_topic)[:-1]:  # the innermost namespace with exactly one IMU topic
        inside = [t for t in imus if t.startswith(ns + "/")]
        if len(inside) == 1:
            return inside[0]
    return None


class RosbagSequence(Sequence):
    """Images of one topic of a ROS 1 or ROS 2 bag (see the module docstring).

    ``topic``, ``camera_info_topic`` (None when ``calib`` was given), ``imu_topic`` (or None),
    ``timestamps`` (s, from the header stamps); ``frame(i)`` reads one message by its bag time."""

    kind = "rosbag"

    def __init__(self, name: str, camera: Camera, path: Path, topic: str, timestamps: np.ndarray,
                 bag_times_ns: np.ndarray):
        super().__init__(name, camera, path)
        self.topic = topic
        self.camera_info_topic: Optional[str] = None
        self.imu_topic: Optional[str] = None
        self.timestamps = np.asarray(timestamps, dtype=np.float64)
        self.timestamps.setflags(write=False)
        self._bag_times = np.asarray(bag_times_ns, dtype=np.int64)
        self._random_access: Optional[_Reader] = None

    def __len__(self) -> int:
        return len(self.timestamps)

    def _where(self, i: int) -> str:
        return f"{self.path}: {self.topic} frame {i}"

    def _image(self, i: int, msgtype: str, msg) -> np.ndarray:
        img = image_from_message(msg, msgtype, self._where(i))
        h, w = img.shape[:2]
        if (w, h) != (self.camera.width, self.camera.height):
            raise InputError(f"{self._where(i)}: image is {w}x{h} but the calibration says "
                             f"{self.camera.width}x{self.camera.height}")
        return img

    def __iter__(self) -> Iterator[Frame]:
        with _Reader(_bag_location(self.path)) as reader:
            for i, (_, msgtype, msg) in enumerate(reader.messages(self.topic)):
                if i >= len(self):
                    break
                yield Frame(i, float(self.timestamps[i]), self._image(i, msgtype, msg), None)

    def frame(self, i: int) -> Frame:
        """Frame ``i`` (random access: reads the messages at its bag time only)."""
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range for {n} frames")
        i %= n
        if self._random_access is None:
            self._random_access = _Reader(_bag_location(self.path))
        t = int(self._bag_times[i])
        rank = i - int(np.searchsorted(self._bag_times, t))     # messages sharing one bag time
        for k, (_, msgtype, msg) in enumerate(self._random_access.messages(self.topic, start=t, stop=t + 1)):
            if k == rank:
                return Frame(i, float(self.timestamps[i]), self._image(i, msgtype, msg), None)
        raise InputError(f"{self._where(i)}: message not found at bag time {t} ns (bag changed since it was opened?)")

    def close(self) -> None:
        if self._random_access is not None:
            self._random_access.close()
            self._random_access = None


def open_rosbag(path: Union[str, os.PathLike], calib=None, *, topic: Optional[str] = None,
                imu_topic: Optional[str] = None) -> RosbagSequence:
    """Open a ROS 1 ``.bag`` file or a ROS 2 bag folder as a sequence (see the module docstring).

    ``calib``: a ``calib.txt`` path, :class:`~lite_vo.io.calib.Calibration` or :class:`Camera`
    overriding the bag's CameraInfo; ``topic``: the image topic (needed when the bag has several);
    ``imu_topic``: the ``sensor_msgs/Imu`` topic (default: the only one, or the one in the
    camera's namespace)."""
    path = Path(path).expanduser()
    if not path.exists():
        raise InputError(f"{path}: no such file or directory")
    location = _bag_location(path)
    with _Reader(location) as reader:
        topics = {}
        for c in reader.reader.connections:
            topics.setdefault(c.topic, c.msgtype)
        if topic is None:
            topic = _choose_topic(location, reader, topics)
        elif topics.get(topic) not in IMAGE_TYPES:
            listing = ", ".join(t for t, typ in sorted(topics.items()) if typ in IMAGE_TYPES) or "none"
            what = "no topic" if topic not in topics else f"topic of type {topics[topic]}, not an image:"
            raise InputError(f"{location}: {what} {topic!r} (image topics: {listing})")

        stamps, bag_times, first = [], [], None
        for t, msgtype, msg in reader.messages(topic):
            if first is None:
                first = (msgtype, msg)
            stamps.append(_stamp_ns(msg, t))
            bag_times.append(t)
        if first is None:
            raise InputError(f"{location}: topic {topic} has no messages")
        stamps_ns = np.asarray(stamps, dtype=np.int64)
        bad = np.nonzero(np.diff(stamps_ns) <= 0)[0]
        if len(bad):
            i = int(bad[0]) + 1
            raise InputError(f"{location}: {topic} frame {i}: header stamp {stamps_ns[i] / 1e9:.9f} s is not after "
                             f"the previous one ({stamps_ns[i - 1] / 1e9:.9f} s); timestamps must be strictly increasing")

        info_topic = None
        if calib is not None:
            camera = load_calibration(calib).camera
        else:
            infos = {t for t, typ in topics.items() if typ == CAMERA_INFO}
            info_topic = next((ns + "/camera_info" for ns in _namespaces(topic) if ns + "/camera_info" in infos), None)
            if info_topic is None:
                raise InputError(f"{location}: no sensor_msgs/CameraInfo for {topic} (looked for "
                                 f"{', '.join(ns + '/camera_info' for ns in _namespaces(topic))}); "
                                 "pass a calibration file (calib= / --calib)")
            _, _, info = next(reader.messages(info_topic))
            camera = _camera_from_info_message(info, f"{location}: {info_topic}")

        acc = None
        imu_name = _choose_imu_topic(location, topics, topic, imu_topic)
        if imu_name is not None:
            t_imu, a_imu = [], []
            for t, _, msg in reader.messages(imu_name):
                ns = _stamp_ns(msg, t)
                if t_imu and ns <= t_imu[-1]:
                    continue        # repeated or out-of-order sample: keep the first
                la = msg.linear_acceleration
                t_imu.append(ns)
                a_imu.append((la.x, la.y, la.z))
            if t_imu:
                a = np.asarray(a_imu, dtype=np.float64)
                if not np.all(np.isfinite(a)):
                    raise InputError(f"{location}: {imu_name}: linear_acceleration contains NaN or infinite values")
                acc = Accelerometer(np.asarray(t_imu, dtype=np.int64) / 1e9, a)

    name = path.stem if path.is_file() and location == path else location.name
    seq = RosbagSequence(name, camera, path, topic, stamps_ns / 1e9, np.asarray(bag_times))
    seq.camera_info_topic = info_topic
    seq.imu_topic = imu_name if acc is not None else None
    seq.accelerometer = acc
    seq._image(0, *first)       # fail early on an unsupported encoding or a wrong calibration
    return seq


# ------------------------------------------------------------------------------------------------
# writing (tools/tum_to_bag.py, tests)
# ------------------------------------------------------------------------------------------------

class BagWriter:
    """Writes ``sensor_msgs`` Image / CompressedImage / CameraInfo / Imu messages into a ROS 1 bag
    (``ros2=False``, a ``.bag`` file) or a ROS 2 bag folder (``storage`` ``"sqlite3"`` or
    ``"mcap"``). Header stamp and bag time are both the given timestamp (seconds). Needs rosbags."""

    def __init__(self, path: Union[str, os.PathLike], ros2: bool = False, storage: str = "sqlite3"):
        _rosbags()
        from rosbags.typesys import Stores, get_typestore
        self.path = Path(path)
        self.ros2 = bool(ros2)
        if self.path.exists():
            raise InputError(f"{self.path}: exists already (a bag is never overwritten)")
        if self.ros2:
            from rosbags.rosbag2 import StoragePlugin, Writer
            plugins = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
            if storage not in plugins:
                raise InputError(f"unknown ROS 2 storage {storage!r} (use sqlite3 or mcap)")
            self.typestore = get_typestore(Stores.ROS2_HUMBLE)
            self._writer = Writer(self.path, version=8, storage_plugin=plugins[storage])
        else:
            from rosbags.rosbag1 import Writer
            self.typestore = get_typestore(Stores.ROS1_NOETIC)
            self._writer = Writer(self.path)
        self._writer.open()
        self._connections: dict = {}
        self._seq: dict = {}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def _header(self, topic: str, t: float, frame_id: str):
        types = self.typestore.types
        ns = int(round(t * 1e9))
        stamp = types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        if self.ros2:
            return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id), ns
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        return types["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame_id), ns

    def write_message(self, topic: str, msg, bag_time_ns: int) -> None:
        """Serialise ``msg`` (a rosbags message of this writer's ``typestore``) onto ``topic``."""
        typ = msg.__msgtype__
        con = self._connections.get(topic)
        if con is None:
            con = self._connections[topic] = self._writer.add_connection(topic, typ, typestore=self.typestore)
        data = (self.typestore.serialize_cdr(msg, typ) if self.ros2 else self.typestore.serialize_ros1(msg, typ))
        self._writer.write(con, int(bag_time_ns), data)

    def image(self, topic: str, t: float, image: np.ndarray, encoding: str, compressed: Optional[str] = None,
              frame_id: str = "camera") -> None:
        """``image`` as ``encoding`` (mono8, mono16, rgb8, bgr8: the array must already be in that
        layout); ``compressed`` ``"jpeg"`` or ``"png"`` writes a CompressedImage instead."""
        import cv2
        types = self.typestore.types
        header, ns = self._header(topic, t, frame_id)
        image = np.ascontiguousarray(image)
        if compressed is not None:
            if compressed not in ("jpeg", "png"):
                raise InputError(f"unknown compression {compressed!r} (use jpeg or png)")
            bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if encoding == "rgb8" else image
            target = "bgr8" if encoding == "rgb8" else encoding
            ok, buf = cv2.imencode("." + ("jpg" if compressed == "jpeg" else "png"), bgr)
            if not ok:
                raise InputError(f"cannot encode a {encoding} image as {compressed}")
            msg = types[COMPRESSED_IMAGE](header=header, format=f"{encoding}; {compressed} compressed {target}",
                                          data=np.frombuffer(buf.tobytes(), np.uint8))
        else:
            h, w = image.shape[:2]
            data = image.astype("<u2") if encoding == "mono16" else image
            msg = types[IMAGE](header=header, height=h, width=w, encoding=encoding, is_bigendian=0,
                               step=data.strides[0], data=np.frombuffer(data.tobytes(), np.uint8))
        self.write_message(topic, msg, ns)

    def camera_info(self, topic: str, t: float, camera: Camera, frame_id: str = "camera") -> None:
        """``camera`` as a plumb_bob CameraInfo (pinhole or radial-tangential)."""
        if camera.model not in ("none", "radtan"):
            raise InputError(f"a {camera.model} camera has no ROS CameraInfo model (plumb_bob only)")
        types = self.typestore.types
        header, ns = self._header(topic, t, frame_id)
        i = camera.intrinsics
        K = np.array([i.fx, 0, i.cx, 0, i.fy, i.cy, 0, 0, 1], dtype=np.float64)
        P = np.array([i.fx, 0, i.cx, 0, 0, i.fy, i.cy, 0, 0, 0, 1, 0], dtype=np.float64)
        D = np.asarray(camera.params if camera.model == "radtan" else (0.0,) * 5, dtype=np.float64)
        R = np.eye(3).reshape(-1)
        roi = types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        mats = dict(d=D, k=K, r=R, p=P) if self.ros2 else dict(D=D, K=K, R=R, P=P)
        msg = types[CAMERA_INFO](header=header, height=i.height, width=i.width, distortion_model="plumb_bob",
                                 binning_x=0, binning_y=0, roi=roi, **mats)
        self.write_message(topic, msg, ns)

    def imu(self, topic: str, t: float, acc_xyz, frame_id: str = "imu") -> None:
        """An Imu message with ``linear_acceleration`` only (orientation and angular velocity
        marked unknown: covariance[0] = -1)."""
        types = self.typestore.types
        header, ns = self._header(topic, t, frame_id)
        V3, Q = types["geometry_msgs/msg/Vector3"], types["geometry_msgs/msg/Quaternion"]
        unknown = np.zeros(9)
        unknown[0] = -1.0
        a = [float(v) for v in acc_xyz]
        msg = types[IMU](header=header, orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=unknown,
                         angular_velocity=V3(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=unknown.copy(),
                         linear_acceleration=V3(x=a[0], y=a[1], z=a[2]), linear_acceleration_covariance=np.zeros(9))
        self.write_message(topic, msg, ns)
