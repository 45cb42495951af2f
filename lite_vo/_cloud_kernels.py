"""numba kernels of the whole-scene point cloud (:func:`lite_vo.keyframes.scene_cloud`).

Owns :func:`support_counts` (the cross-keyframe consistency check: does a neighbouring keyframe have a
hypothesis near a point's projection, and does one of them agree with the point's inverse depth) and
:func:`depth_jump_kernel` (the largest relative inverse-depth step to a hypothesis within a radius). Both
do per point / per pixel what the numpy formulation did with one full-array pass per window offset, with
the same arithmetic (the results are identical: ``tests/naive_cloud.py`` keeps the numpy twins). On ICL
(44 keyframes, 972k points) the cloud of ``map.ply`` took 2.2 s at the end of every run, 1.3 s of it here;
ending a point's window at its first agreeing hypothesis took :func:`lite_vo.keyframes.scene_cloud` on ICL
(39 keyframes, 887k points, ``phone``) from 0.74 to 0.57 s (minimum of six alternating calls), points identical.

Loaded only when a cloud is made (``lite_vo.keyframes`` imports it lazily): a run that writes no cloud never
loads these kernels.

Imports: numpy and numba only.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def support_counts(p_cam, fx, fy, cx, cy, width, height, idepth, rel_tol, win, count, seen_n):
    """For points ``p_cam`` ((N, 3) float64, in the camera of a keyframe with pinhole ``fx, fy, cx, cy`` and
    inverse-depth map ``idepth`` ((height, width), NaN without a hypothesis)): a point in front of the camera
    whose projection, rounded to the nearest pixel, is at least ``win`` pixels inside the image is *seen*
    when a hypothesis lies in the (2 win + 1)^2 window around it and *agrees* when one of those has the
    point's inverse depth within ``rel_tol`` (relative). Adds 1 to ``seen_n`` / ``count`` ((N,) int64) for
    each. The projection is ``fx * x / z + cx`` (as :meth:`PinholeIntrinsics.project`), rounded half to
    even (as ``np.rint``)."""
    n = p_cam.shape[0]
    for i in range(n):
        z = p_cam[i, 2]
        if not (z > 1e-9):
            continue
        # np.int64, not int(): numba compiles the builtin as an out-of-line call
        ui = np.int64(np.rint(fx * p_cam[i, 0] / z + cx))
        vi = np.int64(np.rint(fy * p_cam[i, 1] / z + cy))
        if not (ui >= win and ui < width - win and vi >= win and vi < height - win):
            continue
        want = 1.0 / z
        tol = rel_tol * want
        seen = False
        agree = False
        # the window ends at the first agreeing hypothesis: both answers are then known
        for dv in range(-win, win + 1):
            for du in range(-win, win + 1):
                d = idepth[vi + dv, ui + du]
                if math.isfinite(d):
                    seen = True
                    if abs(d - want) <= tol:
                        agree = True
                        break
            if agree:
                break
        if seen:
            seen_n[i] += 1
        if agree:
            count[i] += 1


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def depth_jump_kernel(idepth, radius, out):
    """Per pixel of ``idepth`` ((H, W) float64, NaN without a hypothesis), the largest ``|d_q - d_p| / d_p``
    over the hypotheses ``q`` within ``radius`` pixels (the pixel itself included: 0), into ``out``; NaN where
    ``p`` has no hypothesis (``d_p`` not finite)."""
    h, w = idepth.shape
    for y in range(h):
        for x in range(w):
            dp = idepth[y, x]
            if not math.isfinite(dp):
                out[y, x] = np.nan
                continue
            m = 0.0
            for yy in range(y - radius, y + radius + 1):
                if yy < 0 or yy >= h:
                    continue
                for xx in range(x - radius, x + radius + 1):
                    if xx < 0 or xx >= w:
                        continue
                    v = abs(idepth[yy, xx] - dp) / dp
                    if v > m:            # NaN (no hypothesis there) never is
                        m = v
            out[y, x] = m


def warmup() -> None:
    """Compile both kernels for the types :mod:`lite_vo.keyframes` calls them with."""
    d32 = np.full((8, 8), np.nan, np.float32)
    d32[3:5, 3:5] = 1.0
    d32.setflags(write=False)             # a keyframe's inverse depth is read-only
    p = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 2.0]])
    count = np.zeros(2, np.int64)
    seen = np.zeros(2, np.int64)
    support_counts(p, 4.0, 4.0, 3.5, 3.5, 8, 8, d32, 0.07, 1, count, seen)
    depth_jump_kernel(d32.astype(np.float64), 2, np.empty((8, 8)))
