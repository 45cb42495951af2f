"""Verification of a random initialisation against two-view geometry, and the two-frame bootstrap.

Random depth initialisation (thesis chapter 5.2) converges only when the first motion suits it;
otherwise the filter settles on a wrong structure (e.g. the inverted-depth solution) and the
tracked motion is wrong although the photometric residual is small. :class:`InitVerifier` watches
the first seconds after a random initialisation:

1. corners of the initialisation frame are followed with pyramidal Lucas-Kanade (OpenCV), at
   ``verify_lk_scale`` times the mapping resolution when the camera has the pixels (frame to frame
   tracking drifts; at twice the resolution it drifts half as much, and the start-up poses are
   only as good as the corners);
2. once their median displacement reaches ``verify_min_parallax_px`` (scaled to the mapping
   width), the essential matrix explains the correspondences clearly better than a homography
   (i.e. there is translation, not only rotation) and the translation direction it gives is known
   to ``verify_max_tdir_std_deg`` (:func:`translation_direction_std_deg`; a motion that is mostly
   rotation leaves it loose, and the map built on it stays wrong for seconds; the bar is lowered
   with time, to three times that at ``verify_max_s``), the relative pose
   from the essential matrix is compared with the pose the VO tracked over the same frames;
3. if they agree (rotation and translation direction within the configured angles) the
   initialisation is accepted; if not, it returns a :class:`Bootstrap`: the init frame and the
   current frame are triangulated, every frame in between gets a PnP pose, all of them are refined
   together by a small bundle adjustment, and the system replays the depth filter with these poses
   (as with ground-truth poses) before tracking goes on.

Owned by the tracking thread. Imports numpy, OpenCV and lite_vo core modules only.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from .camera import PinholeIntrinsics
from .geometry import exp_se3, exp_so3, hat, inverse_se3, log_so3, make_pose

log = logging.getLogger(__name__)


@dataclass
class Bootstrap:
    """Poses ``T_j_init`` (maps init-frame points into frame j) for the stored frames, with the
    scale chosen so that the median depth of the triangulated points in the init frame is 1."""
    T_cur_init: np.ndarray
    T_world_init: np.ndarray                      # pose of the initialisation frame
    T_j_init: dict = field(default_factory=dict)  # frame index -> 4x4 (None when PnP failed)
    frames: list = field(default_factory=list)    # (index, timestamp, image float32) to replay
    reason: str = ""
    affine_j_init: dict = field(default_factory=dict)  # frame index -> (a, b): I_j = a * I_init + b


LCN_SIGMA = 4.0     # px at 320 width: window of the local normalisation the corners are followed in
LCN_EPS = 4.0       # grey levels added to the local contrast (flat and clipped areas stay flat)


def patch_affine(img0: np.ndarray, img1: np.ndarray, p0: np.ndarray, p1: np.ndarray, saturation: float = 250.0,
                 radius: int = 3, min_points: int = 20, min_spread: float = 4.0):
    """Brightness change ``I_1 = a * I_0 + b`` between two images from corresponding points.

    Compares the means of the ``(2 radius + 1)^2`` patches around each pair of points (a mean hardly
    moves with a small tracking error, and an affine change of the pixels is the same change of
    their mean); patches that touch a clipped pixel (at or above ``saturation``, or 0) are left out;
    the line is fitted by least squares, twice more without the points off by more than three robust
    standard deviations (vignetting and occlusions). ``None`` when fewer than ``min_points`` patches
    remain or their means spread by less than ``min_spread`` grey levels (no leverage for a gain).
    """
    import cv2
    k = 2 * radius + 1
    ker = np.ones((k, k), np.uint8)
    vals = []
    for img, p in ((img0, p0), (img1, p1)):
        img = np.asarray(img, np.float32)
        h, w = img.shape
        u = np.rint(p[:, 0]).astype(np.int64)
        v = np.rint(p[:, 1]).astype(np.int64)
        inside = (u >= radius) & (u < w - radius) & (v >= radius) & (v < h - radius)
        u, v = np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)
        mean = cv2.blur(img, (k, k))[v, u]
        hi = cv2.dilate(img, ker)[v, u]
        lo = cv2.erode(img, ker)[v, u]
        vals.append((mean, inside & (hi < saturation) & (lo > 0)))
    (x, ok0), (y, ok1) = vals
    ok = ok0 & ok1
    x, y = x[ok].astype(np.float64), y[ok].astype(np.float64)
    if len(x) < min_points or float(np.std(x)) < min_spread:
        return None
    keep = np.ones(len(x), bool)
    for _ in range(3):
        if keep.sum() < min_points:
            return None
        a, b = np.polyfit(x[keep], y[keep], 1)
        r = y - (a * x + b)
        mad = float(np.median(np.abs(r[keep] - np.median(r[keep])))) * 1.4826
        keep = np.abs(r) <= 3.0 * max(mad, 0.5)
    if not (np.isfinite(a) and np.isfinite(b)) or a <= 0:
        return None
    return float(a), float(b)


def _unit_median_depth(T: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same reconstruction at the scale where the median depth of the points in front is 1."""
    good = rho > 0
    if not good.any():
        return T, rho
    s = float(np.median(1.0 / rho[good]))
    T = T.copy()
    T[:, :3, 3] /= s
    return T, rho * s


def bundle_adjust(K: np.ndarray, T: np.ndarray, rho: np.ndarray, uv: np.ndarray, vis: np.ndarray,
                  iters: int = 100, huber_px: float = 1.0, rel_tol: float = 1e-6, rounds: int = 3):
    """Sparse two-view-start bundle adjustment: corners anchored in view 0 by inverse depth.

    ``T``: (F, 4, 4) poses mapping view 0 into each view (``T[0]`` is the identity and stays);
    ``rho``: (N,) inverse depths of the corners along their rays in view 0 (``uv[0]``); ``uv``:
    (F, N, 2) pixels; ``vis``: (F, N) observations. Levenberg-Marquardt on the reprojection error
    (Huber weights), the inverse depths eliminated by the Schur complement (one unknown each), so
    every view's pose is estimated from all views jointly; the rotation-translation ambiguity of a
    short baseline is what a view-by-view PnP cannot resolve. The scale (a gauge freedom) is held
    at median depth 1 after every accepted step. Runs until a step lowers the cost by less than
    ``rel_tol`` of it (or ``iters`` steps): along the flat valley of a short baseline, a fixed small
    number of steps stops at an arbitrary point of it. A point is projected as ``rho * (R X + t)``
    (``X = ray / rho``): smooth through infinity, so no corner leaves the cost by crossing it;
    corners that end behind the first view (``rho <= 0``, an outlier track) are dropped and the
    rest adjusted again (up to ``rounds`` times). Returns the poses and inverse depths (of every
    corner; the dropped ones keep their last value)."""
    rho = rho.copy()
    use = np.ones(len(rho), bool)
    for _ in range(rounds):
        T, rho[use] = _levenberg_marquardt(K, T, rho[use], uv[:, use], vis[:, use], iters, huber_px, rel_tol)
        behind = use & (rho <= 0)
        if not behind.any() or (use & ~behind).sum() < 6:
            break
        use &= ~behind
    return T, rho


def _levenberg_marquardt(K, T, rho, uv, vis, iters, huber_px, rel_tol):
    """:func:`bundle_adjust`'s inner loop on one set of corners."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    ray = np.stack([(uv[0, :, 0] - cx) / fx, (uv[0, :, 1] - cy) / fy, np.ones(uv.shape[1])], -1)  # (N, 3)
    obs, ob = uv[1:], vis[1:].astype(np.float64)
    F = len(T) - 1
    T, rho = T.copy(), rho.copy()

    def residuals(T, rho):
        q = np.einsum("fij,nj->fni", T[1:, :3, :3], ray) + rho[None, :, None] * T[1:, None, :3, 3]  # rho (R X + t)
        z = q[..., 2]
        ok = z > 1e-6
        zs = np.where(ok, z, 1.0)
        r = np.stack([fx * q[..., 0] / zs + cx, fy * q[..., 1] / zs + cy], -1) - obs
        return r, q, zs, ok

    def cost(r, ok):
        e = np.linalg.norm(r, axis=2)
        w = ob * ok
        h = np.where(e <= huber_px, 0.5 * e * e, huber_px * (e - 0.5 * huber_px))
        return float((w * h).sum())

    T, rho = _unit_median_depth(T, rho)
    r, q, z, ok = residuals(T, rho)
    c = cost(r, ok)
    lam = 1e-3
    converged = False
    for _ in range(iters):
        e = np.linalg.norm(r, axis=2)
        w = ob * ok * np.where(e <= huber_px, 1.0, huber_px / np.maximum(e, 1e-12))        # (F, N)
        dpi = np.zeros(q.shape[:2] + (2, 3))
        dpi[..., 0, 0] = fx / z
        dpi[..., 0, 2] = -fx * q[..., 0] / z ** 2
        dpi[..., 1, 1] = fy / z
        dpi[..., 1, 2] = -fy * q[..., 1] / z ** 2
        Jp = np.concatenate([dpi * rho[None, :, None, None], -dpi @ hat(q)], axis=-1)   # (F, N, 2, 6)
        Jr = np.einsum("fnij,fj->fni", dpi, T[1:, :3, 3])                                 # (F, N, 2)
        Hpp = np.einsum("fnki,fn,fnkj->fij", Jp, w, Jp)
        Hpr = np.einsum("fnki,fn,fnk->fin", Jp, w, Jr)                                    # (F, 6, N)
        Hrr = np.einsum("fnk,fn,fnk->n", Jr, w, Jr)
        gp = np.einsum("fnki,fn,fnk->fi", Jp, w, r)
        gr = np.einsum("fnk,fn,fnk->n", Jr, w, r)
        while True:
            Hrr_d = Hrr * (1.0 + lam) + 1e-9
            S = -np.einsum("fin,gjn,n->figj", Hpr, Hpr, 1.0 / Hrr_d)
            idx = np.arange(F)
            S[idx, :, idx, :] += Hpp + lam * np.einsum("fii->fi", Hpp)[..., None] * np.eye(6)
            S = S.reshape(6 * F, 6 * F)
            bs = (gp - np.einsum("fin,n->fi", Hpr, gr / Hrr_d)).reshape(-1)
            try:
                dp = -np.linalg.solve(S + 1e-9 * np.eye(6 * F), bs).reshape(F, 6)
            except np.linalg.LinAlgError:
                return T, rho
            dr = -(gr + np.einsum("fin,fi->n", Hpr, dp)) / Hrr_d
            T_new = T.copy()
            T_new[1:] = exp_se3(dp) @ T[1:]
            rho_new = rho + dr
            r2, _, _, ok2 = residuals(T_new, rho_new)
            c2 = cost(r2, ok2)
            if c2 < c and np.isfinite(c2):
                converged = c - c2 < rel_tol * c
                T, rho = _unit_median_depth(T_new, rho_new)      # the cost does not change
                r, q, z, ok = residuals(T, rho)
                c = c2
                lam = max(lam / 3.0, 1e-7)
                break
            lam *= 5.0
            if lam > 1e4:
                break
        if lam > 1e4 or converged:
            break
    return T, rho


def translation_direction_std_deg(K: np.ndarray, R: np.ndarray, t: np.ndarray, a: np.ndarray, b: np.ndarray,
                                  sigma_floor_px: float) -> float:
    """How well the corners ``a`` (first view) and ``b`` (second view, pixels) pin down the direction
    of ``t`` in the relative pose ``(R, t)`` (``x_b = R x_a + t``): one standard deviation in degrees
    (the larger axis), from the Gauss-Newton covariance of the signed Sampson errors over rotation
    and translation direction (five unknowns), with the errors' robust spread (at least
    ``sigma_floor_px``) as their noise. Small for a sideways or forward motion seen over many
    corners; large when the motion is mostly rotation (the translation's small share of the
    parallax fits many directions)."""
    Ki = np.linalg.inv(K)
    x1 = np.hstack([a, np.ones((len(a), 1))])
    x2 = np.hstack([b, np.ones((len(b), 1))])
    t = np.asarray(t, np.float64).ravel()
    t = t / np.linalg.norm(t)
    e1 = np.cross(t, np.eye(3)[int(np.argmin(np.abs(t)))])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(t, e1)

    def residuals(p):
        tp = t + e1 * p[3] + e2 * p[4]
        F = Ki.T @ hat(tp / np.linalg.norm(tp)) @ exp_so3(p[:3]) @ R @ Ki
        Fx1 = x1 @ F.T
        Ftx2 = x2 @ F
        den = np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2) + 1e-12
        return np.sum(x2 * Fx1, axis=1) / den

    r = residuals(np.zeros(5))
    J = np.empty((len(r), 5))
    for k in range(5):
        d = np.zeros(5)
        d[k] = 1e-6
        J[:, k] = (residuals(d) - residuals(-d)) / 2e-6
    sigma = max(1.4826 * float(np.median(np.abs(r - np.median(r)))), sigma_floor_px)
    try:
        C = sigma ** 2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return 180.0
    var = float(np.linalg.eigvalsh(C[3:, 3:]).max())
    return float(np.degrees(np.sqrt(var))) if np.isfinite(var) and var > 0 else 180.0


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-12 or nb < 1e-12:
        return 180.0
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / (na * nb), -1.0, 1.0))))


class InitVerifier:
    """Checks a random initialisation with sparse two-view geometry (tracking thread only).

    ``add`` returns ``None`` while undecided, ``"accept"`` when the VO agrees with the
    essential-matrix pose, ``"give_up"`` when no decision is possible (too few corners or out of
    time: the paper's behaviour, the random initialisation is kept), or a :class:`Bootstrap`.
    """

    def __init__(self, config, intrinsics: PinholeIntrinsics, image0: np.ndarray, T_world_init: np.ndarray,
                 index0: int, timestamp0: float, saturation: float = 250.0,
                 lk_intrinsics: PinholeIntrinsics | None = None, lk_image0: np.ndarray | None = None) -> None:
        """``image0``: the first frame at mapping resolution (``intrinsics``); ``lk_image0`` and
        ``lk_intrinsics``: the same frame at the resolution the corners are followed in (then every
        :meth:`observe` and :meth:`add` must get that frame's image at this resolution too); by
        default the mapping resolution."""
        import cv2
        self._cv2 = cv2
        self.cfg = config
        self.saturation = float(saturation)
        self.affine: dict[int, tuple[float, float]] = {}
        self.frames = [(index0, timestamp0, np.asarray(image0, np.float32))]   # for the replay
        if lk_image0 is not None:
            intrinsics, image0 = lk_intrinsics, lk_image0
        self._image0 = np.asarray(image0, np.float32)                           # as the corners see it
        self.K = intrinsics.K
        self.scale_px = intrinsics.width / 320.0
        self.prev = self._lk_normalised(image0)
        img = np.clip(self._image0, 0, 255).astype(np.uint8)
        pts = cv2.goodFeaturesToTrack(img, maxCorners=int(config.verify_features), qualityLevel=0.01,
                                      minDistance=max(3, int(7 * self.scale_px)))
        self.p0 = np.zeros((0, 2), np.float32) if pts is None else pts.reshape(-1, 2).astype(np.float32)
        self.pts = self.p0.copy()
        self.alive = np.ones(len(self.p0), bool)
        self.T_world_init = T_world_init.copy()
        self.index0, self.t0 = index0, timestamp0
        self.tracks: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # index -> (pts, alive)
        self._observed = index0                    # the last frame the corners were followed into
        self._gain = 1.0                           # its gain relative to the init frame (as measured)
        self.done = len(self.p0) < config.verify_min_inliers

    def _lk_normalised(self, image: np.ndarray, gain: float = 1.0) -> np.ndarray:
        """The image locally normalised (zero mean and unit contrast in a Gaussian window of
        ``LCN_SIGMA`` px), 8 bit, for Lucas-Kanade: LK assumes constant brightness, and an
        auto-exposure camera (or vignetting) changes it; the normalised image stays the same under an
        affine brightness change, so the corners do not drift and bias the two-view poses."""
        cv2 = self._cv2
        img = np.asarray(image, np.float32)
        m = cv2.GaussianBlur(img, (0, 0), LCN_SIGMA * self.scale_px)
        v = cv2.GaussianBlur(img * img, (0, 0), LCN_SIGMA * self.scale_px) - m * m
        z = (img - m) / (np.sqrt(np.maximum(v, 0.0)) + LCN_EPS * gain)
        return np.clip(128.0 + 40.0 * z, 0, 255).astype(np.uint8)

    def observe(self, index: int, image: np.ndarray) -> tuple[float, float] | None:
        """Follow the corners into frame ``index`` and measure its brightness relative to the init
        frame (``I = a I_init + b`` on the corners' patch means): independent of the map's depths, so
        the tracker can hold it while the random map cannot say (see :meth:`add`). Returns ``(a, b)``,
        or None when it cannot be measured (too few unclipped corners with enough spread) or the
        verification is over. Called at most once per frame; :meth:`add` calls it when the caller did not.
        ``image``: at the corners' resolution (see the constructor)."""
        if self.done:
            return None
        if index == self._observed:
            return self.affine.get(index)
        if np.shape(image) != self._image0.shape:
            raise ValueError(f"start-up check: frame {index} is {np.shape(image)}, the corners follow {self._image0.shape}")
        cv2 = self._cv2
        self._observed = index
        # always in the normalised images: switching to them when the exposure starts to move shifts
        # the corners (their centre is not the same in both kinds of image), and they cost nothing
        # in accuracy on a constant exposure (ICL, random init: ATE 0.88 -> 0.71 % of the path)
        cur = self._lk_normalised(image, self._gain)
        nxt, st, _ = cv2.calcOpticalFlowPyrLK(self.prev, cur, self.pts.reshape(-1, 1, 2), None,
                                              winSize=(15, 15), maxLevel=3)
        self.alive &= st.ravel() == 1
        self.pts = nxt.reshape(-1, 2)
        h, w = cur.shape
        inside = (self.pts[:, 0] >= 0) & (self.pts[:, 0] < w) & (self.pts[:, 1] >= 0) & (self.pts[:, 1] < h)
        self.alive &= inside
        rel = patch_affine(self._image0, image, self.p0[self.alive], self.pts[self.alive], self.saturation)
        if rel is not None:
            self.affine[index] = rel
            self._gain = rel[0]
        self.prev = cur
        self.tracks[index] = (self.pts.copy(), self.alive.copy())
        return self.affine.get(index)

    def add(self, index: int, timestamp: float, image: np.ndarray, T_world_cam: np.ndarray | None,
            lk_image: np.ndarray | None = None):
        """The frame's tracked pose ``T_world_cam`` (None: lost) against the two-view geometry of the
        corners followed so far: ``None`` (undecided), ``"accept"``, ``"give_up"`` or a :class:`Bootstrap`.
        ``image``: at mapping resolution (replayed by a bootstrap); ``lk_image``: at the corners'
        resolution when it is another one."""
        if self.done:
            return None
        cfg = self.cfg
        if timestamp - self.t0 > cfg.verify_max_s:
            self.done = True
            log.info("init verification: no decision within %.1f s, keeping the random initialisation", cfg.verify_max_s)
            return "give_up"
        if index != self._observed:
            self.observe(index, image if lk_image is None else lk_image)
        cv2 = self._cv2
        self.frames.append((index, timestamp, np.asarray(image, np.float32)))
        a, b = self.p0[self.alive], self.pts[self.alive]
        if len(a) < cfg.verify_min_inliers:
            self.done = True
            return "give_up"
        parallax = float(np.median(np.linalg.norm(a - b, axis=1)))
        if parallax < cfg.verify_min_parallax_px * self.scale_px:
            return None
        # USAC with local optimisation: much more accurate translation directions than plain RANSAC
        method = getattr(cv2, "USAC_ACCURATE", cv2.RANSAC)
        thr = cfg.verify_ransac_px * self.scale_px
        E, inl_e = cv2.findEssentialMat(a, b, self.K, method, 0.999, thr)
        if E is None or E.shape[0] < 3 or inl_e is None:
            return None
        _, inl_h = cv2.findHomography(a, b, method, thr)
        n_e = int(inl_e.sum())
        n_h = int(inl_h.sum()) if inl_h is not None else 0
        if n_e < cfg.verify_min_inliers or n_e < cfg.verify_eh_ratio * n_h:
            return None  # rotation-dominated so far: wait for translation
        _, R, t, mask = cv2.recoverPose(E[:3], a, b, self.K, mask=inl_e.copy())
        if mask is None or int((mask.ravel() > 0).sum()) < cfg.verify_min_inliers:
            return None  # too few points in front of both cameras: no decision yet
        front = mask.ravel() > 0
        tdir_std = translation_direction_std_deg(self.K, R, t, a[front], b[front], 0.1 * self.scale_px)
        # the bar is lowered with time (3x at verify_max_s) so a start that keeps rotating still bootstraps
        if tdir_std > cfg.verify_max_tdir_std_deg * (1.0 + 2.0 * (timestamp - self.t0) / cfg.verify_max_s):
            return None  # mostly rotation so far: the translation direction is still loose
        T_e = make_pose(R, t.ravel())  # T_cur_init, unit translation
        if T_world_cam is not None:
            T_vo = inverse_se3(T_world_cam) @ self.T_world_init
            rot = float(np.degrees(np.linalg.norm(log_so3(R @ T_vo[:3, :3].T))))
            tdir = _angle_deg(t.ravel(), T_vo[:3, 3])
            if rot <= cfg.verify_max_rot_deg and tdir <= cfg.verify_max_tdir_deg and not cfg.bootstrap_always:
                self.done = True
                log.info("init verification: accepted at frame %d (rotation %.2f deg, translation direction %.1f deg)",
                         index, rot, tdir)
                return "accept"
            agree = rot <= cfg.verify_max_rot_deg and tdir <= cfg.verify_max_tdir_deg
            reason = (f"tracked motion {'agrees with' if agree else 'disagrees with'} two-view geometry "
                      f"(rotation {rot:.1f} deg, direction {tdir:.0f} deg)")
        else:
            reason = "tracking lost during initialisation"
        boot = self._bootstrap(a, b, T_e, mask.ravel() > 0, index, reason)
        self.done = True
        return boot

    def _bootstrap(self, a, b, T_e, inl, index, reason):
        cv2 = self._cv2
        P0 = self.K @ np.hstack([np.eye(3), np.zeros((3, 1))])
        P1 = self.K @ T_e[:3]
        X = cv2.triangulatePoints(P0, P1, np.ascontiguousarray(a[inl].T, np.float64),
                                  np.ascontiguousarray(b[inl].T, np.float64))
        if X is None:
            return "give_up"
        X = (X[:3] / X[3]).T
        z1 = (X @ T_e[:3, :3].T + T_e[:3, 3])[:, 2]
        good = (X[:, 2] > 0) & (z1 > 0)
        if good.sum() < self.cfg.verify_min_inliers:
            return "give_up"
        scale = float(np.median(X[good, 2]))
        X = X / scale
        T_e = T_e.copy()
        T_e[:3, 3] /= scale
        # PnP for every stored frame with the corners that were inliers at the decision frame
        alive_idx = np.nonzero(self.alive)[0][inl][good]
        pts3 = X[good]
        T_j: dict[int, np.ndarray | None] = {self.index0: np.eye(4), index: T_e}
        for j, (pts, alive) in self.tracks.items():
            if j == index:
                continue
            ok = alive[alive_idx]
            if ok.sum() < 12:
                T_j[j] = None
                continue
            found, rvec, tvec = cv2.solvePnP(pts3[ok], pts[alive_idx][ok].astype(np.float64), self.K, None,
                                             flags=cv2.SOLVEPNP_EPNP)
            if found:
                found, rvec, tvec = cv2.solvePnP(pts3[ok], pts[alive_idx][ok].astype(np.float64), self.K, None,
                                                 rvec, tvec, True, flags=cv2.SOLVEPNP_ITERATIVE)
            T_j[j] = make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel()) if found else None
        T_j, T_e = self._refine(T_j, alive_idx, pts3[:, 2], index)
        log.debug("start-up: %s at frame %d; the map is rebuilt from two views (%d points)",
                    reason, index, len(pts3))
        return Bootstrap(T_cur_init=T_e, T_world_init=self.T_world_init, T_j_init=T_j, frames=list(self.frames),
                         reason=reason, affine_j_init=dict(self.affine))

    def _refine(self, T_j, alive_idx, z_init, index):
        """The poses of every stored view and the depths ``z_init`` (init frame) of the corners that were
        inliers at the decision frame, adjusted together (:func:`bundle_adjust`)."""
        views = [self.index0] + [j for j in sorted(self.tracks) if T_j.get(j) is not None]
        F, N = len(views), len(alive_idx)
        uv = np.zeros((F, N, 2))
        vis = np.zeros((F, N), bool)
        T = np.zeros((F, 4, 4))
        uv[0], vis[0], T[0] = self.p0[alive_idx], True, np.eye(4)
        for f, j in enumerate(views[1:], 1):
            pts, alive = self.tracks[j]
            uv[f], vis[f], T[f] = pts[alive_idx], alive[alive_idx], T_j[j]
        T, _ = bundle_adjust(self.K, T, 1.0 / z_init, uv, vis)
        out = dict(T_j)
        for f, j in enumerate(views):
            out[j] = T[f]
        return out, out[index]
