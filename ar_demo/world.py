"""The geometry the car drives on and the simulation on it (thesis 5.3, Fig. 5.7).

:class:`ARWorld` owns the ground plane (accelerometer gravity, refined by the map, RANSAC without an
IMU), the world model (in-painted semi-dense map -> collision mesh, rebuilt asynchronously at a
lower rate than tracking) and the pybullet world with the car. It knows nothing of rendering or
video: :class:`ar_demo.sink.ARSink` feeds it maps and camera poses and reads the car back.

Ownership: one thread (the session's) calls every method; the world-model worker thread only
builds meshes from the copies it is handed (:class:`~ar_demo.world_model.AsyncWorldModelBuilder`).

Imports: numpy, lite_vo (camera, geometry), ar_demo (config, ground, world_model, physics).
"""
from __future__ import annotations

import math

import numpy as np

from lite_vo.camera import PinholeIntrinsics
from lite_vo.geometry import transform_points

from .config import ARConfig
from .ground import GravityFilter, GroundPlane, estimate_ground_plane, map_points_world
from .physics import PhysicsFrame, PhysicsWorld, racecar_length
from .world_model import AsyncWorldModelBuilder, WorldModel, build_world_model


def semi_dense_from_depth(image: np.ndarray, depth_m: np.ndarray, min_grad: float,
                          var_rel: float) -> tuple[np.ndarray, np.ndarray]:
    """A semi-dense map from a depth image: pixels with image gradient magnitude above ``min_grad``
    keep their inverse depth (NaN elsewhere), variance ``var_rel * idepth^2`` (tests, benchmarks)."""
    img = np.asarray(image, dtype=np.float32)
    gx = np.zeros_like(img)
    gy = np.zeros_like(img)
    gx[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    gy[1:-1, :] = 0.5 * (img[2:, :] - img[:-2, :])
    grad = np.sqrt(gx * gx + gy * gy)
    d = np.asarray(depth_m, dtype=np.float64)
    ok = (grad > min_grad) & np.isfinite(d) & (d > 0)
    idepth = np.full(d.shape, np.nan)
    idepth[ok] = 1.0 / d[ok]
    var = np.where(ok, var_rel * np.nan_to_num(idepth) ** 2, np.nan)
    return idepth, var


class ARWorld:
    """Ground plane + collision world + car. ``start`` once a map is there, then per frame
    ``submit`` (every k-th), ``swap_in`` and ``step``; ``reset`` after a new monocular map."""

    def __init__(self, cfg: ARConfig, camera: PinholeIntrinsics, metric: bool, accelerometer=None) -> None:
        self.cfg = cfg
        self.camera = camera                     # the full-resolution camera of the video
        self.metric = metric
        self.acc = accelerometer
        self.gravity = GravityFilter(cfg.acc_lowpass_tau_s)
        self._last_acc_t = -np.inf
        self.ground: GroundPlane | None = None
        self.physics: PhysicsWorld | None = None
        self.builder: AsyncWorldModelBuilder | None = None
        self.model: WorldModel | None = None     # newest model swapped into physics
        self.scene_depth: float | None = None
        self._pending: WorldModel | None = None  # built synchronously (async_world=false)
        self.build_ms: list[float] = []
        self.events: list[str] = []

    @property
    def started(self) -> bool:
        return self.physics is not None

    # ------------------------------------------------------------------ gravity
    def feed_imu(self, ts: float, T_world_cam: np.ndarray) -> None:
        """Low-pass the accelerometer samples up to ``ts`` into the world-frame up direction."""
        if self.acc is None or len(self.acc) == 0:
            return
        t = self.acc.timestamps
        m = (t > self._last_acc_t) & (t <= ts)
        if not m.any() and self._last_acc_t == -np.inf:
            m = t <= t[0]                        # at least the first sample
        if m.any():
            self.gravity.update(self.acc.acc_xyz[m], T_world_cam[:3, :3], t[m])
            self._last_acc_t = float(t[m][-1])

    # ------------------------------------------------------------------ life cycle
    def start(self, published) -> bool:
        """Ground plane, physics frame, first collision mesh and the car, from a published map.
        False when the map does not support a ground plane yet."""
        idepth, T_map, intr_map = published.idepth, published.T_world_cam, published.camera
        pts = map_points_world(idepth, intr_map, T_map)
        if len(pts) < self.cfg.ground_min_support:
            return False
        depths = 1.0 / np.asarray(idepth)[np.isfinite(idepth) & (np.asarray(idepth) > 0)]
        self.scene_depth = float(np.median(depths))
        ground = estimate_ground_plane(pts, self.cfg, up_world=self.gravity.up_world, T_world_cam0=T_map,
                                       scene_depth=self.scene_depth)
        if ground is None:
            return False
        self.ground = ground
        model = build_world_model(idepth, published.idepth_var, intr_map, T_map, ground, self.cfg,
                                  published.frame_index, published.timestamp)
        self.build_ms.append(model.build_ms)
        car_len_phys = racecar_length()
        want = self.cfg.car_length_m if self.metric else self.cfg.car_length_rel_depth * self.scene_depth
        frame = PhysicsFrame.from_ground(ground.normal_world, ground.height, T_map, car_len_phys / want)
        self.physics = PhysicsWorld(self.cfg, frame)
        if self.cfg.ground_extent_rel > 0:
            self.physics.add_ground_slab(self.cfg.ground_extent_rel * car_len_phys)
        self.physics.set_world_mesh(model.mesh.vertices_world, model.mesh.faces)
        self.model = model
        xy, yaw = self._spawn_pose(T_map, intr_map)
        self.physics.spawn_car(xy, yaw)
        self.events.append(f"start frame {published.frame_index}: ground {ground.source}, scale {frame.scale:.3f}")
        if self.cfg.async_world:
            self.builder = AsyncWorldModelBuilder(self.cfg, ground)
        return True

    def reset(self, reason: str) -> None:
        """Forget everything (e.g. a new monocular map has a new scale)."""
        self.close()
        self.ground = self.model = None
        self.events.append(f"reset: {reason}")

    def close(self) -> None:
        if self.builder is not None:
            self.builder.close()
        if self.physics is not None:
            self.physics.close()
        self.builder = self.physics = None

    # ------------------------------------------------------------------ per frame
    def submit(self, published) -> None:
        """Rebuild the collision mesh from a newer map (in the worker thread when asynchronous)."""
        args = (published.idepth, published.idepth_var, published.camera, published.T_world_cam,
                published.frame_index, published.timestamp)
        if self.builder is not None:
            self.builder.submit(*args)
        else:
            self._pending = build_world_model(*args[:4], self.ground, self.cfg, *args[4:])

    def swap_in(self) -> None:
        """Put a finished world model into the physics world (one static body, replaced)."""
        if self.builder is not None:
            model = self.builder.poll()
        else:
            model, self._pending = self._pending, None
        if model is not None:
            self.build_ms.append(model.build_ms)
            self.physics.set_world_mesh(model.mesh.vertices_world, model.mesh.faces)
            self.model = model

    def step(self, dt: float, T_world_cam: np.ndarray | None) -> None:
        """Advance the simulation; the autopilot steers towards the ground in the middle of the view."""
        target = self._view_target(T_world_cam) if T_world_cam is not None else None
        self.physics.step(dt * self.cfg.time_scale, target_xy=target)

    def car_position_world(self) -> np.ndarray:
        return self.physics.frame.to_world(self.physics.car_state().T_phys_base[:3, 3][None])[0]

    # ------------------------------------------------------------------ geometry helpers
    def _ground_hit(self, T: np.ndarray, intr: PinholeIntrinsics, u: float, v: float):
        """Physics-frame xy of the ground point seen at pixel (u, v), or None."""
        idepth = self.ground.idepth_at(T, intr, np.array([u]), np.array([v]))[0]
        if idepth <= 0:
            return None
        p_cam = intr.unproject_idepth(np.array([u]), np.array([v]), np.array([idepth]))
        return self.physics.frame.to_phys(transform_points(T, p_cam))[0, :2]

    def _spawn_pose(self, T, intr):
        xy = self._ground_hit(T, intr, intr.cx, intr.cy + self.cfg.spawn_v_rel * intr.height)
        if xy is None:                            # looking above the horizon: two car lengths ahead
            xy = np.array([2.0 * racecar_length(), 0.0])
        return xy, math.pi / 2                    # across the view: the video shows the car's side

    def _view_target(self, T: np.ndarray):
        if self.ground is None:
            return None
        c = self.camera
        return self._ground_hit(T, c, c.cx, c.cy + self.cfg.target_v_rel * c.height)
