"""Synthetic scenes: a textured room box seen from inside plus solid axis-aligned boxes.

World frame (all scenes): metres, **z up**, the floor is the plane z = 0, gravity is
``(0, 0, -9.81)`` m/s^2. Every face carries its own seeded procedural texture in its own 2D
coordinates (see :mod:`lite_vo.synth.textures`); a constant Lambertian shading factor per face
(fixed light direction) is baked into the texture, so intensities do not depend on the viewpoint
(brightness constancy holds exactly up to sampling).

Scenes: ``room`` (6 x 5 x 2.6 m room, table with two objects on it, two low boxes standing on
the floor - obstacles for the AR car - and a cabinet) and ``desk`` (close range: a desk against a
wall with a monitor, books and small boxes, seen from 0.5-1.5 m). Imports numpy (+ cv2 through
textures) only.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ..errors import InputError
from .textures import face_texture, pack_textures

GRAVITY_WORLD = np.array([0.0, 0.0, -9.81])
"""Gravity in the world frame (m/s^2); the floor is z = 0."""

LIGHT_DIR = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])


@dataclass(frozen=True)
class Scene:
    """An axis-aligned box scene with packed mip-mapped textures (arrays are read-only).

    ``room_lo/room_hi``: the enclosing room (seen from inside, faces 0..5).
    ``box_lo/box_hi`` (B, 3): solid boxes (faces ``6 + 6 b + 2 axis + side``).
    ``obstacles``: names of the boxes standing on the floor (z_lo = 0) that a car collides with.
    """
    name: str
    seed: int
    room_lo: np.ndarray
    room_hi: np.ndarray
    box_lo: np.ndarray
    box_hi: np.ndarray
    box_names: tuple
    tex_data: np.ndarray
    tex_meta: np.ndarray
    tex_nlev: np.ndarray
    tex_origin: np.ndarray
    tex_texel: np.ndarray
    obstacles: tuple = ()
    floor_z: float = 0.0
    gravity_world: np.ndarray = field(default_factory=lambda: GRAVITY_WORLD.copy())

    @property
    def n_faces(self) -> int:
        return 6 + 6 * self.box_lo.shape[0]

    def face_name(self, face: int) -> str:
        """Human-readable name of a face index, e.g. ``room.z_lo`` (the floor) or ``box_a.y_hi``."""
        if face < 0:
            return "none"
        owner = "room" if face < 6 else self.box_names[(face - 6) // 6]
        axis, side = divmod(face % 6, 2)
        return f"{owner}.{'xyz'[axis]}_{'hi' if side else 'lo'}"

    @property
    def floor_face(self) -> int:
        """Face index of the floor (the room's z_lo face)."""
        return 4


# (name, lo, hi, texel_m, albedo, feature_scale) - the room box comes first
_ROOM_LAYOUT = (
    ("room", (-3.0, -2.5, 0.0), (3.0, 2.5, 2.6), 0.005, 120.0, 1.0),
    ("table_top", (-0.7, 0.8, 0.71), (0.7, 1.6, 0.75), 0.004, 150.0, 0.6),
    ("table_leg_1", (-0.68, 0.82, 0.0), (-0.63, 0.87, 0.71), 0.004, 70.0, 0.6),
    ("table_leg_2", (0.63, 0.82, 0.0), (0.68, 0.87, 0.71), 0.004, 70.0, 0.6),
    ("table_leg_3", (-0.68, 1.53, 0.0), (-0.63, 1.58, 0.71), 0.004, 70.0, 0.6),
    ("table_leg_4", (0.63, 1.53, 0.0), (0.68, 1.58, 0.71), 0.004, 70.0, 0.6),
    ("box_a", (0.35, -0.45, 0.0), (0.8, -0.05, 0.32), 0.003, 170.0, 0.6),
    ("box_b", (-1.0, -0.2, 0.0), (-0.6, 0.35, 0.22), 0.003, 90.0, 0.6),
    ("box_c", (0.1, 1.0, 0.75), (0.35, 1.25, 0.95), 0.003, 200.0, 0.6),
    ("books", (-0.5, 1.1, 0.75), (-0.2, 1.45, 0.82), 0.003, 110.0, 0.6),
    ("cabinet", (-2.95, 1.5, 0.0), (-2.2, 2.45, 0.9), 0.004, 140.0, 0.6),
)
_ROOM_OBSTACLES = ("box_a", "box_b")

_DESK_LAYOUT = (
    ("room", (-1.5, -2.0, 0.0), (1.5, 0.5, 2.4), 0.004, 130.0, 0.6),
    ("desk_top", (-0.8, -0.3, 0.70), (0.8, 0.5, 0.74), 0.002, 150.0, 0.3),
    ("desk_side_l", (-0.8, -0.3, 0.0), (-0.76, 0.5, 0.70), 0.003, 100.0, 0.3),
    ("desk_side_r", (0.76, -0.3, 0.0), (0.8, 0.5, 0.70), 0.003, 100.0, 0.3),
    ("monitor", (-0.3, 0.3, 0.82), (0.3, 0.34, 1.15), 0.002, 60.0, 0.3),
    ("monitor_stand", (-0.05, 0.3, 0.74), (0.05, 0.36, 0.82), 0.002, 80.0, 0.3),
    ("books", (-0.65, -0.1, 0.74), (-0.4, 0.2, 0.83), 0.0015, 180.0, 0.3),
    ("box", (0.35, 0.0, 0.74), (0.55, 0.18, 0.86), 0.0015, 200.0, 0.3),
    ("cube", (0.05, -0.2, 0.74), (0.13, -0.12, 0.82), 0.0015, 120.0, 0.3),
    ("keyboard", (-0.25, -0.08, 0.74), (0.2, 0.08, 0.76), 0.0015, 90.0, 0.3),
)
_DESK_OBSTACLES = ("books", "box", "cube")

SCENES = ("room", "desk")
"""Names accepted by :func:`make_scene`."""


def _face_normal(face_local: int, inside: bool) -> np.ndarray:
    axis, side = divmod(face_local, 2)
    n = np.zeros(3)
    n[axis] = 1.0 if side else -1.0  # outward normal of a solid box
    return -n if inside else n


def _build(name: str, layout, obstacles, seed: int) -> Scene:
    textures, origins, texels = [], [], []
    for obj_i, (obj_name, lo, hi, texel, albedo, fscale) in enumerate(layout):
        lo = np.asarray(lo, float)
        hi = np.asarray(hi, float)
        obj_rng = np.random.default_rng([seed, 7919, obj_i])
        obj_albedo = albedo * obj_rng.uniform(0.85, 1.15)
        for face_local in range(6):
            axis = face_local // 2
            b, c = (axis + 1) % 3, (axis + 2) % 3
            rng = np.random.default_rng([seed, obj_i, face_local])
            normal = _face_normal(face_local, inside=(obj_i == 0))
            shade = 0.6 + 0.4 * max(0.0, float(normal @ LIGHT_DIR))
            base = obj_albedo * rng.uniform(0.8, 1.2)
            tex = face_texture(rng, hi[b] - lo[b], hi[c] - lo[c], texel, base,
                               contrast=float(np.exp(rng.uniform(np.log(0.3), np.log(1.2)))),
                               feature_scale=fscale)
            textures.append(np.clip(tex * shade, 0.0, 255.0))
            origins.append((lo[b], lo[c]))
            texels.append(texel)
    data, meta, nlev = pack_textures(textures)
    boxes = layout[1:]
    arrays = dict(
        room_lo=np.array(layout[0][1], float), room_hi=np.array(layout[0][2], float),
        box_lo=np.array([b[1] for b in boxes], float).reshape(-1, 3),
        box_hi=np.array([b[2] for b in boxes], float).reshape(-1, 3),
        tex_data=data, tex_meta=meta, tex_nlev=nlev,
        tex_origin=np.array(origins, float), tex_texel=np.array(texels, float))
    for arr in arrays.values():
        arr.setflags(write=False)
    return Scene(name=name, seed=seed, box_names=tuple(b[0] for b in boxes),
                 obstacles=tuple(obstacles), **arrays)


@lru_cache(maxsize=4)
def _make_scene_cached(name: str, seed: int) -> Scene:
    if name == "room":
        return _build(name, _ROOM_LAYOUT, _ROOM_OBSTACLES, seed)
    return _build(name, _DESK_LAYOUT, _DESK_OBSTACLES, seed)


def make_scene(name: str = "room", seed: int = 0) -> Scene:
    """The scene ``name`` (one of :data:`SCENES`) with textures seeded by ``seed`` (cached)."""
    if name not in SCENES:
        raise InputError(f"unknown synthetic scene {name!r} (choose from {', '.join(SCENES)})")
    return _make_scene_cached(name, int(seed))
