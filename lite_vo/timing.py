"""Timing statistics, one definition for the system, the AR demo and the benchmark tools.

:func:`timing_stats` summarises a list of durations (milliseconds); :class:`Timers` collects named
series of them from several threads (float32 arrays: bounded memory per value). Imports numpy only.
"""
from __future__ import annotations

import threading
from typing import Iterable

import numpy as np

#: The keys of a ``timing.json`` entry (contract in ARCHITECTURE.md).
CONTRACT_KEYS = ("count", "mean", "std", "median", "p95")


def timing_stats(values: Iterable[float]) -> dict:
    """``count, mean, std, median, p95, min, max`` of ``values`` (all 0 when there are none)."""
    if not isinstance(values, (np.ndarray, list, tuple)):
        values = list(values)
    a = np.asarray(values, dtype=np.float64).ravel()
    if a.size == 0:
        return {"count": 0, "mean": 0.0, "std": 0.0, "median": 0.0, "p95": 0.0, "min": 0.0, "max": 0.0}
    return {"count": int(a.size), "mean": float(a.mean()), "std": float(a.std()), "median": float(np.median(a)),
            "p95": float(np.percentile(a, 95)), "min": float(a.min()), "max": float(a.max())}


class _Series:
    """A growing float32 array (capacity doubles): 4 bytes per value, not a Python float in a list (32)."""
    __slots__ = ("data", "size")

    def __init__(self) -> None:
        self.data = np.empty(64, dtype=np.float32)
        self.size = 0

    def append(self, value: float) -> None:
        if self.size == self.data.size:
            grown = np.empty(2 * self.data.size, dtype=np.float32)
            grown[:self.size] = self.data
            self.data = grown
        self.data[self.size] = value
        self.size += 1

    def values(self) -> np.ndarray:
        return self.data[:self.size].copy()


class Timers:
    """Named series of durations in milliseconds (thread-safe), summarised with the contract's keys.

    Every value is kept (medians and p95 are exact over a whole run), as float32: a 10,000-frame
    run with 15 stages holds about 0.6 MB."""

    def __init__(self) -> None:
        self._series: dict[str, _Series] = {}
        self._lock = threading.Lock()

    def add(self, name: str, ms: float) -> None:
        with self._lock:
            series = self._series.get(name)
            if series is None:
                series = self._series[name] = _Series()
            series.append(ms)

    def values(self, name: str) -> np.ndarray:
        """The durations of ``name`` in the order they were added (float32 copy; empty when unknown)."""
        with self._lock:
            series = self._series.get(name)
            return series.values() if series is not None else np.zeros(0, dtype=np.float32)

    def names(self) -> list[str]:
        with self._lock:
            return list(self._series)

    def nbytes(self) -> int:
        """Bytes held by the stored values (capacity included)."""
        with self._lock:
            return sum(s.data.nbytes for s in self._series.values())

    @staticmethod
    def summary(values: Iterable[float]) -> dict:
        """The ``timing.json`` entry of ``values``: exactly :data:`CONTRACT_KEYS`."""
        s = timing_stats(values)
        return {k: s[k] for k in CONTRACT_KEYS}
