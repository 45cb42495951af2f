"""The AR pipeline (thesis Fig. 5.7): VO poses + semi-dense maps -> world model (asynchronous, lower
rate) -> physics -> rendering at full camera resolution -> video.

* :class:`ARSink` is a ``lite_vo`` :class:`~lite_vo.system.OutputSink`: ``on_map`` keeps the newest
  semi-dense map, ``on_frame`` feeds the IMU filter, starts the AR world once a map is available
  (ground plane, physics frame, car), submits world-model rebuilds every k-th frame, swaps finished
  models into the physics world, steps the simulation by the frame's time, renders and writes the
  video frame. ``on_finish`` closes everything and fills :attr:`ARSink.summary`.
* :func:`run_ar` opens a sequence and drives the sink either with the real VO
  (``poses="estimate"``: :class:`lite_vo.system.VisualOdometry`) or with ground-truth poses and a
  semi-dense map made from the ground-truth depth (``poses="gt"``): switching is one flag.

Threads (Fig. 5.7: all components run in parallel):
* ``on_map`` may be called from the VO's mapping thread (realtime mode): it only swaps a tuple
  under ``_map_lock``;
* the thread calling ``on_frame`` (the tracking thread) owns the physics, the IMU filter and the
  world-model hand-over, and snapshots each frame into an immutable :class:`RenderJob`;
* the world-model worker (:class:`~ar_demo.world_model.AsyncWorldModelBuilder`) owns its builds;
* the render thread (``render_thread=true``) owns the GL context and the video writer and renders
  the jobs in order (a bounded queue: the caller waits instead of dropping frames).

Imports: numpy, cv2, lite_vo, ar_demo modules; pybullet/moderngl/trimesh through them.
"""
from __future__ import annotations

import json
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from lite_vo.camera import PinholeIntrinsics
from lite_vo.errors import InputError
from lite_vo.geometry import transform_points
from lite_vo.system import OutputSink
from lite_vo.timing import timing_stats

from .config import ARConfig
from .ground import GravityFilter, GroundPlane, estimate_ground_plane, map_points_world

log = logging.getLogger(__name__)


@dataclass
class GTFrameResult:
    """Stand-in for :class:`lite_vo.system.FrameResult` when poses come from the ground truth."""
    index: int
    timestamp: float
    T_world_cam: np.ndarray | None
    lost: bool = False
    quality: dict = field(default_factory=dict)


def semi_dense_from_depth(image: np.ndarray, depth_m: np.ndarray, min_grad: float,
                          var_rel: float) -> tuple[np.ndarray, np.ndarray]:
    """A semi-dense map from a depth image: pixels with image gradient magnitude above ``min_grad``
    keep their inverse depth (NaN elsewhere), variance ``var_rel * idepth^2``."""
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


def look_at(eye, target, up) -> np.ndarray:
    """T_world_cam of an OpenCV camera at ``eye`` looking at ``target`` with image-up ~ ``up``."""
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


@dataclass(frozen=True)
class RenderJob:
    """One video frame to render; all arrays are read-only snapshots."""
    background: np.ndarray
    T_world_cam: np.ndarray | None
    near_far: tuple
    occluder: tuple | None
    objects: list
    idepth: np.ndarray | None
    ground: GroundPlane | None
    scene_depth: float | None


class _RenderThread:
    """Renders and writes frames in order in its own thread (it owns the GL context and, through
    the sink's ``_write``, the video writer). ``put`` blocks when ``queue_size`` frames are waiting,
    so no frame is ever dropped; ``close`` drains the queue."""

    def __init__(self, sink: "ARSink", make_renderer, queue_size: int):
        import queue
        self._sink = sink
        self._queue: "queue.Queue" = queue.Queue(maxsize=max(1, int(queue_size)))
        self._error: BaseException | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(make_renderer,), name="ar-render", daemon=True)
        self._thread.start()
        self._ready.wait()
        self.raise_error()                      # e.g. no EGL: fail in the constructor, like the inline path

    def _run(self, make_renderer) -> None:
        renderer = None
        try:
            renderer = make_renderer()
        except BaseException as err:
            self._error = err
        self._ready.set()
        while True:
            job = self._queue.get()
            if job is None:
                break
            if self._error is not None:
                continue                        # keep draining so put() never blocks forever
            try:
                t0 = time.perf_counter()
                frame = self._sink._render_job(renderer, job)
                self._sink.times["render"].append((time.perf_counter() - t0) * 1e3)
                self._sink._write(frame)
            except BaseException as err:
                self._error = err
        if renderer is not None:
            renderer.release()

    def put(self, job: RenderJob) -> None:
        self.raise_error()
        self._queue.put(job)

    def close(self) -> None:
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()

    def raise_error(self) -> None:
        if self._error is not None:
            err, self._error = self._error, None
            raise err


class ARSink(OutputSink):
    """The AR demo as a VO output sink (see the module docstring)."""

    def __init__(self, cfg: ARConfig, intrinsics_full: PinholeIntrinsics, out_video: str | Path,
                 fps: float = 30.0, accelerometer=None, metric: bool | None = None, renderer=None,
                 mesh_out: str | Path | None = None):
        from .render import ARRenderer, load_racecar_parts
        self.cfg = cfg
        self.intr = intrinsics_full
        self.out_video = Path(out_video)
        self.fps = float(cfg.video_fps or fps)
        self.acc = accelerometer
        self._metric_auto = metric is None and not cfg.metric
        self.metric = cfg.metric if metric is None else bool(metric)
        self.mesh_out = Path(mesh_out) if mesh_out else None
        self._map_lock = threading.Lock()
        self._map: tuple | None = None           # newest (frame_id, ts, T_world_cam, idepth, var, intr); under _map_lock
        self._map_seq = 0
        # owned by the on_frame thread
        def make_renderer():
            return ARRenderer(ambient=cfg.render_ambient,
                              occluder_offset=(1.0 if cfg.occluder_offset > 0 else 0.0, cfg.occluder_offset))
        self.renderer = None
        self._render_thread = None
        if cfg.render_thread and renderer is None:
            self._render_thread = _RenderThread(self, make_renderer, cfg.render_queue)
        else:
            self.renderer = renderer or make_renderer()
        self.car_parts = load_racecar_parts()
        self.gravity = GravityFilter(cfg.acc_lowpass_tau_s)
        self._last_acc_t = -np.inf
        self._images: dict[int, np.ndarray] = {}
        self.ground: GroundPlane | None = None
        self.physics = None
        self.builder = None
        self.world = None                        # newest WorldModel swapped into physics
        self.scene_depth = None
        self._first_map_ts = None
        self._prev_ts = None
        self._frames = 0
        self._submitted_seq = -1
        self._pending_sync = None                # world model built synchronously (async_world=false)
        self.writer = None
        self.times = {"world_model": [], "simulation": [], "render": [], "frame": []}
        self.events: list[str] = []
        self.car_path: list[np.ndarray] = []
        self.summary: dict = {}
        self._finished = False

    # ------------------------------------------------------------------ inputs
    def push_image(self, index: int, image: np.ndarray) -> None:
        """The full-resolution rectified image (grey or RGB, uint8/float 0..255) of frame ``index``."""
        img = np.asarray(image)
        if img.shape[:2] != (self.intr.height, self.intr.width):
            raise InputError(f"AR image {img.shape[1]}x{img.shape[0]} does not match {self.intr.width}x{self.intr.height}")
        self._images[int(index)] = np.clip(img, 0, 255).astype(np.uint8)

    def on_map(self, frame_id, timestamp, T_world_cam, idepth, idepth_var, intrinsics) -> None:
        with self._map_lock:
            self._map = (int(frame_id), float(timestamp), np.array(T_world_cam, dtype=np.float64),
                         idepth, idepth_var, intrinsics)
            self._map_seq += 1

    def _latest_map(self):
        with self._map_lock:
            return self._map, self._map_seq

    # ------------------------------------------------------------------ per frame
    def on_frame(self, result, image) -> None:
        t_frame = time.perf_counter()
        ts = float(result.timestamp)
        if self._metric_auto and getattr(result, "event", "") in ("init", "reinit"):
            init = (getattr(result, "quality", None) or {}).get("init")
            if init is not None:                 # the VO says how its map was initialised
                self.metric = init == "depth"
        if getattr(result, "event", "") == "reinit" and self.physics is not None and not self.metric:
            self._reset_world()                  # a new monocular map has a new scale: start over
        T = None if result.T_world_cam is None or getattr(result, "lost", False) else np.asarray(result.T_world_cam)
        if T is not None:
            self._feed_imu(ts, T)
        the_map, seq = self._latest_map()
        if self.physics is None and T is not None and the_map is not None:
            if self._first_map_ts is None:
                self._first_map_ts = ts
            wait = self.cfg.start_after_s if self.metric else max(self.cfg.start_after_s, self.cfg.start_after_monocular_s)
            if ts - self._first_map_ts >= wait:
                self._start_world(the_map)
        dt = 0.0 if self._prev_ts is None else max(0.0, ts - self._prev_ts)
        self._prev_ts = ts
        if self.physics is not None:
            if (self._frames % self.cfg.world_update_every == 0 and the_map is not None
                    and seq != self._submitted_seq):
                self._submit(the_map)
                self._submitted_seq = seq
            self._swap_in_new_model()
            t0 = time.perf_counter()
            target = self._view_target(T) if T is not None else None
            self.physics.step(dt * self.cfg.time_scale, target_xy=target)
            self.times["simulation"].append((time.perf_counter() - t0) * 1e3)
            self.car_path.append(self.physics.car_state().T_phys_base[:3, 3].copy())
        self._emit(self._make_job(result.index, image, T, the_map))
        for k in [k for k in self._images if k <= result.index]:   # also frames the VO dropped
            del self._images[k]
        self._frames += 1
        self.times["frame"].append((time.perf_counter() - t_frame) * 1e3)

    def _feed_imu(self, ts: float, T: np.ndarray) -> None:
        if self.acc is None or len(self.acc) == 0:
            return
        t = self.acc.timestamps
        m = (t > self._last_acc_t) & (t <= ts)
        if not m.any() and self._last_acc_t == -np.inf:
            m = t <= t[0]                        # at least the first sample
        if m.any():
            self.gravity.update(self.acc.acc_xyz[m], T[:3, :3], t[m])
            self._last_acc_t = float(t[m][-1])

    # ------------------------------------------------------------------ world
    def _start_world(self, the_map) -> None:
        from .physics import PhysicsFrame, PhysicsWorld
        from .world_model import AsyncWorldModelBuilder, build_world_model
        frame_id, ts, T_map, idepth, var, intr_map = the_map
        pts = map_points_world(idepth, intr_map, T_map)
        if len(pts) < self.cfg.ground_min_support:
            return
        depths = 1.0 / np.asarray(idepth)[np.isfinite(idepth) & (np.asarray(idepth) > 0)]
        self.scene_depth = float(np.median(depths))
        up = self.gravity.up_world
        ground = estimate_ground_plane(pts, self.cfg, up_world=up, T_world_cam0=T_map,
                                       scene_depth=self.scene_depth)
        if ground is None:
            return
        self.ground = ground
        model = build_world_model(idepth, var, intr_map, T_map, ground, self.cfg, frame_id, ts)
        self.times["world_model"].append(model.build_ms)
        from .physics import racecar_length
        car_len_phys = racecar_length()
        want = self.cfg.car_length_m if self.metric else self.cfg.car_length_rel_depth * self.scene_depth
        frame = PhysicsFrame.from_ground(ground.normal_world, ground.height, T_map, car_len_phys / want)
        self.physics = PhysicsWorld(self.cfg, frame)
        if self.cfg.ground_extent_rel > 0:
            self.physics.add_ground_slab(self.cfg.ground_extent_rel * car_len_phys)
        self.physics.set_world_mesh(model.mesh.vertices_world, model.mesh.faces)
        self.world = model
        xy, yaw = self._spawn_pose(T_map, intr_map)
        self.physics.spawn_car(xy, yaw)
        self.events.append(f"start frame {frame_id}: ground {ground.source}, scale {frame.scale:.3f}")
        if self.cfg.async_world:
            self.builder = AsyncWorldModelBuilder(self.cfg, ground)

    def _reset_world(self) -> None:
        if self.builder is not None:
            self.builder.close()
        if self.physics is not None:
            self.physics.close()
        self.builder = self.physics = self.world = self.ground = None
        self._first_map_ts = None
        self.events.append("reset after re-initialisation of the VO map")

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
            from .physics import racecar_length
            xy = np.array([2.0 * racecar_length(), 0.0])
        return xy, math.pi / 2                    # across the view: the video shows the car's side

    def _view_target(self, T: np.ndarray):
        if self.ground is None:
            return None
        return self._ground_hit(T, self.intr, self.intr.cx, self.intr.cy + self.cfg.target_v_rel * self.intr.height)

    def _submit(self, the_map) -> None:
        frame_id, ts, T_map, idepth, var, intr_map = the_map
        if self.builder is not None:
            self.builder.submit(idepth, var, intr_map, T_map, frame_id, ts)
        else:
            from .world_model import build_world_model
            model = build_world_model(idepth, var, intr_map, T_map, self.ground, self.cfg, frame_id, ts)
            self._pending_sync = model

    def _swap_in_new_model(self) -> None:
        model = None
        if self.builder is not None:
            model = self.builder.poll()
        else:
            model, self._pending_sync = self._pending_sync, None
        if model is not None:
            self.times["world_model"].append(model.build_ms)
            self.physics.set_world_mesh(model.mesh.vertices_world, model.mesh.faces)
            self.world = model

    # ------------------------------------------------------------------ rendering
    def _background(self, index: int, image) -> np.ndarray:
        img = self._images.get(int(index))
        if img is None:  # only the mapping-resolution image: upsample it
            img = cv2.resize(np.clip(np.asarray(image, dtype=np.float32), 0, 255).astype(np.uint8),
                             (self.intr.width, self.intr.height), interpolation=cv2.INTER_LINEAR)
        return img

    def _near_far(self):
        depth = self.scene_depth or 1.0
        return self.cfg.near_rel * depth, self.cfg.far_rel * depth

    def _car_objects(self):
        from .render import car_objects
        if self.physics is None or self.physics.car < 0:
            return []
        return car_objects(self.car_parts, self.physics.link_poses_phys(), self.physics.frame.S_world_phys)

    def _make_job(self, index, image, T, the_map) -> "RenderJob":
        """Everything one video frame needs, as immutable data (safe to hand to the render thread)."""
        mesh = self.world.mesh if self.world is not None else None
        return RenderJob(
            background=self._background(index, image), T_world_cam=T, near_far=self._near_far(),
            occluder=(mesh.vertices_world, mesh.faces) if mesh is not None else None,
            objects=self._car_objects() if T is not None else [],
            idepth=the_map[3] if (the_map is not None and self.cfg.panels) else None,
            ground=self.ground, scene_depth=self.scene_depth)

    def _render_job(self, renderer, job: "RenderJob") -> np.ndarray:
        near, far = job.near_far
        bg = job.background
        if job.T_world_cam is None:
            main = np.repeat(bg[..., None], 3, axis=2) if bg.ndim == 2 else bg.copy()
            cv2.putText(main, "tracking lost", (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 80, 80), 2)
        else:
            main = renderer.render(self.intr, job.T_world_cam, near, far, background=bg, occluder=job.occluder,
                                   objects=job.objects)
        if not self.cfg.panels:
            return main
        from .video import colorize_idepth, compose_panels, label, panel_size
        pw, ph = panel_size(self.intr.width, self.intr.height)
        depth_panel = colorize_idepth(job.idepth if job.idepth is not None else np.full((ph, pw), np.nan), (pw, ph))
        depth_panel = label(depth_panel, "semi-dense inverse depth")
        mesh_panel = label(self._mesh_panel(renderer, job, pw, ph), "collision mesh")
        return compose_panels(main, depth_panel, mesh_panel)

    def _mesh_panel(self, renderer, job: "RenderJob", pw, ph) -> np.ndarray:
        T, ground = job.T_world_cam, job.ground
        if job.occluder is None or T is None or ground is None:
            return np.zeros((ph, pw, 3), np.uint8)
        up = ground.normal_world
        C = T[:3, 3]
        k = up / np.linalg.norm(up)
        # look at the ground point in the middle of the view (else one scene depth ahead)
        dist = job.scene_depth or 1.0
        centre = C + T[:3, 2] * dist
        hit = ground.idepth_at(T, self.intr, np.array([self.intr.cx]), np.array([self.intr.cy]))[0]
        if hit > 0 and 1.0 / hit < 3 * dist:
            centre = C + T[:3, :3] @ np.array([0.0, 0.0, 1.0 / hit])
        d = C - centre
        h = d - (d @ k) * k
        h = h / (np.linalg.norm(h) + 1e-12)
        az = math.radians(self.cfg.panel_view_azimuth_deg)
        el = math.radians(self.cfg.panel_view_elevation_deg)
        h = h * math.cos(az) + np.cross(k, h) * math.sin(az)          # rotate about the up axis
        r = 1.3 * np.linalg.norm(d)
        eye = centre + r * (math.cos(el) * h + math.sin(el) * k)
        Tv = look_at(eye, centre, up)
        intr = self.intr.scaled(pw, ph)
        intr = PinholeIntrinsics(intr.fx * 0.8, intr.fy * 0.8, intr.cx, intr.cy, pw, ph)
        near, far = job.near_far
        # camera frustum of the current view
        c = self.intr
        corners = [(0, 0), (c.width - 1, 0), (c.width - 1, c.height - 1), (0, c.height - 1)]
        s = 0.25 * np.linalg.norm(d)
        pts = [C + T[:3, :3] @ np.array([(u - c.cx) / c.fx * s, (v - c.cy) / c.fy * s, s]) for u, v in corners]
        segs = []
        for i in range(4):
            segs += [C, pts[i], pts[i], pts[(i + 1) % 4]]
        verts, faces = job.occluder
        return renderer.render(intr, Tv, near, far * 2, background=None,
                               shaded_meshes=[("panel_mesh", verts, faces, (0.55, 0.75, 0.55))],
                               objects=job.objects, lines=[(np.array(segs), (1.0, 0.9, 0.2))],
                               up_world=up, clear_color=(0.08, 0.08, 0.12))

    def _emit(self, job: "RenderJob") -> None:
        """Render and write one frame: in the render thread when there is one, else right here."""
        if self._render_thread is not None:
            self._render_thread.put(job)
            return
        t0 = time.perf_counter()
        frame = self._render_job(self.renderer, job)
        self.times["render"].append((time.perf_counter() - t0) * 1e3)
        self._write(frame)

    def _write(self, frame: np.ndarray) -> None:
        if self.writer is None:
            from .video import VideoWriter
            self.writer = VideoWriter(self.out_video, self.fps, (frame.shape[1], frame.shape[0]))
        self.writer.write(frame)

    # ------------------------------------------------------------------ end
    def on_finish(self) -> None:
        if self._finished:
            return
        self._finished = True
        if self.builder is not None:
            self.builder.close()
        if self._render_thread is not None:
            self._render_thread.close()          # renders the queued frames, closes its GL context
        if self.writer is not None:
            self.writer.close()
        if self.mesh_out is not None and self.world is not None:
            self.world.mesh.export(self.mesh_out)
        path = np.array(self.car_path) if self.car_path else np.zeros((0, 3))
        ap = self.physics.autopilot if self.physics is not None else None
        self.summary = {
            "video": str(self.out_video),
            "frames_written": self.writer.frames if self.writer is not None else 0,
            "video_size": list(self.writer.size) if self.writer is not None else None,
            "fps": self.fps,
            "metric": self.metric,
            "ground_plane": None if self.ground is None else {
                "source": self.ground.source, "normal_world": self.ground.normal_world.tolist(),
                "height": self.ground.height},
            "physics_scale": None if self.physics is None else self.physics.frame.scale,
            "world_models_built": len(self.times["world_model"]),
            "world_swaps": 0 if self.physics is None else self.physics.world_swaps,
            "car_distance_phys": float(np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1).sum()) if len(path) > 1 else 0.0,
            "car_reversals": 0 if ap is None else ap.reversals,
            "car_collisions": 0 if self.physics is None else self.physics.collisions,
            "timing_ms": {k: timing_stats(v) for k, v in self.times.items()},
            "events": self.events,
        }
        if self.physics is not None:
            self.physics.close()
        if self.renderer is not None:
            self.renderer.release()
        if self._render_thread is not None:
            self._render_thread.raise_error()


def _rectifier_full(seq, multiple_of: int = 2):
    cam = seq.camera
    return cam.rectifier(cam.intrinsics.width, multiple_of=multiple_of)


def run_ar(sequence_path, out_video, profile: str = "phone", poses: str = "estimate",
           max_frames: int | None = None, cfg: ARConfig | None = None, panels: bool | None = None,
           overrides=(), trajectory_out: str | Path | None = None, mesh_out: str | Path | None = None,
           progress=None, vo_mode: str = "sync") -> dict:
    """Run the AR demo on a sequence and write ``out_video`` (.mp4). Returns a summary dict.

    ``poses="estimate"``: the real VO (``lite_vo.VisualOdometry`` with ``profile`` and VO
    ``overrides``) drives the sink; ``poses="gt"``: ground-truth poses and a semi-dense map from the
    ground-truth depth (needs both in the sequence). ``cfg``: AR settings (``ar_config(...)``).
    ``trajectory_out``: TUM trajectory of the camera poses used. ``progress(i, n)``: callback.
    """
    import lite_vo
    from lite_vo.io import Trajectory, write_trajectory
    cfg = cfg or ARConfig()
    if panels is not None:
        cfg = cfg.replace(panels=bool(panels))
    if poses not in ("estimate", "gt"):
        raise InputError(f"poses must be 'estimate' or 'gt', not {poses!r}")
    if max_frames is not None and max_frames <= 0:
        raise InputError(f"max_frames must be positive, got {max_frames}")
    t_start = time.perf_counter()
    seq = lite_vo.open_sequence(sequence_path)
    try:
        n_total = len(seq)
    except TypeError:                           # live camera: until max_frames (or Ctrl-C)
        n_total = None
    n = (n_total if max_frames is None else int(max_frames) if n_total is None
         else min(n_total, int(max_frames)))
    if n is None:
        n = float("inf")
    ts_all = getattr(seq, "timestamps", None)
    fps = 30.0
    if ts_all is not None and len(ts_all) > 1:
        fps = float(1.0 / np.median(np.diff(np.asarray(ts_all)[:max(2, int(min(n, len(ts_all))))])))
    rect_full = _rectifier_full(seq)
    intr_full = rect_full.intrinsics
    traj_t: list[float] = []
    traj_T: list[np.ndarray] = []
    vo = None
    if poses == "gt":
        gt = seq.groundtruth
        if gt is None or not seq.has_depth:
            raise InputError(f"{sequence_path}: --poses gt needs groundtruth.txt and depth images")
        rect_map = seq.camera.rectifier(cfg.gt_map_width, multiple_of=16)
        metric = True
    else:
        vo_cfg = lite_vo.load_profile(profile, list(overrides) + [f'system.mode="{vo_mode}"'])
        metric = None
    sink = ARSink(cfg, intr_full, out_video, fps=fps, accelerometer=seq.accelerometer, metric=metric,
                  mesh_out=mesh_out)
    try:
        if poses == "estimate":
            vo = lite_vo.VisualOdometry(seq.camera, vo_cfg, sinks=[sink])
        for i, fr in enumerate(seq):
            if i >= n:
                break
            sink.push_image(fr.index, rect_full(fr.image))
            if vo is not None:
                res = vo.process(fr.image, fr.timestamp, depth=fr.depth)
            else:
                k = gt.nearest(fr.timestamp, max_dt=0.02)
                T = None if k is None else gt.poses[k]
                if T is not None and fr.depth is not None and i % cfg.world_update_every == 0:
                    img_map = rect_map(fr.image)
                    idepth, var = semi_dense_from_depth(img_map, rect_map.depth(fr.depth), cfg.gt_min_grad,
                                                        cfg.gt_idepth_var)
                    sink.on_map(fr.index, fr.timestamp, T, idepth, var, rect_map.intrinsics)
                res = GTFrameResult(fr.index, fr.timestamp, T, T is None)
                sink.on_frame(res, rect_full(fr.image))
            if res.T_world_cam is not None and not res.lost:
                traj_t.append(res.timestamp)
                traj_T.append(np.asarray(res.T_world_cam))
            if progress is not None:
                progress(i + 1, n)
    finally:
        if vo is not None:
            vo.close()                          # calls sink.on_finish()
        sink.on_finish()
        seq.close()
    if trajectory_out is not None:
        write_trajectory(trajectory_out, Trajectory(traj_t, np.reshape(traj_T, (-1, 4, 4))),
                         comment="T_world_cam")
    summary = dict(sink.summary)
    summary.update({"sequence": str(sequence_path), "poses": poses, "profile": profile if poses == "estimate" else None,
                    "frames_in": summary.get("frames_written", 0), "frames_with_pose": len(traj_t),
                    "wall_s": time.perf_counter() - t_start})
    return summary


def write_summary(summary: dict, out_dir: Path) -> None:
    """``summary.json`` and a human-readable ``summary.txt``."""
    out_dir = Path(out_dir)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    t = summary.get("timing_ms", {})
    lines = [f"AR demo on {summary.get('sequence')} (poses: {summary.get('poses')})",
             f"video: {summary.get('video')} ({summary.get('frames_written')} frames, {summary.get('video_size')})",
             f"frames with a pose: {summary.get('frames_with_pose')} of {summary.get('frames_in')}",
             f"ground plane: {summary.get('ground_plane')}",
             f"world models built: {summary.get('world_models_built')}, swaps: {summary.get('world_swaps')}",
             f"car: distance {summary.get('car_distance_phys', 0):.2f} m (physics units), "
             f"collisions {summary.get('car_collisions')}, reversals {summary.get('car_reversals')}"]
    for k in ("world_model", "simulation", "render", "frame"):
        if k in t:
            s = t[k]
            lines.append(f"{k:12s} median {s['median']:.1f} ms, mean {s['mean']:.1f} ms, p95 {s['p95']:.1f} ms (n={s['count']})")
    lines.append(f"wall time: {summary.get('wall_s', 0):.1f} s")
    (out_dir / "summary.txt").write_text("\n".join(lines) + "\n")
