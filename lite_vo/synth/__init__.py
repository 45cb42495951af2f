"""Synthetic sequences with exact ground truth (rendered by a numba ray caster, no GL).

World frame: metres, **z up**, floor at z = 0, gravity ``(0, 0, -9.81)`` m/s^2. Cameras: x
right, y down, z forward; poses are ``T_world_cam``.

* :func:`make_scene` (``SCENES``: ``room``, ``desk``) -> :class:`Scene`
* :func:`make_trajectory` (``TRAJECTORIES``: ``handheld``, ``fast``, ``rotation``, ``forward``)
  -> ``(timestamps, poses)``; :func:`make_motion` for the analytic motion (accelerations)
* :func:`render_frame` -> ``(image float32 0..255, depth float32 metres)``
* :func:`iter_frames` (in memory) and :func:`generate_sequence` (TUM folder, ``lite-vo synth``)

May import numpy, numba, cv2 and lite_vo core modules; never GL, pybullet, trimesh or ar_demo.
"""
from .config import SynthConfig
from .render import default_intrinsics, render_frame
from .scenes import GRAVITY_WORLD, SCENES, Scene, make_scene
from .sequence import GeneratedSequence, SynthFrame, generate_sequence, iter_frames
from .trajectories import TRAJECTORIES, Motion, make_motion, make_trajectory

__all__ = [
    "GRAVITY_WORLD", "GeneratedSequence", "Motion", "SCENES", "Scene", "SynthConfig",
    "SynthFrame", "TRAJECTORIES", "default_intrinsics", "generate_sequence", "iter_frames",
    "make_motion", "make_scene", "make_trajectory", "render_frame",
]
