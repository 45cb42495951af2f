"""Compact per-frame records for long runs: numpy arrays that grow by doubling, not Python objects.

A 10,000-frame session keeps every pose and every depth-accuracy row; as dicts of tuples of arrays
(or lists of dicts) that is ~0.5 KB per frame and per copy, here it is the raw numbers (136 and
64 bytes per frame). Imports numpy only.
"""
from __future__ import annotations

import numpy as np


def _grown(a: np.ndarray, size: int) -> np.ndarray:
    """``a`` with room for at least ``size`` rows (capacity doubles; the first ``len`` rows kept)."""
    if size <= len(a):
        return a
    out = np.empty((max(size, 2 * len(a), 64),) + a.shape[1:], dtype=a.dtype)
    out[:len(a)] = a
    return out


class PoseRecord:
    """Poses by frame index (``T_world_cam``, 4x4) with their timestamps; earlier poses can be
    corrected or removed. Frames are added in increasing index order (as a run produces them)."""

    def __init__(self) -> None:
        self._index = np.empty(0, dtype=np.int64)
        self._t = np.empty(0, dtype=np.float64)
        self._T = np.empty((0, 4, 4), dtype=np.float64)
        self._ok = np.empty(0, dtype=bool)
        self._n = 0
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def __contains__(self, index: int) -> bool:
        return self._row(index) is not None

    def _row(self, index: int, removed_too: bool = False) -> int | None:
        i = int(np.searchsorted(self._index[:self._n], index))
        found = i < self._n and self._index[i] == index
        return i if found and (removed_too or self._ok[i]) else None

    def add(self, index: int, timestamp: float, T_world_cam: np.ndarray | None) -> None:
        """The pose of frame ``index`` (a later frame than every one added so far, or one replaced);
        None records a frame without a pose (lost), which a later :meth:`correct` can give one."""
        i = self._row(index, removed_too=True)
        if i is not None:
            self._t[i] = timestamp
            self._set(i, T_world_cam)
            return
        if self._n and index <= self._index[self._n - 1]:
            raise ValueError(f"frame {index} added after frame {int(self._index[self._n - 1])}")
        n = self._n + 1
        self._index, self._t = _grown(self._index, n), _grown(self._t, n)
        self._T, self._ok = _grown(self._T, n), _grown(self._ok, n)
        self._index[self._n], self._t[self._n], self._ok[self._n] = index, timestamp, False
        self._n = n
        self._set(n - 1, T_world_cam)

    def _set(self, i: int, T_world_cam: np.ndarray | None) -> None:
        if T_world_cam is None:
            if self._ok[i]:
                self._ok[i] = False
                self._count -= 1
            return
        self._T[i] = T_world_cam
        if not self._ok[i]:
            self._ok[i] = True
            self._count += 1

    def correct(self, index: int, T_world_cam: np.ndarray | None) -> bool:
        """Replace the pose of a recorded frame, or give a frame recorded without one (lost) its
        pose; None: it has no pose any more. False when the frame was never recorded or nothing changed."""
        i = self._row(index, removed_too=True)
        if i is None or (T_world_cam is None and not self._ok[i]):
            return False
        self._set(i, T_world_cam)
        return True

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(frame indices, timestamps, poses (N, 4, 4)) of the frames with a pose, in order (copies)."""
        ok = self._ok[:self._n]
        return self._index[:self._n][ok], self._t[:self._n][ok], self._T[:self._n][ok]

    def nbytes(self) -> int:
        return self._index.nbytes + self._t.nbytes + self._T.nbytes + self._ok.nbytes


class RowRecord:
    """Rows of named numbers (float64 columns), read back as dicts: a list of dicts in 8 bytes per value.

    ``ints`` names the fields given back as ``int``. Iterating, indexing and ``len`` work as on
    a list of the row dicts; :meth:`to_list` makes that list."""

    def __init__(self, fields, ints=()) -> None:
        self.fields = tuple(fields)
        self._ints = frozenset(ints)
        self._data = np.empty((0, len(self.fields)), dtype=np.float64)
        self._n = 0

    def append(self, row: dict) -> None:
        """Add a row: a dict with (at least) every field."""
        self._data = _grown(self._data, self._n + 1)
        self._data[self._n] = [row[f] for f in self.fields]
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def _dict(self, values) -> dict:
        return {f: (int(v) if f in self._ints else float(v)) for f, v in zip(self.fields, values)}

    def __getitem__(self, i: int) -> dict:
        if not -self._n <= i < self._n:
            raise IndexError(f"row {i} out of range for {self._n} rows")
        return self._dict(self._data[i % self._n])

    def __iter__(self):
        for i in range(self._n):
            yield self._dict(self._data[i])

    def column(self, name: str) -> np.ndarray:
        """One field of every row (a copy)."""
        return self._data[:self._n, self.fields.index(name)].copy()

    def to_list(self) -> list[dict]:
        return list(self)

    def nbytes(self) -> int:
        return self._data.nbytes
