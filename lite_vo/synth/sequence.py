"""Synthetic sequences: in-memory frames (:func:`iter_frames`) and TUM folders
(:func:`generate_sequence`).

Folder layout (TUM RGB-D, see ARCHITECTURE.md): ``rgb.txt`` + ``rgb/<t>.png`` (8-bit grey),
``depth.txt`` + ``depth/<t>.png`` (uint16, ``depth_scale`` units per metre, 0 = invalid),
``groundtruth.txt`` (``t tx ty tz qx qy qz qw``, T_world_cam), ``accelerometer.txt``
(``t ax ay az``: specific force in the camera frame, ``R_world_cam^T (a_world - g)`` with
``g = (0, 0, -9.81)``, so +9.81 m/s^2 along world-up at rest), ``calib.txt`` (``fx fy cx cy``,
``width height``, ``depth_scale N``), plus ``exposure.txt`` (``t gain offset`` actually applied:
``I = gain * I_true + offset``) and ``synth.json`` (the generator's parameters and the scene's
boxes: room and box extents in world metres, which boxes are floor obstacles).

Deterministic for a seed (scene textures, trajectory variations, noise). Imports numpy, cv2
and the synth modules; never GL.
"""
from __future__ import annotations

import json
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ..camera import PinholeIntrinsics
from ..errors import InputError
from ..geometry import tum_from_pose
from .config import SynthConfig
from .render import default_intrinsics, render_frame
from .scenes import SCENES, make_scene
from .trajectories import TRAJECTORIES, make_motion


@dataclass(frozen=True)
class SynthFrame:
    """One rendered frame: ``image`` float32 0..255 after blur/exposure/noise (not quantised),
    ``depth`` float32 z-depth in metres at the frame time (exact), ``T_world_cam`` (4x4),
    ``acc_cam`` (3,) specific force in the camera frame, ``gain``/``offset`` of the exposure."""
    index: int
    timestamp: float
    image: np.ndarray
    depth: np.ndarray
    T_world_cam: np.ndarray
    acc_cam: np.ndarray
    gain: float
    offset: float


@dataclass(frozen=True)
class GeneratedSequence:
    """What :func:`generate_sequence` wrote."""
    path: Path
    n_frames: int
    intrinsics: PinholeIntrinsics
    render_s: float
    total_s: float


def _exposure(times: np.ndarray, seed: int, cfg: SynthConfig) -> tuple[np.ndarray, np.ndarray]:
    """Smooth per-frame gain and offset (two / one sinusoids with seeded phases)."""
    rng = np.random.default_rng([int(seed), 5557])
    ph = rng.uniform(0, 2 * math.pi, 3)
    w = 2 * math.pi / cfg.exposure_period_s
    gain = 1.0 + cfg.exposure_gain_amp * (0.7 * np.sin(w * times + ph[0])
                                          + 0.3 * np.sin(2.7 * w * times + ph[1]))
    offset = cfg.exposure_offset_amp * np.sin(0.77 * w * times + ph[2])
    return gain, offset


def iter_frames(scene: str = "room", trajectory: str = "handheld", n_frames: int = 300,
                seed: int = 0, width: int = 640, height: int = 480, noise_sigma: float = 0.0,
                blur: int = 1, exposure: bool = False, fps: float = 30.0,
                config: SynthConfig | None = None) -> Iterator[SynthFrame]:
    """Render the frames of a synthetic sequence in memory (same content as
    :func:`generate_sequence` writes, before quantisation to 8/16 bit)."""
    cfg = config or SynthConfig()
    if scene not in SCENES:
        raise InputError(f"unknown synthetic scene {scene!r} (choose from {', '.join(SCENES)})")
    if trajectory not in TRAJECTORIES:
        raise InputError(f"unknown synthetic trajectory {trajectory!r} "
                         f"(choose from {', '.join(TRAJECTORIES)})")
    if int(n_frames) < 1:
        raise InputError(f"--frames must be >= 1, got {n_frames}")
    if int(blur) < 1:
        raise InputError(f"--blur must be >= 1 (number of sub-frames), got {blur}")
    if noise_sigma < 0:
        raise InputError(f"--noise must be >= 0, got {noise_sigma}")
    if fps <= 0:
        raise InputError(f"fps must be > 0, got {fps}")
    sc = make_scene(scene, seed)
    motion = make_motion(trajectory, scene, seed)
    K = default_intrinsics(width, height, cfg)
    rel = np.arange(int(n_frames), dtype=np.float64) / float(fps)
    poses = motion.poses(rel)
    acc = motion.specific_force_cam(rel, sc.gravity_world)
    if cfg.accel_noise_std > 0:
        acc = acc + np.random.default_rng([int(seed), 4242]).normal(
            0.0, cfg.accel_noise_std, acc.shape)
    if exposure:
        gain, offset = _exposure(rel, seed, cfg)
    else:
        gain, offset = np.ones_like(rel), np.zeros_like(rel)
    blur = int(blur)
    for i in range(int(n_frames)):
        depth = None
        if blur == 1:
            img, depth = render_frame(sc, poses[i], K, config=cfg)
        else:
            sub_t = rel[i] + ((np.arange(blur) + 0.5) / blur - 0.5) * cfg.blur_window_s
            sub_T = motion.poses(sub_t)
            img = np.zeros((K.height, K.width), np.float64)
            for k in range(blur):
                sub_img, sub_depth = render_frame(sc, sub_T[k], K, config=cfg)
                img += sub_img
                if blur % 2 == 1 and k == blur // 2:
                    depth = sub_depth  # the middle sub-frame is at the frame time exactly
            img = (img / blur).astype(np.float32)
            if depth is None:
                _, depth = render_frame(sc, poses[i], K, supersample=1, config=cfg)
        if exposure:
            img = img * np.float32(gain[i]) + np.float32(offset[i])
        if noise_sigma > 0:
            rng = np.random.default_rng([int(seed), 31337, i])
            img = img + rng.normal(0.0, noise_sigma, img.shape).astype(np.float32)
        yield SynthFrame(i, float(cfg.start_time_s + rel[i]), img.astype(np.float32), depth,
                         poses[i], acc[i], float(gain[i]), float(offset[i]))


def _prepare_out_dir(out: Path, force: bool) -> None:
    from ..io import prepare_output_dir
    prepare_output_dir(out, force, clean=("rgb/*.png", "depth/*.png"))
    (out / "rgb").mkdir(exist_ok=True)
    (out / "depth").mkdir(exist_ok=True)


def generate_sequence(out_dir, scene: str = "room", trajectory: str = "handheld",
                      n_frames: int = 300, seed: int = 0, width: int = 640, height: int = 480,
                      noise_sigma: float = 0.0, blur: int = 1, exposure: bool = False,
                      force: bool = False, fps: float = 30.0, config: SynthConfig | None = None,
                      progress=None) -> GeneratedSequence:
    """Render a synthetic sequence into ``out_dir`` in the TUM layout (see module docstring).

    Refuses a non-empty existing folder unless ``force``. ``progress(i, n)`` is called after
    each frame if given. Bit-identical output for identical arguments.
    """
    import cv2

    cfg = config or SynthConfig()
    t_start = time.perf_counter()
    out = Path(out_dir)
    sc = make_scene(scene, seed) if scene in SCENES else None
    # validate everything before touching the disk
    K = default_intrinsics(width, height, cfg)
    frames = iter_frames(scene, trajectory, n_frames, seed, width, height, noise_sigma, blur,
                         exposure, fps, cfg)
    t0 = time.perf_counter()
    first = next(frames)  # validates the arguments before anything is written
    render_s = time.perf_counter() - t0
    _prepare_out_dir(out, force)
    label = f"lite_vo synth scene={scene} trajectory={trajectory} seed={seed}"
    png = [cv2.IMWRITE_PNG_COMPRESSION, int(cfg.png_compression)]
    rgb_lines, depth_lines, gt_lines, acc_lines, exp_lines = [], [], [], [], []
    pending = []

    def write(path, arr):
        if not cv2.imwrite(str(path), arr, png):
            raise InputError(f"{path}: cannot write image")

    with ThreadPoolExecutor(max_workers=1) as pool:
        fr = first
        i = 0
        while fr is not None:
            ts = f"{fr.timestamp:.6f}"
            img8 = np.clip(np.rint(fr.image), 0, 255).astype(np.uint8)
            d = np.rint(fr.depth.astype(np.float64) * cfg.depth_scale)
            d16 = np.where((d > 0) & (d <= 65535), d, 0).astype(np.uint16)
            pending.append(pool.submit(write, out / "rgb" / f"{ts}.png", img8))
            pending.append(pool.submit(write, out / "depth" / f"{ts}.png", d16))
            rgb_lines.append(f"{ts} rgb/{ts}.png")
            depth_lines.append(f"{ts} depth/{ts}.png")
            row = tum_from_pose(fr.T_world_cam)
            gt_lines.append(ts + " " + " ".join(f"{x:.9f}" for x in row))
            acc_lines.append(ts + " " + " ".join(f"{x:.9f}" for x in fr.acc_cam))
            exp_lines.append(f"{ts} {fr.gain:.9f} {fr.offset:.9f}")
            while len(pending) > 8:
                pending.pop(0).result()
            i += 1
            if progress is not None:
                progress(i, int(n_frames))
            t0 = time.perf_counter()
            fr = next(frames, None)
            render_s += time.perf_counter() - t0
        for p in pending:
            p.result()

    def text(name, header, lines):
        (out / name).write_text("\n".join([f"# {header}", f"# file: '{label}'"] + lines) + "\n")

    if cfg.accel_rate_hz > 0:  # accelerometer at its own rate (exact motion, own noise stream)
        motion = make_motion(trajectory, scene, seed)
        n_acc = int(np.floor((int(n_frames) - 1) / float(fps) * cfg.accel_rate_hz + 1e-9)) + 1
        t_acc = np.arange(n_acc) / cfg.accel_rate_hz
        acc = motion.specific_force_cam(t_acc, sc.gravity_world)
        if cfg.accel_noise_std > 0:
            acc = acc + np.random.default_rng([int(seed), 4243]).normal(
                0.0, cfg.accel_noise_std, acc.shape)
        acc_lines = [f"{cfg.start_time_s + ta:.6f} " + " ".join(f"{x:.9f}" for x in a)
                     for ta, a in zip(t_acc, acc)]
    text("rgb.txt", "color images (grey)\n# timestamp filename", rgb_lines)
    text("depth.txt", f"depth images (uint16, {cfg.depth_scale:g} per metre)\n# timestamp filename",
         depth_lines)
    text("groundtruth.txt", "ground truth trajectory T_world_cam (world: z up, floor z=0)\n"
         "# timestamp tx ty tz qx qy qz qw", gt_lines)
    text("accelerometer.txt", "accelerometer: specific force in the camera frame (m/s^2), "
         "R_world_cam^T (a_world - g), g = (0, 0, -9.81)\n# timestamp ax ay az", acc_lines)
    text("exposure.txt", "applied exposure: I = gain * I_true + offset\n"
         "# timestamp gain offset", exp_lines)
    (out / "calib.txt").write_text(f"{K.fx:.6f} {K.fy:.6f} {K.cx:.6f} {K.cy:.6f}\n"
                                   f"{K.width} {K.height}\n"
                                   f"depth_scale {cfg.depth_scale:g}\n")
    meta = dict(generator="lite_vo.synth", scene=scene, trajectory=trajectory,
                n_frames=int(n_frames), seed=int(seed), width=int(width), height=int(height),
                fps=float(fps), noise_sigma=float(noise_sigma), blur=int(blur),
                exposure=bool(exposure), config=asdict(cfg),
                world_frame="metres, z up, floor z=0, gravity (0, 0, -9.81)",
                room={"lo": sc.room_lo.tolist(), "hi": sc.room_hi.tolist()},
                boxes=[{"name": n, "lo": sc.box_lo[i].tolist(), "hi": sc.box_hi[i].tolist(),
                        "obstacle": n in sc.obstacles} for i, n in enumerate(sc.box_names)])
    (out / "synth.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    return GeneratedSequence(out, int(n_frames), K, render_s, time.perf_counter() - t_start)
