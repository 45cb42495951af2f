#!/usr/bin/env python3
"""Cut frames out of a TUM-format sequence (a deliberate jump in the view, for relocalisation tests).

    python tools/cut_frames.py SRC DST --drop 100:140 [--drop 300:310 ...]

Rewrites ``rgb.txt`` and ``depth.txt`` (the data lines whose 0-based index lies in a ``START:STOP``
range are dropped; comments are kept; timestamps are unchanged, so ``groundtruth.txt`` still
matches and is copied as is). The other files are copied; image folders are linked (symlinks to
the absolute source folder), so the cut sequence costs no disk space.
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

LISTS = ("rgb.txt", "depth.txt")


def parse_range(text: str) -> range:
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--drop {text!r}: expected START:STOP (0-based, STOP excluded)") from None
    if not 0 <= a < b:
        raise argparse.ArgumentTypeError(f"--drop {text!r}: need 0 <= START < STOP")
    return range(a, b)


def cut_list(src: Path, dst: Path, drops: list[range]) -> tuple[int, int]:
    """Copy a TUM list file without the dropped data lines; returns (kept, dropped)."""
    kept = dropped = 0
    out = []
    i = 0
    for line in src.read_text().splitlines(keepends=True):
        if not line.strip() or line.lstrip().startswith("#"):
            out.append(line)
            continue
        if any(i in r for r in drops):
            dropped += 1
        else:
            out.append(line)
            kept += 1
        i += 1
    dst.write_text("".join(out))
    return kept, dropped


def cut_sequence(src: Path, dst: Path, drops: list[range]) -> dict:
    src, dst = Path(src).resolve(), Path(dst)
    if not (src / "rgb.txt").is_file():
        raise FileNotFoundError(f"{src}: no rgb.txt (not a TUM-format sequence)")
    if dst.exists() and any(dst.iterdir()):
        raise FileExistsError(f"{dst}: exists and is not empty")
    dst.mkdir(parents=True, exist_ok=True)
    counts = {}
    for p in sorted(src.iterdir()):
        if p.name in LISTS:
            counts[p.name] = cut_list(p, dst / p.name, drops)
        elif p.is_dir():
            (dst / p.name).symlink_to(p, target_is_directory=True)
        else:
            shutil.copy2(p, dst / p.name)
    return counts


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--drop", type=parse_range, action="append", required=True,
                    help="START:STOP, 0-based frame indices (STOP excluded); repeatable")
    a = ap.parse_args(argv)
    try:
        counts = cut_sequence(a.src, a.dst, a.drop)
    except (OSError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for name, (kept, dropped) in counts.items():
        print(f"{name}: kept {kept}, dropped {dropped}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
