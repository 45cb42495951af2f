"""``lite-vo synth``: render a synthetic sequence with exact ground truth (TUM folder layout).

Parser only at import time; the renderer is imported inside :func:`run`.
"""
from __future__ import annotations

import argparse

SCENE_CHOICES = ("room", "desk")
TRAJECTORY_CHOICES = ("handheld", "fast", "rotation", "forward")


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "synth", help="render a synthetic sequence with exact ground truth",
        description="Render a synthetic sequence (numba ray caster, no GPU) into DIR in the TUM "
                    "layout: rgb/ + rgb.txt, depth/ + depth.txt (uint16, 5000 per metre), "
                    "groundtruth.txt (T_world_cam), accelerometer.txt (specific force, camera "
                    "frame), calib.txt, exposure.txt, synth.json. World frame: metres, z up, "
                    "floor z = 0, gravity (0, 0, -9.81).")
    p.add_argument("--scene", choices=SCENE_CHOICES, default="room", help="scene (default room)")
    p.add_argument("--trajectory", choices=TRAJECTORY_CHOICES, default="handheld",
                   help="camera motion (default handheld)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (must be empty "
                   "or absent unless --force)")
    p.add_argument("--frames", type=_positive_int, default=300, metavar="N",
                   help="number of frames at 30 Hz (default 300)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="seed (default 0)")
    p.add_argument("--width", type=_positive_int, default=640, metavar="W", help="default 640")
    p.add_argument("--height", type=_positive_int, default=480, metavar="H", help="default 480")
    p.add_argument("--noise", type=float, default=0.0, metavar="SIGMA",
                   help="Gaussian photometric noise std in grey levels (default 0)")
    p.add_argument("--blur", type=_positive_int, default=1, metavar="N",
                   help="motion blur: average of N sub-frame renders over 1/60 s (default 1: off)")
    p.add_argument("--exposure", action="store_true",
                   help="smooth global exposure changes (per-frame gain and offset)")
    p.add_argument("--accel-noise", type=float, default=0.0, metavar="STD",
                   help="accelerometer white noise std in m/s^2 (default 0)")
    p.add_argument("--accel-rate", type=float, default=0.0, metavar="HZ",
                   help="accelerometer sample rate (default 0: one sample per frame)")
    p.add_argument("--force", action="store_true", help="write into a non-empty folder")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    return p


def run(args) -> int:
    import time

    from ..errors import InputError
    from ..progress import Progress
    from ..synth import SynthConfig, generate_sequence

    if args.noise < 0:
        raise InputError(f"--noise must be >= 0, got {args.noise}")
    if args.accel_noise < 0:
        raise InputError(f"--accel-noise must be >= 0, got {args.accel_noise}")
    if args.width < 16 or args.height < 16:
        raise InputError(f"--width/--height must be >= 16, got {args.width}x{args.height}")
    if args.accel_rate < 0:
        raise InputError(f"--accel-rate must be >= 0, got {args.accel_rate}")
    cfg = SynthConfig(accel_noise_std=args.accel_noise, accel_rate_hz=args.accel_rate)
    t0 = time.perf_counter()

    bar = Progress(args.frames, f"synth {args.scene}/{args.trajectory}", quiet=args.quiet)

    def progress(i, n):
        bar.update(i - bar.done)

    with bar:
        res = generate_sequence(args.out, scene=args.scene, trajectory=args.trajectory,
                                n_frames=args.frames, seed=args.seed, width=args.width,
                                height=args.height, noise_sigma=args.noise, blur=args.blur,
                                exposure=args.exposure, force=args.force, config=cfg,
                                progress=progress)
    if not args.quiet:
        print(f"wrote {res.n_frames} frames ({args.width}x{args.height}, scene {args.scene}, "
              f"trajectory {args.trajectory}, seed {args.seed}) to {res.path} in "
              f"{time.perf_counter() - t0:.1f} s")
    return 0
