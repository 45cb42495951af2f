"""Video output of the AR demo: an OpenCV ``.mp4`` writer (``mp4v``) and the side panels.

Layout with panels: the AR view (W x H) on the left, a right column of width W/2 with the
semi-dense depth map colour-coded by inverse depth (Fig. 5.3; black where the map is empty) on top
and the collision mesh seen from another viewpoint (Fig. 5.1) below. Frames are RGB uint8 here and
converted to BGR for OpenCV.

:class:`ARVideo` renders :class:`RenderJob` snapshots with a :class:`FrameComposer` (in a render
thread that owns the GL context and the writer) and writes them in order.

Imports: numpy, cv2, lite_vo (camera, errors); the renderer is handed in (``make_renderer``).
"""
from __future__ import annotations

import math
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lite_vo.camera import PinholeIntrinsics
from lite_vo.errors import InputError
from lite_vo.viewer import colorize_idepth  # noqa: F401  (the paper's depth colours, also for the panels)


class VideoWriter:
    """``.mp4`` (mp4v) writer with a fixed frame size; ``write(rgb)``, ``close()``."""

    def __init__(self, path: str | Path, fps: float, size_wh: tuple[int, int]):
        self.path = Path(path)
        if self.path.suffix.lower() != ".mp4":
            raise InputError(f"{self.path}: the AR video must be an .mp4 file")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.size = (int(size_wh[0]), int(size_wh[1]))
        self.fps = float(fps)
        self._w = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, self.size)
        if not self._w.isOpened():
            raise InputError(f"{self.path}: cannot open an mp4v video writer")
        self.frames = 0

    def write(self, rgb: np.ndarray) -> None:
        img = np.asarray(rgb)
        if img.shape[1::-1] != self.size:
            raise InputError(f"{self.path}: frame {img.shape[1]}x{img.shape[0]} does not match {self.size[0]}x{self.size[1]}")
        self._w.write(np.ascontiguousarray(img[..., ::-1]))
        self.frames += 1

    def close(self) -> None:
        if self._w is not None:
            self._w.release()
            self._w = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def label(img: np.ndarray, text: str) -> np.ndarray:
    out = np.ascontiguousarray(img)
    cv2.putText(out, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def compose_panels(main: np.ndarray, top: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """Main view plus a right column (top, bottom), each resized to half the main size."""
    H, W = main.shape[:2]
    pw, ph = W // 2, H // 2
    col = np.zeros((H, pw, 3), np.uint8)
    for k, p in enumerate((top, bottom)):
        if p is None:
            continue
        p = cv2.resize(p, (pw, ph), interpolation=cv2.INTER_AREA) if p.shape[1::-1] != (pw, ph) else p
        col[k * ph:(k + 1) * ph] = p
    return np.concatenate([main, col], axis=1)


def panel_size(width: int, height: int) -> tuple[int, int]:
    return width // 2, height // 2


def read_video_info(path: str | Path) -> tuple[int, int, int]:
    """(frame count by decoding, width, height) of a video file."""
    cap = cv2.VideoCapture(str(path))
    n = 0
    w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
    h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    while True:
        ok, _ = cap.read()
        if not ok:
            break
        n += 1
    cap.release()
    return n, w, h


# ----------------------------------------------------------------------------------------------
# One video frame: what it shows (RenderJob), how it is drawn (FrameComposer), who draws it (ARVideo)
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RenderJob:
    """One video frame to render; all arrays are read-only snapshots (safe for the render thread)."""
    background: np.ndarray                 # RGB or grey uint8 at the video camera's resolution
    T_world_cam: np.ndarray | None         # None: tracking lost (the frame is labelled)
    near_far: tuple
    occluder: tuple | None                 # (vertices_world, faces) of the collision mesh
    objects: list                          # the car's parts
    idepth: np.ndarray | None              # the semi-dense map for the side panel
    ground: Any = None                     # GroundPlane
    scene_depth: float | None = None
    world_mesh: tuple | None = None        # (vertices_world, faces) of the persistent world (panel)


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


class FrameComposer:
    """Draws a :class:`RenderJob` with an :class:`~ar_demo.render.ARRenderer`: the AR view and, with
    ``cfg.panels``, the depth panel and the collision mesh seen from another viewpoint."""

    def __init__(self, cfg, camera: PinholeIntrinsics) -> None:
        self.cfg, self.intr = cfg, camera

    def render(self, renderer, job: RenderJob) -> np.ndarray:
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
        pw, ph = panel_size(self.intr.width, self.intr.height)
        depth_panel = colorize_idepth(job.idepth if job.idepth is not None else np.full((ph, pw), np.nan), (pw, ph))
        depth_panel = label(depth_panel, "semi-dense inverse depth")
        mesh_panel = label(self._mesh_panel(renderer, job, pw, ph), "persistent world (seen floor, obstacles)")
        return compose_panels(main, depth_panel, mesh_panel)

    def _mesh_panel(self, renderer, job: RenderJob, pw, ph) -> np.ndarray:
        T, ground = job.T_world_cam, job.ground
        mesh = job.world_mesh if job.world_mesh is not None else job.occluder
        if mesh is None or T is None or ground is None or len(mesh[1]) == 0:
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
        verts, faces = mesh
        return renderer.render(intr, Tv, near, far * 2, background=None,
                               shaded_meshes=[("panel_mesh", verts, faces, (0.55, 0.75, 0.55))],
                               objects=job.objects, lines=[(np.array(segs), (1.0, 0.9, 0.2))],
                               up_world=up, clear_color=(0.08, 0.08, 0.12))


class ARVideo:
    """Renders jobs in order and writes them to an ``.mp4``: in its own thread (``threaded``: it then
    owns the GL context and the writer; ``put`` blocks when ``queue_size`` frames wait, so no frame is
    dropped) or inline. ``close`` drains the queue and closes the file, so the video is playable even
    after an interrupted run."""

    def __init__(self, path, fps: float, composer: FrameComposer, make_renderer, threaded: bool = True,
                 queue_size: int = 4, renderer=None) -> None:
        self.path, self.fps, self.composer = Path(path), float(fps), composer
        self.writer: VideoWriter | None = None
        self.render_ms: list[float] = []
        self._error: BaseException | None = None
        self._renderer = None
        self._thread = None
        if threaded and renderer is None:
            self._queue: queue.Queue = queue.Queue(maxsize=max(1, int(queue_size)))
            ready = threading.Event()
            self._thread = threading.Thread(target=self._run, args=(make_renderer, ready), name="ar-render",
                                            daemon=True)
            self._thread.start()
            ready.wait()
            self._raise_error()                 # e.g. no EGL: fail here, like the inline path
        else:
            self._renderer = renderer or make_renderer()

    @property
    def frames(self) -> int:
        return self.writer.frames if self.writer is not None else 0

    @property
    def size(self):
        return self.writer.size if self.writer is not None else None

    def put(self, job: RenderJob) -> None:
        if self._thread is None:
            self._draw(self._renderer, job)
            return
        self._raise_error()
        self._queue.put(job)

    def close(self) -> None:
        if self._thread is not None and self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        if self._renderer is not None:
            self._renderer.release()
            self._renderer = None
        if self.writer is not None:
            self.writer.close()
        self._raise_error()

    def _draw(self, renderer, job: RenderJob) -> None:
        t0 = time.perf_counter()
        frame = self.composer.render(renderer, job)
        self.render_ms.append((time.perf_counter() - t0) * 1e3)
        if self.writer is None:
            self.writer = VideoWriter(self.path, self.fps, (frame.shape[1], frame.shape[0]))
        self.writer.write(frame)

    def _run(self, make_renderer, ready: threading.Event) -> None:
        renderer = None
        try:
            renderer = make_renderer()
        except BaseException as err:            # reported by the constructor
            self._error = err
        ready.set()
        while True:
            job = self._queue.get()
            if job is None:
                break
            if self._error is not None:
                continue                        # keep draining so put() never blocks forever
            try:
                self._draw(renderer, job)
            except BaseException as err:
                self._error = err
        if renderer is not None:
            renderer.release()

    def _raise_error(self) -> None:
        if self._error is not None:
            err, self._error = self._error, None
            raise err
