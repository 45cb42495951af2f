"""The geometry the car drives on and the simulation on it (thesis 5.3, Fig. 5.7, and its future work).

:class:`ARWorld` owns the ground plane (accelerometer gravity, refined by the map, RANSAC without an
IMU, from the points of all keyframes), the persistent world (a height field fused over the VO's
keyframes, :mod:`ar_demo.heightfield`, rebuilt asynchronously at a lower rate than tracking; the
newest map's in-painted mesh is kept for occlusion in the video) and the pybullet world with the car.
It knows nothing of rendering or video: :class:`ar_demo.sink.ARSink` feeds it maps, keyframes and
camera poses and reads the car back.

**Car size**: metric runs: ``car_length_m`` (0.3 m, a toy car); monocular runs: ``car_length_rel_height``
times the camera height above the ground plane at the start (0.2: a 30 cm car for a camera 1.5 m up).

**Car behaviour**: it spawns upright on seen floor inside the current view (its footprint centre on
a floor disc of ``spawn_clearance`` car lengths, not hidden behind obstacles of the field), the
autopilot steers towards seen floor in the lower middle of the view around obstacles of the field
(and backs up when blocked or pressed against an obstacle), and it respawns there when it fell,
flipped (tilted beyond ``respawn_tilt_deg`` for ``respawn_tilt_s``; with no seen floor in view it is put
back on its wheels where it lies), left the field, stayed out of view for ``respawn_out_of_view_s``, hidden behind obstacles
of the field for ``respawn_hidden_s`` or stuck (less than a quarter of its length of progress in
``respawn_stuck_s``, whether driving or backing up). It stands on the fused local floor height (see
:mod:`ar_demo.heightfield`), so it stays on the floor the current camera sees when the pose drifts
against the ground plane.

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
from .heightfield import FLOOR, OBSTACLE, FieldSpec, HeightField, WorldFusion
from .physics import PhysicsFrame, PhysicsWorld, racecar_length
from .world_model import AsyncWorldModelBuilder, WorldModel, build_world


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
    """Ground plane + persistent world + car. ``start`` once a map is there, then per frame
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
        self.fusion: WorldFusion | None = None
        self.model: WorldModel | None = None     # newest model swapped into physics
        self.field: HeightField | None = None
        self.scene_depth: float | None = None
        self.camera_height: float | None = None
        self.car_length_world: float | None = None
        self._pending: WorldModel | None = None  # built synchronously (async_world=false)
        self._out_of_view_s = 0.0
        self._tilted_s = 0.0
        self._hidden_s = 0.0                     # how long obstacles of the field hid the car from the camera
        self._stuck_from = None                  # (sim time, xy) where the car last made progress
        self._inside_geometry = False
        self.spawns = 0
        self.respawn_reasons: dict[str, int] = {}
        self.build_ms: list[float] = []
        self.events: list[str] = []

    @property
    def started(self) -> bool:
        return self.physics is not None

    @property
    def has_car(self) -> bool:
        return self.physics is not None and self.physics.car >= 0

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
    def start(self, published, keyframes=()) -> bool:
        """Ground plane, physics frame, the first world and (when seen floor is in view) the car,
        from a published map and the keyframes. False when the map does not support a ground plane yet."""
        idepth, T_map, intr_map = published.idepth, published.T_world_cam, published.camera
        pts = [map_points_world(idepth, intr_map, T_map)]
        for kf in keyframes:
            pts.append(map_points_world(kf.idepth, kf.camera, kf.T_world_cam))
        pts = np.concatenate(pts)
        if len(pts) < self.cfg.ground_min_support:
            return False
        depths = 1.0 / np.asarray(idepth)[np.isfinite(idepth) & (np.asarray(idepth) > 0)]
        self.scene_depth = float(np.median(depths)) if len(depths) else 1.0
        ground = estimate_ground_plane(pts, self.cfg, up_world=self.gravity.up_world, T_world_cam0=T_map,
                                       scene_depth=self.scene_depth)
        if ground is None:
            return False
        height = float(ground.signed_distance(T_map[:3, 3][None])[0])
        if height <= 0:
            return False                         # the camera must be above the floor it stands on
        self.ground, self.camera_height = ground, height
        car_len_phys = racecar_length()
        self.car_length_world = self.cfg.car_length_m if self.metric else self.cfg.car_length_rel_height * height
        frame = PhysicsFrame.from_ground(ground.normal_world, ground.height, T_map, car_len_phys / self.car_length_world)
        self.physics = PhysicsWorld(self.cfg, frame)
        c = self.cfg
        spec = FieldSpec(c.field_cells, c.field_cell * car_len_phys, c.wall_height * car_len_phys,
                         -c.floor_band * car_len_phys)
        self.fusion = WorldFusion(c, ground, frame, spec, car_len_phys)
        model = build_world(published, list(keyframes) if c.world_keyframes else [], ground, c, self.fusion)
        self._install(model)
        self.events.append(f"start frame {published.frame_index}: ground {ground.source}, camera height "
                           f"{height:.3f}, car {self.car_length_world:.3f} (world units), scale {frame.scale:.3f}")
        self._try_spawn(T_map, "start")
        if c.async_world:
            self.builder = AsyncWorldModelBuilder(c, ground, self.fusion)
        return True

    def reset(self, reason: str) -> None:
        """Forget everything (e.g. a new monocular map has a new scale)."""
        self.close()
        self.ground = self.model = self.field = self.fusion = None
        self.events.append(f"reset: {reason}")

    def close(self) -> None:
        if self.builder is not None:
            self.builder.close()
        if self.physics is not None:
            self.physics.close()
        self.builder = self.physics = None

    # ------------------------------------------------------------------ per frame
    def submit(self, published, keyframes=()) -> None:
        """Rebuild the world from the keyframes and the newest map (in the worker thread when asynchronous)."""
        kfs = list(keyframes) if self.cfg.world_keyframes else []
        if self.builder is not None:
            self.builder.submit(published, kfs)
        else:
            self._pending = build_world(published, kfs, self.ground, self.cfg, self.fusion)

    def swap_in(self) -> None:
        """Put a finished world into the physics world (the one height-field body, updated in place)."""
        if self.builder is not None:
            model = self.builder.poll()
        else:
            model, self._pending = self._pending, None
        if model is not None:
            self._install(model)

    def _install(self, model: WorldModel) -> None:
        self.build_ms.append(model.build_ms)
        k = self.cfg.physics_upsample
        self.physics.set_height_field(model.field.heights(k), model.field.spec.cell / k)
        self.model, self.field = model, model.field
        self._inside_geometry = False
        if self.has_car:                          # the new world puts real geometry where the car is
            self._inside_geometry = not self.field.free_disc(self.physics.car_centre_xy(),
                                                             self.cfg.inside_radius * self.physics.car_length)

    def step(self, dt: float, T_world_cam: np.ndarray | None) -> None:
        """Advance the simulation; spawn, steer and respawn the car with respect to the current view."""
        ph = self.physics
        if not self.has_car:
            if T_world_cam is not None:
                self._try_spawn(T_world_cam, "spawn")
            if not self.has_car:
                return
        target = self._steer_target(T_world_cam) if T_world_cam is not None else None
        ph.step(dt * self.cfg.time_scale, target_xy=target)
        self._check_respawn(dt, T_world_cam)

    # ------------------------------------------------------------------ the car in the world frame
    def car_pose_world(self) -> np.ndarray | None:
        """``T_world_car``: origin at the centre of the car's footprint on its surface, x forward,
        z up, in the world frame and units of the camera trajectory (None without a car)."""
        if not self.has_car:
            return None
        ph = self.physics
        T = ph.car_state().T_phys_base.copy()
        T[:3, 3] = T[:3, :3] @ ph.footprint_offset() + T[:3, 3]
        f = ph.frame
        out = np.eye(4)
        out[:3, :3] = f.R_phys_world.T @ T[:3, :3]
        out[:3, 3] = f.to_world(T[:3, 3][None])[0]
        return out

    def car_position_world(self) -> np.ndarray:
        return self.car_pose_world()[:3, 3]

    def in_view(self, T_world_cam: np.ndarray, p_world: np.ndarray, margin: float = 0.0) -> bool:
        p = transform_points(np.linalg.inv(T_world_cam), np.asarray(p_world, dtype=np.float64)[None])[0]
        if p[2] <= 0:
            return False
        c = self.camera
        u, v = c.fx * p[0] / p[2] + c.cx, c.fy * p[1] / p[2] + c.cy
        mu, mv = margin * c.width, margin * c.height
        return bool(mu - 0.5 <= u <= c.width - 0.5 - mu and mv - 0.5 <= v <= c.height - 0.5 - mv)

    # ------------------------------------------------------------------ geometry helpers
    def _ground_hit(self, T: np.ndarray, intr: PinholeIntrinsics, u, v) -> np.ndarray:
        """Physics-frame xy (N, 2) of the ground points seen at pixels (u, v); NaN where the ray misses."""
        u, v = np.atleast_1d(np.asarray(u, float)), np.atleast_1d(np.asarray(v, float))
        idepth = self.ground.idepth_at(T, intr, u, v)
        out = np.full((len(u), 2), np.nan)
        ok = idepth > 0
        if ok.any():
            p_cam = intr.unproject_idepth(u[ok], v[ok], idepth[ok])
            out[ok] = self.physics.frame.to_phys(transform_points(T, p_cam))[:, :2]
        return out

    def _visible(self, cam_phys: np.ndarray, xy: np.ndarray) -> bool:
        """No obstacle cell of the field stands between the camera and the floor point ``xy``."""
        f = self.field
        target = np.array([xy[0], xy[1], 0.0])
        s = np.linspace(0.0, 1.0, 40)[:, None]
        seg = cam_phys[None] + s * (target - cam_phys)[None]
        near = np.linalg.norm(seg[:, :2] - target[:2], axis=1) > 0.6 * self.physics.car_length
        seg = seg[near]
        ix, iy, inside = f.spec.index(seg)
        ix, iy, seg = ix[inside], iy[inside], seg[inside]
        blocked = (f.state[ix, iy] == OBSTACLE) & (seg[:, 2] < 2.0 * f.obstacle_height[ix, iy])
        return not bool(blocked.any())

    def _floor_in_view(self, T: np.ndarray, v_rel: float, radius_cars: float = 0.6):
        """The seen, free and visible floor point in view closest (in the image) to the pixel at the
        centre column, ``v_rel`` image heights below the centre; None if there is none."""
        if self.field is None:
            return None
        c, m = self.camera, self.cfg.view_margin
        us = np.linspace(m * c.width, (1 - m) * c.width, 11)
        vs = np.linspace(max(m, 0.35) * c.height, (1 - m) * c.height, 9)
        U, V = np.meshgrid(us, vs)
        U, V = U.ravel(), V.ravel()
        want = np.array([c.cx, c.cy + v_rel * c.height])
        order = np.argsort(np.hypot(U - want[0], V - want[1]))
        xy = self._ground_hit(T, c, U[order], V[order])
        cam = self.physics.frame.to_phys(T[:3, 3][None])[0]
        radius = radius_cars * self.physics.car_length
        for p in xy:
            if np.all(np.isfinite(p)) and self.field.free_disc(p, radius) and self._visible(cam, p):
                return p
        return None

    def _try_spawn(self, T: np.ndarray, why: str) -> bool:
        xy = self._floor_in_view(T, self.cfg.spawn_v_rel, radius_cars=self.cfg.spawn_clearance)
        if xy is None:
            return False
        fwd = self.physics.frame.R_phys_world @ T[:3, 2]
        yaw = math.atan2(fwd[1], fwd[0]) + math.pi / 2      # across the view: the video shows its side
        self.physics.spawn_car(xy, yaw)
        self._count_spawn(why)
        self._out_of_view_s = self._hidden_s = 0.0
        self._inside_geometry = False            # the new place is free (it was the old one that was not)
        return True

    def _count_spawn(self, why: str) -> None:
        """Book a (re)spawn: counted by reason; the tilt and progress clocks start over."""
        self.spawns += 1
        self.respawn_reasons[why] = self.respawn_reasons.get(why, 0) + 1
        self._tilted_s = 0.0
        self._stuck_from = None

    def _steer_target(self, T: np.ndarray):
        """Where the autopilot steers: towards the floor in the middle of the view, around obstacles."""
        goal = self._floor_in_view(T, self.cfg.target_v_rel, radius_cars=0.4)
        if goal is None:
            return None
        pos = self.physics.car_centre_xy()
        d = goal - pos
        dist = float(np.hypot(*d))
        L = self.physics.car_length
        if dist < 1e-9:
            return goal
        base = math.atan2(d[1], d[0])
        look = min(dist, 1.5 * L)
        for off in (0, 20, -20, 40, -40, 60, -60, 90, -90, 120, -120):
            a = base + math.radians(off)
            dirv = np.array([math.cos(a), math.sin(a)])
            pts = pos[None] + np.linspace(0.3 * L, look, 6)[:, None] * dirv[None]
            if np.all(self.field.at(pts) == FLOOR):
                return pos + max(look, self.cfg.target_radius * L * 1.01) * dirv if off else goal
        return goal

    def _stuck(self, xy: np.ndarray) -> bool:
        """The car made less than a quarter of its length of progress in the last ``respawn_stuck_s``."""
        lim = self.cfg.respawn_stuck_s
        t = self.physics.sim_time
        if lim <= 0:
            return False
        if self._stuck_from is None or np.hypot(*(xy - self._stuck_from[1])) > 0.25 * self.physics.car_length:
            self._stuck_from = (t, np.array(xy, dtype=np.float64))
            return False
        return t - self._stuck_from[0] > lim

    def _check_respawn(self, dt: float, T: np.ndarray | None) -> None:
        ph = self.physics
        st = ph.car_state()
        z_axis = st.T_phys_base[:3, 2]
        tilt = math.degrees(math.acos(float(np.clip(z_axis[2], -1.0, 1.0))))
        if tilt > self.cfg.respawn_tilt_deg:
            self._tilted_s += dt
        elif tilt < 0.5 * self.cfg.respawn_tilt_deg:
            self._tilted_s = 0.0                   # back on its wheels (a car rocking on its side keeps counting)
        pos = st.T_phys_base[:3, 3]
        _, _, inside = self.field.spec.index(pos[None])
        reason = None
        if pos[2] < -0.5 * ph.car_length or not inside[0]:
            reason = "fell or left the world"
        elif self._inside_geometry:
            reason = "inside real geometry"
        elif self._tilted_s > self.cfg.respawn_tilt_s:
            reason = "tipped over"
        elif self._stuck(pos[:2]):
            reason = "stuck"
        elif T is not None:
            if self.in_view(T, self.car_position_world()):
                self._out_of_view_s = 0.0
            else:
                self._out_of_view_s += dt
            cam = ph.frame.to_phys(T[:3, 3][None])[0]
            self._hidden_s = 0.0 if self._visible(cam, ph.car_centre_xy()) else self._hidden_s + dt
            lim, lim_hidden = self.cfg.respawn_out_of_view_s, self.cfg.respawn_hidden_s
            if lim > 0 and self._out_of_view_s > lim:
                reason = "out of view"
            elif lim_hidden > 0 and self._hidden_s > lim_hidden:
                reason = "hidden behind real geometry"
        if reason is not None and T is not None:
            if not self._try_spawn(T, reason) and reason == "tipped over":
                self._right_in_place()

    def _right_in_place(self) -> bool:
        """Put a tipped car back on its wheels where it lies (no seen floor in view to respawn on),
        when seen floor is under it; heading kept."""
        ph = self.physics
        xy = ph.car_centre_xy()
        if not self.field.free_disc(xy, self.cfg.inside_radius * ph.car_length):
            return False
        fwd = ph.car_state().T_phys_base[:3, 0]
        ph.spawn_car(xy, math.atan2(fwd[1], fwd[0]))
        self._count_spawn("tipped over, righted in place")
        return True
