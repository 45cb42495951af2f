#!/usr/bin/env python
"""Write a TUM-layout folder (``rgb.txt`` + images + ``calib.txt``, optional ``accelerometer.txt``)
into a ROS bag: a ROS 1 ``.bag`` file when OUT ends in ``.bag``, else a ROS 2 bag folder
(``--storage sqlite3`` or ``mcap``). Needs the ``[ros]`` extra (rosbags).

    python tools/tum_to_bag.py ../shared/data/icl_livingroom_211 /tmp/icl90.bag --max-frames 90
    python tools/tum_to_bag.py SEQ /tmp/seq_ros2 --storage mcap --encoding rgb8 --compressed jpeg

Topics: ``TOPIC`` (default ``/camera/image_raw``; ``TOPIC/compressed`` with ``--compressed``) with
header stamps = the rgb.txt timestamps (the bag time too), ``<namespace>/camera_info`` (plumb_bob,
one per image) and, when the folder has ``accelerometer.txt``, ``/imu`` (``sensor_msgs/Imu``, only
``linear_acceleration``). Ground truth and depth images stay in the folder (``lite-vo eval --gt FOLDER``).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ENCODINGS = ("mono8", "mono16", "rgb8", "bgr8")


def image_as(path: Path, encoding: str) -> np.ndarray:
    """The image file ``path`` in the layout of the ROS ``encoding``."""
    import cv2

    from lite_vo.errors import InputError
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(f"{path}: cannot read image")
    if encoding == "bgr8":
        return img
    if encoding == "rgb8":
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    return grey if encoding == "mono8" else grey.astype(np.uint16) * 257


def convert(folder: Path, out: Path, *, max_frames: int | None = None, encoding: str = "mono8",
            compressed: str | None = None, storage: str = "sqlite3", topic: str = "/camera/image_raw",
            camera_info: bool = True, imu_topic: str = "/imu") -> int:
    """Write the bag; returns the number of images written."""
    from lite_vo.errors import InputError
    from lite_vo.io.rosbag import BagWriter
    from lite_vo.io.sequences import open_tum
    if encoding not in ENCODINGS:
        raise InputError(f"unknown encoding {encoding!r} (use one of {', '.join(ENCODINGS)})")
    if not topic.startswith("/") or topic.endswith("/"):
        raise InputError(f"topic {topic!r} must start with '/' and not end with '/'")
    seq = open_tum(folder)
    n = len(seq) if max_frames is None else min(len(seq), max_frames)
    t_img = seq.timestamps[:n]
    info_topic = topic.rsplit("/", 1)[0] + "/camera_info"
    image_topic = topic + "/compressed" if compressed else topic
    acc = seq.accelerometer
    imu = []
    if acc is not None:
        keep = acc.timestamps <= t_img[-1] + 0.5
        imu = list(zip(acc.timestamps[keep], acc.acc_xyz[keep]))
    # messages in time order (the bag time is the stamp): images with their CameraInfo, then IMU
    events = [(float(t), 0, i) for i, t in enumerate(t_img)] + [(float(t), 1, k) for k, (t, _) in enumerate(imu)]
    events.sort()
    with BagWriter(out, ros2=out.suffix.lower() != ".bag", storage=storage) as w:
        for t, kind, i in events:
            if kind == 0:
                if camera_info:
                    w.camera_info(info_topic, t, seq.camera)
                w.image(image_topic, t, image_as(seq.image_paths[i], encoding), encoding, compressed)
            else:
                w.imu(imu_topic, t, imu[i][1])
    return n


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folder", type=Path, help="TUM-layout folder (rgb.txt, images, calib.txt)")
    p.add_argument("out", type=Path, help="OUT.bag (ROS 1) or a folder name (ROS 2); must not exist")
    p.add_argument("--max-frames", type=int, default=None, help="write at most N images")
    p.add_argument("--encoding", choices=ENCODINGS, default="mono8", help="image encoding (default mono8)")
    p.add_argument("--compressed", choices=("jpeg", "png"), default=None,
                   help="write sensor_msgs/CompressedImage on TOPIC/compressed instead of raw images")
    p.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3", help="ROS 2 storage (default sqlite3)")
    p.add_argument("--topic", default="/camera/image_raw", help="image topic (default /camera/image_raw)")
    p.add_argument("--no-camera-info", action="store_true", help="leave out the CameraInfo messages")
    args = p.parse_args(argv)
    from lite_vo.errors import LiteVOError
    if args.max_frames is not None and args.max_frames <= 0:
        print("tum_to_bag: error: --max-frames must be positive", file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    try:
        n = convert(args.folder, args.out, max_frames=args.max_frames, encoding=args.encoding,
                    compressed=args.compressed, storage=args.storage, topic=args.topic,
                    camera_info=not args.no_camera_info)
    except LiteVOError as err:
        print(f"tum_to_bag: error: {err}", file=sys.stderr)
        return 1
    print(f"wrote {n} images to {args.out} in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
