"""PLY point clouds: ``x y z`` (float32), optional ``idepth_var`` (float32) and colour
(``red green blue`` uchar; a grey value is written to all three). Binary little-endian or ASCII.

:func:`read_ply` reads back what :func:`write_ply` writes (vertex-only files with float/uchar
properties), for tests and tools. Imports numpy only.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from .outputs import atomic_writer

_PLY_TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "uchar": "u1",
              "uint8": "u1", "int": "<i4", "int32": "<i4", "uint": "<u4", "short": "<i2", "ushort": "<u2",
              "char": "i1"}


_CHUNK = 1 << 16     # points per block of the binary body


def write_ply(path: str | os.PathLike, points_xyz, idepth_var=None, colors=None, binary: bool = True) -> None:
    """Write points (N, 3) with optional ``idepth_var`` (N,) and ``colors`` (N,) grey or (N, 3) RGB
    (0..255) to a PLY file. Non-finite points are an error (filter them first).

    The file is written beside ``path`` and renamed over it at the end (never half-written); the
    binary body is written in blocks of 65536 points, so a large cloud needs no second copy."""
    path = Path(path)
    pts = np.asarray(points_xyz)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points_xyz must be (N, 3), got {pts.shape}")
    n = len(pts)
    if not np.all(np.isfinite(pts)):
        raise ValueError("points_xyz contains NaN or infinite values")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    var = None
    if idepth_var is not None:
        var = np.asarray(idepth_var).reshape(-1)
        if len(var) != n:
            raise ValueError(f"idepth_var has {len(var)} values for {n} points")
        fields.append(("idepth_var", "<f4"))
    c = None
    if colors is not None:
        c = np.asarray(colors)
        if c.ndim == 1:
            c = c[:, None]
        if c.shape not in ((n, 3), (n, 1)):
            raise ValueError(f"colors must be (N,) or (N, 3), got {np.shape(colors)}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    names = {"<f4": "float", "u1": "uchar"}
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
              "comment lite_vo semi-dense map", f"element vertex {n}"]
    header += [f"property {names[t]} {name}" for name, t in fields]
    header.append("end_header")
    with atomic_writer(path) as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        for a in range(0, n, _CHUNK):
            b = min(a + _CHUNK, n)
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
