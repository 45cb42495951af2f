#!/usr/bin/env python3
"""Run ``lite-vo`` on the packages of another checkout: before/after numbers on the same machine.

    python tools/code_under_test.py DIR run SEQ --profile phone ...     # lite-vo's arguments after DIR

``DIR`` holds ``lite_vo/`` (and ``ar_demo/``, ``profiles/``) of the code to measure, e.g.
``git archive <commit> lite_vo ar_demo profiles | tar -x -C DIR`` or a ``git worktree``. The benchmark
scripts use :func:`use_code` for their child processes (``tools/bench_memory.py --code``,
``tools/bench_whole_program.py --ab``); numba compiles that code's kernels into its own cache the first time
(run ``python tools/code_under_test.py DIR warmup`` once before timing).
"""
from __future__ import annotations

import sys
from pathlib import Path


def use_code(folder: str | Path) -> None:
    """Import lite_vo and ar_demo from ``folder`` instead of the (editable) installation."""
    base = Path(folder).resolve()
    if not (base / "lite_vo").is_dir():
        raise SystemExit(f"{base}: no lite_vo package here")
    if base == Path(__file__).resolve().parents[1]:
        return          # this checkout: the (editable) installation already imports it
    if not (base / "lite_vo" / "profiles").exists() and (base / "profiles").is_dir():
        (base / "lite_vo" / "profiles").symlink_to(base / "profiles")   # the installed package layout
    sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in type(f).__module__.lower()
                        and "editable" not in getattr(f, "__name__", "").lower()]
    sys.path.insert(0, str(base))


def main(argv: list[str]) -> int:
    if not argv:
        print("usage: python tools/code_under_test.py DIR LITE_VO_ARGUMENTS...", file=sys.stderr)
        return 2
    use_code(argv[0])
    import lite_vo
    if not Path(lite_vo.__file__).resolve().is_relative_to(Path(argv[0]).resolve()):
        raise SystemExit(f"lite_vo was imported from {lite_vo.__file__}, not from {argv[0]}")
    from lite_vo.cli.main import main as lite_vo_main
    return lite_vo_main(argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
