"""The one frame driver: source -> :class:`VisualOdometry` -> output sinks.

Every command (``run``, ``ar``, ``demo``, ``profile``) and the Python API reach frames through
:class:`Session`; no other module calls :meth:`VisualOdometry.process`. Data flows one way:

1. frames come from any sequence (folder, EuRoC, video, camera, ROS bag), decoded ahead in a
   reader thread (a camera driver's job; order unchanged, so sync runs stay deterministic);
2. the session applies realtime pacing (``system.mode="realtime"``: frames at their timestamps,
   a frame that is late when the next one arrives is dropped) or none (``sync``), looks up given
   poses (``pose_source="gt"``), skips unreadable frames, and calls the VO;
3. the VO returns a :class:`~lite_vo.system.FrameResult` and hands every published map over
   through a slot; the session drains it and calls every :class:`OutputSink` **on the session's
   own thread**: ``on_corrections``, ``on_map``, ``on_frame`` in that order per frame, then
   ``on_finish`` once at the end, also after Ctrl-C, SIGTERM or an error (then with that status).

Sinks are the extension point (trajectory/map/run-info writers, progress, the AR demo, a viewer);
none of them needs a lock, because none is ever called from the mapping thread.
"""
from __future__ import annotations

import ctypes
import dataclasses
import gc
import itertools
import logging
import platform
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from .camera import PinholeIntrinsics
from .config import VOConfig
from .errors import InputError, Interrupted, LiteVOError
from .io import open_sequence
from .photometric import load_photometric
from .progress import announce_if_slow
from .records import PoseRecord
from .system import FrameResult, PublishedMap, VisualOdometry
from .warmup import CORE_KERNEL_MODULES, warmup

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------------
# What sinks receive
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SessionInfo:
    """Given to :meth:`OutputSink.on_start` before the first frame."""
    name: str                              # sequence name
    path: str                              # where it came from
    frames_total: int | None               # frames the run will read (None: live source)
    config: VOConfig
    profile: str
    camera: PinholeIntrinsics              # full-resolution rectified camera (FrameEvent.image)
    map_camera: PinholeIntrinsics          # mapping-resolution camera (maps, FrameEvent.image_map)
    accelerometer: Any = None              # lite_vo.io.Accelerometer or None
    depth_source: str = "filter"
    pose_source: str = "estimate"
    start_frame: int = 0
    max_frames: int | None = None
    has_depth: bool = False
    keyframes: Any = None                  # the VO's lite_vo.keyframes.KeyframeStore (read only)


@dataclass(frozen=True)
class FrameEvent:
    """One processed frame: the VO's result plus the images a sink may want."""
    result: FrameResult
    image_map: np.ndarray                  # float32 grey at mapping resolution (what the VO saw)
    image: np.ndarray | None = None        # uint8 full-resolution rectified image, BGR when the source is
                                           # colour: only when a sink sets ``wants_image``


@dataclass
class RunEnd:
    """Given to :meth:`OutputSink.on_finish`: how the run ended and what it measured."""
    status: str                            # ok, ok_with_losses, ok_with_skipped_frames, lost,
                                           # failed: ..., interrupted at frame N
    frames: dict                           # in, tracked, lost, dropped, skipped, reinit, ...
    timing: dict                           # the timing.json contract (+ wall_s, cpu_s, warmup_s)
    events: list                           # [{"frame", "t", "event"}, ...]
    metric: bool                           # the map has metric scale (depth init or given poses)
    depth_accuracy_series: Any = field(default_factory=list)  # rows (dicts): a list or a records.RowRecord
    error: str | None = None
    frames_read: int = 0
    vignette: dict | None = None           # the vignette estimated during the run (system.auto_vignette), if on


class OutputSink:
    """Observer of a session; every method is a no-op by default.

    All methods are called on the session's thread, in order; arrays received must not be modified.
    Set ``wants_image = True`` to receive the full-resolution rectified image in each
    :class:`FrameEvent` (rectifying it costs time, so it is only made when asked for).
    """
    wants_image: bool = False

    def on_start(self, info: SessionInfo) -> None:
        """Before the first frame."""

    def on_frame(self, event: FrameEvent) -> None:
        """A frame was processed (tracked, lost or initialised)."""

    def on_map(self, published: PublishedMap) -> None:
        """The VO published a new map (after mapping a frame, or at (re-)initialisation)."""

    def on_corrections(self, corrections: dict) -> None:
        """Earlier poses were re-estimated: ``{frame index: T_world_cam or None (no pose)}``."""

    def on_finish(self, end: RunEnd) -> None:
        """The run ended (normally, interrupted, or with an error)."""


@dataclass
class SessionResult:
    """What a session produced: the tracked poses (with corrections applied) and how it ended."""
    end: RunEnd
    timestamps: list
    poses: list
    info: SessionInfo

    @property
    def status(self) -> str:
        return self.end.status


# ----------------------------------------------------------------------------------------------
# The driver
# ----------------------------------------------------------------------------------------------

class Session:
    """Drives one run: ``Session(source, config, sinks=[...]).run() -> SessionResult``.

    ``source``: a sequence path, camera index, or an opened sequence (``calib``: a calibration file
    overriding the source's own; ``topic``: the image topic of a ROS bag). ``pose_source="gt"`` takes
    the poses from the sequence's ground truth (mapping only); ``depth_source="images"`` tracks
    every frame against the previous depth image (tracking only). Unreadable frames are skipped
    with a warning; more than ``max_bad_frames`` in a row end the run with an error.
    ``warm_up_kernels=False`` leaves the numba compile (cold cache) in the first frames.
    ``photometric``: a folder with DSO's ``pcalib.txt`` / ``vignette.png`` (else such files beside the
    sequence's calibration are used when present).
    """

    def __init__(self, source, config: VOConfig, sinks: Iterable[OutputSink] = (), *,
                 depth_source: str = "filter", pose_source: str = "estimate", start_frame: int = 0,
                 max_frames: int | None = None, max_bad_frames: int = 10, profile_name: str | None = None,
                 calib=None, topic: str | None = None, warm_up_kernels: bool = True, photometric=None) -> None:
        if pose_source not in ("estimate", "gt"):
            raise InputError(f"pose source must be 'estimate' or 'gt', not {pose_source!r}")
        if start_frame < 0:
            raise InputError(f"--start-frame must be >= 0, got {start_frame}")
        if max_frames is not None and max_frames <= 0:
            raise InputError(f"--max-frames must be positive, got {max_frames}")
        if max_bad_frames < 0:
            raise InputError(f"--max-bad-frames must be >= 0, got {max_bad_frames}")
        seq = source
        self._owns_sequence = isinstance(source, (str, Path, int))
        if self._owns_sequence:
            seq = open_sequence(source, calib=calib, topic=topic)
        self.sequence = seq
        self.config = config
        self.sinks = list(sinks)
        self.depth_source, self.pose_source = depth_source, pose_source
        self.start_frame, self.max_frames, self.max_bad_frames = start_frame, max_frames, max_bad_frames
        if depth_source == "images" and not seq.has_depth:
            raise InputError(f"{seq.name}: --depth images needs depth images, the sequence has none")
        if config.system.init == "depth" and not seq.has_depth:
            raise InputError(f"{seq.name}: --init depth needs depth images, the sequence has none")
        self._gt = None
        if pose_source == "gt":
            self._gt = seq.groundtruth
            if self._gt is None:
                raise InputError(f"{seq.name}: --poses gt needs ground truth, the sequence has none")
        try:
            total = len(seq) - start_frame
        except TypeError:                  # live source
            total = None
        if total is not None and total <= 0:
            raise InputError(f"{seq.name}: --start-frame {start_frame} is past the last frame ({len(seq)} frames)")
        if max_frames is not None and total is not None:
            total = min(total, max_frames)
        self.frames_total = total
        self.profile_name = profile_name or config.name
        self.warm_up_kernels = warm_up_kernels
        seq_dir = getattr(seq, "path", None)
        seq_dir = Path(seq_dir) if seq_dir is not None and Path(seq_dir).is_dir() else None
        self.photometric = load_photometric(photometric, seq_dir)   # DSO's pcalib/vignette/exposures
        if self.photometric is not None:
            log.info("photometric calibration from %s", photometric or seq_dir)
        self._full_rectifier = None

    # ------------------------------------------------------------------ helpers
    def _full_resolution(self):
        if self._full_rectifier is None:
            cam = self.sequence.camera
            self._full_rectifier = cam.rectifier(cam.intrinsics.width, multiple_of=2)
        return self._full_rectifier

    def _sink_image(self, fr) -> np.ndarray:
        """The full-resolution rectified uint8 image of a frame (BGR when the source has colour)."""
        rect = self._full_resolution()
        color = getattr(fr, "color", None)
        if color is not None and color.ndim == 3:
            img = rect.color(color)
        else:
            img = rect(fr.image)
        return np.clip(img + 0.5, 0, 255).astype(np.uint8)

    def _given_pose(self, t: float):
        i = self._gt.nearest(t, 0.02)
        return None if i is None else self._gt.poses[i]

    def _fan_out(self, method: str, *args) -> None:
        for s in self.sinks:
            getattr(s, method)(*args)

    # ------------------------------------------------------------------ the loop
    def run(self) -> SessionResult:
        """Process every frame; sinks see everything. Re-raises Ctrl-C, SIGTERM and errors after
        ``on_finish`` was called with the matching status."""
        t_warm = time.perf_counter()
        if self.warm_up_kernels:           # compile/load kernels before the clock starts
            with announce_if_slow("compiling the numba kernels (the first run on this machine takes about a "
                                  "minute; `lite-vo warmup` does it once after installing) ..."):
                warmup(CORE_KERNEL_MODULES, runtime=True)   # what a run uses: each loaded kernel costs memory
        warmup_s = time.perf_counter() - t_warm
        seq, cfg = self.sequence, self.config
        if cfg.system.auto_vignette and any(getattr(s, "wants_raw_images", False) for s in self.sinks):
            # a sink fits the camera's vignetting to the images as they come (VignetteSink): a correction made
            # during the run would mix in
            log.info("system.auto_vignette is off for this run: a sink estimates the vignette from the images as they come")
            cfg = dataclasses.replace(cfg, system=dataclasses.replace(cfg.system, auto_vignette=False))
        vo = VisualOdometry(seq.camera, cfg, depth_source=self.depth_source,
                            pose_source="given" if self.pose_source == "gt" else "estimate",
                            photometric=self.photometric)
        want_image = any(getattr(s, "wants_image", False) for s in self.sinks)
        info = SessionInfo(
            name=seq.name, path=str(getattr(seq, "path", None) or seq.name), frames_total=self.frames_total,
            config=cfg, profile=self.profile_name,
            camera=self._full_resolution().intrinsics if want_image else vo.map_intrinsics,
            map_camera=vo.map_intrinsics, accelerometer=getattr(seq, "accelerometer", None),
            depth_source=self.depth_source, pose_source=self.pose_source, start_frame=self.start_frame,
            max_frames=self.max_frames, has_depth=bool(seq.has_depth), keyframes=vo.keyframes)
        self._fan_out("on_start", info)
        tracked = PoseRecord()
        events: list[dict] = []
        counts = {"skipped": 0}
        realtime = cfg.system.mode == "realtime"
        pacing = _Pacing(cfg.system.realtime_speed) if realtime else None
        bad_in_row = 0
        last_index = -1
        read = 0
        status, error, exc = None, None, None
        t_wall = time.perf_counter()
        c_wall = time.process_time()
        try:
            # depth images are decoded when a frame needs one (initialisation, the sampled depth
            # evaluation), except for RGB-D tracking, which needs every one
            defer = self.depth_source != "images"
            # colour is decoded for the keyframes only, unless a sink shows every frame
            for fr in prefetch(seq, self.start_frame, self.max_frames, defer_depth=defer, defer_color=not want_image):
                read += 1
                if getattr(fr, "error", None) or fr.image is None:
                    counts["skipped"] += 1
                    bad_in_row += 1
                    reason = getattr(fr, "error", None) or f"frame {fr.index}: no image"
                    log.warning("skipping unreadable frame: %s", reason)
                    if bad_in_row > self.max_bad_frames:
                        raise InputError(f"{bad_in_row} unreadable frames in a row (more than --max-bad-frames "
                                         f"{self.max_bad_frames}); the last: {reason}")
                    continue
                bad_in_row = 0
                if pacing is not None and pacing.late(fr.timestamp):
                    vo.note_dropped()          # the next frame has already arrived, as a live camera would
                    continue
                T_given = None
                if self._gt is not None:
                    T_given = self._given_pose(fr.timestamp)
                    if T_given is None:
                        vo.note_dropped()
                        continue
                depth = fr.depth if getattr(fr, "depth_reader", None) is None else fr.depth_reader
                color = getattr(fr, "color", None)
                if color is None:
                    color = getattr(fr, "color_reader", None)
                res = vo.process(fr.image, fr.timestamp, depth=depth, T_world_cam=T_given,
                                 color=color)   # colour for the keyframes' cloud
                last_index = fr.index
                if res.event:
                    events.append({"frame": res.index, "t": res.timestamp, "event": res.event})
                    _log_event(res, events)
                if res.corrections:
                    for idx, T in res.corrections.items():   # earlier poses re-estimated (bootstrap)
                        tracked.correct(idx, T)
                    self._fan_out("on_corrections", dict(res.corrections))
                # a lost frame is recorded without a pose: the two-view start-up may give it one later
                tracked.add(res.index, res.timestamp, None if res.lost else res.T_world_cam)
                for m in vo.take_published_maps():
                    self._fan_out("on_map", m)
                self._fan_out("on_frame", FrameEvent(res, res.image, self._sink_image(fr) if want_image else None))
        except KeyboardInterrupt as err:
            status, exc = f"interrupted at frame {last_index + 1}", err
        except Interrupted as err:
            status, exc = f"interrupted at frame {last_index + 1}", err
        except LiteVOError as err:
            status, error, exc = f"failed: {err}", str(err), err
        except Exception as err:           # a bug: still finish the files, then show the traceback
            status, error, exc = f"failed: {type(err).__name__}: {err}", str(err), err
        finally:
            try:
                vo.close()
            except LiteVOError as err:
                if exc is None:
                    status, error, exc = f"failed: {err}", str(err), err
            for m in vo.take_published_maps():
                self._fan_out("on_map", m)
        wall_s = time.perf_counter() - t_wall
        cpu_s = time.process_time() - c_wall
        frames = {k: int(v) for k, v in vo.counts.items()} | counts
        frames["posed"] = len(tracked)  # frames with a pose in the end (start-up corrections included)
        if status is None:
            status = _status(frames, events)
        timing = vo.timing()
        timing["wall_s"] = wall_s
        timing["cpu_s"] = cpu_s       # CPU time of the whole process (all threads) over the same span
        timing["warmup_s"] = warmup_s
        end = RunEnd(status=status, frames=frames, timing=timing, events=events,
                     metric=bool(vo.metric or self.pose_source == "gt"),
                     depth_accuracy_series=vo.depth_accuracy_series, error=error, frames_read=read,
                     vignette=vo.vignette_summary())
        # the exports (map.ply, plots) reuse the memory of the VO's working state (the keyframe store
        # stays: the sinks have it): on ICL, board, the end-of-run peak stays at the frame loop's
        del vo
        gc.collect()
        trim_malloc()
        finish_error = None
        for s in self.sinks:               # every sink finishes, even when one of them fails
            try:
                s.on_finish(end)
            except Exception as err:       # noqa: BLE001 - re-raised below
                finish_error = finish_error or err
        if self._owns_sequence:
            seq.close()
        if exc is not None:
            raise exc
        if finish_error is not None:
            raise finish_error
        _, timestamps, poses = tracked.arrays()
        return SessionResult(end, timestamps.tolist(), list(poses), info)


_EVENT_TEXT = {"init": "map initialised ({init}) at frame {index}",
               "waiting": "start-up waits: frame {index} is blown out or too dark to start on (system.start_max_clipped, "
                          "system.start_max_clipped_centre, system.start_min_textured)",
               "bootstrap": "start-up: map rebuilt from two views at frame {index}; earlier poses corrected",
               "reinit": "map re-initialised at frame {index}",
               "lost": "tracking lost at frame {index}",
               "recovered": "tracking recovered at frame {index}"}


def _log_event(res: FrameResult, events: list) -> None:
    """One INFO line per event (a run of lost frames is one line)."""
    if res.event in ("lost", "waiting") and len(events) > 1 and events[-2]["event"] == res.event:
        return
    text = _EVENT_TEXT.get(res.event, res.event + " at frame {index}")
    log.info(text.format(index=res.index, init=(res.quality or {}).get("init", "?")))


def _status(frames: dict, events: list) -> str:
    if frames.get("tracked", 0) == 0:
        return "failed: no frame tracked"
    if events and events[-1]["event"] == "lost":
        return "lost"
    if frames.get("lost", 0) > 0 or frames.get("reinit", 0) > 0:
        return "ok_with_losses"
    if frames.get("skipped", 0) > 0:
        return "ok_with_skipped_frames"
    return "ok"


class _Pacing:
    """Realtime playback: sleeps until a frame is due; says when a frame is too late to process."""

    def __init__(self, speed: float) -> None:
        self.speed = speed
        self.first: tuple[float, float] | None = None
        self.last_ts: float | None = None

    def late(self, ts: float) -> bool:
        if self.first is None:
            self.first = (ts, time.perf_counter())
        period = ts - self.last_ts if self.last_ts is not None else 1.0 / 30.0
        self.last_ts = ts
        due = (ts - self.first[0]) / self.speed
        now = time.perf_counter() - self.first[1]
        if now < due:
            time.sleep(due - now)
            return False
        return now > due + period / self.speed


# ----------------------------------------------------------------------------------------------
# The reader thread and the allocator
# ----------------------------------------------------------------------------------------------

#: frames between two ``malloc_trim`` calls while a session reads frames (0: never)
TRIM_EVERY = 100
_glibc = None


def _glibc_malloc():
    """glibc's C library (for ``malloc_trim``), or None elsewhere (macOS, musl, Windows)."""
    global _glibc
    if _glibc is None:
        _glibc = False
        if platform.system() == "Linux" and platform.libc_ver()[0] == "glibc":
            try:
                libc = ctypes.CDLL(None)
                libc.malloc_trim.argtypes = [ctypes.c_size_t]
                _glibc = libc
            except (OSError, AttributeError):
                pass
    return _glibc or None


def trim_malloc() -> bool:
    """Give the free memory glibc's malloc holds (in every arena) back to the system; no-op elsewhere."""
    libc = _glibc_malloc()
    return bool(libc.malloc_trim(0)) if libc is not None else False


def prefetch(seq, start_frame: int, max_frames: int | None, depth: int = 4, trim_every: int | None = None,
             defer_depth: bool = False, defer_color: bool = False):
    """Frames ``start_frame ..`` of ``seq`` decoded ahead in a reader thread (a camera driver's job).

    ``defer_depth``: sequences that can (``seq.frames(start, defer_depth=True)``) leave the depth images
    undecoded (``Frame.depth_reader`` reads one on demand); ``defer_color`` likewise the colour images
    (``Frame.color_reader``).

    Order is unchanged, so sync runs stay deterministic; an exception in the reader is re-raised
    in the caller. Frames are allocated in the reader thread and freed in the caller's, which
    leaves free memory in the reader's malloc arena; with glibc, every ``trim_every`` frames
    (default :data:`TRIM_EVERY`) the free memory of every arena is returned (:func:`trim_malloc`).
    """
    trim_every = TRIM_EVERY if trim_every is None else trim_every
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    end = object()

    def reader():
        try:
            if hasattr(seq, "frames"):
                source = seq.frames(start_frame, defer_depth=defer_depth, defer_color=defer_color)
            elif start_frame > 0 and hasattr(seq, "frame"):  # random access: skip without decoding
                source = (seq.frame(i) for i in range(start_frame, len(seq)))
            else:
                source = itertools.islice(seq, start_frame, None)
            for n, fr in enumerate(source):
                if stop.is_set() or (max_frames is not None and n >= max_frames):
                    break
                q.put(fr)
            q.put(end)
        except BaseException as err:  # handed to the consumer
            q.put(err)

    t = threading.Thread(target=reader, name="lite_vo-reader", daemon=True)
    t.start()
    try:
        for n in itertools.count(1):
            item = q.get()
            if item is end:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
            if trim_every > 0 and n % trim_every == 0:
                trim_malloc()
    finally:
        stop.set()
        while t.is_alive():
            try:
                q.get_nowait()
            except queue.Empty:
                t.join(0.05)
