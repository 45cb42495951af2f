"""The :class:`Mapper`: the semi-dense inverse-depth map of the current frame and how it is maintained.

Owns: :class:`MapFrame` (one tracked frame handed to mapping), :class:`MappingStats`,
:class:`Mapper` (map state, the bounded buffer of past frames used as stereo references,
one mapping iteration = propagate + observe + regularise + fill), :func:`mapping_params` (the
kernels' parameter vector) and :func:`depth_accuracy`. The per-pixel work is done by the numba
kernels in ``_kernels.py``.

Threading: a Mapper is owned by ONE thread (the mapping thread, or the caller in sync mode).
All its members are written by that thread only; :meth:`Mapper.current` returns copies, so the
arrays it hands out can be read by another thread (tracking) without locks.

Imports: numpy, ``lite_vo.camera``, ``lite_vo.errors``, ``lite_vo.photometric`` and this package;
never tracking, system, io or anything of the AR demo.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numba
import numpy as np

from ..camera import PinholeIntrinsics
from ..errors import InputError
from ..photometric import affine_transfer
from . import _kernels as kernels
from ._kernels import MapState, RefFrames, fill_work, new_state, propagation_work, regularize_work
from .config import MappingConfig


@dataclass(frozen=True)
class MapFrame:
    """A tracked frame at the mapping resolution (image float32 0..255, pose T_world_cam).

    ``affine = (A, B)``: the frame's brightness relative to a common one, ``I = A * J + B`` (chained
    from the tracker's frame-to-reference estimates); stereo and propagation compare intensities of
    two frames after mapping one into the other's brightness. ``noise_sigma``: the frame's image
    noise estimate (grey levels; NaN = unknown): the photometric variance uses
    ``max(config.sigma_i, noise_sigma)``."""
    frame_id: int
    timestamp: float
    image: np.ndarray
    T_world_cam: np.ndarray
    tracking_residual: float = 0.0
    affine: tuple = (1.0, 0.0)
    noise_sigma: float = float("nan")



@dataclass
class MappingStats:
    """What one :meth:`Mapper.update` did. Times in ms; counts in pixels."""
    frame_id: int = -1
    stage_ms: dict = field(default_factory=dict)          # wall-clock ms per stage
    stage_cpu_ms: dict = field(default_factory=dict)      # CPU time of the calling thread per stage (Mapper.measure_cpu)
    propagated: int = 0         # hypotheses that survived propagation (after collisions)
    dropped_border: int = 0
    dropped_intensity: int = 0
    occluded: int = 0
    fused_on_propagation: int = 0
    candidates: int = 0         # pixels with gradient >= min_grad
    stride: int = 1             # candidate sub-sampling of the adaptive budget (1 = all)
    updated: int = 0            # successful stereo fusions
    created: int = 0            # new hypotheses from stereo
    inconsistent: int = 0
    failed: int = 0             # searches without a (good) match
    no_reference: int = 0       # no usable reference (line outside the image, scale change)
    no_epipolar: int = 0        # epipolar line too short / gradient along it too weak
    skipped_converged: int = 0  # converged pixels waiting for more baseline
    removed_gradient: int = 0
    removed_regularize: int = 0
    filled: int = 0
    valid_count: int = 0
    references: int = 0         # frames in the reference buffer

    @property
    def total_ms(self) -> float:
        return float(sum(self.stage_ms.values()))


_VAR_MODES = {"min": 0, "own": 1, "fused": 2}


def mapping_params(cfg: MappingConfig) -> np.ndarray:
    """The float64 parameter vector of the mapping kernels (layout: ``_kernels.P_*``), built once
    per configuration."""
    p = np.zeros(kernels.P_N, np.float64)
    p[kernels.P_MIN_GRAD] = cfg.min_grad
    p[kernels.P_MIN_EPL_LENGTH] = cfg.min_epl_length
    p[kernels.P_MIN_EPL_GRAD_SQ] = cfg.min_epl_grad_sq
    p[kernels.P_MIN_EPL_ANGLE_COS] = cfg.min_epl_angle_cos
    p[kernels.P_MAX_IDEPTH] = 1.0 / cfg.min_depth
    p[kernels.P_MAX_EPL] = cfg.max_epl_search
    p[kernels.P_MIN_EPL] = cfg.min_epl_search
    p[kernels.P_SSD_MAX] = cfg.ssd_max
    p[kernels.P_SSD_GRAD_FACTOR] = cfg.ssd_grad_factor
    p[kernels.P_AMBIGUITY] = cfg.ambiguity_factor
    p[kernels.P_MIN_SCALE] = cfg.min_scale
    p[kernels.P_MAX_SCALE] = cfg.max_scale
    p[kernels.P_SUBPIXEL] = 1.0 if cfg.subpixel else 0.0
    p[kernels.P_SIGMA_I2] = cfg.sigma_i ** 2
    p[kernels.P_MAX_VAR] = cfg.max_var
    p[kernels.P_PRED_NOISE] = cfg.prediction_noise
    p[kernels.P_FAIL_VAR_INC] = cfg.fail_var_inflation
    p[kernels.P_BORDER_SAMPLES] = cfg.search_border
    p[kernels.P_MIN_CLIPPED_EPL] = cfg.min_clipped_epl
    p[kernels.P_GEO_BASE] = cfg.geo_error_base
    p[kernels.P_SUBPIX_VAR] = cfg.subpixel_var
    p[kernels.P_NOSUBPIX_VAR] = cfg.no_subpixel_var
    p[kernels.P_SEARCH_SIGMAS] = cfg.search_sigmas
    p[kernels.P_DIFF_FAC_OBSERVE] = cfg.observe_diff_fac
    p[kernels.P_VALIDITY_INC] = cfg.validity_inc
    p[kernels.P_VALIDITY_DEC] = cfg.validity_dec
    p[kernels.P_VALIDITY_MAX] = cfg.validity_max
    p[kernels.P_VALIDITY_MAX_GRAD] = cfg.validity_max_grad
    p[kernels.P_OBSERVE_VALIDITY] = cfg.observe_validity
    p[kernels.P_CREATE_PRIOR] = cfg.create_prior_idepth
    p[kernels.P_MIN_BLACKLIST] = cfg.min_blacklist
    p[kernels.P_SKIP_CONVERGED] = cfg.converged_skip
    p[kernels.P_BORDER] = cfg.border
    p[kernels.P_PROP_DIFF_CONST2] = cfg.prop_diff_const ** 2
    p[kernels.P_PROP_DIFF_GRAD] = cfg.prop_diff_grad_fac
    p[kernels.P_PROP_MERGE] = cfg.prop_merge_fac
    p[kernels.P_PROP_VAR_ADD] = cfg.propagation_sigma
    p[kernels.P_VALIDITY_CAP] = cfg.validity_max + cfg.validity_max_grad
    p[kernels.P_REG_RADIUS] = cfg.reg_radius
    p[kernels.P_REG_DIST_VAR] = cfg.reg_dist_var
    p[kernels.P_REG_DIFF_FAC] = cfg.reg_diff_fac
    p[kernels.P_REG_VALIDITY_SUM] = cfg.reg_validity_sum
    p[kernels.P_REG_VAR_MODE] = _VAR_MODES[cfg.reg_var_mode]
    p[kernels.P_FILL_VALIDITY_SUM] = cfg.fill_validity_sum
    p[kernels.P_UNBLACKLIST_SUM] = cfg.unblacklist_validity_sum
    p[kernels.P_INIT_VAR] = cfg.init_var
    p[kernels.P_FILL_VALIDITY] = cfg.fill_validity
    p[kernels.P_SATURATION] = cfg.saturation
    p[kernels.P_SAT_GAIN_TOL] = cfg.saturation_gain_tol
    p[kernels.P_KEEP_CLIPPED] = 1.0 if cfg.keep_clipped else 0.0
    return p


def image_gradients(image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(gx, gy, maxgrad): half central differences and the 3x3 max filter of their magnitude."""
    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.ndim != 2:
        raise InputError(f"image_gradients: expected a 2-D image, got shape {img.shape}")
    gx = np.zeros(img.shape, np.float32)
    gy = np.zeros(img.shape, np.float32)
    mg = np.zeros(img.shape, np.float32)
    if img.shape[0] >= 1 and img.shape[1] >= 1:
        kernels.gradients_kernel(img, gx, gy, mg)
    return gx, gy, mg


@dataclass
class _Prepared:
    frame: MapFrame
    image: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    maxgrad: np.ndarray


def _no_clock() -> float:
    return 0.0


class Mapper:
    """Semi-dense inverse-depth filter for the newest tracked frame (no keyframes).

    Owned by one thread (the mapping thread). Members:
    ``config``, ``intrinsics`` (mapping resolution), ``state`` (per-pixel arrays),
    ``_cur`` (the frame the map lives in, with its gradients), ``_buffer`` (past frames, oldest
    first, images in the ring ``_buf_images``, inverse poses in ``_buf_T_ref_world``), ``_rng`` (seeded,
    random initialisation), the kernels' scratch (``_spare``: the other map of the double buffer,
    ``_prop_work``, ``_fill_work``, ``_reg_work``, ``_status``), ``measure_cpu`` (set it to also record
    each stage's thread CPU time in ``stage_cpu_ms``).
    """

    def __init__(self, config: MappingConfig, intrinsics0: PinholeIntrinsics, seed: int = 0):
        self.config = config
        self.intrinsics = intrinsics0
        self.h, self.w = int(intrinsics0.height), int(intrinsics0.width)
        if self.h < 1 or self.w < 1:
            raise InputError(f"Mapper: invalid image size {self.w}x{self.h}")
        self._rng = np.random.default_rng(seed)
        self._params = mapping_params(config)
        self._cam = np.array([intrinsics0.fx, intrinsics0.fy, intrinsics0.cx, intrinsics0.cy], np.float64)
        self.state: MapState = new_state(self.h, self.w)
        self._spare: MapState = new_state(self.h, self.w)
        self._prop_work = propagation_work(self.h, self.w)
        self._fill_work = fill_work(self.h, self.w)
        self._reg_work = regularize_work(self.h, self.w, int(config.reg_radius))
        self._cur: _Prepared | None = None
        self._buf_images = np.zeros((config.buffer_size, self.h, self.w), np.float32)
        self._buf_T_ref_world = np.zeros((config.buffer_size, 4, 4))    # inverse pose of each slot's frame
        self._status = np.zeros((self.h, self.w), np.int8)             # observe's per-pixel outcome (scratch)
        self._buffer: list[tuple[MapFrame, int]] = []   # (frame, slot), oldest first
        self._iteration = 0
        self._last_costs: dict | None = None
        self._per_search_ms: float | None = None
        self.last_stats = MappingStats()
        self.measure_cpu = False    # also record each stage's CPU time (benchmarks; costs a clock read per stage)
        self.image_version = 0      # the photometric correction its images are in (rescale_images)

    # ------------------------------------------------------------------ helpers
    def _check_frame(self, frame: MapFrame, gradients: bool = True) -> _Prepared:
        # the mapper's own copy: the caller may make its array read-only later (a TrackingReference
        # shares it), and the kernels are compiled for writable arrays only
        img = np.array(frame.image, dtype=np.float32, order="C", copy=True)
        if img.shape != (self.h, self.w):
            raise InputError(f"Mapper: frame {frame.frame_id} image has shape {img.shape}, "
                             f"expected {(self.h, self.w)} (mapping resolution)")
        T = np.asarray(frame.T_world_cam, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"Mapper: frame {frame.frame_id} has an invalid T_world_cam")
        if not gradients:                     # a pure stereo reference needs only its image
            return _Prepared(frame, img, None, None, None)
        gx, gy, mg = image_gradients(img)
        return _Prepared(frame, img, gx, gy, mg)

    @property
    def frame(self) -> MapFrame | None:
        """The frame the current map lives in."""
        return None if self._cur is None else self._cur.frame

    def rescale_images(self, ratio: np.ndarray, version: int) -> None:
        """Re-express the stored images (the stereo references and the current frame, whose gradients
        are recomputed) in a new photometric correction: each is multiplied by ``ratio`` ((H, W), the new
        correction over the old one); ``version`` becomes :attr:`image_version`, the correction the
        frames given to :meth:`update` / :meth:`add_reference` are expected in."""
        ratio = np.asarray(ratio, np.float32)
        if ratio.shape != (self.h, self.w):
            raise InputError(f"Mapper.rescale_images: ratio has shape {ratio.shape}, expected {(self.h, self.w)}")
        for _, slot in self._buffer:
            self._buf_images[slot] *= ratio
        if self._cur is not None:
            img = self._cur.image * ratio
            gx, gy, mg = image_gradients(img)
            self._cur = _Prepared(self._cur.frame, img, gx, gy, mg)
        self.image_version = int(version)

    # ------------------------------------------------------------------ initialisation
    def _reset(self, prep: _Prepared) -> None:
        self.state = new_state(self.h, self.w)
        self._buffer = []
        self._cur = prep
        self._iteration = 0
        self._last_costs = None
        self._per_search_ms = None

    def initialize_random(self, frame: MapFrame) -> None:
        """Chapter 5.2: idepth = min + U(0, range), var = init_var for every pixel with gradient >= min_grad."""
        prep = self._check_frame(frame)
        self._reset(prep)
        cfg, s = self.config, self.state
        mask = prep.maxgrad >= cfg.min_grad
        mask[:1, :] = False
        mask[-1:, :] = False
        mask[:, :1] = False
        mask[:, -1:] = False
        rnd = self._rng.random((self.h, self.w))
        s.idepth[:] = np.where(mask, cfg.random_idepth_min + cfg.random_idepth_range * rnd, 0.0)
        self._init_common(mask, cfg.init_var, frame.frame_id)

    def initialize_from_depth(self, frame: MapFrame, depth_m: np.ndarray) -> None:
        """Hypotheses from a depth image (0 / non-finite = invalid) at pixels with gradient >= min_grad."""
        prep = self._check_frame(frame)
        depth = np.asarray(depth_m, dtype=np.float64)
        if depth.shape != (self.h, self.w):
            raise InputError(f"Mapper: depth image has shape {depth.shape}, expected {(self.h, self.w)}")
        self._reset(prep)
        cfg, s = self.config, self.state
        ok = np.isfinite(depth) & (depth > 0)
        mask = ok & (prep.maxgrad >= cfg.min_grad)
        with np.errstate(divide="ignore", invalid="ignore"):
            s.idepth[:] = np.where(mask, 1.0 / np.where(ok, depth, 1.0), 0.0)
        self._init_common(mask, cfg.depth_init_var, frame.frame_id)

    def initialize_from_idepth(self, frame: MapFrame, idepth: np.ndarray, idepth_var: np.ndarray) -> None:
        """Hypotheses from a stored map (a keyframe): inverse depth and variance (NaN / <= 0 = none)."""
        prep = self._check_frame(frame)
        d = np.asarray(idepth, dtype=np.float64)
        v = np.asarray(idepth_var, dtype=np.float64)
        if d.shape != (self.h, self.w) or v.shape != (self.h, self.w):
            raise InputError(f"Mapper: idepth/var have shape {d.shape}/{v.shape}, expected {(self.h, self.w)}")
        self._reset(prep)
        mask = np.isfinite(d) & (d > 0) & np.isfinite(v) & (v > 0)
        self.state.idepth[:] = np.where(mask, d, 0.0)
        self._init_common(mask, 0.0, frame.frame_id)
        self.state.idepth_var[:] = np.where(mask, v, 0.0)
        self.state.var_s[:] = self.state.idepth_var

    def _init_common(self, mask: np.ndarray, var: float, frame_id: int) -> None:
        s = self.state
        s.idepth_var[:] = np.where(mask, var, 0.0)
        s.idepth_s[:] = s.idepth
        s.var_s[:] = s.idepth_var
        s.valid[:] = mask
        s.validity[:] = np.where(mask, self.config.init_validity, 0.0)
        s.ref_id[:] = frame_id

    # ------------------------------------------------------------------ one iteration
    def update(self, frame: MapFrame) -> MappingStats:
        """Propagate the map into ``frame`` (when it is new), stereo-update it against the
        buffer, regularise and fill holes. Returns the iteration's :class:`MappingStats`."""
        if self._cur is None:
            raise InputError("Mapper.update: the map is not initialised (call initialize_random "
                             "or initialize_from_depth first)")
        stats = MappingStats(frame_id=int(frame.frame_id))
        # the thread's CPU clock only when asked: reading it costs up to milliseconds per call on
        # some (virtualised) machines while parallel kernels run, five times per iteration
        clock = time.perf_counter
        cpu = time.thread_time if self.measure_cpu else _no_clock
        t0, c0 = clock(), cpu()
        if frame.frame_id != self._cur.frame.frame_id:
            prep = self._check_frame(frame)
            self._propagate(prep, stats)
            self._push_reference(self._cur)
            self._cur = prep
        t1, c1 = clock(), cpu()
        self._observe(stats)
        t2, c2 = clock(), cpu()
        self._regularize(stats)
        t3, c3 = clock(), cpu()
        self._fill(stats)
        t4, c4 = clock(), cpu()
        stats.stage_ms = {"propagate": 1e3 * (t1 - t0), "observe": 1e3 * (t2 - t1),
                          "regularize": 1e3 * (t3 - t2), "fill": 1e3 * (t4 - t3)}
        if self.measure_cpu:
            stats.stage_cpu_ms = {"propagate": 1e3 * (c1 - c0), "observe": 1e3 * (c2 - c1),
                                  "regularize": 1e3 * (c3 - c2), "fill": 1e3 * (c4 - c3)}
        stats.valid_count = int(np.count_nonzero(self.state.valid))
        stats.references = len(self._buffer)
        self._last_costs = {"observe_ms": stats.stage_ms["observe"],
                            "other_ms": stats.total_ms - stats.stage_ms["observe"],
                            "searched": max(stats.updated + stats.created + stats.inconsistent
                                            + stats.failed + stats.no_reference + stats.no_epipolar, 1)}
        self._iteration += 1
        self.last_stats = stats
        return stats

    def add_reference(self, frame: MapFrame) -> None:
        """Add a tracked frame that is not mapped into the stereo reference buffer."""
        if self._cur is not None and frame.frame_id == self._cur.frame.frame_id:
            return
        self._push_reference(self._check_frame(frame, gradients=False))

    def _push_reference(self, prep: _Prepared) -> None:
        if any(f.frame_id == prep.frame.frame_id for f, _ in self._buffer):
            return
        if len(self._buffer) >= self.config.buffer_size:
            _, slot = self._buffer.pop(0)
        else:
            used = {s for _, s in self._buffer}
            slot = next(i for i in range(self.config.buffer_size) if i not in used)
        self._buf_images[slot] = prep.image
        self._buf_T_ref_world[slot] = np.linalg.inv(np.asarray(prep.frame.T_world_cam, np.float64))
        self._buffer.append((prep.frame, slot))
        self._buffer.sort(key=lambda e: e[0].frame_id)

    def _propagate(self, new: _Prepared, stats: MappingStats) -> None:
        cfg, old = self.config, self.state
        T_new_old = np.linalg.inv(new.frame.T_world_cam) @ np.asarray(self._cur.frame.T_world_cam, np.float64)
        R = np.ascontiguousarray(T_new_old[:3, :3])
        t = np.ascontiguousarray(T_new_old[:3, 3])
        ns = self._spare                    # double buffer: the kernel resets it (valid, positions, blacklist)
        aff = np.array(affine_transfer(self._cur.frame.affine, new.frame.affine))
        res = kernels.propagate_kernel(old, self._cur.image, new.image, new.maxgrad, R, t, self._cam,
                                       self._params, aff, ns, self._prop_work,
                                       kernels.propagation_bands(numba.get_num_threads()))
        k = cfg.blacklist_recovery_frames
        if k > 0 and self._iteration % k == 0:
            np.add(ns.blacklist, 1, out=ns.blacklist, where=ns.blacklist < 0)
        self._spare = old
        self.state = ns
        stats.propagated = int(np.count_nonzero(ns.valid))
        _, stats.dropped_border, stats.dropped_intensity, stats.occluded, stats.fused_on_propagation = map(int, res)

    def _reference_frames(self) -> RefFrames:
        n = len(self._buffer)
        slots = np.zeros(n, np.int64)
        ids = np.zeros(n, np.int64)
        Rs = np.zeros((n, 3, 3))
        ts = np.zeros((n, 3))
        cs = np.zeros((n, 3))
        res = np.zeros(n)
        aff = np.zeros((n, 2))
        T_world_cur = np.asarray(self._cur.frame.T_world_cam, np.float64)
        for i, (f, slot) in enumerate(self._buffer):
            T_ref_cur = self._buf_T_ref_world[slot] @ T_world_cur     # the inverse computed once, on arrival
            slots[i], ids[i] = slot, f.frame_id
            Rs[i] = T_ref_cur[:3, :3]
            ts[i] = T_ref_cur[:3, 3]
            cs[i] = -T_ref_cur[:3, :3].T @ T_ref_cur[:3, 3]      # reference centre in the current frame
            r = float(f.tracking_residual)
            res[i] = r if np.isfinite(r) and r >= 0 else 0.0   # unknown residual: no extra geometric error
            aff[i] = affine_transfer(f.affine, self._cur.frame.affine)
        return RefFrames(self._buf_images, slots, ids, Rs, ts, cs, res, aff)

    def _budget_stride(self, n_cand: int) -> int:
        """Chapter 3.4: sub-sample the candidates (rotating offset) so the iteration fits the budget.

        From the previous iteration: the cost per searched pixel (smoothed) and the time of the
        other stages; observe always gets at least a quarter of the budget, and the stride changes
        by at most a factor 2 per iteration (no run-away on a noisy clock)."""
        budget = self.config.budget_ms
        if budget <= 0 or self._last_costs is None or n_cand <= 0:
            return 1
        lc = self._last_costs
        if lc["searched"] >= 100:
            per = lc["observe_ms"] / lc["searched"]
            self._per_search_ms = per if self._per_search_ms is None else 0.7 * self._per_search_ms + 0.3 * per
        per = self._per_search_ms
        if per is None or not per > 0:
            return 1
        old = max(self.last_stats.stride, 1)
        allowed = max(budget - lc["other_ms"], 0.25 * budget) / per
        expected = lc["searched"] * old          # searches without sub-sampling
        want = max(1, int(np.ceil(expected / max(allowed, 1.0))))
        return int(min(max(want, old // 2, 1), old * 2))

    def _observe(self, stats: MappingStats) -> None:
        cur, s, cfg = self._cur, self.state, self.config
        n_cand = int(np.count_nonzero(cur.maxgrad >= cfg.min_grad))
        stats.candidates = n_cand
        stride = max(self._budget_stride(n_cand), cfg.stereo_stride)
        stats.stride = stride
        status = self._status          # the kernel writes every pixel it visits; the border stays 0
        if len(self._buffer) > 0 and self.h > 6 and self.w > 6:
            scratch = int(cfg.max_epl_search + cfg.min_epl_search) + 16
            prm = self._params
            sigma = cfg.noise_sigma_gain * cur.frame.noise_sigma
            if np.isfinite(sigma) and sigma > cfg.sigma_i:    # a noisy frame: wider photometric variance
                prm = prm.copy()
                prm[kernels.P_SIGMA_I2] = sigma * sigma
            kernels.observe_kernel(cur.image, cur.gx, cur.gy, cur.maxgrad, self._reference_frames(), s, self._cam,
                                   prm, int(stride), int(self._iteration % stride), scratch, status,
                                   int(numba.get_num_threads()))
        else:
            status.fill(0)
        counts = kernels.count_codes(status, 9)
        stats.no_epipolar, stats.skipped_converged = int(counts[7]), int(counts[8])
        stats.updated, stats.created, stats.inconsistent = int(counts[1]), int(counts[2]), int(counts[3])
        stats.failed, stats.no_reference, stats.removed_gradient = int(counts[4]), int(counts[5]), int(counts[6])

    def _regularize(self, stats: MappingStats) -> None:
        s = self.state
        o_valid = np.zeros_like(s.valid)
        n_before = int(np.count_nonzero(s.valid))
        kernels.regularize_kernel(s, self._params, o_valid, self._reg_work)
        np.copyto(s.valid, o_valid)
        stats.removed_regularize = n_before - int(np.count_nonzero(o_valid))

    def _fill(self, stats: MappingStats) -> None:
        s = self.state
        new_flag = np.zeros_like(s.valid)
        kernels.fill_kernel(s, self._cur.maxgrad, self._params, new_flag, self._fill_work)
        np.bitwise_or(s.valid, new_flag, out=s.valid)
        stats.filled = int(np.count_nonzero(new_flag))

    # ------------------------------------------------------------------ output
    def current(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(idepth, idepth_var, valid) of the map in :attr:`frame` (copies; regularised values;
        0 where invalid)."""
        s = self.state
        out = (np.empty((self.h, self.w), np.float32), np.empty((self.h, self.w), np.float32),
               np.empty((self.h, self.w), np.bool_))
        kernels.masked_map(s.idepth_s, s.var_s, s.valid, *out)
        return out


def depth_accuracy(idepth: np.ndarray, valid: np.ndarray, depth_gt_m: np.ndarray) -> dict:
    """Accuracy of a semi-dense map against a depth image.

    density: share of ALL pixels with a hypothesis; the error statistics compare 1/idepth with the
    ground truth where it is > 0 (and finite): median absolute relative error, share within 5% / 10%.
    """
    idepth = np.asarray(idepth)
    valid = np.asarray(valid, dtype=bool)
    gt = np.asarray(depth_gt_m)
    if idepth.shape != valid.shape or idepth.shape != gt.shape:
        raise InputError(f"depth_accuracy: shapes differ: idepth {idepth.shape}, valid {valid.shape}, "
                         f"depth {gt.shape}")
    n = idepth.size
    density = float(np.count_nonzero(valid)) / n if n else 0.0
    # the tests in the arrays' own type (a float32 value is finite and > 0 exactly when its float64 is),
    # the arithmetic in float64 on the compared pixels only
    m = valid & np.isfinite(gt) & (gt > 0) & np.isfinite(idepth) & (idepth > 0)
    if not np.any(m):
        return {"density": density, "median_abs_rel_error": float("nan"),
                "within_5pct": 0.0, "within_10pct": 0.0, "compared": 0}
    flat = np.flatnonzero(m)                  # gathers the values of gt[m], idepth[m] (same order) faster
    g = gt.reshape(-1).take(flat).astype(np.float64)
    rel = np.abs(1.0 / idepth.reshape(-1).take(flat).astype(np.float64) - g) / g
    return {"density": density, "median_abs_rel_error": float(np.median(rel)),
            "within_5pct": float(np.mean(rel <= 0.05)), "within_10pct": float(np.mean(rel <= 0.10)),
            "compared": int(flat.size)}
