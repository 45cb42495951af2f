"""Relocalisation after a tracking loss: re-track a new frame against stored keyframes.

Candidates (LSD-SLAM's Relocalizer, ALGORITHM_NOTES "Real cameras"): the ``reloc_pose_candidates``
keyframes nearest by pose to the last good pose, then the ``reloc_thumb_candidates`` best by a tiny
thumbnail's SSD against the new frame (zero-mean, unit-variance 16x12 thumbnails). Each candidate
is tracked from its own pose (and, when ORB features match, from a PnP pose of the matches with the
keyframe's semi-dense depth: a guess for view changes beyond the direct basin); a result is accepted
when it passes the tracker's lost test, with the residual-spread bound ``reloc_max_abs_residual``
(20 grey levels; tracking's ``max_abs_residual`` is 15: a keyframe seen from elsewhere leaves
occlusions and view-dependent shading in the residuals; on ICL with 40 frames cut out the right
keyframe spread 15.1-15.3 with 92 % good residuals), and the stricter ``reloc_min_good_ratio``. Of the accepted
candidates the one whose pose is best determined wins (once one candidate is accepted, the others are
tracked again from the pose it found: their own pose or features may have been outside the basin; on
ICL with 40 frames cut out the better-converged keyframe 24 was reached only this way, ATE 1.46 ->
0.40 % with affine brightness): the smallest residual over the square root of
the number of good residuals (a standard error; the residual alone ties at noise level between a
keyframe that sees little of the new frame and one that sees much of it: on the synthetic loop 0.96
against 0.99 with 7,400 and 10,700 good points).

Brightness: the brightness of a stored keyframe relative to a frame after a jump is unknown, and
estimating it jointly with a pose that is still far off lets the gain collapse towards 0 (a flattened
reference "explains" a misaligned image: measured on ICL with 40 frames cut out, the right keyframe
converged to a wrong pose or failed the lost test, the wrong ones to gains of 0.1-0.3). So every
candidate is tracked with the brightness held at ``affine_guess`` (default ``(1, 0)``: the
keyframe's), which also makes the candidates' residuals comparable, and only the winner's pose and
brightness are then refined jointly (when ``affine_brightness`` is on; the refinement is kept when it
passes the same tests).

Keyframes are duck-typed (``index``, ``T_world_cam``, ``camera``, ``image`` uint8, ``idepth`` and
``idepth_var`` NaN where empty, as :class:`lite_vo.keyframes.Keyframe`). Tracking thread only.
Imports numpy, cv2, lite_vo (geometry, image, keyframes) and this package only.
"""
from __future__ import annotations

import dataclasses
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import inverse_se3, project_to_se3
from ..image import image_pyramid
from ..keyframes import pose_distance
from .config import TrackingConfig
from .reference import TrackingReference
from .tracker import Tracker, TrackingResult

THUMB_SIZE = (16, 12)


@dataclass
class Relocalisation:
    """A successful relocalisation: the keyframe, the new frame's pose and the tracking result."""
    keyframe: object
    T_world_new: np.ndarray
    result: TrackingResult
    guess: str                    # "keyframe" (from its own pose), "pnp" (feature guess) or "shared" (from the
                                  # pose another candidate found)
    tried: int                    # tracking calls made


def thumbnail(image: np.ndarray) -> np.ndarray:
    """Zero-mean, unit-variance 16x12 thumbnail (float32) of a grey image."""
    t = cv2.resize(np.asarray(image, dtype=np.float32), THUMB_SIZE, interpolation=cv2.INTER_AREA)
    t -= t.mean()
    return t / max(float(t.std()), 1e-6)


def _score(tr: TrackingResult) -> float:
    """Candidate choice, lower is better: the residual over the square root of the good residuals."""
    return tr.residual / np.sqrt(max(tr.good_ratio * tr.points_used, 1.0))


class Relocalizer:
    """Tries to re-track lost frames against keyframes (see the module docstring)."""

    def __init__(self, config: TrackingConfig, tracker: Tracker, pyramid_levels: int, track_level: int):
        self.config = config
        self.tracker = tracker
        # candidates are tracked with the brightness held fixed (see the module docstring)
        # and with the spread bound of relocalisation: an old keyframe seen from elsewhere leaves more
        # occlusions and view-dependent shading in the residuals than the last frame does
        self._fixed = Tracker(dataclasses.replace(config, affine_brightness=False,
                                                  max_abs_residual=config.reloc_max_abs_residual),
                              tracker.intrinsics0, pyramid_levels, track_level)
        self.pyramid_levels = int(pyramid_levels)
        self.track_level = int(track_level)
        self._refs: OrderedDict = OrderedDict()       # keyframe index -> TrackingReference (LRU)
        self._thumbs: dict = {}                       # keyframe index -> thumbnail
        self._features: dict = {}                     # keyframe index -> (points3d, descriptors)
        self._orb = None
        self.attempts = 0
        self.successes = 0

    # ------------------------------------------------------------------ caches
    def _reference(self, kf) -> TrackingReference:
        ref = self._refs.get(kf.index)
        if ref is not None and ref.frame_id == (kf.index, id(kf)):
            self._refs.move_to_end(kf.index)
            return ref
        img = np.asarray(kf.image, dtype=np.float32)
        pyr = image_pyramid(img, self.pyramid_levels)
        d = np.asarray(kf.idepth, dtype=np.float32)
        v = np.asarray(kf.idepth_var, dtype=np.float32)
        valid = np.isfinite(d) & (d > 0) & np.isfinite(v) & (v > 0)
        ref = TrackingReference.build(pyr, np.where(valid, d, 0), np.where(valid, v, 0), valid, kf.camera,
                                      (kf.index, id(kf)), smooth_sigma=self.config.smooth_sigma,
                                      min_level=self.track_level)
        self._refs[kf.index] = ref
        while len(self._refs) > self.config.reloc_cache:
            self._refs.popitem(last=False)
        return ref

    def _thumb(self, kf) -> np.ndarray:
        t = self._thumbs.get(kf.index)
        if t is None:
            t = self._thumbs[kf.index] = thumbnail(kf.image)
        return t

    def _kf_features(self, kf):
        f = self._features.get(kf.index)
        if f is not None and f[2] is kf:
            return f[0], f[1]
        kps, des = self._detect(kf.image)
        pts3, keep = [], []
        d = np.asarray(kf.idepth)
        h, w = d.shape
        for i, kp in enumerate(kps):
            u, v = int(round(kp.pt[0])), int(round(kp.pt[1]))
            win = d[max(v - 1, 0):min(v + 2, h), max(u - 1, 0):min(u + 2, w)]
            win = win[np.isfinite(win) & (win > 0)]
            if win.size:
                pts3.append(kf.camera.unproject_idepth(np.array([kp.pt[0]]), np.array([kp.pt[1]]),
                                                        np.array([float(np.median(win))]))[0])
                keep.append(i)
        out = (np.asarray(pts3, np.float64).reshape(-1, 3), des[keep] if des is not None and keep else None)
        self._features[kf.index] = (out[0], out[1], kf)
        return out

    def _detect(self, image):
        if self._orb is None:
            self._orb = cv2.ORB_create(nfeatures=self.config.reloc_features, fastThreshold=10, edgeThreshold=15,
                                       patchSize=15)
        img = np.clip(np.asarray(image, dtype=np.float32) + 0.5, 0, 255).astype(np.uint8)
        return self._orb.detectAndCompute(img, None)

    def forget(self, keep_indices) -> None:
        """Drop cached data of keyframes that left the store."""
        keep = set(keep_indices)
        for cache in (self._refs, self._thumbs, self._features):
            for k in [k for k in cache if k not in keep]:
                del cache[k]

    # ------------------------------------------------------------------ candidates
    def candidates(self, keyframes, T_world_last, image) -> list:
        """Candidate keyframes, best first: nearest by pose to ``T_world_last``, then by thumbnail SSD."""
        kfs = list(keyframes)
        if not kfs:
            return []
        c = self.config
        out = []
        if T_world_last is not None and c.reloc_pose_candidates > 0:
            depths = [k.median_depth for k in kfs if np.isfinite(getattr(k, "median_depth", np.nan))]
            depth = float(np.median(depths)) if depths else 1.0
            by_pose = sorted(kfs, key=lambda k: pose_distance(k.T_world_cam, T_world_last, depth))
            out += by_pose[:c.reloc_pose_candidates]
        if c.reloc_thumb_candidates > 0:
            t = thumbnail(image)
            by_thumb = sorted(kfs, key=lambda k: float(np.sum((self._thumb(k) - t) ** 2)))
            out += [k for k in by_thumb if all(k is not o for o in out)][:c.reloc_thumb_candidates]
        return out

    def _pnp_guess(self, kf, new_kps, new_des):
        """``T_kf_new`` from ORB matches and the keyframe's depth (None when too few inliers)."""
        pts3, des = self._kf_features(kf)
        if des is None or new_des is None or len(pts3) < self.config.reloc_min_inliers:
            return None
        matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(des, new_des)
        if len(matches) < self.config.reloc_min_inliers:
            return None
        obj = np.array([pts3[m.queryIdx] for m in matches], np.float64)
        img = np.array([new_kps[m.trainIdx].pt for m in matches], np.float64)
        cam = kf.camera
        K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]], np.float64)
        cv2.setRNGSeed(0)
        ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, K, None, iterationsCount=200, reprojectionError=2.0,
                                                 confidence=0.99, flags=cv2.SOLVEPNP_EPNP)
        if not ok or inl is None or len(inl) < self.config.reloc_min_inliers:
            return None
        T_new_kf = np.eye(4)
        T_new_kf[:3, :3] = cv2.Rodrigues(rvec)[0]
        T_new_kf[:3, 3] = tvec.ravel()
        if not np.all(np.isfinite(T_new_kf)):
            return None
        return inverse_se3(project_to_se3(T_new_kf))

    # ------------------------------------------------------------------ relocalise
    def relocalise(self, keyframes, T_world_last, pyramid, image, affine_guess=(1.0, 0.0),
                   sigma_i=None) -> Relocalisation | None:
        """Try the candidates against the new frame (``pyramid`` as for :meth:`Tracker.track`);
        ``affine_guess``: the new frame's brightness relative to a keyframe, held fixed while the
        candidates are tried."""
        c = self.config
        self.attempts += 1
        cands = self.candidates(keyframes, T_world_last, image)
        best, tried = None, 0
        new_feat = None
        for kf in cands:
            ref = self._reference(kf)
            guesses = [("keyframe", np.eye(4))]
            if c.reloc_features > 0:
                if new_feat is None:
                    new_feat = self._detect(image)
                g = self._pnp_guess(kf, *new_feat)
                if g is not None:
                    guesses.insert(0, ("pnp", g))
            for name, guess in guesses:
                tried += 1
                tr = self._fixed.track(ref, pyramid, guess, affine_guess, sigma_i)
                if not self._accepted(tr):
                    continue
                if best is None or _score(tr) < _score(best[2]):
                    best = (kf, name, tr)
                break
        if best is None:
            return None
        # the other candidates again, from the pose the winner found (a guess inside their basin)
        T_world_new = np.asarray(best[0].T_world_cam, np.float64) @ best[2].T_ref_new
        for kf in cands:
            if kf is best[0]:
                continue
            tried += 1
            guess = inverse_se3(np.asarray(kf.T_world_cam, np.float64)) @ T_world_new
            tr = self._fixed.track(self._reference(kf), pyramid, guess, affine_guess, sigma_i)
            if self._accepted(tr) and _score(tr) < _score(best[2]):
                best = (kf, "shared", tr)
        kf, name, tr = best
        if self.config.affine_brightness:   # the joint pose + brightness estimate, from the winner's
            tried += 1
            joint = self.tracker.track(self._reference(kf), pyramid, tr.T_ref_new, tr.affine, sigma_i)
            if self._accepted(joint):
                tr = joint
        self.successes += 1
        T_world_new = project_to_se3(np.asarray(kf.T_world_cam, np.float64) @ tr.T_ref_new)
        return Relocalisation(kf, T_world_new, tr, name, tried)

    def _accepted(self, tr: TrackingResult) -> bool:
        return not tr.lost and tr.good_ratio >= self.config.reloc_min_good_ratio and bool(np.all(np.isfinite(tr.T_ref_new)))
