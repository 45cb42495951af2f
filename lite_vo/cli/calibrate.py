"""``lite-vo calibrate``: a calib.txt from views of a chessboard or ChArUco board.

Parser only at import time; the work is :func:`lite_vo.calibrate.calibrate_source`.
"""
from __future__ import annotations

import argparse


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "calibrate", help="calibrate a camera from views of a chessboard (writes calib.txt)",
        description="Find a chessboard (or ChArUco board) in a video, an image folder or a live camera, pick "
                    "well-spread views (at most --max-views), calibrate with OpenCV (pinhole + radial-tangential "
                    "k1 k2 p1 p2) and write a calib.txt that `lite-vo run` reads. Prints the RMS reprojection "
                    "error, the error of every view used and which parts of the image the board covered. "
                    "Show the whole board, sharp and still, near and far, tilted, in every part of the image "
                    "(corners too: that is where the distortion is).")
    p.add_argument("source", help="video file, image folder, or live camera index (e.g. 0)")
    board = p.add_mutually_exclusive_group(required=True)
    board.add_argument("--chessboard", metavar="COLSxROWS",
                       help="chessboard size in INNER corners, as OpenCV counts them (a board of 10x7 squares is 9x6)")
    board.add_argument("--charuco", metavar="COLSxROWS", help="ChArUco board size in squares (needs --marker)")
    p.add_argument("--square", type=float, required=True, metavar="METRES", help="side of one square in metres")
    p.add_argument("--marker", type=float, default=None, metavar="METRES", help="ChArUco marker side in metres")
    p.add_argument("--dictionary", default="DICT_5X5_100", help="ChArUco ArUco dictionary (default DICT_5X5_100)")
    p.add_argument("--out", required=True, metavar="FILE", help="calibration file to write (calib.txt format)")
    p.add_argument("--max-views", type=int, default=40, metavar="N", help="views used at most (default 40)")
    p.add_argument("--min-views", type=int, default=None, metavar="N",
                   help="refuse with fewer good views (default 8)")
    p.add_argument("--max-images", type=int, default=200, metavar="N",
                   help="images searched at most, spread evenly over a video or folder (default 200)")
    p.add_argument("--duration", type=float, default=60.0, metavar="S",
                   help="live camera: seconds to record (default 60)")
    p.add_argument("--k3", action="store_true", help="also estimate the 6th-order radial coefficient k3 "
                   "(wide-angle lenses; needs many well-spread views)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def run(args) -> int:
    import sys
    import textwrap

    from ..calibrate import MIN_VIEWS, Board, calibrate_source, parse_pattern
    from ..errors import InputError
    from ..io import check_output_file, write_calib_txt

    check_output_file(args.out, args.force)
    if args.max_views < 3:
        raise InputError(f"--max-views must be >= 3, got {args.max_views}")
    min_views = MIN_VIEWS if args.min_views is None else args.min_views
    if min_views < 3:
        raise InputError(f"--min-views must be >= 3, got {min_views}")
    if args.max_images < 1:
        raise InputError(f"--max-images must be >= 1, got {args.max_images}")
    if args.chessboard:
        cols, rows = parse_pattern(args.chessboard, "--chessboard")
        board = Board("chessboard", cols, rows, args.square)
    else:
        cols, rows = parse_pattern(args.charuco, "--charuco")
        if args.marker is None:
            raise InputError("--charuco needs --marker METRES (the side of the ArUco markers)")
        board = Board("charuco", cols, rows, args.square, args.marker, args.dictionary)

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"calibrate: {msg}", file=sys.stderr, flush=True)

    source = int(args.source) if args.source.isdigit() else args.source
    progress(f"looking for the {board.describe()} in {args.source}")
    res = calibrate_source(source, board, max_views=args.max_views, min_views=min_views,
                           max_candidates=args.max_images, duration_s=args.duration, k3=args.k3,
                           progress=progress)
    cam = res.camera
    i = cam.intrinsics
    print(f"board found in {res.boards_found} of {res.frames_read} images; {len(res.view_errors)} views used"
          + (f", {len(res.dropped)} dropped (errors " + ", ".join(f"{n} {e:.2f} px" for n, e in res.dropped) + ")"
             if res.dropped else ""))
    print(f"RMS reprojection error {res.rms:.3f} px")
    print(textwrap.fill("per view (px): " + ", ".join(f"{n} {e:.2f}" for n, e in res.view_errors), width=100,
                        subsequent_indent="    ", break_on_hyphens=False))
    print(f"image covered by corners: {100 * res.coverage:.0f} % of {8 * 6} cells (# covered, . never):")
    for line in res.coverage_map.splitlines():
        print("    " + line)
    print(f"camera {i.width}x{i.height}: fx {i.fx:.2f} fy {i.fy:.2f} cx {i.cx:.2f} cy {i.cy:.2f}"
          + (f"; k1 k2 p1 p2 k3 {' '.join(f'{v:.5g}' for v in cam.params)}" if cam.params else ""))
    if res.coverage < 0.6:
        print("warning: the board never reached large parts of the image: the distortion there is guessed; "
              "record more views near the edges and corners", file=sys.stderr)
    if res.rms > 1.0:
        print(f"warning: RMS error {res.rms:.2f} px is high (expect < 0.5 px): blurred views, a board that is not "
              "flat, or a wrong board size", file=sys.stderr)
    comment = (f"lite-vo calibrate {args.source}: {board.describe()}; {len(res.view_errors)} views, "
               f"RMS {res.rms:.3f} px, coverage {100 * res.coverage:.0f} %")
    write_calib_txt(args.out, cam, comment=comment)
    print(f"wrote {args.out}")
    return 0
