"""Sequence readers (TUM RGB-D, EuRoC, image folders, video files, live cameras), calibration
files (``calib.txt``, OpenCV, Kalibr, ROS camera_info and EuRoC YAML), trajectory (TUM format)
and PLY point-cloud I/O.

May import numpy, cv2 (lazily), PyYAML (lazily), ``lite_vo.camera``, ``lite_vo.geometry``,
``lite_vo.errors``; never the tracking, mapping, system or CLI modules.
"""
from .calib import Calibration, freiburg_camera, read_calib_txt, write_calib_txt
from .calib_formats import camera_from_ros, load_calibration, read_calibration, read_euroc_camera_yaml
from .outputs import check_output_file, prepare_output_dir, write_file_atomic
from .ply import read_ply, write_ply, write_ply_parts
from .sequences import (EurocSequence, FileSequence, ImageFolderSequence, LiveCameraSequence, Sequence,
                        TumSequence, VideoSequence, associate_nearest, open_sequence)
from .trajectory import read_trajectory, write_trajectory
from .types import Accelerometer, Frame, Trajectory

__all__ = [
    "open_sequence", "Sequence", "FileSequence", "TumSequence", "EurocSequence", "ImageFolderSequence",
    "VideoSequence", "LiveCameraSequence", "Frame", "Trajectory", "Accelerometer",
    "read_trajectory", "write_trajectory", "write_ply", "write_ply_parts", "read_ply", "prepare_output_dir", "check_output_file", "write_file_atomic",
    "Calibration", "read_calibration", "load_calibration", "camera_from_ros", "read_calib_txt", "write_calib_txt",
    "read_euroc_camera_yaml", "freiburg_camera", "associate_nearest",
]
