"""AR demo parameters (world model, physics, rendering, video) as one frozen dataclass.

Every magic number of the AR demo lives here with a doc line and a valid range. The VO itself is
configured by ``lite_vo`` profiles; this section is separate because ``lite_vo`` may not know about
``ar_demo``. Overrides use the same ``key=value`` TOML syntax as the VO profiles (``ar.key=value``).

Imports: standard library and ``lite_vo.config_fields`` only.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from typing import Any, Iterable

from lite_vo.config_fields import param
from lite_vo.errors import ConfigError


@dataclass(frozen=True)
class ARConfig:
    """World model (ground plane, in-painting, mesh), physics, autopilot, rendering, video."""
    # --- ground plane (5.3.2)
    acc_lowpass_tau_s: float = param(1.0, "time constant of the accelerometer low-pass filter (gravity direction), seconds", 0.0, 1000.0)
    ground_min_support: int = param(150, "minimum number of depth samples supporting the ground height", 3, 10**7)
    ground_band_rel: float = param(0.004, "height band of the supporting samples, relative to the median scene depth", 1e-5, 0.5)
    ground_max_dist_rel: float = param(2.0, "use map points closer to the camera than this times their median distance", 0.1, 1e6)
    ground_max_points: int = param(20000, "map points used for the ground plane (random subset beyond this)", 100, 10**7)
    ground_refine_max_deg: float = param(5.0, "refine the IMU normal by the dominant map plane within this angle (0: IMU only)", 0.0, 45.0)
    ransac_iterations: int = param(300, "fallback without IMU: RANSAC plane hypotheses", 1, 100000)
    ransac_max_angle_deg: float = param(40.0, "fallback: largest angle between a plane normal and the first camera's up", 1.0, 90.0)
    ransac_inlier_rel: float = param(0.01, "fallback: RANSAC inlier distance relative to the median scene depth", 1e-5, 0.5)
    # --- variational in-painting (eq. 5.6)
    grid_height: int = param(15, "rows of the in-painted inverse-depth grid (paper: 15)", 2, 480)
    grid_width: int = param(20, "columns of the in-painted inverse-depth grid (paper: 20)", 2, 640)
    alpha: float = param(0.3, "weight of the Huber regulariser (in normalised inverse-depth units)", 0.0, 1e6)
    huber_delta: float = param(0.05, "Huber threshold on the normalised inverse-depth gradient per grid cell", 1e-6, 1e3)
    ground_var: float = param(0.2, "V_pi: variance of the ground-plane prior (normalised inverse depth^2)", 1e-8, 1e6)
    min_var: float = param(1e-4, "variance floor of the data term (normalised inverse depth^2)", 1e-12, 1.0)
    solver_iterations: int = param(400, "maximum preconditioned gradient-descent iterations", 1, 100000)
    solver_tol: float = param(1e-9, "stop when the relative energy decrease of an iteration is below this", 0.0, 1.0)
    # --- collision mesh
    max_depth_ratio: float = param(1.6, "drop triangles whose corner depths differ by more than this factor (0 disables)", 0.0, 100.0)
    mesh_idepth_floor_rel: float = param(0.05, "clamp in-painted inverse depth below this fraction of the median (far plane)", 1e-4, 1.0)
    # --- persistent world: height field fused over keyframes (ar_demo.heightfield)
    field_cells: int = param(160, "cells per side of the square height field around the start position", 16, 2000)
    field_cell: float = param(0.3, "height-field cell size in car lengths", 0.05, 5.0)
    fuse_grid_width: int = param(80, "columns of the in-painted grid of each keyframe fused into the world", 4, 640)
    fuse_grid_height: int = param(60, "rows of the in-painted grid of each keyframe fused into the world", 3, 480)
    fuse_data_dilate: int = param(1, "fuse in-painted cells up to this many grid cells away from map data", 0, 20)
    fuse_max_depth_ratio: float = param(1.15, "skip in-painted cells whose depth differs from a neighbour's by more than this factor (occluding edges)", 1.0, 100.0)
    floor_band: float = param(0.2, "points within this height of the ground plane vote floor (car lengths)", 0.0, 10.0)
    obstacle_step: float = param(0.3, "points higher than this above the ground vote obstacle (car lengths)", 0.0, 100.0)
    obstacle_top: float = param(4.0, "points higher than this (e.g. the ceiling) do not vote (car lengths)", 0.0, 1000.0)
    min_obstacle_votes: int = param(5, "obstacle votes a cell needs to be an obstacle", 1, 10**6)
    obstacle_share: float = param(0.5, "share of a cell's votes that must be obstacle votes for an obstacle", 0.0, 1.0)
    min_floor_votes: int = param(2, "floor votes a cell needs to be floor", 1, 10**6)
    floor_height_recency: float = param(0.5, "per-cell floor height: weight of a newer keyframe's heights against the older ones (1: newest only)", 0.0, 1.0)
    floor_smooth: int = param(7, "per-cell floor height: mean over this many cells square (1: no smoothing)", 1, 101)
    floor_margin: int = param(1, "grow the seen floor by this many cells into unknown cells", 0, 100)
    physics_upsample: int = param(2, "pybullet height-field vertices per cell and side (walls become ramps 1/k cell wide: steeper, no roll-overs)", 1, 8)
    wall_height: float = param(2.0, "physics height of obstacles and unknown cells (car lengths)", 0.1, 100.0)
    world_keyframes: bool = param(True, "fuse the VO's keyframes (false: the newest map only, as in the paper)")
    # --- physics
    metric: bool = param(False, "true: world units are metres (gt poses, metric VO); false: monocular, arbitrary scale")
    car_length_m: float = param(0.3, "metric runs: car length in metres (a toy car)", 0.01, 100.0)
    car_length_rel_height: float = param(0.2, "monocular runs: car length relative to the camera height above the ground plane", 1e-3, 10.0)
    physics_hz: float = param(240.0, "physics time step rate (Hz)", 30.0, 2000.0)
    time_scale: float = param(1.0, "simulated seconds per video second", 0.01, 100.0)
    world_update_every: int = param(5, "rebuild the world model every k-th frame (asynchronously, Fig. 5.7)", 1, 1000)
    async_world: bool = param(True, "build world models in a worker thread (false: synchronous, deterministic)")
    start_after_s: float = param(0.5, "start the AR world this long after the first map (lets a random initialisation converge)", 0.0, 1000.0)
    start_after_monocular_s: float = param(2.0, "as start_after_s when the VO map is not metric (random initialisation)", 0.0, 1000.0)
    spawn_height: float = param(0.05, "drop the car from this height above the ground (car lengths)", 0.0, 10.0)
    # --- autopilot
    drive_speed: float = param(12.0, "target wheel speed when driving (rad/s)", 0.0, 200.0)
    drive_force: float = param(8.0, "maximum wheel motor force (N)", 0.0, 1000.0)
    max_steer: float = param(0.5, "largest steering angle (rad)", 0.0, 1.0)
    blocked_speed: float = param(0.08, "the car counts as blocked below this speed (car lengths/s) while driving", 0.0, 100.0)
    blocked_time_s: float = param(0.6, "reverse after being blocked this long (s)", 0.01, 100.0)
    reverse_time_s: float = param(1.0, "reverse for this long (s)", 0.01, 100.0)
    obstacle_normal_z: float = param(0.5, "a contact whose normal has |z| below this counts as a collision (not ground)", 0.0, 1.0)
    wander_amplitude: float = param(0.5, "steering wander amplitude as a fraction of max_steer", 0.0, 1.0)
    steer_gain: float = param(1.5, "steering angle per radian of heading error towards the view target", 0.0, 100.0)
    target_radius: float = param(1.5, "no target steering within this distance of the view target (car lengths)", 0.0, 100.0)
    blocked_grace_s: float = param(0.5, "ignore low speed this long after a drive/reverse switch (s)", 0.0, 100.0)
    spawn_v_rel: float = param(0.25, "spawn the car on the ground seen this far below the image centre (image heights)", -0.5, 0.5)
    target_v_rel: float = param(0.0, "the autopilot aims at the ground seen this far below the image centre", -0.5, 0.5)
    wander_period_s: float = param(4.0, "period of the gentle steering wander (s)", 0.1, 1000.0)
    respawn_out_of_view_s: float = param(1.5, "respawn on seen floor in view after the car was out of view this long (s; 0: never)", 0.0, 1000.0)
    spawn_clearance: float = param(0.75, "spawn only where seen floor extends this far around the car (car lengths)", 0.0, 10.0)
    respawn_hidden_s: float = param(0.2, "respawn on seen floor in view after obstacles of the world hid the car from the camera this long (s; 0: never)", 0.0, 1000.0)
    respawn_stuck_s: float = param(1.5, "respawn on seen floor in view when the car moved less than a quarter of its length in this long (s; 0: never): wedged against real geometry", 0.0, 1000.0)
    respawn_tilt_deg: float = param(60.0, "respawn when the car is tilted more than this for respawn_tilt_s (fell over; the time counts until it is back below half this tilt)", 1.0, 180.0)
    respawn_tilt_s: float = param(0.5, "how long the car may lie tilted before it respawns (s); with no floor in view it is put back on its wheels where it is", 0.0, 1000.0)
    inside_radius: float = param(0.3, "a world rebuild that puts anything but seen floor within this distance of the car's footprint centre respawns it (car lengths)", 0.0, 10.0)
    view_margin: float = param(0.12, "the autopilot aims and spawns this far inside the image border (image fraction)", 0.0, 0.45)
    # --- rendering / video
    video_fps: float = param(0.0, "video frame rate (0: from the sequence timestamps)", 0.0, 240.0)
    panels: bool = param(False, "add side panels: semi-dense depth (Fig. 5.3) and collision mesh (Fig. 5.1)")
    panel_view_elevation_deg: float = param(35.0, "mesh panel: elevation of the virtual viewpoint above the camera", -89.0, 89.0)
    panel_view_azimuth_deg: float = param(30.0, "mesh panel: rotation of the viewpoint about the up axis", -180.0, 180.0)
    world_thread: bool = param(True, "run the AR world (world hand-over to pybullet, simulation, autopilot) in its own thread: the tracking thread only queues the frame; needs render_thread")
    render_thread: bool = param(True, "render and encode the video in its own thread (parallel to tracking, Fig. 5.7)")
    render_queue: int = param(4, "frames waiting for the render thread before the caller blocks (none are dropped)", 1, 1000)
    render_ambient: float = param(0.35, "ambient share of the car's lighting (rest: one directional light from above)", 0.0, 1.0)
    occluder_offset: float = param(4.0, "depth offset (glPolygonOffset units, factor 1) pushing the real geometry back", 0.0, 1000.0)
    near_rel: float = param(0.01, "near clipping plane relative to the median scene depth", 1e-6, 1.0)
    far_rel: float = param(50.0, "far clipping plane relative to the median scene depth", 1.0, 1e6)
    # --- semi-dense map from ground-truth depth (poses='gt' and tests)
    gt_min_grad: float = param(8.0, "keep ground-truth depth pixels whose image gradient magnitude exceeds this", 0.0, 1000.0)
    gt_idepth_var: float = param(1e-4, "idepth variance given to ground-truth map pixels (relative to idepth^2)", 1e-12, 10.0)

    def replace(self, **kw) -> "ARConfig":
        return dataclasses.replace(self, **kw)


def ar_config(overrides: Iterable[str] | dict[str, Any] | None = None, **kw) -> ARConfig:
    """An :class:`ARConfig` with validated overrides (``"key=value"`` strings or a dict)."""
    from lite_vo.config import check_value  # validation shared with the VO profiles
    by_name = {f.name: f for f in fields(ARConfig)}
    values: dict[str, Any] = {}
    items: list[tuple[str, Any]] = []
    if isinstance(overrides, dict):
        items += list(overrides.items())
    elif overrides:
        try:
            import tomllib
        except ModuleNotFoundError:  # pragma: no cover
            import tomli as tomllib  # type: ignore[no-redef]
        for text in overrides:
            if "=" not in text:
                raise ConfigError(f"AR override {text!r}: expected key=value")
            key, raw = (s.strip() for s in text.split("=", 1))
            key = key[3:] if key.startswith("ar.") else key
            try:
                value = tomllib.loads(f"v = {raw}")["v"]
            except Exception:
                value = raw
            items.append((key, value))
    items += list(kw.items())
    for key, value in items:
        if key not in by_name:
            raise ConfigError(f"unknown AR setting {key!r}")
        f = by_name[key]
        if f.type in (float, "float") and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        values[key] = check_value(f"ar.{key}", f, value)
    return ARConfig(**values)
