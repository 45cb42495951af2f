"""PLY point clouds: ``x y z`` (float32), optional ``idepth_var`` (float32) and colour
(``red green blue`` uchar; a grey value is written to all three). Binary little-endian or ASCII.

:func:`write_ply_parts` writes a cloud given in parts (streamed, never all in memory).
:func:`read_ply` reads back what :func:`write_ply` writes (vertex-only files with float/uchar
properties), for tests and tools. Imports numpy only.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from ..errors import InputError
from .outputs import atomic_writer

_PLY_TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "uchar": "u1",
              "uint8": "u1", "int": "<i4", "int32": "<i4", "uint": "<u4", "short": "<i2", "ushort": "<u2",
              "char": "i1"}


_CHUNK = 1 << 16     # points per block of the binary body


def _check_parts(points_xyz, idepth_var, colors):
    """The arrays of one block of points, checked: (points (N, 3), var (N,) or None, colours (N, 1|3) or None)."""
    pts = np.asarray(points_xyz)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points_xyz must be (N, 3), got {pts.shape}")
    n = len(pts)
    if not np.all(np.isfinite(pts)):
        raise ValueError("points_xyz contains NaN or infinite values")
    var = None
    if idepth_var is not None:
        var = np.asarray(idepth_var).reshape(-1)
        if len(var) != n:
            raise ValueError(f"idepth_var has {len(var)} values for {n} points")
    c = None
    if colors is not None:
        c = np.asarray(colors)
        if c.ndim == 1:
            c = c[:, None]
        if c.shape not in ((n, 3), (n, 1)):
            raise ValueError(f"colors must be (N,) or (N, 3), got {np.shape(colors)}")
    return pts, var, c


def _fields(with_var: bool, with_colors: bool) -> list:
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if with_var:
        fields.append(("idepth_var", "<f4"))
    if with_colors:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    return fields


def _header(n: int, fields: list, binary: bool) -> bytes:
    names = {"<f4": "float", "u1": "uchar"}
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
              "comment lite_vo semi-dense map", f"element vertex {n}"]
    header += [f"property {names[t]} {name}" for name, t in fields]
    header.append("end_header")
    return ("\n".join(header) + "\n").encode("ascii")


def _write_body(f, fields: list, pts, var, c, binary: bool) -> None:
    """The vertices of one checked block, in blocks of ``_CHUNK`` points (no second copy of a large cloud)."""
    for a in range(0, len(pts), _CHUNK):
        b = min(a + _CHUNK, len(pts))
        arr = np.zeros(b - a, dtype=fields)
        arr["x"], arr["y"], arr["z"] = pts[a:b, 0], pts[a:b, 1], pts[a:b, 2]
        if var is not None:
            arr["idepth_var"] = var[a:b]
        if c is not None:
            rgb = np.clip(np.rint(np.nan_to_num(c[a:b].astype(np.float64))), 0, 255).astype(np.uint8)
            if rgb.shape[1] == 1:
                rgb = np.repeat(rgb, 3, axis=1)
            arr["red"], arr["green"], arr["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
        if binary:
            arr.tofile(f)
        else:
            f.write("".join(" ".join(f"{v:.7g}" if isinstance(v, np.floating) else str(int(v)) for v in row) + "\n"
                            for row in arr).encode("ascii"))


def write_ply(path: str | os.PathLike, points_xyz, idepth_var=None, colors=None, binary: bool = True) -> None:
    """Write points (N, 3) with optional ``idepth_var`` (N,) and ``colors`` (N,) grey or (N, 3) RGB
    (0..255) to a PLY file. Non-finite points are an error (filter them first).

    The file is written beside ``path`` and renamed over it at the end (never half-written); the
    binary body is written in blocks of 65536 points, so a large cloud needs no second copy."""
    pts, var, c = _check_parts(points_xyz, idepth_var, colors)
    fields = _fields(var is not None, c is not None)
    with atomic_writer(Path(path)) as f:
        f.write(_header(len(pts), fields, binary))
        _write_body(f, fields, pts, var, c, binary)


def write_ply_parts(path: str | os.PathLike, parts, with_var: bool = True, with_colors: bool = True,
                    binary: bool = True) -> int:
    """Write a cloud given in parts (an iterable of ``(points, idepth_var, colors)``, each as for
    :func:`write_ply`, ``None`` for a column the file does not have) without holding all of it: the
    vertices go to a temporary file as they come, then behind the header (which needs their count).
    Returns the number of points; the file appears only when complete, as with :func:`write_ply`."""
    path = Path(path)
    fields = _fields(with_var, with_colors)
    body = path.with_name(path.name + ".body.tmp")
    n = 0
    try:
        with open(body, "wb") as f:
            for points_xyz, idepth_var, colors in parts:
                pts, var, c = _check_parts(points_xyz, idepth_var, colors)
                if (var is not None) != with_var or (c is not None) != with_colors:
                    raise ValueError("every part must have the same columns (with_var / with_colors)")
                _write_body(f, fields, pts, var, c, binary)
                n += len(pts)
        with atomic_writer(path) as f, open(body, "rb") as src:
            f.write(_header(n, fields, binary))
            shutil.copyfileobj(src, f, 1 << 20)
    finally:
        body.unlink(missing_ok=True)
    return n


def read_ply(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Vertex properties of a vertex-only PLY file as ``{name: array}`` (binary LE or ASCII)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: PLY file not found")
    data = path.read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply") or end < 0:
        raise InputError(f"{path}: not a PLY file")
    header = data[:end].decode("ascii", errors="replace").splitlines()
    body = data[end + len(b"end_header\n"):]
    fmt, n, props = None, 0, []
    for line in header:
        f = line.split()
        if not f:
            continue
        if f[0] == "format":
            fmt = f[1]
        elif f[0] == "element":
            if f[1] != "vertex":
                raise InputError(f"{path}: only vertex elements are supported, found {f[1]!r}")
            n = int(f[2])
        elif f[0] == "property":
            if f[1] not in _PLY_TYPES:
                raise InputError(f"{path}: unsupported property type {f[1]!r}")
            props.append((f[2], _PLY_TYPES[f[1]]))
    dtype = np.dtype(props)
    if fmt == "binary_little_endian":
        if len(body) < n * dtype.itemsize:
            raise InputError(f"{path}: truncated (expected {n} vertices)")
        arr = np.frombuffer(body[:n * dtype.itemsize], dtype=dtype)
    elif fmt == "ascii":
        rows = [r.split() for r in body.decode("ascii").splitlines() if r.strip()][:n]
        if len(rows) < n:
            raise InputError(f"{path}: truncated (expected {n} vertices)")
        arr = np.zeros(n, dtype=dtype)
        for k, (name, _) in enumerate(props):
            arr[name] = [float(r[k]) for r in rows]
    else:
        raise InputError(f"{path}: unsupported PLY format {fmt!r}")
    return {name: np.array(arr[name]) for name, _ in props}
