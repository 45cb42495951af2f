"""The vignette model and its fit to the VO's own maps (the core of :mod:`lite_vo.vignette`), and
:class:`OnlineVignette`, the estimate made while the VO runs (``system.auto_vignette``).

Model, correspondences and fit: see :mod:`lite_vo.vignette`. This module imports nothing of the
session layer, so the VO (:mod:`lite_vo.system`) can use it. numpy only.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .errors import InputError

log = logging.getLogger(__name__)

#: at most this many correspondences are kept from one pair of maps (evenly spaced)
MAX_POINTS_PER_PAIR = 3000
#: a pair of maps this many frames apart or more is not used (re-initialisation, relocalisation)
MAX_FRAME_GAP = 12
#: fewer correspondences than this in a pair: the pair is skipped
MIN_POINTS_PER_PAIR = 200
#: intensities at or above this are clipped (not proportional to the irradiance)
SATURATION = 250.0
#: std of the pixel position error (px at map resolution) that weights each residual by its gradient
POSITION_SIGMA_PX = 0.5
#: std of the intensity noise (grey levels) in the same weights
INTENSITY_SIGMA = 3.0


def radial_frame(camera) -> tuple[float, float, float]:
    """``(cx, cy, r2max)`` of a pinhole camera (:class:`~lite_vo.camera.PinholeIntrinsics`): the
    principal point and the squared distance from it to the farthest image corner."""
    cx, cy = float(camera.cx), float(camera.cy)
    xs, ys = (0.0, camera.width - 1.0), (0.0, camera.height - 1.0)
    return cx, cy, max((x - cx) ** 2 + (y - cy) ** 2 for x in xs for y in ys)


def radius2(x: np.ndarray, y: np.ndarray, frame: tuple[float, float, float]) -> np.ndarray:
    """``rho^2`` of pixels in the :func:`radial_frame` ``frame``."""
    cx, cy, r2max = frame
    return ((x - cx) ** 2 + (y - cy) ** 2) / r2max


def vignette_of(k: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """``V = 1 + k1 rho^2 + k2 rho^4 + k3 rho^6`` at ``rho^2 = r2``."""
    k1, k2, k3 = (float(v) for v in k)
    return 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))


def _basis(r2: np.ndarray) -> np.ndarray:
    return np.stack([r2, r2 * r2, r2 * r2 * r2], axis=-1)


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    ix = np.floor(x).astype(np.int64)
    iy = np.floor(y).astype(np.int64)
    dx, dy = x - ix, y - iy
    a, b = img[iy, ix], img[iy, ix + 1]
    c, d = img[iy + 1, ix], img[iy + 1, ix + 1]
    return (1 - dx) * (1 - dy) * a + dx * (1 - dy) * b + (1 - dx) * dy * c + dx * dy * d


@dataclass
class PairSamples:
    """Correspondences between two published maps (map-resolution pixels)."""
    r2_old: np.ndarray
    r2_new: np.ndarray
    i_old: np.ndarray
    i_new: np.ndarray
    weight: np.ndarray


def correspondences(old, new, max_points: int = MAX_POINTS_PER_PAIR) -> PairSamples | None:
    """The pixels of the map ``old`` (a :class:`~lite_vo.session.PublishedMap`) projected into the
    frame of the map ``new`` with their intensities in both images, or None when the pair is
    unusable (too far apart in frames, different image sizes, too few points)."""
    if not 0 < new.frame_index - old.frame_index < MAX_FRAME_GAP:
        return None
    h, w = old.image.shape
    if new.image.shape != (h, w):
        return None
    ok = old.valid & (old.idepth_raw > 1e-6)
    v, u = np.nonzero(ok)
    if len(u) < MIN_POINTS_PER_PAIR:
        return None
    step = max(1, len(u) // max_points)
    v, u = v[::step], u[::step]
    T = np.linalg.inv(np.asarray(new.T_world_cam, np.float64)) @ np.asarray(old.T_world_cam, np.float64)
    q = old.camera.unproject_idepth(u, v, old.idepth_raw[v, u]) @ T[:3, :3].T + T[:3, 3]
    ok = q[:, 2] > 1e-9
    q, v, u = q[ok], v[ok], u[ok]
    un, vn = new.camera.project(q).T
    inside = (un >= 1) & (vn >= 1) & (un < w - 2) & (vn < h - 2)
    if int(inside.sum()) < MIN_POINTS_PER_PAIR:
        return None
    u, v, un, vn = u[inside], v[inside], un[inside], vn[inside]
    img_new = np.asarray(new.image, np.float64)
    i_old = np.asarray(old.image, np.float64)[v, u]
    i_new = _bilinear(img_new, un, vn)
    gx = 0.5 * (_bilinear(img_new, un + 1, vn) - _bilinear(img_new, un - 1, vn))
    gy = 0.5 * (_bilinear(img_new, un, vn + 1) - _bilinear(img_new, un, vn - 1))
    keep = (i_old < SATURATION) & (i_new < SATURATION) & (i_old > 2.0) & (i_new > 2.0)
    if int(keep.sum()) < MIN_POINTS_PER_PAIR:
        return None
    weight = 1.0 / (INTENSITY_SIGMA ** 2 + POSITION_SIGMA_PX ** 2 * (gx * gx + gy * gy))
    frame = radial_frame(old.camera)
    return PairSamples(radius2(u.astype(np.float64), v.astype(np.float64), frame)[keep],
                       radius2(un, vn, frame)[keep], i_old[keep], i_new[keep], weight[keep])


@dataclass
class VignetteFit:
    """The fitted radial vignette and how well the data constrained it."""
    k: np.ndarray                               # (k1, k2, k3)
    pairs: int                                  # pairs of maps used
    samples: int                                # correspondences used
    residual_rms: float                         # weighted-inlier RMS of the intensity residual (grey levels)
    corner: float                               # V at the image corners (rho = 1), relative to the centre
    corner_std: float                           # its standard deviation from the fit's covariance
    iterations: int
    frame: tuple                                # radial_frame of the map camera the fit was made in

    def to_dict(self) -> dict:
        return {"written": True, "model": "V = 1 + k1 rho^2 + k2 rho^4 + k3 rho^6, rho = distance from the principal point / "
                         "its distance to the farthest image corner (map image)",
                "k": [float(v) for v in self.k], "corner": self.corner, "corner_std": self.corner_std,
                "pairs": self.pairs, "samples": self.samples, "residual_rms": self.residual_rms,
                "iterations": self.iterations, "centre": list(self.frame[:2]), "corner_radius": self.frame[2] ** 0.5}


#: a pair whose median normalised residual (no vignette, its own exposure fit) is this many times the
#: median over all pairs is left out: its points do not correspond (a re-initialised map, a bad pose)
PAIR_OUTLIER_FACTOR = 3.0


def _consistent(pairs: list) -> list:
    """The pairs (enough points) whose correspondences agree about as well as the others'."""
    pairs = [p for p in pairs if p is not None and len(p.i_old) >= MIN_POINTS_PER_PAIR]
    if len(pairs) < 3:
        return pairs
    spread = []
    for p in pairs:
        A = np.stack([p.i_old, np.ones_like(p.i_old)], axis=1) * np.sqrt(p.weight)[:, None]
        ab = np.linalg.lstsq(A, p.i_new * np.sqrt(p.weight), rcond=None)[0]
        spread.append(np.median(np.abs(p.i_new - ab[0] * p.i_old - ab[1]) * np.sqrt(p.weight)))
    spread = np.array(spread)
    keep = spread <= PAIR_OUTLIER_FACTOR * np.median(spread)
    return [p for p, k in zip(pairs, keep) if k]


def fit_vignette(pairs: list[PairSamples], frame: tuple, iterations: int = 30,
                 huber: float = 2.0) -> VignetteFit:
    """Fit ``k`` to the correspondences of several pairs of maps (see the module docstring).

    Pairs whose points disagree far more than the others' are left out first (:data:`PAIR_OUTLIER_FACTOR`).
    Raises :class:`InputError` when there are not enough pairs (a run too short or hardly moving)."""
    pairs = _consistent(pairs)
    if len(pairs) < 3:
        raise InputError(f"vignette estimate: only {len(pairs)} usable pairs of maps (at least 3 needed: "
                         "a longer run, or one that moves the camera)")
    pid = np.concatenate([np.full(len(p.i_old), i) for i, p in enumerate(pairs)])
    r2o = np.concatenate([p.r2_old for p in pairs])
    r2n = np.concatenate([p.r2_new for p in pairs])
    io = np.concatenate([p.i_old for p in pairs])
    inew = np.concatenate([p.i_new for p in pairs])
    w0 = np.concatenate([p.weight for p in pairs])
    bo, bn = _basis(r2o), _basis(r2n)
    n = len(pairs)
    k = np.zeros(3)
    a = np.ones(n)
    b = np.zeros(n)
    wr = np.ones_like(io)
    H = np.eye(3)
    it = 0
    for it in range(1, iterations + 1):
        vo, vn = 1.0 + bo @ k, 1.0 + bn @ k
        x = vn / vo * io
        # per pair: (a, b) by weighted least squares of inew ~ a x + b
        w = w0 * wr
        sw = np.bincount(pid, w, n)
        sx = np.bincount(pid, w * x, n)
        sy = np.bincount(pid, w * inew, n)
        sxx = np.bincount(pid, w * x * x, n)
        sxy = np.bincount(pid, w * x * inew, n)
        det = sw * sxx - sx * sx
        good = det > 1e-12 * np.maximum(sw * sxx, 1e-300)
        a = np.where(good, (sw * sxy - sx * sy) / np.where(good, det, 1.0), 1.0)
        b = np.where(good, (sy - a * sx) / np.maximum(sw, 1e-300), 0.0)
        r = inew - a[pid] * x - b[pid]
        # Huber weights: a residual beyond ``huber`` times its expected spread (1 / sqrt(w0)) counts less
        scale = huber / np.sqrt(w0)
        wr = np.where(np.abs(r) <= scale, 1.0, scale / np.maximum(np.abs(r), 1e-12))
        w = w0 * wr
        # Gauss-Newton on k: d r / d k = -a x (phi(u) / V(u) - phi(p) / V(p))
        J = -(a[pid] * x)[:, None] * (bn / vn[:, None] - bo / vo[:, None])
        H = J.T @ (J * w[:, None])
        g = J.T @ (w * r)
        step = np.linalg.solve(H + 1e-9 * np.trace(H) * np.eye(3), -g)
        k = k + step
        if np.max(np.abs(step)) < 1e-6:
            break
    vo, vn = 1.0 + bo @ k, 1.0 + bn @ k
    r = inew - a[pid] * (vn / vo) * io - b[pid]
    inl = np.abs(r) <= huber / np.sqrt(w0)
    rms = float(np.sqrt(np.mean(r[inl] ** 2))) if inl.any() else float("nan")
    # covariance of k from the weighted normal equations, scaled by the residual variance per weight
    sigma2 = float(np.sum(w * r * r) / max(len(r) - 3 - 2 * n, 1))
    cov = np.linalg.pinv(H) * sigma2
    grad_corner = np.ones(3)                     # d V(1) / d k
    corner = float(vignette_of(k, np.array(1.0)))
    corner_std = float(np.sqrt(max(grad_corner @ cov @ grad_corner, 0.0)))
    return VignetteFit(k, n, len(io), rms, corner, corner_std, it, tuple(frame))


#: an estimate is only written when the corners' brightness is known to this standard deviation ...
MAX_CORNER_STD = 0.02
#: ... and lies in this range (a lens darkens its corners; brighter corners mean the data did not fit)
CORNER_RANGE = (0.2, 1.03)


def fit_problem(fit: VignetteFit) -> str | None:
    """Why ``fit`` should not be used (a camera that hardly moved across the image, data that do not
    fit a vignette), or None."""
    if not fit.corner_std <= MAX_CORNER_STD:
        return (f"the corners' brightness is too uncertain ({100 * fit.corner:.0f} +- {100 * fit.corner_std:.1f} %; "
                f"at most +- {100 * MAX_CORNER_STD:.0f} %): the camera must move so that points cross the image")
    lo, hi = CORNER_RANGE
    if not lo <= fit.corner <= hi:
        return (f"the corners would be {100 * fit.corner:.0f} % as bright as the centre (expected "
                f"{100 * lo:.0f}-{100 * hi:.0f} %): the data do not fit a lens vignette")
    return None


def vignette_image(fit: VignetteFit, camera, map_camera) -> np.ndarray:
    """The vignette at the camera's native resolution (float, maximum 1), for DSO's
    ``vignette.png``. The fit lives in the rectified map image: each native pixel is undistorted
    through the lens model (``camera``: :class:`~lite_vo.camera.Camera`) and projected with the map's
    pinhole intrinsics (``map_camera``: :class:`~lite_vo.camera.PinholeIntrinsics`, the published maps')."""
    intr = camera.intrinsics
    W, H = intr.width, intr.height
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = camera.unproject(np.stack([xs.ravel(), ys.ravel()], axis=-1))          # undistorted normalised
    ux = map_camera.fx * rays[:, 0] + map_camera.cx
    uy = map_camera.fy * rays[:, 1] + map_camera.cy
    r2 = radius2(ux, uy, fit.frame).reshape(H, W)
    v = vignette_of(fit.k, np.where(np.isfinite(r2), r2, 1.0))
    v = np.clip(v, 1e-3, None)
    return v / v.max()


#: an online estimate is fitted once this many usable pairs of maps were collected in one correction's images
ONLINE_PAIRS = 6
#: each published map is paired with this many maps before it (all within MAX_FRAME_GAP frames)
ONLINE_PARTNERS = 3
#: correspondences kept per pair online (a fit over the most pairs, ONLINE_MAX_FIT_PAIRS, takes 20-100 ms)
ONLINE_POINTS_PER_PAIR = 2000
#: a first estimate whose corners are at least this bright (relative to the centre) is no vignette worth
#: correcting: the estimator stops and the images stay as they are. Clean ICL: 105.5 +- 0.9 %; ICL with a 50 %
#: vignette: 50-59 % (seeds 1-12 of tools/augment.py with every effect); KITTI 07's real camera: 92.5 %, and
#: correcting it (two rounds, to 72-77 %) left ATE as it was and made RPE worse on 8 of 10 seeds (4.95 -> 5.35 %
#: median): a mild fall-off is not worth a correction the run has to guess
ONLINE_MIN_CORNER_DROP = 0.15
#: a later round whose residual correction moves the corners by less than this ends the estimate
ONLINE_CONVERGED = 0.02
#: a later round that would change the corners by more than this factor is not a refinement but a disagreement
#: (seen in realtime mode, where the mapping thread skips frames: 51 -> 33 % on a 50 % vignette): the
#: estimate ends with the corrections it has
ONLINE_MAX_REFINE = (0.7, 1.43)
#: at most this many corrections are applied (each round fits what the previous ones left)
ONLINE_MAX_ROUNDS = 2
#: a fit uses at most the latest this many pairs
ONLINE_MAX_FIT_PAIRS = 24
#: give up when this many pairs in one round did not give an acceptable fit (a camera that hardly moves)
ONLINE_MAX_PAIRS = 60


class OnlineVignette:
    """The vignette estimated while the VO runs (``system.auto_vignette``), so a camera nobody calibrated
    gets its darker corners corrected from the run's first seconds on.

    Fed every published map (:meth:`offer`, with the correction its frame's image was made with; the
    start-up's replayed maps at once: :meth:`offer_maps`), each paired with the :data:`ONLINE_PARTNERS`
    maps before it; once :data:`ONLINE_PAIRS` pairs were collected, fits :func:`fit_vignette` to (at most
    :data:`ONLINE_MAX_FIT_PAIRS` of) them. An estimate that passes :func:`fit_problem` and darkens the corners by more than
    :data:`ONLINE_MIN_CORNER_DROP` becomes the correction of the following frames (:meth:`offer`
    returns the new inverse vignette at mapping resolution; the caller applies it and re-expresses its
    stored images in it). Maps made with the new correction then give what is left (the first pass's
    maps were built from vignetted images, which flattens the fall-off), and the product is applied
    again, until a round changes the corners by less than :data:`ONLINE_CONVERGED`, by more than a
    refinement (:data:`ONLINE_MAX_REFINE`), or after :data:`ONLINE_MAX_ROUNDS` corrections. A first
    estimate that leaves the corners within :data:`ONLINE_MIN_CORNER_DROP` of the centre (or none at all
    within :data:`ONLINE_MAX_PAIRS` pairs) ends it without a change. ``camera``: the mapping
    resolution's :class:`~lite_vo.camera.PinholeIntrinsics`.
    """

    def __init__(self, camera) -> None:
        self.frame = radial_frame(camera)
        h, w = int(camera.height), int(camera.width)
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
        self._r2 = radius2(xs, ys, self.frame)
        self.vignette = np.ones((h, w))         # the correction applied so far (maximum 1)
        self.version = 0                        # how many corrections were applied
        self.done = False
        self.fits: list[VignetteFit] = []       # the accepted fits, in order
        self.reason = ""                        # why it ended
        self._pairs: list[PairSamples] = []
        self._tried = 0
        self._previous: list = []              # the latest maps (each new map is paired with them)

    @property
    def corner(self) -> float:
        """The correction's brightness in its darkest image corner (1 before the first correction)."""
        v = self.vignette
        return float(min(v[0, 0], v[0, -1], v[-1, 0], v[-1, -1]))

    def offer(self, published, version: int) -> np.ndarray | None:
        """A published map whose image was corrected with correction ``version``. Returns the inverse
        of a new correction (float32, mapping resolution; multiply the images with it) when one was
        accepted, else None."""
        return self.offer_maps([published], version)

    def offer_maps(self, maps: list, version: int) -> np.ndarray | None:
        """Several consecutive maps at once (the start-up's replayed maps: one fit over all of them)."""
        if self.done:
            return None
        if version != self.version:             # made before the last correction reached the frames
            self._previous = []
            return None
        for published in maps:
            previous = self._previous
            self._previous = (previous + [published])[-ONLINE_PARTNERS:]
            new = [p for p in (correspondences(q, published, ONLINE_POINTS_PER_PAIR) for q in previous)
                   if p is not None]
            self._pairs.extend(new)
            self._tried += len(new)
        self._pairs = self._pairs[-ONLINE_MAX_FIT_PAIRS:]
        if len(self._pairs) < ONLINE_PAIRS:
            return None
        try:
            fit = fit_vignette(self._pairs, self.frame)
        except InputError:
            fit = None
        if (self.version == 0 and fit is not None and fit.corner_std <= MAX_CORNER_STD
                and fit.corner >= 1.0 - ONLINE_MIN_CORNER_DROP):
            self._finish(f"no vignetting to correct (corners {100 * fit.corner:.1f} +- {100 * fit.corner_std:.1f} %)")
            return None
        problem = "no fit" if fit is None else fit_problem(fit)
        if problem:
            if self._tried >= ONLINE_MAX_PAIRS:
                self._finish(f"no estimate after {self._tried} pairs of maps; the last fit: {problem}")
            return None
        if self.version > 0 and abs(fit.corner - 1.0) < ONLINE_CONVERGED:
            self._finish(f"converged (what was left: {100 * fit.corner:.1f} % at the corners)")
            return None
        if self.version > 0 and not ONLINE_MAX_REFINE[0] <= fit.corner <= ONLINE_MAX_REFINE[1]:
            self._finish(f"kept the estimate: a later round would move the corners to {100 * fit.corner:.1f} % of it "
                         f"(more than a refinement)")
            return None
        v = self.vignette * vignette_of(fit.k, self._r2)
        v = np.clip(v / v.max(), 1e-3, None)
        self.vignette = v
        self.fits.append(fit)
        self.version += 1
        self._pairs, self._tried, self._previous = [], 0, []
        log.info("vignette estimated during the run (correction %d): %.1f %% at the corners (%d pairs of maps)",
                 self.version, 100 * self.corner, fit.pairs)
        if self.version >= ONLINE_MAX_ROUNDS:
            self._finish(f"{self.version} corrections applied")
        return (1.0 / v).astype(np.float32)

    def restart(self) -> None:
        """A new map (another scale, or an unverified random one): the next map is not paired with the
        ones before (the pairs collected so far stay: each is consistent in itself)."""
        self._previous = []

    def stop(self, reason: str) -> None:
        """End the estimate where it is (the corrections made so far stay), with ``reason``."""
        self._finish(reason)

    def _finish(self, reason: str) -> None:
        self.done = True
        self.reason = reason
        self._pairs, self._previous = [], []
        log.info("vignette estimate during the run ended: %s", reason)
