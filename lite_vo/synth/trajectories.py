"""Smooth analytic camera trajectories (30 Hz by default) with exact accelerations.

Every position is ``p(t) = offset + sum_k amp_k * sin(omega_k t + phase_k)`` per axis, so the
velocity and the acceleration are analytic (the accelerometer is exact). Orientation comes from a
look-at construction (camera z towards a moving target point, or along the horizontal walking
direction pitched down), camera x to the right (horizontal), y down, plus a small roll sinusoid.

Trajectories (per scene, randomised a little by the seed):

* ``handheld``: TUM fr2/xyz-like hand-held motion, ~5-20 cm/s and ~5-20 deg/s, looking at the
  scene with the floor visible; it starts with a sideways translation (good for random-depth
  initialisation: the other components start with zero velocity).
* ``fast``: ``handheld`` played 3x faster (3x velocities, 9x accelerations).
* ``rotation``: pure rotation about the camera centre (the degenerate case for monocular VO);
  the accelerometer then reads exactly gravity.
* ``forward``: walking forward: in the room a loop (ellipse) looking along the walking direction,
  pitched down, with a step bob; at the desk a slow approach towards the desk (forward during the
  first 10 s, then back).

World frame: z up, floor z = 0 (see :mod:`lite_vo.synth.scenes`). Imports numpy and lite_vo.geometry only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry import make_pose

TRAJECTORIES = ("handheld", "fast", "rotation", "forward")
"""Names accepted by :func:`make_trajectory`."""

_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class SinusoidSum:
    """``offset + sum_k amp[k] * sin(omega[k] t + phase[k])`` per axis; amp, phase (K, D)."""
    offset: np.ndarray
    amp: np.ndarray
    omega: np.ndarray
    phase: np.ndarray

    def value(self, t: np.ndarray, deriv: int = 0) -> np.ndarray:
        """The ``deriv``-th time derivative (0, 1, 2) at times ``t`` (N,) -> (N, D)."""
        t = np.asarray(t, dtype=np.float64)[:, None, None]
        arg = self.omega[None, :, None] * t + self.phase[None]
        w = self.omega[None, :, None]
        if deriv == 0:
            terms = self.amp[None] * np.sin(arg)
            return self.offset[None] + terms.sum(axis=1)
        if deriv == 1:
            return (self.amp[None] * w * np.cos(arg)).sum(axis=1)
        if deriv == 2:
            return (-self.amp[None] * w * w * np.sin(arg)).sum(axis=1)
        raise ValueError("deriv must be 0, 1 or 2")

    def scaled_time(self, factor: float) -> "SinusoidSum":
        """The same curve played ``factor`` times faster."""
        return SinusoidSum(self.offset, self.amp, self.omega * factor, self.phase)


def _terms(start, terms, dims: int) -> SinusoidSum:
    """A sum whose value at t = 0 is ``start``; terms: (amp vector, period_s, phase)."""
    amp = np.array([a for a, _, _ in terms], float).reshape(-1, dims)
    omega = np.array([2 * math.pi / p for _, p, _ in terms], float)
    phase = np.array([[ph] * dims for _, _, ph in terms], float).reshape(-1, dims)
    offset = np.asarray(start, float) - (amp * np.sin(phase)).sum(axis=0)
    return SinusoidSum(offset, amp, omega, phase)


@dataclass(frozen=True)
class Motion:
    """An analytic camera motion: position terms, look mode and roll (degrees)."""
    position: SinusoidSum
    look: str                       # "target" or "heading"
    target: SinusoidSum | None      # look-at point (look == "target")
    heading_terms: np.ndarray | None  # (K,) bool: position terms defining the walking direction
    pitch_deg: float                # look == "heading": downward pitch
    roll_deg: SinusoidSum           # (1-D) roll about the optical axis

    def positions(self, t: np.ndarray) -> np.ndarray:
        return self.position.value(t)

    def accelerations_world(self, t: np.ndarray) -> np.ndarray:
        """Second derivative of the position (world frame, m/s^2), analytic."""
        return self.position.value(t, 2)

    def rotations(self, t: np.ndarray) -> np.ndarray:
        """R_world_cam (N, 3, 3): camera z forward, x right (horizontal before roll), y down."""
        t = np.asarray(t, dtype=np.float64)
        p = self.position.value(t)
        if self.look == "target":
            fwd = self.target.value(t) - p
        else:
            pos = self.position
            m = self.heading_terms
            vel = SinusoidSum(np.zeros(3), pos.amp[m], pos.omega[m], pos.phase[m]).value(t, 1)
            vel[:, 2] = 0.0
            vel /= np.linalg.norm(vel, axis=1, keepdims=True)
            pitch = math.radians(self.pitch_deg)
            fwd = vel * math.cos(pitch)
            fwd[:, 2] = -math.sin(pitch)
        fwd = fwd / np.linalg.norm(fwd, axis=1, keepdims=True)
        right = np.cross(fwd, _UP)
        right /= np.linalg.norm(right, axis=1, keepdims=True)
        down = np.cross(fwd, right)
        roll = np.radians(self.roll_deg.value(t)[:, 0])[:, None]
        c, s = np.cos(roll), np.sin(roll)
        x = c * right + s * down
        y = -s * right + c * down
        return np.stack([x, y, fwd], axis=-1)

    def poses(self, t: np.ndarray) -> np.ndarray:
        """T_world_cam (N, 4, 4) at times ``t`` (N,)."""
        return make_pose(self.rotations(t), self.positions(t))

    def specific_force_cam(self, t: np.ndarray, gravity_world=(0.0, 0.0, -9.81)) -> np.ndarray:
        """Accelerometer reading (N, 3) in the camera frame: ``R_world_cam^T (a_world - g)``."""
        f_world = self.accelerations_world(t) - np.asarray(gravity_world, float)[None]
        return np.einsum("nji,nj->ni", self.rotations(t), f_world)


# per-scene anchors: (camera start, look-at target, motion scale)
_ANCHORS = {
    "room": (np.array([0.0, -1.9, 1.35]), np.array([0.0, 0.4, 0.35]), 1.0),
    "desk": (np.array([0.0, -0.55, 1.25]), np.array([0.0, 0.15, 0.78]), 0.4),
}


def make_motion(name: str, scene: str = "room", seed: int = 0) -> Motion:
    """The analytic :class:`Motion` of trajectory ``name`` in scene ``scene`` (a name)."""
    if name not in TRAJECTORIES:
        raise InputError(f"unknown synthetic trajectory {name!r} "
                         f"(choose from {', '.join(TRAJECTORIES)})")
    scene_name = getattr(scene, "name", scene)
    if scene_name not in _ANCHORS:
        raise InputError(f"unknown synthetic scene {scene_name!r}")
    p0, q0, k = _ANCHORS[scene_name]
    rng = np.random.default_rng([int(seed), 104729])
    # the seed varies amplitudes (+-20 %), periods (+-15 %) and signs, never the start pose
    def jit(a):
        return a * rng.uniform(0.8, 1.2) * (1 if rng.random() < 0.5 else -1)

    def per(p):
        return p * rng.uniform(0.87, 1.15)

    H = math.pi / 2  # phase of a term with zero velocity at t = 0
    ex, ey, ez = np.eye(3)
    roll_small = _terms([0.0], [(jit(3.0), per(6.0), H), (jit(1.0), per(2.3), H)], 1)
    if name in ("handheld", "fast"):
        side = 1.0 if rng.random() < 0.5 else -1.0
        pos = _terms(p0, [
            (side * k * 0.18 * rng.uniform(0.9, 1.1) * ex, per(8.0), 0.0),  # sideways start
            (k * jit(0.05) * ex, per(3.1), H),
            (k * jit(0.10) * ey, per(9.0), H), (k * jit(0.03) * ey, per(4.3), H),
            (k * jit(0.065) * ez, per(5.5), H), (k * jit(0.02) * ez, per(2.7), H),
        ], 3)
        tgt = _terms(q0, [
            (k * jit(0.35) * ex, per(10.0), H), (k * jit(0.08) * ex, per(3.7), H),
            (k * jit(0.15) * ez, per(8.0), H), (k * jit(0.05) * ez, per(3.3), H),
            (k * jit(0.20) * ey, per(13.0), H),
        ], 3)
        m = Motion(pos, "target", tgt, None, 0.0, roll_small)
        if name == "fast":
            m = Motion(pos.scaled_time(3.0), "target", tgt.scaled_time(3.0), None, 0.0,
                       roll_small.scaled_time(3.0))
        return m
    if name == "rotation":
        pos = _terms(p0, [(np.zeros(3), 10.0, 0.0)], 3)
        dist = float(np.linalg.norm(q0 - p0))
        tgt = _terms(q0, [
            (dist * jit(0.30) * ex, per(8.0), 0.0), (dist * jit(0.05) * ex, per(2.9), H),
            (dist * jit(0.12) * ez, per(6.5), H), (dist * jit(0.03) * ez, per(2.1), H),
        ], 3)
        return Motion(pos, "target", tgt, None, 0.0, roll_small)
    # forward
    if scene_name == "room":
        a, b, z = 2.0 * rng.uniform(0.95, 1.05), 1.6 * rng.uniform(0.95, 1.05), 1.4
        period = 2 * math.pi * math.hypot(a, b) / math.sqrt(2) / 0.4  # ~0.4 m/s
        step = per(1.0 / 1.8)
        pos = SinusoidSum(
            offset=np.array([0.0, 0.0, z]),
            amp=np.array([[a, 0.0, 0.0], [0.0, b, 0.0], [0.0, 0.0, 0.015], [0.0, 0.0, 0.006]]),
            omega=np.array([2 * math.pi / period] * 2 + [2 * math.pi / step, math.pi / step]),
            phase=np.array([[0.0] * 3, [-H] * 3, [0.0] * 3, [H] * 3]))
        # start at (0, -b) walking towards +x (counter-clockwise loop)
        return Motion(pos, "heading", None, np.array([True, True, False, False]),
                      24.0, _terms([0.0], [(jit(1.5), step * 2, H)], 1))
    step = per(1.0 / 1.8)
    start = p0 + np.array([0.0, -0.6, 0.05])
    pos = _terms(start, [
        (0.45 * ey, 20.0, -H),                      # y = y0 + 0.45 (1 - cos): forward 0.9 m
        (0.01 * ez, step, 0.0), (jit(0.006) * ex, 2 * step, H),
    ], 3)
    tgt = _terms(q0 + np.array([0.0, 0.05, 0.0]), [(k * jit(0.05) * ex, per(7.0), H)], 3)
    return Motion(pos, "target", tgt, None, 0.0, _terms([0.0], [(jit(1.0), 2 * step, H)], 1))


def make_trajectory(name: str, n_frames: int, fps: float = 30.0, seed: int = 0,
                    scene: str = "room", start_time_s: float = 0.0):
    """``(timestamps (N,), poses T_world_cam (N, 4, 4))`` of trajectory ``name`` in ``scene``."""
    if n_frames < 1 or fps <= 0:
        raise InputError(f"need n_frames >= 1 and fps > 0 (got {n_frames}, {fps})")
    motion = make_motion(name, scene, seed)
    rel = np.arange(int(n_frames), dtype=np.float64) / float(fps)
    return rel + start_time_s, motion.poses(rel)
