"""A live viewer as an output sink: the run in rerun (``rerun-sdk``, the optional ``[viewer]`` extra).

:class:`RerunSink` logs, per frame, the camera pose and image, the tracking quality over time and the
trajectory; per published map, the semi-dense inverse depth colour-coded as in the paper (near red,
far blue) and its points in the world; at the end, the whole-scene cloud of the keyframes. It is a
plain :class:`~lite_vo.session.OutputSink`: off unless asked for (``--viewer``, ``--rrd FILE``,
``--connect HOST:PORT``), so it costs nothing when off, and rerun is imported only when it is on.

Targets: ``spawn`` (start a native viewer on this machine), ``rrd`` (record to a file that
``rerun FILE.rrd`` opens later) or ``connect`` (stream to a viewer elsewhere, e.g. from a board to a
laptop that runs ``rerun``).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .errors import InputError, MissingExtraError
from .session import FrameEvent, OutputSink, PublishedMap, RunEnd, SessionInfo

VIEWER_EXTRA_MESSAGE = "the viewer needs the [viewer] extra: pip install 'lite-vo[viewer]'"


def import_rerun():
    try:
        import rerun
    except ImportError as err:
        raise MissingExtraError(VIEWER_EXTRA_MESSAGE) from err
    return rerun


def colorize_idepth(idepth: np.ndarray, size_wh: tuple[int, int] | None = None,
                    lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """RGB uint8 image of an inverse-depth map as in the paper: near red, far blue (jet over the 2-98 %
    range unless ``lo``/``hi`` are given), black where empty (NaN); resized to ``size_wh`` if given."""
    d = np.asarray(idepth, dtype=np.float64)
    ok = np.isfinite(d) & (d > 0)
    out = np.zeros(d.shape + (3,), np.uint8)
    if ok.any():
        lo = np.percentile(d[ok], 2) if lo is None else lo
        hi = np.percentile(d[ok], 98) if hi is None else hi
        t = np.clip((np.where(ok, d, lo) - lo) / max(hi - lo, 1e-12), 0, 1)
        jet = cv2.applyColorMap((t * 255).astype(np.uint8), cv2.COLORMAP_JET)[..., ::-1]
        out[ok] = jet[ok]
    if size_wh is not None and out.shape[1::-1] != tuple(size_wh):
        out = cv2.resize(out, tuple(size_wh), interpolation=cv2.INTER_NEAREST)
    return out


def parse_target(viewer: bool = False, rrd=None, connect: str | None = None) -> tuple[str, str | None] | None:
    """``(kind, where)`` of the viewer options, None when all are off; at most one may be given."""
    given = [(k, w) for k, w, on in (("spawn", None, viewer), ("rrd", rrd, rrd is not None),
                                     ("connect", connect, connect is not None)) if on]
    if len(given) > 1:
        raise InputError("choose one of --viewer, --rrd FILE and --connect HOST:PORT")
    if not given:
        return None
    kind, where = given[0]
    if kind == "connect":
        host, sep, port = str(where).rpartition(":")
        if not sep or not host or not port.isdigit():
            raise InputError(f"--connect {where!r}: expected HOST:PORT (e.g. 192.168.1.20:9876)")
    if kind == "rrd" and Path(where).suffix != ".rrd":
        raise InputError(f"--rrd {where}: the recording must end in .rrd")
    return kind, (str(where) if where is not None else None)


class RerunSink(OutputSink):
    """The run in rerun (see the module docstring). ``every_map``: log the points of every k-th map."""

    def __init__(self, kind: str, where: str | None = None, every_map: int = 5, max_points: int = 20000) -> None:
        self.rr = import_rerun()
        self.kind, self.where = kind, where
        self.every_map, self.max_points = max(1, int(every_map)), max_points
        self.rec = None
        self._positions: list[np.ndarray] = []
        self._maps = 0
        self._keyframes = None

    def on_start(self, info: SessionInfo) -> None:
        rr = self.rr
        self.rec = rec = rr.RecordingStream("lite_vo", recording_id=f"lite_vo-{info.name}")
        if self.kind == "spawn":
            rec.spawn()
        elif self.kind == "rrd":
            rec.save(self.where)
        else:
            rec.connect_grpc(f"rerun+http://{self.where}/proxy")
        self._keyframes = getattr(info, "keyframes", None)
        cam = info.map_camera
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log("world/camera/image", rr.Pinhole(focal_length=[cam.fx, cam.fy], principal_point=[cam.cx, cam.cy],
                                                 width=cam.width, height=cam.height,
                                                 camera_xyz=rr.ViewCoordinates.RDF), static=True)

    def _time(self, index: int, timestamp: float) -> None:
        self.rec.set_time("frame", sequence=int(index))
        self.rec.set_time("t", duration=float(timestamp))

    def on_frame(self, event: FrameEvent) -> None:
        rr, rec, r = self.rr, self.rec, event.result
        self._time(r.index, r.timestamp)
        rec.log("world/camera/image", rr.Image(np.clip(event.image_map, 0, 255).astype(np.uint8)))
        rec.log("status/lost", rr.Scalars(float(r.lost)))
        for key in ("residual", "good_ratio", "inside_ratio", "sharpness", "noise_sigma"):
            v = (r.quality or {}).get(key)
            if v is not None and np.isfinite(v):
                rec.log(f"quality/{key}", rr.Scalars(float(v)))
        if r.T_world_cam is None or r.lost:
            return
        T = np.asarray(r.T_world_cam)
        rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        self._positions.append(T[:3, 3].copy())
        if len(self._positions) % 10 == 1:
            rec.log("world/trajectory", rr.LineStrips3D([np.array(self._positions)], colors=[[255, 200, 0]]))

    def on_map(self, published: PublishedMap) -> None:
        rr, rec = self.rr, self.rec
        self._time(published.frame_index, published.timestamp)
        rec.log("world/camera/image/depth", rr.Image(colorize_idepth(published.idepth)))
        self._maps += 1
        if self._maps % self.every_map:
            return
        pts, _, (v, u) = published.points_world()
        if len(pts) > self.max_points:
            keep = np.linspace(0, len(pts) - 1, self.max_points).astype(int)
            pts, v, u = pts[keep], v[keep], u[keep]
        grey = np.clip(published.image[v, u], 0, 255).astype(np.uint8)
        rec.log("world/map", rr.Points3D(pts, colors=np.repeat(grey[:, None], 3, axis=1), radii=0.004))

    def log_mesh(self, index: int, timestamp: float, path: str, vertices: np.ndarray, faces: np.ndarray) -> None:
        """A triangle mesh in the world frame (the AR demo's collision world)."""
        self._time(index, timestamp)
        self.rec.log(path, self.rr.Mesh3D(vertex_positions=np.asarray(vertices, np.float32),
                                          triangle_indices=np.asarray(faces, np.uint32),
                                          albedo_factor=[0.55, 0.75, 0.55, 0.6]))

    def log_box(self, index: int, timestamp: float, path: str, T_world_obj: np.ndarray, length: float) -> None:
        """A box of ``length`` x length/2 x length/3 standing on the pose's origin (the AR demo's car)."""
        self._time(index, timestamp)
        T = np.asarray(T_world_obj)
        half = np.array([length / 2, length / 4, length / 6])
        self.rec.log(path, self.rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        self.rec.log(f"{path}/body", self.rr.Boxes3D(half_sizes=[half], centers=[[0.0, 0.0, half[2]]],
                                                     colors=[[40, 60, 230]]))

    def on_corrections(self, corrections: dict) -> None:
        self._positions = []                   # earlier poses changed: the trajectory starts over

    def on_finish(self, end: RunEnd) -> None:
        if self.rec is None:
            return
        rr, rec = self.rr, self.rec
        if self._positions:
            rec.log("world/trajectory", rr.LineStrips3D([np.array(self._positions)], colors=[[255, 200, 0]]))
        if self._keyframes is not None and len(self._keyframes):
            from .keyframes import scene_cloud
            cloud = scene_cloud(self._keyframes)
            if len(cloud.points):
                rec.log("world/scene", rr.Points3D(cloud.points, colors=cloud.colors, radii=0.004), static=True)
        rec.log("status/end", rr.TextLog(f"{end.status}: {end.frames.get('tracked', 0)} of "
                                         f"{end.frames.get('in', 0)} frames tracked"))
        rec.flush()
        if self.kind == "rrd":
            rec.disconnect()
