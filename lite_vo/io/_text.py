"""Small strict parsers for the plain-text index files of sequences (TUM lists, CSV, calib.txt).

Every problem becomes an :class:`~lite_vo.errors.InputError` whose one-line message names the
file and, where it applies, the line number. Imports numpy only.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError


def read_lines(path: Path, what: str = "file") -> list[tuple[int, str]]:
    """(line number, stripped text) of the non-empty, non-comment lines of a text file."""
    path = Path(path)
    if not path.is_file():
        if path.exists():
            raise InputError(f"{path}: is not a file")
        raise InputError(f"{path}: {what} not found")
    try:
        text = path.read_text(encoding="utf-8-sig", errors="strict")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror or err})") from None
    out = []
    for n, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#") or s.startswith("%"):
            continue
        out.append((n, s))
    return out


def split_fields(s: str, sep: str | None) -> list[str]:
    if sep is None:
        return s.split()
    return [f.strip() for f in s.split(sep)]


def parse_float(path: Path, n: int, tok: str, what: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise InputError(f"{path} line {n}: {what} {tok!r} is not a number") from None
    return v


def parse_table(path: Path, min_cols: int, max_cols: int | None = None, sep: str | None = None,
                what: str = "file", layout: str = "") -> tuple[np.ndarray, list[int]]:
    """Numeric table (N, min_cols) of the leading ``min_cols`` columns; line numbers of each row.

    Lines with fewer than ``min_cols`` or more than ``max_cols`` fields, and non-numeric or NaN
    fields, are errors naming the line."""
    lines = read_lines(path, what)
    fast = _fast_table(lines, min_cols, max_cols, sep)
    if fast is not None:
        return fast, [n for n, _ in lines]
    rows, numbers = [], []
    for n, s in lines:
        f = split_fields(s, sep)
        if len(f) < min_cols or (max_cols is not None and len(f) > max_cols):
            exp = f"{min_cols}" if max_cols == min_cols else f"at least {min_cols}"
            raise InputError(f"{path} line {n}: expected {exp} fields{' (' + layout + ')' if layout else ''}, "
                             f"got {len(f)}")
        vals = []
        for tok in f[:min_cols]:
            v = parse_float(path, n, tok, "value")
            if not np.isfinite(v):
                raise InputError(f"{path} line {n}: value {tok!r} is not finite")
            vals.append(v)
        rows.append(vals)
        numbers.append(n)
    arr = np.array(rows, dtype=np.float64).reshape(-1, min_cols)
    return arr, numbers


def _fast_table(lines: list[tuple[int, str]], min_cols: int, max_cols: int | None,
                sep: str | None) -> np.ndarray | None:
    """numpy's C parser for well-formed tables; None when anything is off (then the strict
    line-by-line parser runs and reports the offending line)."""
    if len(lines) < 64:
        return None
    import io
    try:
        arr = np.loadtxt(io.StringIO("\n".join(s for _, s in lines)), delimiter=sep, dtype=np.float64,
                         ndmin=2, comments=None)
    except ValueError:
        return None
    if arr.shape[0] != len(lines) or arr.shape[1] < min_cols or (max_cols is not None and arr.shape[1] > max_cols):
        return None
    arr = np.ascontiguousarray(arr[:, :min_cols])
    if not np.all(np.isfinite(arr)):
        return None
    return arr


def check_increasing(path: Path, timestamps: np.ndarray, line_numbers: list[int]) -> None:
    """Timestamps must be strictly increasing; the error names the first offending line."""
    t = np.asarray(timestamps)
    if len(t) < 2:
        return
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if len(bad):
        i = int(bad[0]) + 1
        raise InputError(f"{path} line {line_numbers[i]}: timestamp {float(t[i])!r} is not after the previous one "
                         f"({float(t[i - 1])!r}); timestamps must be strictly increasing")
