"""Timing statistics, one definition for the system, the AR demo and the benchmark tools.

:func:`timing_stats` summarises a list of durations (milliseconds); :class:`Timers` collects named
lists of them from several threads. Imports numpy only.
"""
from __future__ import annotations

import threading
from typing import Iterable

import numpy as np

#: The keys of a ``timing.json`` entry (contract in ARCHITECTURE.md).
CONTRACT_KEYS = ("count", "mean", "std", "median", "p95")


def timing_stats(values: Iterable[float]) -> dict:
    """``count, mean, std, median, p95, min, max`` of ``values`` (all 0 when there are none)."""
    a = np.asarray(list(values), dtype=np.float64)
    if a.size == 0:
        return {"count": 0, "mean": 0.0, "std": 0.0, "median": 0.0, "p95": 0.0, "min": 0.0, "max": 0.0}
    return {"count": int(a.size), "mean": float(a.mean()), "std": float(a.std()), "median": float(np.median(a)),
            "p95": float(np.percentile(a, 95)), "min": float(a.min()), "max": float(a.max())}


class Timers:
    """Named lists of durations in milliseconds (thread-safe), summarised with the contract's keys."""

    def __init__(self) -> None:
        self._lists: dict[str, list[float]] = {}
        self._lock = threading.Lock()

    def add(self, name: str, ms: float) -> None:
        with self._lock:
            self._lists.setdefault(name, []).append(float(ms))

    def values(self, name: str) -> list[float]:
        with self._lock:
            return list(self._lists.get(name, ()))

    def names(self) -> list[str]:
        with self._lock:
            return list(self._lists)

    @staticmethod
    def summary(values: Iterable[float]) -> dict:
        """The ``timing.json`` entry of ``values``: exactly :data:`CONTRACT_KEYS`."""
        s = timing_stats(values)
        return {k: s[k] for k in CONTRACT_KEYS}
