"""Configuration: frozen dataclasses per subsystem, combined in :class:`VOConfig`, loaded from
TOML profiles (``profiles/*.toml``, installed as ``lite_vo.profiles``).

Every field is declared with :func:`param` (default, one doc line, valid range or choices).
Loading rejects unknown sections and keys, wrong types and out-of-range values with a
:class:`~lite_vo.errors.ConfigError` naming the profile, section and key.

A profile may start with ``base = "other"`` to inherit another profile and change a few values.
Command-line overrides are ``section.key=value`` strings (value in TOML syntax; bare words are
taken as strings).

Imports: numpy-free, no numba; may import the ``config`` modules of tracking and mapping only.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any, Iterable, Mapping

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

from .config_fields import param
from .errors import ConfigError


@dataclass(frozen=True)
class ResolutionConfig:
    """Image sizes: mapping resolution and how much coarser tracking runs."""
    map_width: int = param(320, "mapping image width in pixels; the height follows the camera's aspect ratio", 32, 4096)
    track_level: int = param(1, "finest pyramid level used for tracking (0 = mapping resolution, 1 = half)", 0, 4)
    pyramid_levels: int = param(5, "number of pyramid levels (level 0 = mapping resolution)", 1, 7)
    min_track_row_share: float = param(0.2, "the finest tracking level is track_level unless its image would have "
                                       "fewer rows than this share of the mapping width, then the next finer one "
                                       "(down to 0): wide cameras keep enough rows for the pose (KITTI 1226x370 at "
                                       "phone: 320x96 mapping, tracked at 320x96 instead of 160x48; 4:3, 16:9 and "
                                       "EuRoC's 752x480 keep their level at every shipped profile); 0 = off",
                                       0.0, 1.0)


@dataclass(frozen=True)
class SystemConfig:
    """How tracking and mapping are scheduled and initialised."""
    mode: str = param("sync", "sync: deterministic, one thread; realtime: two threads at the frames' timestamps",
                      choices=("sync", "realtime"))
    map_every: int = param(1, "a mapping iteration on every k-th tracked frame (sync mode; realtime mode maps at most "
                           "that often, less when the mapping thread is busy)", 1, 30)
    map_every_startup: int = param(4, "mapping interval during the first startup_s seconds (paper: every 4th frame)", 1, 30)
    startup_s: float = param(3.0, "duration of the start-up phase in seconds", 0.0, 60.0)
    keyframe_memory_mb: float = param(32.0, "bound of the keyframe history (whole-scene map.ply, relocalisation, AR "
                                      "world; compact keyframes: about 0.44 MB at 320x240 with colour): older, redundant keyframes are "
                                      "thinned to stay under it", 1.0, 100000.0)
    keyframe_min_move: float = param(0.03, "a published map becomes a keyframe when the camera moved more than this "
                                     "times the map's median depth since the newest keyframe (or turned more than "
                                     "keyframe_min_turn_deg; or the map has a new scale)", 0.0, 10.0)
    keyframe_min_turn_deg: float = param(3.0, "a published map becomes a keyframe when the camera turned more than "
                                         "this many degrees since the newest keyframe (or moved: keyframe_min_move)",
                                         0.0, 180.0)
    depth_eval_every: int = param(4, "when the sequence has depth images: compare every k-th mapped frame's map with "
                                  "its depth image (run.json depth_accuracy; the comparison is evaluation, not "
                                  "odometry: sampling keeps it off the frame budget); 0 = never", 0, 1000)
    init: str = param("auto", "map initialisation: depth image, random depth, or depth when the sequence has it",
                      choices=("auto", "depth", "random"))
    numba_threads: int = param(0, "numba threads for parallel kernels (0 = all cores)", 0, 256)
    seed: int = param(0, "seed for random initialisation", 0, 2**31 - 1)
    max_lost_frames: int = param(30, "re-initialise the map after this many consecutive lost frames", 1, 10000)
    realtime_speed: float = param(1.0, "realtime mode: playback speed relative to the timestamps", 0.01, 100.0)
    start_max_clipped: float = param(0.4, "a monocular start waits for a frame with at most this share of its pixels "
                                     "clipped (auto-exposure still settling), at most start_max_wait_s; the frames "
                                     "before are tracked backwards once the start-up is resolved (1 = off: start on "
                                     "the first frame; start_max_clipped_centre's wait too)", 0.0, 1.0)
    start_max_clipped_centre: float = param(0.55, "... and with at most this share of the pixels of its centre clipped "
                                            "(nearer the principal point than half its distance to the farthest "
                                            "corner): a vignetting lens darkens the rest of the frame, so the share "
                                            "over the whole frame understates a blown-out exposure (1 = off)", 0.0, 1.0)
    start_min_textured: float = param(0.2, "... and for a frame with at least this share of its pixels textured enough for "
                                      "a hypothesis (mapping.min_grad): not black or too dark (a camera still opening); "
                                      "a depth start waits for this one too (0 = off)", 0.0, 1.0)
    start_max_wait_s: float = param(2.0, "longest wait of start_max_clipped / start_min_textured (then the start-up "
                                    "begins anyway)", 0.0, 600.0)
    auto_vignette: bool = param(True, "estimate the camera's vignetting (darker corners) from the run's own maps once the "
                                "start-up is resolved, and correct the following frames with it when the corners are "
                                "more than 15 % darker than the centre (not done when a photometric calibration with a "
                                "vignette is given; false: never)")
    verify_init: bool = param(True, "check a random initialisation against two-view geometry; re-initialise from two views when they disagree")
    verify_features: int = param(300, "corners followed by Lucas-Kanade for the check", 20, 5000)
    verify_min_parallax_px: float = param(25.0, "median corner displacement (px at 320 width) before the check", 1.0, 500.0)
    verify_ransac_px: float = param(1.0, "RANSAC threshold of the essential matrix and homography (px at 320 width)", 0.1, 20.0)
    verify_eh_ratio: float = param(1.2, "the essential matrix must have this many times the homography's inliers (translation, not just rotation)", 1.0, 10.0)
    verify_min_inliers: int = param(40, "fewest corner inliers for a decision", 8, 5000)
    verify_lk_scale: float = param(2.0, "the corners are followed at this multiple of the mapping resolution (at most the camera's own); 1: at the mapping resolution", 1.0, 4.0)
    verify_max_tdir_std_deg: float = param(0.6, "wait until the two-view translation direction is known to this (one standard deviation, from the corners' epipolar residuals; three times this at verify_max_s)", 0.01, 180.0)
    bootstrap_always: bool = param(True, "re-initialise from two views as soon as the geometry allows, even when the tracked motion agrees (the two-view poses are the better ones)")
    verify_max_rot_deg: float = param(2.0, "largest rotation difference between tracked and two-view pose that counts as agreement", 0.0, 180.0)
    verify_max_tdir_deg: float = param(30.0, "largest translation-direction difference that counts as agreement", 0.0, 180.0)
    verify_max_s: float = param(6.0, "give the check up (keep the random map) after this many seconds", 0.1, 600.0)
    blur_window: int = param(15, "frames in the recent-sharpness median a frame's motion-blur score is relative to", 1, 1000)
    blur_min_sharpness: float = param(0.6, "a frame whose sharpness is below this share of the recent median is tracked "
                                      "only: never mapped, never a stereo reference (0 = off)", 0.0, 1.0)
    bootstrap_replay_every: int = param(1, "two-view bootstrap: replay the depth filter on every k-th stored frame", 1, 30)


def tracking_level(res: ResolutionConfig, map_width: int, map_height: int) -> int:
    """The finest tracking level for a mapping image of ``map_width`` x ``map_height``: ``res.track_level``,
    lowered (down to 0) while that level's image has fewer rows than ``res.min_track_row_share`` times
    the mapping width (level ``l`` has ``map_height // 2**l`` rows)."""
    level = res.track_level
    while level > 0 and map_height // 2 ** level < res.min_track_row_share * map_width:
        level -= 1
    return level


def _section_types() -> dict[str, type]:
    from .mapping.config import MappingConfig
    from .tracking.config import TrackingConfig
    return {"resolution": ResolutionConfig, "tracking": TrackingConfig,
            "mapping": MappingConfig, "system": SystemConfig}


def _default(cls_name: str):
    return field(default_factory=lambda: _section_types()[cls_name]())


@dataclass(frozen=True)
class VOConfig:
    """The whole configuration of the visual odometry system."""
    resolution: ResolutionConfig = _default("resolution")
    tracking: Any = _default("tracking")
    mapping: Any = _default("mapping")
    system: SystemConfig = _default("system")
    name: str = "default"

    def to_dict(self) -> dict:
        return {s: dataclasses.asdict(getattr(self, s)) for s in _section_types()} | {"name": self.name}


def describe(cls) -> list[tuple[str, Any, str, str]]:
    """(name, default, valid range, doc) of each field of a section class."""
    out = []
    for f in fields(cls):
        md = f.metadata
        if md.get("choices"):
            rng = "one of " + ", ".join(map(str, md["choices"]))
        else:
            rng = f"[{md.get('lo')}, {md.get('hi')}]"
        out.append((f.name, f.default, rng, md.get("doc", "")))
    return out


def check_value(where: str, f: dataclasses.Field, value: Any) -> Any:
    expected = f.type if isinstance(f.type, type) else {"int": int, "float": float, "bool": bool,
                                                        "str": str}.get(str(f.type))
    if expected is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
    elif expected is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
    elif expected is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        value = float(value)
        if value != value:
            raise ConfigError(f"{where}: NaN is not allowed")
    elif expected is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
    md = f.metadata
    if md.get("choices") and value not in md["choices"]:
        raise ConfigError(f"{where}: {value!r} is not one of {', '.join(map(str, md['choices']))}")
    lo, hi = md.get("lo"), md.get("hi")
    if lo is not None and value < lo or hi is not None and value > hi:
        raise ConfigError(f"{where}: {value!r} is out of range [{lo}, {hi}]")
    return value


def build_config(data: Mapping[str, Any], source: str = "profile", name: str = "custom") -> VOConfig:
    """Validate a nested mapping ``{section: {key: value}}`` and build a :class:`VOConfig`."""
    types = _section_types()
    sections = {}
    for sec, values in data.items():
        if sec == "name" and isinstance(values, str):  # as written by VOConfig.to_dict()
            name = values
            continue
        if sec not in types:
            raise ConfigError(f"{source}: unknown section [{sec}] (known: {', '.join(types)})")
        if not isinstance(values, Mapping):
            raise ConfigError(f"{source}: [{sec}] must be a table of key = value")
        cls = types[sec]
        by_name = {f.name: f for f in fields(cls)}
        kwargs = {}
        for key, value in values.items():
            if key not in by_name:
                raise ConfigError(f"{source}: unknown key {sec}.{key}")
            kwargs[key] = check_value(f"{source}: {sec}.{key}", by_name[key], value)
        sections[sec] = cls(**kwargs)
    cfg = VOConfig(name=name, **sections)
    _check_consistency(cfg, source)
    return cfg


def _check_consistency(cfg: VOConfig, source: str) -> None:
    r = cfg.resolution
    if r.track_level >= r.pyramid_levels:
        raise ConfigError(f"{source}: resolution.track_level ({r.track_level}) must be below "
                          f"resolution.pyramid_levels ({r.pyramid_levels})")


def profile_names() -> list[str]:
    """Names of the profiles shipped with the package."""
    return sorted(p.name[:-5] for p in resources.files("lite_vo.profiles").iterdir()
                  if p.name.endswith(".toml"))


def _read_profile(name_or_path: str | os.PathLike, seen: tuple = ()) -> tuple[dict, str, str]:
    s = str(name_or_path)
    if s.endswith(".toml") or os.sep in s or "/" in s:
        path = Path(s)
        if not path.is_file():
            raise ConfigError(f"{path}: profile file not found")
        text, source, name = path.read_text(encoding="utf-8"), str(path), path.stem
        base_dir = path.parent
    else:
        res = resources.files("lite_vo.profiles").joinpath(s + ".toml")
        if not res.is_file():
            raise ConfigError(f"unknown profile {s!r} (available: {', '.join(profile_names())})")
        text, source, name = res.read_text(encoding="utf-8"), f"profile {s}", s
        base_dir = None
    key = str(path.resolve()) if base_dir is not None else f"shipped:{name}"
    if key in seen:
        raise ConfigError(f"{source}: profile inheritance loop via {name!r}")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{source}: not valid TOML ({err})") from None
    base = data.pop("base", None)
    if base is not None:
        if not isinstance(base, str):
            raise ConfigError(f"{source}: base must be a profile name or path")
        if base_dir is not None and (base_dir / base).is_file():
            base = str(base_dir / base)
        parent, _, _ = _read_profile(base, seen + (key,))
        for sec, values in data.items():
            if isinstance(values, Mapping) and isinstance(parent.get(sec), Mapping):
                parent[sec] = {**parent[sec], **values}
            else:
                parent[sec] = values
        data = parent
    return data, source, name


def parse_override(text: str) -> tuple[str, str, Any]:
    """``"section.key=value"`` -> (section, key, value); value in TOML syntax, else a string."""
    if "=" not in text:
        raise ConfigError(f"override {text!r}: expected section.key=value")
    lhs, rhs = text.split("=", 1)
    parts = lhs.strip().split(".")
    if len(parts) != 2 or not all(parts):
        raise ConfigError(f"override {text!r}: expected section.key=value")
    rhs = rhs.strip()
    try:
        value = tomllib.loads(f"v = {rhs}")["v"]
    except tomllib.TOMLDecodeError:
        value = rhs
    return parts[0], parts[1], value


def load_profile(name_or_path: str | os.PathLike = "phone", overrides: Iterable[str] = ()) -> VOConfig:
    """Load a shipped profile by name (``"phone"``) or a TOML file by path, apply overrides."""
    data, source, name = _read_profile(name_or_path)
    for ov in overrides:
        sec, key, value = parse_override(ov)
        data.setdefault(sec, {})
        if not isinstance(data[sec], dict):
            raise ConfigError(f"override {ov!r}: unknown section [{sec}]")
        data[sec][key] = value
    return build_config(data, source=source, name=name)
