"""The visual odometry system (thesis chapter 5, Fig. 5.4): tracking and mapping sharing one map.

:class:`VisualOdometry` owns the frame preprocessing (rectify, resize, pyramid), a
:class:`~lite_vo.tracking.Tracker` and a :class:`~lite_vo.mapping.Mapper`.

Threads and ownership
---------------------
``mode="sync"`` runs everything in the caller's thread, mapping every k-th frame: deterministic.

``mode="realtime"`` runs mapping in a second thread:

* **tracking thread** (the caller of :meth:`VisualOdometry.process`) only: ``_tracker``,
  ``_verifier``, ``_last_pose``, ``_velocity`` (``_velocity_dt``: the time it took; ``_pose_t``: the last good
  pose's time), ``_lost_count``, the timers of tracking.
* **mapping thread** only: the *contents* of ``_mapper`` (``update``), the mapping timers.
* **shared**: ``_reference`` (an immutable :class:`TrackingReference` plus the pose of the frame it
  lives in), swapped under ``_ref_lock`` by whoever built it; ``_pending`` (the newest tracked
  frame waiting for mapping; older ones are replaced, i.e. skipped) under ``_cond``;
  ``_published`` (maps waiting for :meth:`VisualOdometry.take_published_maps`) under ``_ref_lock``.
  (Re-)initialisation happens in the tracking thread: it builds a *new* mapper and installs it
  under ``_ref_lock``; a map made meanwhile by the old mapper is not published, and frames tracked
  against the old map (``_Frame.mapper``) are not mapped into the new one.
  No array is written after it has been handed to the other thread.

Numba kernels release the GIL, so both threads really run in parallel.

The VO calls nobody back: :meth:`VisualOdometry.process` returns a :class:`FrameResult`, and every
published map waits in a small bounded slot until the frame driver (:mod:`lite_vo.session`) takes
it with :meth:`VisualOdometry.take_published_maps` and hands it to the output sinks on its own thread.

This module never imports ``ar_demo`` or any GL/physics package.
"""
from __future__ import annotations

import collections
import functools
import logging
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import cv2
import numba
import numpy as np

from .bootstrap import InitVerifier, patch_affine
from .camera import Camera, PinholeIntrinsics
from .config import VOConfig, tracking_level
from .errors import InputError, LiteVOError
from .geometry import exp_se3, inverse_se3, log_se3, project_to_se3
from .image import image_pyramid
from .keyframes import Keyframe, KeyframeStore, PointCloud, scene_cloud
from .mapping import MapFrame, Mapper, depth_accuracy, image_gradients
from .records import RowRecord
from .timing import Timers
from .tracking import Tracker, TrackingReference, depth_image_idepth
from .tracking.relocalizer import Relocalizer
from .photometric import PhotometricCalibration, PhotometricMonitor, affine_transfer, compose_affine

log = logging.getLogger(__name__)


#: a monocular start on a frame with more than this share of clipped pixels gets a warning (ICL with
#: tools/augment.py's auto-exposure: the seeds that start 58-79 % clipped lose accuracy; README "Real cameras");
#: with the start-up's wait on (system.start_max_clipped) that happens only when the wait ran out
BLOWN_OUT_START = 0.5
#: ... or with more than this share of the pixels of its centre clipped (:data:`CENTRE_RADIUS`): a vignetting
#: lens darkens the rest of the frame, so the share over the whole frame understates a blown-out exposure
#: (on ICL's auto-exposure frames a whole-frame share of 0.5 goes with 0.65-0.75 in the centre)
BLOWN_OUT_START_CENTRE = 0.7
#: the constant-velocity guess is scaled to the time since the last good pose when that is more than this many
#: times (or less than its inverse) the time the last motion took (:meth:`VisualOdometry._velocity_over`)
VELOCITY_TIME_RATIO = 1.5
#: a frame this many times the last motion's time after the last good pose follows a gap in the input: its
#: brightness may have changed by more than tracking.max_gain_change against the reference (:meth:`_after_gap`)
GAP_FACTOR = 2.0
#: the centre whose clipped share system.start_max_clipped_centre bounds: pixels nearer the principal point than
#: this fraction of its distance to the farthest image corner (where a vignette darkens by a quarter of its corners'
#: fall-off at most, for a fall-off in r^2)
CENTRE_RADIUS = 0.5

#: the fields of a row of :attr:`VisualOdometry.depth_accuracy_series`
DEPTH_ACCURACY_FIELDS = ("frame", "t", "scale", "density", "median_abs_rel_error", "within_5pct", "within_10pct",
                         "compared")


@dataclass
class FrameResult:
    """Outcome of one frame: the pose (None when lost), the quality of tracking and timing."""
    index: int
    timestamp: float
    T_world_cam: np.ndarray | None
    lost: bool
    quality: dict = field(default_factory=dict)
    mapped: bool = False
    event: str = ""  # "init", "waiting" (start-up skips a blown-out frame), "bootstrap" (two-view start-up),
    #                  "reinit" (after a loss), "lost", "recovered",
    #                  "relocalised" (re-tracked against a stored keyframe: quality["keyframe"]) or ""
    corrections: dict = field(default_factory=dict)  # earlier frame index -> corrected T_world_cam or None
    image: np.ndarray | None = field(default=None, repr=False)  # float32 grey at mapping resolution


@dataclass(frozen=True, eq=False)
class PublishedMap:
    """A semi-dense map the VO published (read-only arrays at mapping resolution)."""
    frame_index: int
    timestamp: float
    T_world_cam: np.ndarray
    camera: PinholeIntrinsics
    image: np.ndarray                      # float32 grey image of the map's frame
    idepth_raw: np.ndarray = field(repr=False)
    idepth_var_raw: np.ndarray = field(repr=False)
    valid: np.ndarray = field(repr=False)

    @cached_property
    def idepth(self) -> np.ndarray:
        """float32 inverse depth, NaN where there is no hypothesis."""
        return np.where(self.valid, self.idepth_raw, np.nan).astype(np.float32)

    @cached_property
    def idepth_var(self) -> np.ndarray:
        """float32 inverse-depth variance, NaN where there is no hypothesis."""
        return np.where(self.valid, self.idepth_var_raw, np.nan).astype(np.float32)

    def points_world(self, min_idepth: float = 1e-6) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """World-frame points (N, 3), their idepth variance (N,) and their pixels ``(v, u)``."""
        ok = self.valid & (self.idepth_raw > min_idepth)
        v, u = np.nonzero(ok)
        if len(u) == 0:
            return np.zeros((0, 3)), np.zeros(0), (v, u)
        p_cam = self.camera.unproject_idepth(u, v, self.idepth_raw[ok])
        T = self.T_world_cam
        return p_cam @ T[:3, :3].T + T[:3, 3], self.idepth_var_raw[ok].astype(np.float64), (v, u)



@dataclass(frozen=True)
class _Reference:
    """What tracking tracks against: an immutable reference and the map it was built from."""
    tracking_ref: Any
    map: PublishedMap
    affine: tuple = (1.0, 0.0)   # brightness (A, B) of the reference frame: I = A * J + B
    vig: int = 0                 # the photometric correction its image is in (system.auto_vignette)

    @property
    def T_world_ref(self) -> np.ndarray:
        return self.map.T_world_cam


@dataclass
class _Frame:
    """A preprocessed frame (arrays never written after construction)."""
    index: int
    timestamp: float
    image: np.ndarray                 # float32 at mapping resolution
    pyramid: list
    depth_native: Any                 # as read (camera resolution, metres) or a reader of it; rectified on first use
    T_world_cam: np.ndarray | None = None
    color: Any = None                 # the input BGR image (native resolution) for colour sources, or a
                                      # function decoding it (called when the frame becomes a keyframe)
    residual: float = 0.0
    mapper: Any = None                # the mapper whose map this frame was tracked against
    sharpness: float = 1.0            # relative to the recent frames (motion blur: < 1)
    clipped: float = 0.0              # share of the pixels at or above mapping.saturation
    textured: float = float("nan")    # share of the pixels with a hypothesis' gradient (measured only before a start)
    clipped_centre: float = float("nan")  # share of the pixels of the centre (CENTRE_RADIUS) clipped (only before a start)
    affine: tuple = (1.0, 0.0)        # brightness (A, B): I = A * J + B, chained by tracking
    noise_sigma: float = float("nan")  # smoothed image noise estimate (grey levels)
    rectify_depth: Any = None          # native depth -> mapping resolution (the system's rectifier)
    corner_image: np.ndarray | None = None  # at the start-up corners' resolution, while they are followed
    vig: int = 0                      # the photometric correction its image is in (system.auto_vignette)
    _depth_m: np.ndarray | None = None

    @property
    def depth_m(self) -> np.ndarray | None:
        """The depth image at mapping resolution (0 = invalid), rectified on first use: most frames
        never need it (only initialisation, RGB-D tracking and the sampled depth evaluation do)."""
        if self._depth_m is None and self.depth_native is not None:
            d = self.depth_native() if callable(self.depth_native) else self.depth_native
            self._depth_m = self.rectify_depth(d)
        return self._depth_m


def _evaluate_depth(frame: _Frame, idepth: np.ndarray, valid: np.ndarray, monocular: bool, t: float) -> dict | None:
    """One row of the depth evaluation (run on the evaluation worker): the map of ``frame`` against its
    depth image; a monocular map is first scaled by the median ratio. None when the image cannot be read."""
    try:
        gt = frame.depth_m
    except InputError as err:     # a deferred depth image that cannot be read: evaluation only
        log.warning("depth evaluation skips frame %d: %s", frame.index, err)
        return None
    scale = 1.0
    if monocular:
        # arbitrary scale: align it per frame (median ratio) before comparing
        both = valid & (gt > 0) & (idepth > 0)
        if both.any():
            scale = float(np.median(gt[both] * idepth[both]))
            idepth = idepth / scale
    acc = depth_accuracy(idepth, valid, gt)
    return {"frame": frame.index, "t": t, "scale": scale, **acc}


def warp_idepth(idepth: np.ndarray, idepth_var: np.ndarray, valid: np.ndarray, T_dst_src: np.ndarray,
                intrinsics: PinholeIntrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An inverse-depth map moved into another view of the same camera (``T_dst_src``): every valid pixel
    is projected to the nearest pixel there, the nearest point wins where several land, its variance is
    scaled as the inverse depth (``var (rho_dst / rho_src)^4``). Returns (idepth, idepth_var, valid),
    0 where nothing landed."""
    h, w = idepth.shape
    v, u = np.nonzero(np.asarray(valid) & (idepth > 0) & np.isfinite(idepth))
    rho = idepth[v, u].astype(np.float64)
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    P = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(rho)]) / rho
    Q = T_dst_src[:3, :3] @ P + T_dst_src[:3, 3:4]
    z = Q[2]
    front = z > 1e-9
    z_safe = np.where(front, z, 1.0)
    ud = np.rint(fx * Q[0] / z_safe + cx).astype(np.int64)
    vd = np.rint(fy * Q[1] / z_safe + cy).astype(np.int64)
    keep = front & (ud >= 0) & (ud < w) & (vd >= 0) & (vd < h)
    rho_d = 1.0 / z_safe[keep]
    var_d = idepth_var[v[keep], u[keep]] * (rho_d / rho[keep]) ** 4
    pix = vd[keep] * w + ud[keep]
    order = np.lexsort((-rho_d, pix))                  # per pixel, the nearest first
    first = order[np.unique(pix[order], return_index=True)[1]]
    out_rho = np.zeros(h * w, np.float32)
    out_var = np.zeros(h * w, np.float32)
    out_valid = np.zeros(h * w, bool)
    out_rho[pix[first]] = rho_d[first]
    out_var[pix[first]] = var_d[first]
    out_valid[pix[first]] = True
    return out_rho.reshape(h, w), out_var.reshape(h, w), out_valid.reshape(h, w)


@functools.lru_cache(maxsize=4)
def _patch_grid(h: int, w: int) -> np.ndarray:
    """Points every 4 px (4 px from the border) of an h x w image, float32 (N, 2), read-only and shared."""
    gy, gx = np.mgrid[4:h - 4:4, 4:w - 4:4]
    grid = np.column_stack([gx.ravel(), gy.ravel()]).astype(np.float32)
    grid.setflags(write=False)
    return grid


def _aligned_brightness(image0: np.ndarray, image1: np.ndarray, saturation: float) -> tuple | None:
    """The brightness change ``I_1 = a I_0 + b`` between two nearly aligned frames (consecutive ones), from
    :func:`patch_affine` on a grid of patch means; None when it cannot be measured."""
    grid = _patch_grid(*image0.shape)
    return patch_affine(image0, image1, grid, grid, saturation)


# a random map's first published maps are not offered to the vignette estimate (system.auto_vignette)
# unless a two-view start-up rebuilds it: with given poses the depths need about a second to converge
# (ICL, `--poses gt`: 24.5 % in the corners from the first six pairs, against the true 50 %)
VIGNETTE_YOUNG_MAPS = 8


# the back-fill's brightness, measured from frame to frame on a mostly clipped image, drifts by a few
# per cent a frame: a tracked estimate this close to it is kept, a collapsed one (gain 0.1-0.8) is not
BACKFILL_GAIN_TOL = 0.3
BACKFILL_GREY_TOL = 30.0


def _brightness_disagrees(estimated: tuple, measured: tuple, gain_tol: float = 0.1, grey_tol: float = 10.0) -> bool:
    """Whether a tracked brightness change ``(a, b)`` is far from a measured one: gains more than
    ``gain_tol`` apart (relative) or mid-grey (128) mapped more than ``grey_tol`` grey levels apart."""
    (a, b), (am, bm) = estimated, measured
    if not (a > 0 and am > 0):
        return True
    return abs(math.log(a / am)) > gain_tol or abs((a - am) * 128.0 + b - bm) > grey_tol


class VisualOdometry:
    """Semi-dense monocular visual odometry: ``process(image, timestamp) -> FrameResult``.

    Parameters
    ----------
    camera:
        a :class:`lite_vo.camera.Camera` (anything with ``rectifier(width, multiple_of)``), or a
        :class:`PinholeIntrinsics` of already undistorted input images.
    config:
        a :class:`VOConfig` (``lite_vo.load_profile("phone")``).
    depth_source:
        ``"filter"`` (the semi-dense filter, normal operation) or ``"images"`` (track every frame
        against the previous frame's depth image: RGB-D odometry, isolates tracking).
    pose_source:
        ``"estimate"`` (tracking) or ``"given"`` (poses passed to :meth:`process`: isolates mapping; with
        ``tracking.affine_brightness`` each frame is still aligned to the map, for its brightness only).
    photometric:
        a :class:`PhotometricCalibration` applied to every raw image first (None: none).
    """

    #: published maps kept for :meth:`take_published_maps` (older ones are dropped when nobody takes them)
    MAX_WAITING_MAPS = 16

    def __init__(self, camera, config: VOConfig, depth_source: str = "filter", pose_source: str = "estimate",
                 photometric: PhotometricCalibration | None = None) -> None:
        if depth_source not in ("filter", "images"):
            raise LiteVOError(f"depth_source must be 'filter' or 'images', not {depth_source!r}")
        if pose_source not in ("estimate", "given"):
            raise LiteVOError(f"pose_source must be 'estimate' or 'given', not {pose_source!r}")
        self.config = config
        self.depth_source = depth_source
        self.pose_source = pose_source
        res = config.resolution
        if config.system.numba_threads > 0:
            numba.set_num_threads(min(config.system.numba_threads, numba.config.NUMBA_NUM_THREADS))
        if isinstance(camera, PinholeIntrinsics):  # already undistorted input: resize and crop only
            camera = Camera(camera)
        self._rectifier = camera.rectifier(res.map_width, multiple_of=2 ** (res.pyramid_levels - 1))
        self.map_intrinsics: PinholeIntrinsics = self._rectifier.intrinsics
        # the monocular start-up follows its corners at a finer resolution when the camera has the pixels
        lk_width = min(int(round(config.system.verify_lk_scale * res.map_width)), camera.intrinsics.width)
        self._corner_rectifier = (camera.rectifier(lk_width, multiple_of=2) if lk_width > res.map_width
                                  and config.system.verify_init and pose_source == "estimate" else None)
        #: the finest tracking level (``resolution.track_level``, finer for wide images: :func:`tracking_level`)
        self.track_level = tracking_level(res, self.map_intrinsics.width, self.map_intrinsics.height)
        if self.track_level != res.track_level:
            lv = self.map_intrinsics.level(self.track_level)
            log.info("tracking at level %d (%dx%d) instead of %d: a %dx%d mapping image has too few rows "
                     "(resolution.min_track_row_share)", self.track_level, lv.width, lv.height, res.track_level,
                     self.map_intrinsics.width, self.map_intrinsics.height)
        self.timers = Timers()
        self._rng_seed = config.system.seed
        # tracking thread only
        self._tracker = Tracker(config.tracking, self.map_intrinsics, res.pyramid_levels, self.track_level)
        self._last_pose: np.ndarray | None = None
        self._last_good_pose: np.ndarray | None = None
        self._velocity = np.eye(4)
        self._velocity_dt = 0.0          # the time the velocity's motion took (0: no velocity)
        self._pose_t = 0.0               # timestamp of _last_good_pose
        self._lost_count = 0
        self._photometric = photometric
        # the vignette estimated during the run (system.auto_vignette): fed the published maps, it hands a
        # new correction to _vig_pending (under _vig_lock); the tracking thread adopts it between start-ups
        # (_vig_version; _vig_inv: version -> inverse vignette at mapping resolution, None = 1). In realtime
        # mode the estimator works in a thread of its own (_vig_worker, every call in order): a fit takes
        # 10-120 ms, which the tracking thread would pay in dropped frames
        self._vignette = None
        self._vig_worker: ThreadPoolExecutor | None = None
        if config.system.auto_vignette and (photometric is None or photometric.vignette is None):
            from .vignette_fit import OnlineVignette
            self._vignette = OnlineVignette(self.map_intrinsics)
            if config.system.mode == "realtime":
                self._vig_worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="lite_vo-vignette")
        self._vig_lock = threading.Lock()
        self._vig_inv: dict[int, np.ndarray | None] = {0: None}
        self._vig_version = 0
        self._vig_pending: tuple | None = None
        self._vig_from: list[int] = []        # the first frame of each adopted correction
        self._vig_corner = 1.0                # the adopted correction's darkest corner
        self._vig_young = 0                   # published maps still too young to offer (a random start's first ones)
        self._monitor = PhotometricMonitor(config.system.blur_window, config.tracking.noise_smoothing)
        self._recent_affine: dict[int, tuple] = {}   # frame index -> brightness, for the bootstrap replay
        self._index = 0
        self._t0: float | None = None
        self._wait_t0: float | None = None   # first frame a monocular start skipped (system.start_max_clipped)
        self._centre_mask: np.ndarray | None = None   # the image centre of system.start_max_clipped_centre
        # the skipped frames (index, timestamp, tracking levels of the pyramid, sharpness): tracked backwards
        # against the map once the start-up is resolved (_backfill_waited), then dropped
        self._waited: list[tuple] = []
        self._start_pose: np.ndarray | None = None   # the first map's pose and brightness (the back-fill starts there)
        self._start_affine: tuple = (1.0, 0.0)
        self._start_pyramid: list | None = None  # its image pyramid (only while skipped frames wait for a pose)
        self._late_corrections: dict = {}    # poses of earlier frames found while processing this one
        self._reinit_wait_t0: float | None = None   # a due re-initialisation waits for a usable frame since then
        self._prev_tracked: tuple | None = None      # (image at the tracking level, brightness) of the last tracked frame
        self._last_ts: float | None = None
        self.counts = {"in": 0, "tracked": 0, "lost": 0, "dropped": 0, "waited": 0, "backfilled": 0, "reinit": 0,
                       "bootstrap": 0,
                       "mapped": 0, "relocalised": 0}
        self._relocalizer = Relocalizer(config.tracking, self._tracker, res.pyramid_levels, self.track_level) \
            if config.tracking.relocalise else None
        self._prev_depth_frame: _Frame | None = None
        # mapping thread only (replaced as a whole, under _ref_lock, on (re-)initialisation)
        self._mapper_count = 0  # mappers made so far: each new one gets its own seed
        self._mapper = self._new_mapper()
        self._verifier = None  # tracking thread only: InitVerifier after a random initialisation
        # one row (dict) per mapped frame with a depth image, stored as numbers (long runs stay small)
        self._depth_eval_count = 0       # mapped frames offered to the depth evaluation
        self._depth_series = RowRecord(DEPTH_ACCURACY_FIELDS, ints=("frame", "compared"))
        self._depth_eval: ThreadPoolExecutor | None = None      # evaluates off the tracking thread
        self._depth_jobs: collections.deque = collections.deque()  # its results, in submission order
        self._depth_lock = threading.Lock()
        # shared
        self._ref_lock = threading.Lock()
        self._reference: _Reference | None = None
        self._published: collections.deque = collections.deque(maxlen=self.MAX_WAITING_MAPS)
        self._cond = threading.Condition()
        self._pending: _Frame | None = None
        self._stop = False
        self._map_error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self._initialized = False
        self.metric = False  # True when the map has metric scale (depth images)
        # keyframe history (thread-safe; filled where maps are published, read by sinks)
        self.keyframes = KeyframeStore(max_bytes=int(config.system.keyframe_memory_mb * 2**20),
                                       min_translation_rel=config.system.keyframe_min_move,
                                       min_rotation_deg=config.system.keyframe_min_turn_deg)
        self._scale_id = 0   # a new id for every map with a new monocular scale
        # the scale id of self._mapper's maps, set with it under _ref_lock: a map the mapping thread publishes
        # from the old mapper while a new map (a new scale) is being installed keeps the old id (realtime mode)
        self._mapper_scale_id = 0
        if config.system.mode == "realtime" and depth_source == "filter":
            self._thread = threading.Thread(target=self._mapping_loop, name="lite_vo-mapping", daemon=True)
            self._thread.start()

    # ------------------------------------------------------------------ public API
    @property
    def initialized(self) -> bool:
        return self._initialized

    def process(self, image: np.ndarray, timestamp: float, depth: np.ndarray | None = None,
                T_world_cam: np.ndarray | None = None, color: Any = None) -> FrameResult:
        """Track one frame (and map it, in sync mode, when it is its turn).

        ``image``: grey, or BGR (then converted here); ``color``: the BGR image of a grey ``image``
        when the caller has both (keyframes keep colour for the point cloud), or a function ``f(r)``
        returning it (or None), called only if the frame becomes a keyframe; it may return the image at
        1/r of the native size (``r``: 1, 2, 4 or 8, what the rectifier can take without a remap). ``depth`` (metres,
        0 = invalid, camera resolution; or a function returning it, called only if the frame needs
        it) is used for depth initialisation, in ``depth_source="images"`` and for the depth evaluation; ``T_world_cam`` is required with ``pose_source="given"``.
        """
        self._check_input(image, timestamp, T_world_cam)
        t_start = time.perf_counter()
        frame = self._preprocess(image, timestamp, depth, color)
        self.counts["in"] += 1
        if self._map_error is not None:
            raise LiteVOError(f"mapping thread failed: {self._map_error}") from self._map_error
        if self.depth_source == "images":
            result = self._process_rgbd(frame, t_start)
        elif self.pose_source == "given":
            result = self._process_given_pose(frame, T_world_cam, t_start)
        else:
            result = self._process_tracking(frame, t_start)
        if self._late_corrections:
            result.corrections = {**self._late_corrections, **result.corrections}
            self._late_corrections = {}
        if not result.lost and result.T_world_cam is not None:      # the image and brightness exposure steps compare with
            self._prev_tracked = (frame.pyramid[self.track_level], frame.affine)
        result.image = frame.image
        return result

    def take_published_maps(self) -> list[PublishedMap]:
        """The maps published since the last call, oldest first (the frame driver drains this)."""
        with self._ref_lock:
            maps = list(self._published)
            self._published.clear()
        return maps

    def depth_map(self) -> tuple[np.ndarray, np.ndarray]:
        """(idepth, idepth_var) of the latest published map at mapping resolution, NaN where empty."""
        with self._ref_lock:
            ref = self._reference
        if ref is None:
            h, w = self.map_intrinsics.height, self.map_intrinsics.width
            return np.full((h, w), np.nan, np.float32), np.full((h, w), np.nan, np.float32)
        return ref.map.idepth, ref.map.idepth_var

    def map_points(self) -> tuple[np.ndarray, np.ndarray]:
        """World-frame points (N, 3) of the latest map and their idepth variance (N,)."""
        with self._ref_lock:
            ref = self._reference
        if ref is None:
            return np.zeros((0, 3)), np.zeros(0)
        pts, var, _ = ref.map.points_world()
        return pts, var

    def point_cloud(self, **kw) -> PointCloud:
        """The whole-scene point cloud of the keyframes (see :func:`lite_vo.keyframes.scene_cloud`)."""
        return scene_cloud(self.keyframes, **kw)

    @property
    def depth_accuracy_series(self) -> RowRecord:
        """Rows of the sampled depth evaluation against the sequence's depth images (fields
        ``DEPTH_ACCURACY_FIELDS``), complete up to the last processed frame (waits for the evaluations
        still running in the background)."""
        self._drain_depth_jobs(wait=True)
        return self._depth_series

    def _drain_depth_jobs(self, wait: bool) -> None:
        """Append the finished evaluations (all of them with ``wait``) in the order they were made (the
        mapping thread submits in realtime mode, any thread may read: one lock)."""
        with self._depth_lock:
            jobs = self._depth_jobs
            while jobs and (wait or jobs[0].done()):
                row = jobs[0].result()
                jobs.popleft()
                if row is not None:
                    self._depth_series.append(row)

    def close(self) -> None:
        """Stop the mapping thread (realtime mode) after it finished the pending frame, and finish the
        depth evaluations still running."""
        if self._thread is not None:
            with self._cond:
                self._stop = True
                self._cond.notify_all()
            self._thread.join()
            self._thread = None
        if self._vig_worker is not None:
            self._vig_worker.shutdown(wait=True)
            self._vig_worker = None
        try:
            self._drain_depth_jobs(wait=True)
        finally:
            if self._depth_eval is not None:
                self._depth_eval.shutdown(wait=True)
                self._depth_eval = None
        if self._map_error is not None:
            raise LiteVOError(f"mapping thread failed: {self._map_error}") from self._map_error

    def __enter__(self) -> "VisualOdometry":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def timing(self) -> dict:
        """The ``timing.json`` contract (times in ms)."""
        stages = {n: Timers.summary(self.timers.values(n)) for n in sorted(self.timers.names())
                  if n not in ("tracking", "mapping")}
        return {
            "tracking": Timers.summary(self.timers.values("tracking")),
            "mapping": Timers.summary(self.timers.values("mapping")),
            "stages": stages,
            # waited / backfilled: only when a start waited (system.start_max_clipped)
            "frames": {k: int(self.counts[k]) for k in ("in", "tracked", "lost", "dropped", "waited", "backfilled")
                       if k not in ("waited", "backfilled") or self.counts["waited"]},
            "relocalised": int(self.counts["relocalised"]),
            # wide basin: frames on which the motion hypotheses were tried, and which guess won
            "hypotheses": {"tried": int(self._tracker.hypothesis_frames),
                           "won": dict(sorted(self._tracker.hypothesis_counts.items()))},
        }

    def note_dropped(self) -> None:
        """Count a frame the caller skipped (realtime playback behind schedule)."""
        self.counts["dropped"] += 1

    # ------------------------------------------------------------------ preprocessing
    def _check_input(self, image, timestamp, T_world_cam) -> None:
        if not isinstance(image, np.ndarray) or image.ndim not in (2, 3):
            raise InputError("image must be a 2-D (grey) or 3-D (colour) numpy array")
        if not np.isfinite(timestamp):
            raise InputError(f"timestamp {timestamp!r} is not finite")
        if self._last_ts is not None and timestamp <= self._last_ts:
            raise InputError(f"timestamps must increase: {timestamp!r} after {self._last_ts!r}")
        self._last_ts = float(timestamp)
        if self.pose_source == "given":
            if T_world_cam is None:
                raise InputError("pose_source='given' needs T_world_cam for every frame")
            if not np.all(np.isfinite(T_world_cam)):
                raise InputError(f"pose at t={timestamp} contains NaN")

    def _preprocess(self, image: np.ndarray, timestamp: float, depth: np.ndarray | None,
                    color: Any = None) -> _Frame:
        t = time.perf_counter()
        if image.ndim == 3:
            if color is None and image.shape[2] == 3:
                color = image
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if self._photometric is not None:
            image = self._photometric.correct(image, self._photometric.exposure_at(timestamp))
        img = self._rectifier(image)
        clipped = float(np.count_nonzero(img >= self.config.mapping.saturation)) / img.size
        if self._vig_pending is not None and self._verifier is None:
            self._adopt_vignette()
        inv = self._vig_inv[self._vig_version]
        if inv is not None:
            img = np.multiply(img, inv, dtype=np.float32)
        sharp = self._monitor.sharpness(img)
        pyr = image_pyramid(img, self.config.resolution.pyramid_levels)
        self.timers.add("preprocess", (time.perf_counter() - t) * 1e3)
        if self._t0 is None:
            self._t0 = float(timestamp)
        frame = _Frame(self._index, float(timestamp), img, pyr, depth, sharpness=sharp, color=color,
                       rectify_depth=self._rectifier.depth, clipped=clipped, vig=self._vig_version)
        if self._corner_rectifier is not None and (
                not self._initialized or self._verifier is not None
                or self._lost_count + 1 >= self.config.system.max_lost_frames):
            # a monocular start-up may begin (the first frame, or the frame whose loss re-initialises the
            # map: _process_tracking counts it lost first) or is on
            frame.corner_image = self._corner_rectifier(image)
        self._index += 1
        return frame

    # ------------------------------------------------------------------ tracking thread
    def _current_reference(self) -> _Reference | None:
        with self._ref_lock:
            return self._reference

    def _publish(self, ref: _Reference, mapper, frame: _Frame) -> None:
        with self._ref_lock:
            if mapper is not self._mapper:  # a map built by a mapper that was replaced meanwhile
                return
            self._reference = ref
            self._published.append(ref.map)
            scale_id = self._mapper_scale_id
        self._offer_keyframe(ref.map, frame, scale_id)
        if self._vignette is not None and not self._vignette.done and self._verifier is None:
            if self._vig_young > 0:
                self._vig_young -= 1
            else:
                self._offer_to_vignette([ref.map], ref.vig)

    # ------------------------------------------------------------------ the vignette estimated during the run
    def vignette_summary(self) -> dict | None:
        """What the vignette estimate during the run did (run.json ``vignette_during_run``), None when off."""
        v = self._vignette
        if v is None:
            return None
        return {"corrections": len(self._vig_from), "from_frames": list(self._vig_from),
                "corner": self._vig_corner, "ended": v.reason if v.done else "still estimating when the run ended"}

    def _vignette_call(self, fn, *args) -> None:
        """Run ``fn(*args)`` (a call on the vignette estimator) here, or in realtime mode queued on its thread."""
        if self._vig_worker is None:
            fn(*args)
        else:
            self._vig_worker.submit(fn, *args)

    def _offer_to_vignette(self, maps: list, vig: int) -> None:
        self._vignette_call(self._offer_to_vignette_now, maps, vig)

    def _offer_to_vignette_now(self, maps: list, vig: int) -> None:
        t = time.perf_counter()
        est = self._vignette
        try:
            inv = est.offer_maps(maps, vig)
        except Exception as err:          # the run goes on uncorrected rather than failing (realtime: its own thread)
            log.warning("vignette estimate during the run failed (%s: %s); the images stay as they are",
                        type(err).__name__, err)
            est.stop(f"failed: {type(err).__name__}: {err}")
            inv = None
        if inv is not None:
            with self._vig_lock:
                self._vig_pending = (est.version, inv, est.corner)
        self.timers.add("vignette", (time.perf_counter() - t) * 1e3)

    @property
    def vignette_estimate(self):
        """The :class:`~lite_vo.vignette.OnlineVignette` of ``system.auto_vignette`` (``version``: corrections
        applied so far, ``vignette``: the newest at mapping resolution, ``done`` / ``reason``), or None when off."""
        return self._vignette

    def _vig_ratio(self, old: int, new: int) -> np.ndarray:
        """The image in correction ``new`` over the same image in correction ``old``."""
        a, b = self._vig_inv[old], self._vig_inv[new]
        one = np.ones((self.map_intrinsics.height, self.map_intrinsics.width), np.float32)
        return (one if b is None else b) / (one if a is None else a)

    def _adopt_vignette(self, first: int | None = None) -> None:
        """Tracking thread, between start-ups: the frames from this one on are corrected with the newest
        estimate; the keyframes' images are re-expressed in it (the tracking reference and the mapper's
        images follow when they next meet a frame of the new correction)."""
        with self._vig_lock:
            version, inv, corner = self._vig_pending
            self._vig_pending = None
            old = self._vig_version
            self._vig_inv[version] = inv
            self._vig_version = version
            self.keyframes.rescale_images(self._vig_ratio(old, version))
            if self._relocalizer is not None:
                self._relocalizer.forget(())       # its cached references were made from the old images
            self._vig_from.append(self._index if first is None else first)
            self._vig_corner = corner
        self._prev_tracked = None     # the exposure-step check compares patch means of one correction only
        log.info("frame %d on: images corrected with the vignette estimated during the run (correction %d)",
                 self._index if first is None else first, version)

    def _in_correction(self, ref: _Reference, vig: int) -> _Reference:
        """``ref`` with its image in correction ``vig`` (rebuilt once per new correction; the system's
        current reference is replaced by the rebuilt one unless a newer map arrived meanwhile)."""
        if ref.vig == vig:
            return ref
        m = ref.map
        img = np.multiply(m.image, self._vig_ratio(ref.vig, vig), dtype=np.float32)
        img.setflags(write=False)
        frame = _Frame(m.frame_index, m.timestamp, img, image_pyramid(img, self.config.resolution.pyramid_levels),
                       None, T_world_cam=np.array(m.T_world_cam), affine=ref.affine, vig=vig)
        new = self._build_reference(frame, m.idepth_raw, m.idepth_var_raw, m.valid)
        with self._ref_lock:
            if self._reference is ref:
                self._reference = new
        return new

    def _mapper_in_correction(self, mapper, vig: int) -> None:
        """Re-express ``mapper``'s stored images in correction ``vig`` when they are in another one."""
        if mapper.image_version != vig:
            mapper.rescale_images(self._vig_ratio(mapper.image_version, vig), vig)

    def _offer_keyframe(self, m: PublishedMap, frame: _Frame, scale_id: int) -> None:
        """Keep the map (of scale ``scale_id``) as a keyframe when the camera moved enough since the last one."""
        if not self.keyframes.wants(m.T_world_cam, scale_id):
            return
        color = frame.color
        if callable(color):            # deferred: decoded now, at a reduced size when the rectifier allows
            color = color(self._rectifier.color_reduction)
        if color is not None:
            color = self._rectifier.color(color)
        with self._vig_lock:            # the store holds images in the newest adopted correction
            image = m.image
            if frame.vig != self._vig_version:
                image = np.multiply(image, self._vig_ratio(frame.vig, self._vig_version), dtype=np.float32)
            self.keyframes.add(Keyframe.make(m.frame_index, m.timestamp, m.T_world_cam, m.camera, image, m.idepth,
                                             m.idepth_var, color, scale_id))

    def _build_reference(self, frame: _Frame, idepth, idepth_var, valid) -> _Reference:
        t = time.perf_counter()
        tref = TrackingReference.build(frame.pyramid, idepth, idepth_var, valid, self.map_intrinsics, frame.index,
                                       smooth_sigma=self.config.tracking.smooth_sigma,
                                       min_level=self.track_level,
                                       point_stride=self.config.tracking.point_stride,
                                       coarse_point_stride=self.config.tracking.coarse_point_stride)
        self.timers.add("build_reference", (time.perf_counter() - t) * 1e3)
        arrays = [np.array(a) for a in (idepth, idepth_var, valid)]
        for a in arrays:
            a.setflags(write=False)
        T = frame.T_world_cam.copy()
        T.setflags(write=False)
        published = PublishedMap(frame.index, frame.timestamp, T, self.map_intrinsics, frame.image, *arrays)
        return _Reference(tref, published, affine=frame.affine, vig=frame.vig)

    def _new_mapper(self):
        seed = self._rng_seed + self._mapper_count
        self._mapper_count += 1
        return Mapper(self.config.mapping, self.map_intrinsics, seed=seed)

    def _install_mapper(self, mapper, frame: _Frame) -> None:
        """Make ``mapper`` (already initialised in ``frame``) the system's map and publish it."""
        idepth, idepth_var, valid = mapper.current()
        ref = self._build_reference(frame, idepth, idepth_var, valid)
        self._stop_mapping_work()
        with self._ref_lock:
            self._mapper = mapper
            self._mapper_scale_id = self._scale_id
        self._tracker.reset_motion_history()
        self._restart_vignette_pairs()
        self._publish(ref, mapper, frame)

    def _restart_vignette_pairs(self) -> None:
        if self._vignette is not None:
            self._vignette_call(self._vignette.restart)

    def _initialize(self, frame: _Frame, T_world_cam: np.ndarray, event: str) -> FrameResult:
        """(Re-)initialise the map in ``frame`` (depth image or random depth) with a new mapper."""
        use_depth = self._depth_start(frame)
        if use_depth and frame.depth_m is None:
            raise InputError("init=depth needs a depth image for the first frame (the sequence has none)")
        frame.T_world_cam = T_world_cam
        frame.affine = self._monitor.affine          # the new map keeps the brightness chain
        mf = MapFrame(frame.index, frame.timestamp, frame.image, T_world_cam, 0.0, frame.affine, frame.noise_sigma)
        mapper = self._new_mapper()
        mapper.image_version = frame.vig
        # a random map's first maps are no vignette evidence (their depths are still the random guesses); a
        # monocular start-up's two-view map replaces them anyway (and sets this back)
        self._vig_young = 0 if use_depth else VIGNETTE_YOUNG_MAPS + 1
        if self._initialized and not use_depth and self.pose_source == "estimate":
            self._scale_id += 1             # a new monocular map: a new scale
        if use_depth:
            mapper.initialize_from_depth(mf, frame.depth_m)
        else:
            mapper.initialize_random(mf)
            if self.pose_source == "estimate" and (frame.clipped > BLOWN_OUT_START
                                                   or self._clipped_centre(frame) > BLOWN_OUT_START_CENTRE):
                log.warning("the monocular start-up begins on frame %d with %.0f %% of its pixels clipped (%.0f %% of its "
                            "centre; auto-exposure still settling?): its corners and first map come from the rest of the "
                            "image, which costs accuracy; start the run where the image is no longer blown out "
                            "(--start-frame), or let the start-up wait for it (system.start_max_clipped, "
                            "system.start_max_clipped_centre, system.start_max_wait_s)",
                            frame.index, 100 * frame.clipped, 100 * self._clipped_centre(frame))
            elif frame.textured < self.config.system.start_min_textured and self.pose_source == "estimate":
                log.warning("the monocular start-up begins on frame %d with only %.0f %% of its pixels textured enough "
                            "for a map (black or very dark: the camera still opening?) after waiting %.1f s "
                            "(system.start_max_wait_s): it may be lost until the map is re-initialised",
                            frame.index, 100 * frame.textured, self.config.system.start_max_wait_s)
        self._install_mapper(mapper, frame)
        self._verifier = None
        if not use_depth and self.config.system.verify_init and self.pose_source == "estimate":
            fine = frame.corner_image is not None
            self._verifier = InitVerifier(self.config.system, self.map_intrinsics, frame.image, T_world_cam,
                                          frame.index, frame.timestamp, self.config.tracking.saturation,
                                          self._corner_rectifier.intrinsics if fine else None, frame.corner_image)
            self._recent_affine[frame.index] = frame.affine
        frame.corner_image = None
        if event == "init":
            self._start_pose, self._start_affine = T_world_cam.copy(), frame.affine
            self._start_pyramid = frame.pyramid if self._waited else None
        if use_depth and self._waited:
            self._late_corrections.update(self._backfill_waited())    # a metric map: nothing to resolve first
        if self._verifier is None:
            self._waited = []       # no start-up to resolve (verify_init off): the skipped frames keep no pose
        self._initialized = True
        self.metric = bool(use_depth)
        self._accept_pose(T_world_cam.copy(), frame.timestamp, smooth=False)
        self.counts["tracked"] += 1
        if event == "reinit":
            self.counts["reinit"] += 1
        quality = {"init": "depth" if use_depth else "random", "clipped": frame.clipped}
        if math.isfinite(frame.clipped_centre):
            quality["clipped_centre"] = frame.clipped_centre
        return FrameResult(frame.index, frame.timestamp, T_world_cam.copy(), False, quality, mapped=True, event=event)

    def _depth_start(self, frame: _Frame) -> bool:
        """Whether a map started in ``frame`` starts from its depth image (``system.init``; ``auto``: when it has one)."""
        init = self.config.system.init
        return init == "depth" or (init == "auto" and frame.depth_native is not None)

    def _unusable_for_a_map(self, frame: _Frame) -> bool:
        """Whether a map should not start in this frame: too much of it clipped (``system.start_max_clipped``,
        or of its centre: ``system.start_max_clipped_centre``) or too little of it textured (:meth:`_textureless`)."""
        sc = self.config.system
        if sc.start_max_clipped < 1.0:           # 1: no wait for clipping at all
            if frame.clipped > sc.start_max_clipped:
                return True
            if sc.start_max_clipped_centre < 1.0 and self._clipped_centre(frame) > sc.start_max_clipped_centre:
                return True
        return self._textureless(frame)

    def _clipped_centre(self, frame: _Frame) -> float:
        """The share of the pixels within :data:`CENTRE_RADIUS` of the principal point that are clipped (at or
        above ``mapping.saturation`` before the vignette estimated during the run corrects them, as
        ``frame.clipped``); measured once per frame, only where a map may start."""
        if not math.isfinite(frame.clipped_centre):
            if self._centre_mask is None or self._centre_mask.shape != frame.image.shape:
                h, w = frame.image.shape
                cx, cy = self.map_intrinsics.cx, self.map_intrinsics.cy
                far = max(math.hypot(x - cx, y - cy) for x in (-0.5, w - 0.5) for y in (-0.5, h - 0.5))
                yy, xx = np.mgrid[:h, :w]
                self._centre_mask = np.hypot(xx - cx, yy - cy) < CENTRE_RADIUS * far
            sat = self.config.mapping.saturation
            inv = self._vig_inv[frame.vig]
            centre = frame.image[self._centre_mask]
            clipped = centre >= (sat if inv is None else sat * inv[self._centre_mask])
            frame.clipped_centre = float(np.count_nonzero(clipped)) / max(centre.size, 1)
        return frame.clipped_centre

    def _textureless(self, frame: _Frame) -> bool:
        """Whether too little of the frame has the gradient a hypothesis needs (``system.start_min_textured``:
        black, very dark or nearly all white; a camera still opening or covered): no map starts there, and a
        lost frame like this is not relocalised (nothing to align; a relocalisation costs tens of ms)."""
        sc = self.config.system
        if sc.start_min_textured <= 0.0:
            return False
        if not math.isfinite(frame.textured):
            frame.textured = float(np.count_nonzero(image_gradients(frame.image)[2] >= self.config.mapping.min_grad)
                                   ) / frame.image.size
        return frame.textured < sc.start_min_textured

    def _waits_for_exposure(self, frame: _Frame) -> bool:
        """Whether a start skips this frame while the wait (``system.start_max_wait_s`` from the first skipped
        frame) lasts: a monocular start when it is blown out or black (:meth:`_unusable_for_a_map`), a start
        from a depth image only when it is black or very dark (:meth:`_textureless`: the depth is good, but
        tracking needs the image's gradients; a clipped part leaves the rest to track)."""
        if not (self._textureless(frame) if self._depth_start(frame) else self._unusable_for_a_map(frame)):
            return False
        if self._wait_t0 is None:
            self._wait_t0 = frame.timestamp
        return frame.timestamp - self._wait_t0 < self.config.system.start_max_wait_s

    def _process_tracking(self, frame: _Frame, t_start: float) -> FrameResult:
        if not self._initialized and self._waits_for_exposure(frame):
            self.counts["waited"] += 1
            lvl = self.track_level      # only the levels tracking reads are kept
            self._waited.append((frame.index, frame.timestamp, [None] * lvl + list(frame.pyramid[lvl:]),
                                 frame.sharpness))
            self._t0 = None          # the run's start-up phase (map_every_startup) begins with the first used frame
            self.timers.add("tracking", (time.perf_counter() - t_start) * 1e3)
            quality = {"clipped": frame.clipped}
            if math.isfinite(frame.clipped_centre):
                quality["clipped_centre"] = frame.clipped_centre
            if math.isfinite(frame.textured):
                quality["textured"] = frame.textured
            return FrameResult(frame.index, frame.timestamp, None, True, quality, event="waiting")
        if not self._initialized:
            result = self._initialize(frame, np.eye(4), "init")
            self.timers.add("tracking", (time.perf_counter() - t_start) * 1e3)
            return result
        ref = self._in_correction(self._current_reference(), frame.vig)
        T_ref_world = inverse_se3(ref.T_world_ref)
        base = self._last_pose if self._lost_count == 0 else self._last_good_pose
        guess_world = base @ self._velocity_over(frame.timestamp) if self.config.tracking.constant_velocity else base
        T_guess = T_ref_world @ guess_world
        sigma = self._tracking_sigma(frame)
        measured = None
        if self._verifier is not None and self.config.tracking.affine_brightness:
            # the corners' patch means measure the brightness independently of the depths
            rel = self._verifier.observe(frame.index, frame.image if frame.corner_image is None else frame.corner_image)
            init_affine = self._recent_affine.get(self._verifier.index0)
            if rel is not None and init_affine is not None:
                measured = affine_transfer(ref.affine, compose_affine(init_affine, rel))
        motion = (T_ref_world @ base, self._velocity)
        affine_guess = self._monitor.affine_guess(ref.affine)
        tr = self._tracker.track(ref.tracking_ref, frame.pyramid, T_guess, affine_guess, sigma, motion=motion)
        if measured is not None and _brightness_disagrees(tr.affine, measured):
            # on an unverified random map a free gain can collapse (shrinks towards 0, the offset
            # towards the mean): track again holding the measured brightness
            held = self._tracker.track(ref.tracking_ref, frame.pyramid, T_guess, measured, sigma, motion=motion,
                                       fix_affine=True)
            held.level_ms = {k: v + tr.level_ms.get(k, 0.0) for k, v in held.level_ms.items()}
            tr = held
        if self._verifier is not None and tr.lost_reason in ("residual too large", "implausible brightness change"):
            # an unverified random map: its residuals are large by nature (worse the brighter the
            # frame); a frame lost now is never mapped, so the map never converges, and the two-view
            # check replaces the map and these poses if the tracked motion is wrong. A gain beyond the
            # bound that the corners measured too is real (an exposure ramping up while the camera
            # opens: 2.3x against a reference that lost frames never replace)
            measured_gain = measured is not None and not _brightness_disagrees(tr.affine, measured)
            tr.lost_reason = self._tracker.lost_reason(tr, check_residual=False, check_gain=not measured_gain)
            tr.lost = bool(tr.lost_reason)
        if tr.lost_reason == "implausible brightness change" and self._gain_change_is_real(tr, ref, frame, affine_guess):
            tr.lost_reason = self._tracker.lost_reason(tr, check_residual=self._verifier is None, check_gain=False)
            tr.lost = bool(tr.lost_reason)
        for lvl, ms in tr.level_ms.items():
            self.timers.add(f"track_lvl{lvl}", ms)
        quality = {"residual": float(tr.residual), "good_ratio": float(tr.good_ratio), "hypothesis": tr.hypothesis,
                   "inside_ratio": float(tr.inside_ratio), "points_used": int(tr.points_used),
                   "sharpness": float(frame.sharpness), "affine_a": tr.affine[0], "affine_b": tr.affine[1],
                   "lost_reason": tr.lost_reason, "clipped": frame.clipped}
        lost = bool(tr.lost) or not np.all(np.isfinite(tr.T_ref_new))
        if not lost:
            self._book_brightness(frame, ref.affine, tr)
            self._recent_affine[frame.index] = frame.affine
            self._recent_affine.pop(frame.index - 1000, None)
        quality["noise_sigma"] = float(self._monitor.noise_sigma)
        if not lost:   # the frame's brightness in the chain: I = A * J + B (J: the first frame's)
            quality["brightness_a"], quality["brightness_b"] = float(frame.affine[0]), float(frame.affine[1])
        T_world_new = None if lost else project_to_se3(ref.T_world_ref @ tr.T_ref_new)
        if self._verifier is not None:
            decision = self._verifier.add(frame.index, frame.timestamp, frame.image, T_world_new, frame.corner_image)
            # the corner image stays until the frame is handed on: a lost frame may still start a new map
            if decision is not None:
                self._verifier = None
                if isinstance(decision, str) and self._waited:     # the random map stays: its world and scale
                    self._late_corrections.update(self._backfill_waited())
                if not isinstance(decision, str):
                    frame.corner_image = None
                    result = self._apply_bootstrap(decision, frame, quality)
                    self.timers.add("tracking", (time.perf_counter() - t_start) * 1e3)
                    return result
        if lost and self._relocalizer is not None and self._verifier is None and not self._textureless(frame):
            result = self._relocalise(frame, quality, sigma)
            if result is not None:
                self.timers.add("tracking", (time.perf_counter() - t_start) * 1e3)
                return result
        if lost:
            self._lost_count += 1
            self.counts["lost"] += 1
            self.timers.add("tracking", (time.perf_counter() - t_start) * 1e3)
            if self._lost_count >= self.config.system.max_lost_frames and self._last_good_pose is not None \
                    and not self._defers_reinit(frame):
                self._reinit_wait_t0 = None
                log.warning("tracking lost for %d frames: re-initialising the map at frame %d (a new map%s)",
                            self._lost_count - 1, frame.index, "" if self.metric else " with a new scale")
                self.counts["tracked"] -= 1  # _initialize counts it; this frame is the new start
                res = self._initialize(frame, self._last_good_pose.copy(), "reinit")
                self.counts["tracked"] += 1
                self.counts["lost"] -= 1
                return res
            return FrameResult(frame.index, frame.timestamp, None, True, quality, event="lost")
        event = "recovered" if self._lost_count > 0 else ""
        self._accept_pose(T_world_new, frame.timestamp, smooth=self._lost_count == 0)
        frame.T_world_cam = T_world_new
        frame.residual = float(tr.residual)
        self.counts["tracked"] += 1
        self.timers.add("tracking", (time.perf_counter() - t_start) * 1e3)
        mapped = self._hand_to_mapping(frame)
        return FrameResult(frame.index, frame.timestamp, T_world_new.copy(), False, quality,
                           mapped=mapped, event=event)

    def _relocalise(self, frame: _Frame, quality: dict, sigma: float) -> FrameResult | None:
        """Re-track a lost frame against stored keyframes of the current scale; on success the
        keyframe's map (same world frame and scale) becomes the current map."""
        t = time.perf_counter()
        kfs = [k for k in self.keyframes.snapshot() if k.scale_id == self._scale_id]
        self._relocalizer.forget(k.index for k in kfs)
        rel = self._relocalizer.relocalise(kfs, self._last_good_pose, frame.pyramid, frame.image,
                                           (1.0, 0.0), sigma)
        self.timers.add("relocalise", (time.perf_counter() - t) * 1e3)
        if rel is None:
            return None
        kf = rel.keyframe
        img = np.asarray(kf.image, dtype=np.float32)
        kf_frame = _Frame(kf.index, kf.timestamp, img, image_pyramid(img, self.config.resolution.pyramid_levels),
                          None, T_world_cam=np.array(kf.T_world_cam, dtype=np.float64),
                          affine=self._monitor.affine, vig=self._vig_version)     # the store is in the newest correction
        mapper = self._new_mapper()
        mapper.image_version = self._vig_version
        mapper.initialize_from_idepth(MapFrame(kf.index, kf.timestamp, img, kf_frame.T_world_cam, 0.0,
                                               kf_frame.affine), kf.idepth, kf.idepth_var)
        idepth, idepth_var, valid = mapper.current()
        ref = self._build_reference(kf_frame, idepth, idepth_var, valid)
        self._stop_mapping_work()
        with self._ref_lock:              # installed, not published: the keyframe's map is already stored
            self._mapper = mapper
            self._mapper_scale_id = self._scale_id      # the keyframe's (only those of this scale are tried)
            self._reference = ref
        self._tracker.reset_motion_history()
        tr = rel.result
        self._book_brightness(frame, ref.affine, tr)
        T_world_new = rel.T_world_new
        log.info("relocalised frame %d against keyframe %d (%s guess, %d tracking calls)", frame.index,
                 kf.index, rel.guess, rel.tried)
        self._accept_pose(T_world_new, frame.timestamp, smooth=False)
        frame.T_world_cam = T_world_new
        frame.residual = float(tr.residual)
        self.counts["tracked"] += 1
        self.counts["relocalised"] += 1
        quality = {**quality, "residual": float(tr.residual), "good_ratio": float(tr.good_ratio),
                   "inside_ratio": float(tr.inside_ratio), "points_used": int(tr.points_used),
                   "keyframe": int(kf.index), "reloc_guess": rel.guess, "affine_a": tr.affine[0],
                   "affine_b": tr.affine[1], "brightness_a": float(frame.affine[0]),
                   "brightness_b": float(frame.affine[1]), "lost_reason": ""}
        mapped = self._hand_to_mapping(frame)
        return FrameResult(frame.index, frame.timestamp, T_world_new.copy(), False, quality, mapped=mapped,
                           event="relocalised")

    def _defers_reinit(self, frame: _Frame) -> bool:
        """Whether a re-initialisation that is due waits for a better frame: this one is blown out or black
        (:meth:`_unusable_for_a_map`: a covered lens, a lamp filling the view) and the wait has lasted less
        than ``system.start_max_wait_s``. A map started in it would be lost again, and a monocular one would
        take a new scale, which the relocalisation against the earlier keyframes cannot cross."""
        if not self._unusable_for_a_map(frame):
            return False
        if self._reinit_wait_t0 is None:
            self._reinit_wait_t0 = frame.timestamp
            log.info("re-initialisation due at frame %d waits for a frame that is not blown out or black", frame.index)
        return frame.timestamp - self._reinit_wait_t0 < self.config.system.start_max_wait_s

    def _accept_pose(self, T_world_new: np.ndarray, t: float, smooth: bool) -> None:
        """Book-keeping of a tracked pose (of the frame at time ``t``): velocity (constant-velocity guess) and
        last poses."""
        if smooth and self._last_pose is not None:
            self._velocity = inverse_se3(self._last_pose) @ T_world_new
            self._velocity_dt = t - self._pose_t
        else:
            self._velocity = np.eye(4)
            self._velocity_dt = 0.0
        self._pose_t = t
        self._lost_count = 0
        self._reinit_wait_t0 = None
        self._last_pose = T_world_new
        self._last_good_pose = T_world_new

    def _gain_change_is_real(self, tr, ref: _Reference, frame: _Frame, affine_guess: tuple) -> bool:
        """Whether a gain beyond ``tracking.max_gain_change`` against the reference is a real exposure change."""
        if self._prev_tracked is not None:
            # an exposure step (auto-exposure jumping by more than the bound in one frame) is real when the
            # last tracked frame and this one, nearly the same view, show the same change on patch means
            prev_image, prev_affine = self._prev_tracked
            rel = _aligned_brightness(prev_image, frame.pyramid[self.track_level], self.config.tracking.saturation)
            if rel is not None and not _brightness_disagrees(
                    tr.affine, affine_transfer(ref.affine, compose_affine(prev_affine, rel))):
                return True
        if self._after_gap(frame.timestamp):
            # after a gap in the input (frames dropped, a stalled reader or sink) the exposure had longer to change
            # than the gain's bound against the reference allows; the change is real when it continues the
            # brightness chain (a collapsed gain does not)
            bound = self.config.tracking.max_gain_change
            return affine_guess[0] > 0 and 1.0 / bound <= tr.affine[0] / affine_guess[0] <= bound
        return False

    def _after_gap(self, t: float) -> bool:
        """Whether a frame at time ``t`` comes more than ``GAP_FACTOR`` times the last motion's time after the last
        good pose (frames dropped in realtime mode, a stalled input, lost frames)."""
        return self._velocity_dt > 0 and t - self._pose_t > GAP_FACTOR * self._velocity_dt

    def _velocity_over(self, t: float) -> np.ndarray:
        """The constant-velocity motion from the last good pose to a frame at time ``t``: the last motion,
        scaled to the time since that pose when it differs from the last motion's by more than
        ``VELOCITY_TIME_RATIO`` (frames dropped in realtime mode, a stalled input, lost frames; evenly
        spaced frames keep the plain per-frame velocity)."""
        dt = self._velocity_dt
        if not dt > 0:
            return self._velocity
        r = (t - self._pose_t) / dt
        if not r > 0 or 1.0 / VELOCITY_TIME_RATIO <= r <= VELOCITY_TIME_RATIO:
            return self._velocity
        return exp_se3(r * log_se3(self._velocity))

    def _apply_bootstrap(self, boot, frame: _Frame, quality: dict) -> FrameResult:
        """Replace a badly initialised random map: replay the filter with two-view + PnP poses."""
        t = time.perf_counter()
        boot_world = boot.T_world_init
        mapper = self._new_mapper()
        mapper.image_version = frame.vig      # no new correction is adopted during a start-up
        idx0, ts0, img0 = boot.frames[0]
        # an empty map: with these poses, stereo searches the full depth range and creates the
        # hypotheses itself (a random prior would keep pixels whose guess is off by > 2 sigma)
        aff = dict(self._recent_affine)
        aff0 = aff.get(idx0, (1.0, 0.0))
        if self.config.tracking.affine_brightness:
            # the brightness measured on the two-view corners: frames where tracking was lost have no
            # chained estimate, and a chained one may have drifted with the random map
            for idx, rel in boot.affine_j_init.items():
                aff[idx] = compose_affine(aff0, rel)
        posed = [f for f in boot.frames[1:] if boot.T_j_init.get(f[0]) is not None]
        every = self.config.system.bootstrap_replay_every
        replay = [f for k, f in enumerate(posed) if (len(posed) - 1 - k) % every == 0]
        estimating = self._vignette is not None and not self._vignette.done

        def replayed_map(mapper, ratio):
            """The depth filter replayed into ``mapper`` over the start-up's frames (images times ``ratio``,
            if any), and its maps when the vignette is being estimated."""
            mapper.initialize_from_depth(MapFrame(idx0, ts0, img0 if ratio is None else img0 * ratio, boot_world, 0.0,
                                                  aff0), np.zeros_like(img0))
            maps = []
            for idx, ts, img in replay:
                T = boot_world @ inverse_se3(boot.T_j_init[idx])
                img = img if ratio is None else img * ratio
                mapper.update(MapFrame(idx, ts, img, T, 0.0, aff.get(idx, (1.0, 0.0))))
                if estimating:
                    maps.append(PublishedMap(idx, ts, T, self.map_intrinsics, img, *mapper.current()))
            return maps

        replayed = replayed_map(mapper, None)
        self._vig_young = 0
        if replayed:        # the replayed maps give the vignette estimate its first pairs right away ...
            self._restart_vignette_pairs()
            self._offer_to_vignette(replayed, frame.vig)
            if self._vig_pending is not None:
                # ... and when they give one, the start-up's map is rebuilt from corrected images and the
                # run goes on in the correction from this frame on
                old = frame.vig
                self._adopt_vignette(frame.index)
                ratio = self._vig_ratio(old, self._vig_version)
                mapper = self._new_mapper()
                mapper.image_version = self._vig_version
                replayed_map(mapper, ratio)
                frame.image = np.multiply(frame.image, ratio, dtype=np.float32)
                frame.pyramid = image_pyramid(frame.image, self.config.resolution.pyramid_levels)
                frame.vig = self._vig_version
        T_world_cur = project_to_se3(boot_world @ inverse_se3(boot.T_cur_init))
        frame.T_world_cam = T_world_cur
        if frame.index in boot.affine_j_init and self.config.tracking.affine_brightness:
            frame.affine = aff[frame.index]          # the chain goes on from the measured brightness
            self._monitor.affine = frame.affine
            self._recent_affine[frame.index] = frame.affine
        self._scale_id += 1                 # the two-view map has another scale than the random one
        self._install_mapper(mapper, frame)
        self._accept_pose(T_world_cur, frame.timestamp, smooth=False)
        self.counts["tracked"] += 1
        self.counts["bootstrap"] += 1
        self.timers.add("bootstrap", (time.perf_counter() - t) * 1e3)
        corrections = {}
        for idx, _, _ in boot.frames[1:]:
            if idx == frame.index:
                continue
            T = boot.T_j_init.get(idx)
            corrections[idx] = None if T is None else project_to_se3(boot_world @ inverse_se3(T))
        self.keyframes.apply_corrections(corrections)
        if self._waited:                # the frames skipped before the start-up, in the two-view map's world
            self._start_pose, self._start_affine = boot_world, aff0
            corrections.update(self._backfill_waited())
        quality = {**quality, "init": "bootstrap", "reason": boot.reason}
        idepth, _, valid = mapper.current()
        self._record_depth_accuracy(frame, idepth, valid)
        return FrameResult(frame.index, frame.timestamp, T_world_cur.copy(), False, quality, mapped=True,
                           event="bootstrap", corrections=corrections)

    def _backfill_waited(self) -> dict:
        """Poses for the frames a start skipped (:meth:`_waits_for_exposure`), once the start-up is resolved
        (a depth start: right away). The current map is warped into the start-up's first frame (its pose and brightness
        are known; the skipped frames are its neighbours, mostly clipped in the same places) and each
        skipped frame is tracked against it, newest first, from the previous one's pose and brightness
        (with the backward motion of the last two) until two in a row are lost. The brightness is also
        measured from each frame to the later one (patch means: on frames this clipped a free gain can
        collapse towards a flat bright image); a tracked estimate far from it is tracked again holding
        it. Returns ``{index: T_world_cam}``; the state for the frames to come is left as it was."""
        waited, self._waited = self._waited, []
        start, self._start_pyramid = self._start_pyramid, None
        cur = self._current_reference()
        if cur is None or self._start_pose is None or start is None:
            return {}
        m = cur.map
        T_start_cur = inverse_se3(self._start_pose) @ cur.T_world_ref
        idepth, var, valid = warp_idepth(m.idepth_raw, m.idepth_var_raw, m.valid, T_start_cur, self.map_intrinsics)
        tref = TrackingReference.build(start, idepth, var, valid, self.map_intrinsics, -1,
                                       smooth_sigma=self.config.tracking.smooth_sigma, min_level=self.track_level,
                                       point_stride=self.config.tracking.point_stride,
                                       coarse_point_stride=self.config.tracking.coarse_point_stride)
        tc = self.config.tracking
        ref_affine = self._start_affine
        T_world_ref = self._start_pose
        pose_ref, affine, step = np.eye(4), ref_affine, np.eye(4)       # pose in the start frame
        later = start[self.track_level]
        out: dict = {}
        misses = 0
        for index, _, pyramid, sharpness in reversed(waited):
            image = pyramid[self.track_level]
            rel = _aligned_brightness(later, image, tc.saturation)
            later = image
            measured = None if rel is None else compose_affine(affine, rel)
            sigma = self._monitor.tracking_sigma(tc.sigma_i, tc.noise_sigma_gain, sharpness)
            guess = pose_ref @ step
            first = affine_transfer(ref_affine, affine if measured is None else measured)
            tr = self._tracker.track(tref, pyramid, guess, first, sigma)
            if measured is not None:
                if _brightness_disagrees(tr.affine, first, BACKFILL_GAIN_TOL, BACKFILL_GREY_TOL):
                    tr = self._tracker.track(tref, pyramid, guess, first, sigma, fix_affine=True)
                # the gain agrees with (or is held at) the measured one: beyond the lost test's bound it is
                # real (a camera opening: a dark frame at a third of the start frame's brightness)
                tr.lost_reason = self._tracker.lost_reason(tr, bool(np.all(np.isfinite(tr.T_ref_new))),
                                                           check_gain=False)
                tr.lost = bool(tr.lost_reason)
            if tr.lost or not np.all(np.isfinite(tr.T_ref_new)):
                misses += 1
                if misses == 2:
                    break
                if measured is not None:
                    affine = measured
                continue
            misses = 0
            T = project_to_se3(tr.T_ref_new)
            step = inverse_se3(pose_ref) @ T
            pose_ref, affine = T, compose_affine(ref_affine, tr.affine)
            out[index] = project_to_se3(T_world_ref @ T)
        log.info("the start-up skipped %d frames (blown out or too dark); %d of them got a pose, tracked backwards "
                 "against the map",
                 len(waited), len(out))
        self.counts["backfilled"] += len(out)
        return out

    def _process_given_pose(self, frame: _Frame, T_world_cam: np.ndarray, t_start: float) -> FrameResult:
        T_world_cam = np.asarray(T_world_cam, dtype=np.float64)
        if not self._initialized:
            res = self._initialize(frame, T_world_cam.copy(), "init")
            self._record_depth_accuracy(frame)
            return res
        frame.T_world_cam = T_world_cam.copy()
        quality = self._given_pose_brightness(frame) if self.config.tracking.affine_brightness else {}
        self.counts["tracked"] += 1
        mapped = self._hand_to_mapping(frame)
        return FrameResult(frame.index, frame.timestamp, T_world_cam.copy(), False, quality, mapped=mapped)

    def _tracking_sigma(self, frame: _Frame) -> float:
        """Intensity noise std of the tracking weights for this frame (noise estimate, blur)."""
        tc = self.config.tracking
        return self._monitor.tracking_sigma(tc.sigma_i, tc.noise_sigma_gain, frame.sharpness)

    def _book_brightness(self, frame: _Frame, ref_affine: tuple, tr) -> None:
        """The frame's brightness in the chain (and the smoothed noise) from an accepted alignment ``tr``
        against a reference of brightness ``ref_affine``."""
        frame.affine = self._monitor.accept(ref_affine, tr.affine, tr.residual_sigma, tr.noise_sigma)
        frame.noise_sigma = self._monitor.noise_sigma

    def _given_pose_brightness(self, frame: _Frame) -> dict:
        """The frame's brightness in the chain when the pose is given (no tracking of its own): the
        tracker aligns the frame to the current map from the given pose and only its brightness
        estimate ``(a, b)`` is kept, so mapping compares exposure-compensated intensities as it does
        for tracked frames. A failed alignment (a map still too young, a bad view) keeps the last
        brightness."""
        ref = self._current_reference()
        if ref is None:
            return {}
        ref = self._in_correction(ref, frame.vig)
        sigma = self._tracking_sigma(frame)
        T_ref_new = inverse_se3(ref.T_world_ref) @ frame.T_world_cam
        tr = self._tracker.track(ref.tracking_ref, frame.pyramid, T_ref_new, self._monitor.affine_guess(ref.affine), sigma)
        if tr.lost or not np.all(np.isfinite(tr.affine)):
            frame.affine = self._monitor.affine
            return {"brightness_lost_reason": tr.lost_reason}
        self._book_brightness(frame, ref.affine, tr)
        return {"brightness_a": float(frame.affine[0]), "brightness_b": float(frame.affine[1]),
                "noise_sigma": float(self._monitor.noise_sigma)}

    def _process_rgbd(self, frame: _Frame, t_start: float) -> FrameResult:
        """Frame-to-frame RGB-D odometry: track against the previous frame's depth image."""
        if frame.depth_m is None:
            raise InputError(f"depth_source='images' needs a depth image for every frame (frame {frame.index} has none)")
        prev = self._prev_depth_frame
        if prev is None:
            T_world_new = np.eye(4)
            quality: dict = {"init": "depth"}
            lost = False
            self._initialized = True
            self.metric = True
        else:
            idepth, valid = depth_image_idepth(prev.image, prev.depth_m, self.config.tracking)
            var = np.full_like(idepth, self.config.mapping.depth_init_var)
            ref = self._build_reference(prev, idepth, var, valid)
            base = self._last_pose
            guess_world = base @ self._velocity if self.config.tracking.constant_velocity else base
            tr = self._tracker.track(ref.tracking_ref, frame.pyramid, inverse_se3(prev.T_world_cam) @ guess_world)
            for lvl, ms in tr.level_ms.items():
                self.timers.add(f"track_lvl{lvl}", ms)
            quality = {"residual": float(tr.residual), "good_ratio": float(tr.good_ratio),
                       "inside_ratio": float(tr.inside_ratio), "points_used": int(tr.points_used)}
            lost = bool(tr.lost) or not np.all(np.isfinite(tr.T_ref_new))
            # RGB-D odometry has no map to recover with: keep the last pose as the new reference
            T_world_new = project_to_se3(prev.T_world_cam @ tr.T_ref_new) if not lost else self._last_pose
            self._velocity = inverse_se3(self._last_pose) @ T_world_new if not lost else np.eye(4)
        frame.T_world_cam = T_world_new
        self._last_pose = T_world_new
        self._prev_depth_frame = frame
        self.counts["lost" if lost else "tracked"] += 1
        self.timers.add("tracking", (time.perf_counter() - t_start) * 1e3)
        return FrameResult(frame.index, frame.timestamp, None if lost else T_world_new.copy(), lost, quality,
                           event="lost" if lost else ("init" if prev is None else ""))

    def _mapping_due(self, frame: _Frame) -> bool:
        s = self.config.system
        every = s.map_every_startup if frame.timestamp - self._t0 < s.startup_s else s.map_every
        return frame.index % every == 0

    def _hand_to_mapping(self, frame: _Frame) -> bool:
        frame.corner_image = None           # followed by the start-up check (if any): not kept with the frame
        frame.mapper = self._mapper
        if frame.sharpness < self.config.system.blur_min_sharpness:
            return False  # motion blur: tracked only (no stereo reference, no map in it, no new hypotheses)
        if self._thread is None:  # sync
            if not self._mapping_due(frame):
                # not mapped, but still a stereo reference for later frames
                self._mapper_in_correction(self._mapper, frame.vig)
                self._mapper.add_reference(MapFrame(frame.index, frame.timestamp, frame.image,
                                                    frame.T_world_cam, frame.residual, frame.affine,
                                                    frame.noise_sigma))
                return False
            self._map_frame(frame)
            return True
        if not self._mapping_due(frame):
            return False  # realtime maps at most as often as sync mode (start-up throttle, map_every)
        with self._cond:  # realtime: replace (skip) an older pending frame
            self._pending = frame
            self._cond.notify()
        return False

    def _stop_mapping_work(self) -> None:
        """Drop a pending frame (used before re-initialisation)."""
        with self._cond:
            self._pending = None

    # ------------------------------------------------------------------ mapping thread
    def _mapping_loop(self) -> None:
        try:
            if self.config.system.numba_threads > 0:  # numba's thread count is per calling thread
                numba.set_num_threads(min(self.config.system.numba_threads, numba.config.NUMBA_NUM_THREADS))
            while True:
                with self._cond:
                    while self._pending is None and not self._stop:
                        self._cond.wait()
                    if self._pending is None and self._stop:
                        return
                    frame, self._pending = self._pending, None
                self._map_frame(frame)
        except BaseException as err:  # surfaced in the tracking thread
            log.exception("mapping thread failed")
            self._map_error = err

    def _map_frame(self, frame: _Frame) -> None:
        t = time.perf_counter()
        mapper = frame.mapper
        if mapper is not self._mapper:
            return  # tracked against a map that was replaced meanwhile (other scale): skip it
        mf = MapFrame(frame.index, frame.timestamp, frame.image, frame.T_world_cam, frame.residual, frame.affine,
                      frame.noise_sigma)
        self._mapper_in_correction(mapper, frame.vig)
        stats = mapper.update(mf)
        for name, ms in stats.stage_ms.items():
            self.timers.add(name, ms)
        idepth, idepth_var, valid = mapper.current()
        ref = self._build_reference(frame, idepth, idepth_var, valid)
        self.timers.add("mapping", (time.perf_counter() - t) * 1e3)
        self.counts["mapped"] += 1
        self._publish(ref, mapper, frame)
        self._record_depth_accuracy(frame, idepth, valid)

    def _record_depth_accuracy(self, frame: _Frame, idepth=None, valid=None) -> None:
        every = self.config.system.depth_eval_every
        if frame.depth_native is None or every <= 0:
            return
        self._depth_eval_count += 1
        if (self._depth_eval_count - 1) % every:
            return
        if idepth is None:
            idepth, _, valid = self._mapper.current()      # fresh arrays: nobody writes them afterwards
        # decoding the depth image (a 16-bit PNG: about 3 ms at 640x480) and comparing run on a worker
        # thread: nothing the VO does depends on the result, and one worker keeps the rows in order
        monocular = not (self.metric or self.pose_source == "given")
        with self._depth_lock:       # realtime mode: the tracking thread (initialisation) and the mapping thread
            if self._depth_eval is None:
                self._depth_eval = ThreadPoolExecutor(max_workers=1, thread_name_prefix="lite_vo-depth-eval")
            self._depth_jobs.append(self._depth_eval.submit(_evaluate_depth, frame, idepth, valid, monocular,
                                                            frame.timestamp - self._t0))
        self._drain_depth_jobs(wait=False)

