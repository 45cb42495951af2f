"""Progress for long steps: a tqdm bar on a terminal, one plain line every few seconds when the
output is piped to a file (so a log still shows that something happens), nothing when quiet.

Imports the standard library only (tqdm lazily, when a terminal shows the bar).
"""
from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager


class Progress:
    """``update(n=1)`` per item, ``close()`` at the end (or use it as a context manager)."""

    def __init__(self, total: int | None, desc: str, unit: str = "frame", quiet: bool = False,
                 stream=None, every_s: float = 5.0) -> None:
        self.total, self.desc, self.unit = total, desc, unit
        self.stream = stream or sys.stderr
        self.every_s = every_s
        self.quiet = quiet
        self.done = 0
        self.note = ""
        self._bar = None
        self._t0 = self._last = time.monotonic()
        if not quiet and self.stream.isatty():
            from tqdm import tqdm
            self._bar = tqdm(total=total, desc=desc, unit=unit, file=self.stream, dynamic_ncols=True, leave=True)

    def update(self, n: int = 1, note: str | None = None) -> None:
        self.done += n
        if note is not None:
            self.note = note
        if self.quiet:
            return
        if self._bar is not None:
            self._bar.update(n)
            if note is not None:
                self._bar.set_postfix_str(note, refresh=False)
            return
        now = time.monotonic()
        if now - self._last >= self.every_s or (self.total is not None and self.done == self.total):
            self._last = now
            total = f"/{self.total}" if self.total else ""
            rate = self.done / max(now - self._t0, 1e-9)
            extra = f", {self.note}" if self.note else ""
            print(f"{self.desc}: {self.unit} {self.done}{total}, {rate:.1f}/s{extra}", file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@contextmanager
def announce_if_slow(message: str, after_s: float = 2.0, say=None):
    """Say ``message`` once when the block is still running after ``after_s`` seconds (e.g. the first
    numba compile on a machine), so no long step is silent."""
    import logging
    say = say or logging.getLogger("lite_vo").info
    timer = threading.Timer(after_s, say, args=(message,))
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
