"""Which profiles a sweep runs: the paper's six, validation of ``--profiles``, labels, resolutions.

Imports the standard library and ``lite_vo.errors`` only at module level (the CLI parser reads
:data:`PAPER_PROFILES` and must stay free of numpy); ``lite_vo.config`` lazily.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

from ..errors import InputError

#: The paper's mapping/tracking combinations (Table 5.1), finest first.
PAPER_PROFILES: tuple[str, ...] = ("desktop", "m640_t320", "m320_t320", "phone", "m160_t160", "m160_t80")


def profile_resolution(name: str) -> dict:
    """Mapping/tracking widths of a profile (heights follow the camera's aspect ratio)."""
    from ..config import load_profile
    r = load_profile(name).resolution
    track_width = r.map_width // (2 ** r.track_level)
    return {"map_width": r.map_width, "track_level": r.track_level, "track_width": track_width,
            "pyramid_levels": r.pyramid_levels, "label": f"{r.map_width}/{track_width}"}


def parse_profiles(text: str | Sequence[str] | None) -> list[str]:
    """``"a,b"`` or a list -> validated profile names/paths (each must load)."""
    from ..config import load_profile
    if text is None:
        names = list(PAPER_PROFILES)
    elif isinstance(text, str):
        names = [p.strip() for p in text.split(",") if p.strip()]
    else:
        names = [str(p) for p in text]
    if not names:
        raise InputError("--profiles: no profile given")
    for n in names:
        load_profile(n)  # raises ConfigError naming the problem
    if len(set(names)) != len(names):
        raise InputError(f"--profiles: duplicate profile in {','.join(names)}")
    return names


def profile_label(name: str) -> str:
    """A short, path-safe name for a profile given by name or file path."""
    s = str(name)
    if s.endswith(".toml") or "/" in s or os.sep in s:
        return Path(s).stem
    return s
