"""``lite-vo warmup``: compile and cache every numba kernel (parser + run; the work is in
:mod:`lite_vo.warmup`)."""
from __future__ import annotations

import argparse


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "warmup", help="compile and cache all numba kernels",
        description="Compile every numba kernel once and store the machine code in numba's cache, "
                    "so the first frame of later runs is not seconds late. Run it once after "
                    "installing, on the machine (CPU model) that will run lite-vo. Modules that "
                    "do not exist (e.g. the AR demo without the [ar] extra) are skipped with a note.")
    p.add_argument("--quiet", action="store_true", help="print nothing unless a module fails")
    return p


def run(args) -> int:
    import sys
    import time

    from ..warmup import numba_cache_location, warmup

    quiet = bool(getattr(args, "quiet", False))

    def show(res) -> None:
        if res.status == "error":
            print(f"  {res.module:<28} ERROR  {res.message}", file=sys.stderr)
        elif not quiet:
            if res.status == "ok":
                print(f"  {res.module:<28} {res.total_s:7.2f} s  (import {res.import_s:.2f} s, "
                      f"kernels {res.compile_s:.2f} s)")
            else:
                print(f"  {res.module:<28}     --    {res.message}")

    if not quiet:
        print(f"warming up numba kernels (cache: {numba_cache_location()})")
    t0 = time.perf_counter()
    results = warmup(on_result=show)
    errors = [r for r in results if r.status == "error"]
    if not quiet:
        done = sum(r.status == "ok" for r in results)
        print(f"done: {done} module(s) warmed up in {time.perf_counter() - t0:.2f} s"
              + (f", {len(errors)} failed" if errors else ""))
    return 1 if errors else 0
