"""The overwrite rule for everything the commands write: nothing the user has is replaced without
``--force``. One place for the check and its one-line messages."""
from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path
from typing import Iterable

from ..errors import InputError


def prepare_output_dir(out: Path, force: bool, clean: Iterable[str] = ()) -> Path:
    """Create ``out``; refuse an existing non-empty folder unless ``force``.

    With ``force``, the entries matching the glob patterns ``clean`` (the command's own outputs)
    are removed first; nothing else in the folder is touched.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise InputError(f"{out}: output folder exists and is not empty (use --force to overwrite)")
        for pattern in clean:
            for p in out.glob(pattern):
                if p.is_dir():
                    shutil.rmtree(p)
                else:
                    p.unlink()
    out.mkdir(parents=True, exist_ok=True)
    return out


def check_output_file(path, force: bool) -> None:
    """Refuse to replace an existing file unless ``force``."""
    path = Path(path)
    if path.exists() and not force:
        raise InputError(f"{path}: already exists (use --force to overwrite)")


@contextlib.contextmanager
def atomic_writer(path):
    """A binary file ``<name>.tmp`` beside ``path``, renamed over ``path`` when the block ends
    without an error, so nobody ever reads a half-written file (for outputs written in parts)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        yield f
    os.replace(tmp, path)


def write_file_atomic(path, data: str | bytes) -> None:
    """Write ``data`` (text as UTF-8) through :func:`atomic_writer`."""
    with atomic_writer(path) as f:
        f.write(data.encode("utf-8") if isinstance(data, str) else data)
