"""World model of the AR demo: semi-dense map -> in-painted low-resolution grid -> mesh (occlusion),
plus the height field fused over the keyframes (:mod:`ar_demo.heightfield`, collision), built
synchronously (:func:`build_world`) or in a worker thread (:class:`AsyncWorldModelBuilder`, Fig. 5.7:
updated asynchronously at a lower rate than tracking).

Thread ownership of :class:`AsyncWorldModelBuilder`:
* caller thread: ``submit`` (replaces any pending job: only the newest map matters), ``poll``
  (takes the newest finished model), ``close``;
* worker thread: runs the builds; it only reads the submitted arrays (the caller hands over
  copies and never writes them) and publishes each finished model under the lock.

Imports: numpy, ar_demo (inpaint, mesh, ground), lite_vo (camera).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from lite_vo.camera import PinholeIntrinsics

from .ground import GroundPlane
from .inpaint import InpaintResult, inpaint, reduce_idepth
from .mesh import CollisionMesh, grid_mesh


@dataclass
class WorldModel:
    frame_id: int
    timestamp: float
    T_world_cam: np.ndarray
    grid_intrinsics: PinholeIntrinsics
    inpaint: InpaintResult
    mesh: CollisionMesh
    build_ms: float
    stage_ms: dict | None = None      # "reduce", "inpaint", "mesh", "fuse"
    field: object = None              # ar_demo.heightfield.HeightField fused over the keyframes


def build_world(published, keyframes, ground: GroundPlane, cfg, fusion) -> WorldModel:
    """The newest map's in-painted mesh (occlusion in the video) and the height field fused over
    ``keyframes`` and that map (the collision world)."""
    t0 = time.perf_counter()
    model = build_world_model(published.idepth, published.idepth_var, published.camera, published.T_world_cam,
                              ground, cfg, published.frame_index, published.timestamp)
    t1 = time.perf_counter()
    model.field = fusion.fuse(keyframes, extra=[published])
    model.stage_ms["fuse"] = (time.perf_counter() - t1) * 1e3
    model.build_ms = (time.perf_counter() - t0) * 1e3
    return model


def build_world_model(idepth: np.ndarray, idepth_var: np.ndarray, intrinsics: PinholeIntrinsics,
                      T_world_cam: np.ndarray, ground: GroundPlane, cfg, frame_id: int = -1,
                      timestamp: float = 0.0) -> WorldModel:
    """In-paint the semi-dense map (NaN / non-positive idepth = empty) on the ground-plane prior
    and turn the grid into a world-frame collision mesh."""
    t0 = time.perf_counter()
    gi = intrinsics.scaled(cfg.grid_width, cfg.grid_height)
    prior = ground.idepth_grid(T_world_cam, gi)
    D, V, _ = reduce_idepth(idepth, idepth_var, prior.shape)
    t1 = time.perf_counter()
    res = inpaint(D, V, prior, cfg.alpha, cfg.huber_delta, cfg.ground_var, cfg.min_var,
                  cfg.solver_iterations, cfg.solver_tol)
    t2 = time.perf_counter()
    floor = cfg.mesh_idepth_floor_rel * res.scale
    mesh = grid_mesh(res.idepth, gi, T_world_cam, cfg.max_depth_ratio, floor, frame_id, timestamp)
    t3 = time.perf_counter()
    stages = {"reduce": (t1 - t0) * 1e3, "inpaint": (t2 - t1) * 1e3, "mesh": (t3 - t2) * 1e3}
    return WorldModel(frame_id, timestamp, np.array(T_world_cam, dtype=np.float64), gi, res, mesh,
                      (t3 - t0) * 1000.0, stages)


class AsyncWorldModelBuilder:
    """Builds world models in one worker thread; the newest submitted job wins."""

    def __init__(self, cfg, ground: GroundPlane, fusion):
        self.cfg = cfg
        self.ground = ground
        self.fusion = fusion                    # owned by the worker thread from now on
        self._cond = threading.Condition()
        self._job: tuple | None = None          # guarded by _cond
        self._result: WorldModel | None = None  # guarded by _cond
        self._error: BaseException | None = None
        self._stop = False
        self.busy = False
        self.built = 0
        self.dropped = 0
        self._thread = threading.Thread(target=self._run, name="ar-world-model", daemon=True)
        self._thread.start()

    def submit(self, published, keyframes) -> None:
        """A job: the newest map and a keyframe snapshot (both immutable, so they are not copied)."""
        job = (published, list(keyframes))
        with self._cond:
            if self._job is not None:
                self.dropped += 1
            self._job = job
            self._cond.notify_all()

    def poll(self) -> WorldModel | None:
        """The newest finished model since the last poll (None if none)."""
        with self._cond:
            if self._error is not None:
                err, self._error = self._error, None
                raise err
            res, self._result = self._result, None
            return res

    def wait_idle(self, timeout: float | None = None) -> None:
        """Block until no job is pending or running (used at the end and in deterministic runs)."""
        with self._cond:
            self._cond.wait_for(lambda: self._job is None and not self.busy, timeout)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._job is not None or self._stop)
                if self._stop:
                    return
                job, self._job = self._job, None
                self.busy = True
            try:
                model = build_world(job[0], job[1], self.ground, self.cfg, self.fusion)
            except BaseException as err:  # handed to the caller by poll()
                model = None
                with self._cond:
                    self._error = err
            with self._cond:
                if model is not None:
                    self._result = model
                    self.built += 1
                self.busy = False
                self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join()
