"""The AR demo as a plain output sink of the frame driver (:mod:`lite_vo.session`).

:class:`ARSink` wires the parts: every published map goes to the :class:`~ar_demo.world.ARWorld`
(ground plane, persistent world, car) once it supports a ground plane, and every k-th frame a newer
map and the VO's keyframes (``SessionInfo.keyframes``) rebuild the world; each frame advances the simulation by the frame's time and hands
an immutable :class:`~ar_demo.video.RenderJob` to the :class:`~ar_demo.video.ARVideo` (the render
thread draws it over the full-resolution rectified camera image, colour when the source is colour).
``on_finish`` closes everything and fills :attr:`ARSink.summary`.

Threads: the session's thread calls the sink's methods. With ``world_thread`` (the default) they only
queue what the frame needs (the event, the newest map, a snapshot of the keyframe list) for the
*world thread*, which owns the :class:`~ar_demo.world.ARWorld` and pybullet and handles the frames in
order: handing a new world to pybullet (tens of ms) and stepping the simulation no longer stall
tracking. The queue is bounded (``render_queue``): a world thread that falls behind makes the caller
wait, no frame is dropped. An error in the world thread is raised on the session's thread at the next
call. Without ``world_thread`` (or without ``render_thread``, or with a renderer given: the GL context
then belongs to the caller's thread) everything runs on the caller's thread. The world-model worker and the
render thread own only what they are handed.
"""
from __future__ import annotations

import queue
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from lite_vo.session import FrameEvent, OutputSink, PublishedMap, RunEnd, SessionInfo
from lite_vo.timing import timing_stats

from .config import ARConfig
from .video import ARVideo, FrameComposer, RenderJob
from .heightfield import field_mesh
from .world import ARWorld


class ARSink(OutputSink):
    """AR world + video from a VO session (see the module docstring)."""
    wants_image = True

    def __init__(self, cfg: ARConfig, out_video, fps: float = 30.0, metric: bool | None = None,
                 renderer=None, mesh_out=None, car_out=None, viewer=None) -> None:
        self.cfg = cfg
        self.viewer = viewer                     # a lite_vo.viewer.RerunSink: the world and the car go there too
        self._viewed_field = None
        self.out_video = Path(out_video)
        self.fps = float(cfg.video_fps or fps)
        self._metric_auto = metric is None and not cfg.metric
        self.metric = cfg.metric if metric is None else bool(metric)
        self.mesh_out = Path(mesh_out) if mesh_out else None
        self.car_out = Path(car_out) if car_out else None
        self.keyframes = None
        self.car_poses: list[tuple[float, np.ndarray]] = []   # (t, T_world_car) per frame with a car
        self._car_file = None
        self._field_mesh = None
        self._renderer = renderer
        self.world: ARWorld | None = None
        self.video: ARVideo | None = None
        self.car_parts = None
        self.camera = None
        self._map: PublishedMap | None = None
        self._map_seq = 0
        self._submitted_seq = -1
        self._first_map_ts = None
        self._prev_ts = None
        self._frames = 0
        self.times = {"simulation": [], "frame": [], "world_frame": []}
        self._queue: queue.Queue | None = None
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self.car_path: list[np.ndarray] = []
        self.summary: dict = {}

    # ------------------------------------------------------------------ session events
    def on_start(self, info: SessionInfo) -> None:
        from .render import ARRenderer, load_racecar_parts
        cfg = self.cfg
        self.camera = info.camera
        self.keyframes = info.keyframes
        if self.car_out is not None:
            self.car_out.parent.mkdir(parents=True, exist_ok=True)
            self._car_file = open(self.car_out, "w", encoding="utf-8", buffering=1)
            self._car_file.write("# T_world_car: footprint centre on the surface, x forward, z up (TUM: t tx ty tz qx qy qz qw)\n")
        self.car_parts = load_racecar_parts()
        self.world = ARWorld(cfg, info.camera, self.metric, info.accelerometer)

        def make_renderer():
            return ARRenderer(ambient=cfg.render_ambient,
                              occluder_offset=(1.0 if cfg.occluder_offset > 0 else 0.0, cfg.occluder_offset))
        self.video = ARVideo(self.out_video, self.fps, FrameComposer(cfg, info.camera), make_renderer,
                             threaded=cfg.render_thread, queue_size=cfg.render_queue, renderer=self._renderer)
        if cfg.world_thread and cfg.render_thread and self._renderer is None:
            # (without the render thread the GL context belongs to this thread, so the world stays here too)
            self._queue = queue.Queue(maxsize=cfg.render_queue)
            self._thread = threading.Thread(target=self._world_loop, name="ar-world", daemon=True)
            self._thread.start()

    def on_map(self, published: PublishedMap) -> None:
        self._map = published
        self._map_seq += 1

    def on_corrections(self, corrections: dict) -> None:
        self._post(("corrections",))

    def on_frame(self, event: FrameEvent) -> None:
        t_frame = time.perf_counter()
        self._post(("frame", event, self._map, self._map_seq, self._keyframes()))
        self.times["frame"].append((time.perf_counter() - t_frame) * 1e3)

    def flush(self) -> None:
        """Wait until the world thread has handled every queued frame (raises its error, if any)."""
        if self._queue is not None:
            self._queue.join()
        self._raise_world_error()

    # ------------------------------------------------------------------ the world thread
    def _post(self, msg: tuple) -> None:
        if self._queue is None:
            self._handle(msg)
            return
        self._raise_world_error()
        self._queue.put(msg)

    def _raise_world_error(self) -> None:
        if self._error is not None:
            err, self._error = self._error, None
            raise RuntimeError(f"AR world thread: {err}") from err

    def _world_loop(self) -> None:
        failed = False
        while True:
            msg = self._queue.get()
            try:
                if msg is None:
                    return
                if not failed:                   # after an error: keep draining, so the caller never blocks
                    self._handle(msg)
            except BaseException as err:         # noqa: BLE001 - handed to the session's thread
                self._error, failed = err, True
            finally:
                self._queue.task_done()

    def _handle(self, msg: tuple) -> None:
        if msg[0] == "corrections":
            # the two-view bootstrap replaced the map and earlier poses: a monocular world built on the
            # old map has another scale, so it starts over on the new one
            if self.world.started and not self.metric:
                self.world.reset("the VO re-estimated its map and earlier poses")
                self._first_map_ts = None
            return
        t_frame = time.perf_counter()
        self._world_frame(*msg[1:])
        self.times["world_frame"].append((time.perf_counter() - t_frame) * 1e3)

    def _world_frame(self, event: FrameEvent, the_map: PublishedMap | None, map_seq: int, keyframes: list) -> None:
        result = event.result
        ts = float(result.timestamp)
        world = self.world
        if self._metric_auto and result.event in ("init", "reinit", "bootstrap"):
            init = (result.quality or {}).get("init")
            if init is not None:                 # the VO says how its map was initialised
                self.metric = world.metric = init == "depth"
        if result.event == "reinit" and world.started and not self.metric:
            world.reset("re-initialisation of the VO map")   # a new monocular map has a new scale
            self._first_map_ts = None
        T = None if result.T_world_cam is None or result.lost else np.asarray(result.T_world_cam)
        if T is not None:
            world.feed_imu(ts, T)
        if not world.started and T is not None and the_map is not None:
            if self._first_map_ts is None:
                self._first_map_ts = ts
            wait = self.cfg.start_after_s if self.metric else max(self.cfg.start_after_s,
                                                                   self.cfg.start_after_monocular_s)
            if ts - self._first_map_ts >= wait and world.start(the_map, keyframes):
                self._submitted_seq = map_seq
        dt = 0.0 if self._prev_ts is None else max(0.0, ts - self._prev_ts)
        self._prev_ts = ts
        if world.started:
            if (self._frames % self.cfg.world_update_every == 0 and the_map is not None
                    and map_seq != self._submitted_seq):
                world.submit(the_map, keyframes)
                self._submitted_seq = map_seq
            world.swap_in()
            t0 = time.perf_counter()
            world.step(dt, T)
            self.times["simulation"].append((time.perf_counter() - t0) * 1e3)
            T_car = world.car_pose_world()
            if T_car is not None:
                self.car_path.append(world.physics.car_state().T_phys_base[:3, 3].copy())
                self.car_poses.append((ts, T_car))
                if self._car_file is not None:
                    from lite_vo.sinks import tum_line
                    self._car_file.write(tum_line(ts, T_car))
            if self.viewer is not None:
                self._show(result.index, ts, T_car)
        self.video.put(self._job(event, T, the_map))
        self._frames += 1

    def on_finish(self, end: RunEnd) -> None:
        error = None
        if self._thread is not None:             # let the world thread handle what is queued, then stop it
            self._queue.put(None)
            self._thread.join()
            self._thread = self._queue = None
            error, self._error = self._error, None
        try:
            self._finish()
        finally:
            if error is not None:
                raise RuntimeError(f"AR world thread: {error}") from error

    def _finish(self) -> None:
        world = self.world
        if self._car_file is not None:
            self._car_file.close()
            self._car_file = None
        if world is None:                        # never started
            return
        try:
            self.video.close()                   # renders the queued frames; the .mp4 is playable
        finally:
            if self.mesh_out is not None and world.model is not None:
                world.model.mesh.export(self.mesh_out)
            self.summary = self._summary()
            world.close()

    # ------------------------------------------------------------------ helpers
    def _world_mesh(self):
        """The persistent world as triangles for the panel (made again only when the field changed)."""
        field = self.world.field
        if field is None:
            return None
        if self._field_mesh is None or self._field_mesh[0] is not field:
            self._field_mesh = (field, field_mesh(field, self.world.physics.frame))
        return self._field_mesh[1]

    def _show(self, index: int, ts: float, T_car) -> None:
        """The collision world (when it changed) and the car in the viewer."""
        world = self.world
        if world.field is not None and world.field is not self._viewed_field:
            mesh = self._world_mesh()
            if mesh is not None:
                self.viewer.log_mesh(index, ts, "world/ar/collision", *mesh)
            self._viewed_field = world.field
        if T_car is not None:
            self.viewer.log_box(index, ts, "world/ar/car", T_car, world.car_length_world)

    def _keyframes(self) -> list:
        return self.keyframes.current() if self.keyframes is not None else []

    def _background(self, event: FrameEvent) -> np.ndarray:
        img = event.image
        if img is None:                          # only the mapping-resolution image: upsample it
            img = cv2.resize(np.clip(event.image_map, 0, 255).astype(np.uint8),
                             (self.camera.width, self.camera.height), interpolation=cv2.INTER_LINEAR)
        if img.ndim == 3:
            img = img[..., ::-1]                 # BGR -> RGB (the video frames are RGB)
        return np.ascontiguousarray(img)

    def _job(self, event: FrameEvent, T, the_map) -> RenderJob:
        """Everything one video frame needs, as immutable data (safe to hand to the render thread)."""
        from .render import car_objects
        world = self.world
        mesh = world.model.mesh if world.model is not None else None
        objects = []
        if T is not None and world.has_car:
            objects = car_objects(self.car_parts, world.physics.link_poses_phys(), world.physics.frame.S_world_phys)
        depth = world.scene_depth or 1.0
        return RenderJob(
            background=self._background(event), T_world_cam=T,
            near_far=(self.cfg.near_rel * depth, self.cfg.far_rel * depth),
            occluder=(mesh.vertices_world, mesh.faces) if mesh is not None else None,
            world_mesh=self._world_mesh() if self.cfg.panels else None,
            objects=objects, idepth=the_map.idepth if (the_map is not None and self.cfg.panels) else None,
            ground=world.ground, scene_depth=world.scene_depth)

    def _summary(self) -> dict:
        world = self.world
        path = np.array(self.car_path) if self.car_path else np.zeros((0, 3))
        physics = world.physics
        ap = physics.autopilot if physics is not None else None
        times = {"world_model": world.build_ms, "simulation": self.times["simulation"],
                 "render": self.video.render_ms, "frame": self.times["frame"], "world_frame": self.times["world_frame"]}
        return {
            "video": str(self.out_video),
            "frames_written": self.video.frames,
            "video_size": list(self.video.size) if self.video.size is not None else None,
            "fps": self.fps,
            "metric": self.metric,
            "ground_plane": None if world.ground is None else {
                "source": world.ground.source, "normal_world": world.ground.normal_world.tolist(),
                "height": world.ground.height},
            "physics_scale": None if physics is None else physics.frame.scale,
            "car_size": None if world.car_length_world is None else {
                "length": world.car_length_world, "units": "m" if self.metric else "world units (monocular)",
                "rule": "car_length_m (metric run)" if self.metric else
                f"{self.cfg.car_length_rel_height} x camera height above the ground plane"},
            "camera_height": world.camera_height,
            "world_extent": None if world.field is None else world.field.extent(1.0 / physics.frame.scale),
            "car_frames": len(self.car_poses),
            "car_spawns": world.spawns,
            "car_spawn_reasons": dict(world.respawn_reasons),
            "keyframes": None if self.keyframes is None else len(self.keyframes),
            "keyframe_bytes": None if self.keyframes is None else self.keyframes.nbytes,
            "world_models_built": len(world.build_ms),
            "world_updates": 0 if physics is None else physics.field_updates,
            "car_distance_phys": float(np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1).sum()) if len(path) > 1 else 0.0,
            "car_reversals": 0 if ap is None else ap.reversals,
            "car_collisions": 0 if physics is None else physics.collisions,
            "timing_ms": {k: timing_stats(v) for k, v in times.items()},
            "events": world.events,
        }
