"""Camera calibration from views of a chessboard (or a ChArUco board) with OpenCV.

The steps of ``lite-vo calibrate``:

1. :func:`iter_images` reads grey images from a video, an image folder or a live camera (at most
   ``max_candidates`` frames spread evenly over a file source);
2. :func:`detect_board` finds the board's inner corners (``cv2.findChessboardCornersSB`` refined
   by ``cv2.cornerSubPix``, or the ChArUco detector);
3. :func:`select_views` keeps at most ``max_views`` well-spread views: greedy farthest-point
   sampling over board centre, apparent size and tilt (perspective foreshortening of the board's
   sides), so near-duplicates of a hand-held sweep do not dominate;
4. :func:`calibrate_views` runs ``cv2.calibrateCameraExtended`` (radial-tangential k1 k2 p1 p2,
   k3 on request), drops views whose reprojection error is far above the others and calibrates
   again; the result has the RMS and per-view errors and the share of the image the corners
   covered (:func:`coverage`).

Too few good views is an :class:`~lite_vo.errors.InputError` saying what to do. Imports numpy,
``lite_vo.camera``, ``lite_vo.errors``; cv2 lazily.
"""
from __future__ import annotations

import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Optional

import numpy as np

from .camera import Camera, PinholeIntrinsics
from .errors import InputError

#: fewer good views than this and the calibration is refused
MIN_VIEWS = 8
#: a view whose RMS error exceeds this multiple of the median (and 1 px) is dropped
OUTLIER_FACTOR = 3.0
COVERAGE_GRID = (8, 6)


@dataclass(frozen=True)
class Board:
    """A calibration board. ``kind`` ``"chessboard"``: ``cols`` x ``rows`` inner corners (OpenCV's
    pattern size); ``"charuco"``: ``cols`` x ``rows`` squares with ArUco markers of side ``marker``
    from ``dictionary`` (e.g. ``DICT_5X5_100``). Lengths in metres."""
    kind: str
    cols: int
    rows: int
    square: float
    marker: float = 0.0
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self):
        if self.kind not in ("chessboard", "charuco"):
            raise InputError(f"unknown board kind {self.kind!r} (chessboard, charuco)")
        if self.cols < 2 or self.rows < 2:
            raise InputError(f"board needs at least 2x2 {'inner corners' if self.kind == 'chessboard' else 'squares'}, "
                             f"got {self.cols}x{self.rows}")
        if not (np.isfinite(self.square) and self.square > 0):
            raise InputError(f"--square must be a positive length in metres, got {self.square}")
        if self.kind == "charuco" and not (0 < self.marker < self.square):
            raise InputError(f"--marker must be positive and smaller than --square ({self.square}), got {self.marker}")

    def describe(self) -> str:
        if self.kind == "chessboard":
            return f"chessboard {self.cols}x{self.rows} inner corners, {self.square * 1000:g} mm squares"
        return (f"ChArUco {self.cols}x{self.rows} squares ({self.dictionary}), {self.square * 1000:g} mm squares, "
                f"{self.marker * 1000:g} mm markers")

    def chessboard_points(self) -> np.ndarray:
        """(rows*cols, 3) float32 object points in OpenCV's corner order, z = 0."""
        j, i = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.stack([j.ravel() * self.square, i.ravel() * self.square, np.zeros(j.size)], -1).astype(np.float32)


def parse_pattern(text: str, what: str) -> tuple[int, int]:
    """``"9x6"`` -> (9, 6); a one-line InputError otherwise."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text or "")
    if not m:
        raise InputError(f"{what} must be COLSxROWS (e.g. 9x6), got {text!r}")
    return int(m.group(1)), int(m.group(2))


@dataclass
class View:
    """One detection: ``image_points`` (N, 2) and ``object_points`` (N, 3), float32."""
    name: str
    image_points: np.ndarray
    object_points: np.ndarray

    def features(self, width: int, height: int) -> np.ndarray:
        """(centre x, centre y, size, tilt x, tilt y), each roughly in [-1, 1]."""
        p = self.image_points.astype(np.float64)
        centre = p.mean(0)
        hull_area = _polygon_area(_convex_hull(p))
        size = np.sqrt(hull_area / (width * height))
        tilt = _tilt(p, self.object_points)
        return np.array([2 * centre[0] / width - 1, 2 * centre[1] / height - 1, 2 * size, *tilt])


@dataclass
class Result:
    """A calibration: the camera, RMS and per-view errors (pixels), corner coverage."""
    camera: Camera
    rms: float
    view_errors: list = field(default_factory=list)       # [(name, rms px)] of the views used
    dropped: list = field(default_factory=list)           # [(name, rms px)] dropped as outliers
    coverage: float = 0.0
    coverage_map: str = ""
    frames_read: int = 0
    boards_found: int = 0


# ------------------------------------------------------------------------------------------------
# geometry helpers
# ------------------------------------------------------------------------------------------------

def _convex_hull(p: np.ndarray) -> np.ndarray:
    import cv2
    return cv2.convexHull(p.astype(np.float32)).reshape(-1, 2).astype(np.float64)


def _polygon_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))


def _tilt(img: np.ndarray, obj: np.ndarray) -> tuple[float, float]:
    """Foreshortening of the board along its x and y axes: log of the ratio of the apparent
    scale at the two ends (0 for a board facing the camera), from the board-to-image homography."""
    import cv2
    H, _ = cv2.findHomography(obj[:, :2].astype(np.float64), img.astype(np.float64), 0)
    if H is None:
        return 0.0, 0.0
    lo, hi = obj[:, :2].min(0), obj[:, :2].max(0)
    mid = 0.5 * (lo + hi)
    d = 0.05 * (hi - lo)

    def scale(x, y):  # local apparent size of a small board patch at (x, y)
        q = np.array([[x - d[0], y - d[1]], [x + d[0], y - d[1]], [x + d[0], y + d[1]], [x - d[0], y + d[1]]])
        r = cv2.perspectiveTransform(q.reshape(-1, 1, 2), H).reshape(-1, 2)
        return max(_polygon_area(r), 1e-12)

    tx = 0.5 * np.log(scale(hi[0], mid[1]) / scale(lo[0], mid[1]))
    ty = 0.5 * np.log(scale(mid[0], hi[1]) / scale(mid[0], lo[1]))
    return float(np.clip(tx, -1, 1)), float(np.clip(ty, -1, 1))


# ------------------------------------------------------------------------------------------------
# detection
# ------------------------------------------------------------------------------------------------

class _Charuco:
    def __init__(self, board: Board):
        import cv2
        aruco = getattr(cv2, "aruco", None)
        if aruco is None or not hasattr(aruco, "CharucoDetector"):
            raise InputError("ChArUco boards need OpenCV's aruco module with CharucoDetector (OpenCV >= 4.7)")
        if not hasattr(aruco, board.dictionary):
            raise InputError(f"unknown ArUco dictionary {board.dictionary!r} (e.g. DICT_4X4_50, DICT_5X5_100, "
                             "DICT_6X6_250)")
        dictionary = aruco.getPredefinedDictionary(getattr(aruco, board.dictionary))
        self.board = aruco.CharucoBoard((board.cols, board.rows), board.square, board.marker, dictionary)
        self.detector = aruco.CharucoDetector(self.board)

    def detect(self, grey: np.ndarray):
        corners, ids, _, _ = self.detector.detectBoard(grey)
        if ids is None or len(ids) < 6:
            return None
        obj, img = self.board.matchImagePoints(corners, ids)
        if obj is None or len(obj) < 6:
            return None
        return img.reshape(-1, 2).astype(np.float32), obj.reshape(-1, 3).astype(np.float32)


class BoardDetector:
    """Finds ``board`` in grey images: (image points (N, 2), object points (N, 3)) or None."""

    def __init__(self, board: Board):
        self.board = board
        self._charuco = _Charuco(board) if board.kind == "charuco" else None
        self._obj = board.chessboard_points() if board.kind == "chessboard" else None

    def __call__(self, grey: np.ndarray):
        import cv2
        if self._charuco is not None:
            return self._charuco.detect(grey)
        pattern = (self.board.cols, self.board.rows)
        # CALIB_CB_ACCURACY is ~4x slower and was less accurate than cornerSubPix on rendered boards
        ok, corners = cv2.findChessboardCornersSB(grey, pattern,
                                                  flags=cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE)
        if not ok or corners is None or len(corners) != pattern[0] * pattern[1]:
            return None
        grid = corners.reshape(pattern[1], pattern[0], 2)
        spacing = min(np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
                      np.linalg.norm(np.diff(grid, axis=1), axis=2).min())
        win = int(np.clip(0.3 * spacing, 2, 7))           # stay clear of the neighbouring corners
        corners = cv2.cornerSubPix(grey, np.ascontiguousarray(corners, np.float32), (win, win), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3))
        return corners.reshape(-1, 2).astype(np.float32), self._obj


def detect_board(grey: np.ndarray, board: Board):
    """One-off detection (builds the detector each time; use :class:`BoardDetector` in loops)."""
    return BoardDetector(board)(grey)


# ------------------------------------------------------------------------------------------------
# sources
# ------------------------------------------------------------------------------------------------

def _to_grey(img: np.ndarray) -> np.ndarray:
    import cv2
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    if img.dtype == np.uint16:
        img = (img.astype(np.float32) / 257.0 + 0.5).astype(np.uint8)
    return img


def iter_images(source, max_candidates: int = 200, duration_s: float = 60.0,
                warn: Callable[[str], None] = lambda m: None) -> Iterator[tuple[str, np.ndarray, int, Optional[int]]]:
    """(name, grey image, frames read so far, total or None) from a video file, an image folder
    or a camera index. File sources are subsampled evenly to at most ``max_candidates`` frames;
    a camera is read for ``duration_s`` seconds. Unreadable images are skipped with ``warn``."""
    import cv2

    from .io.sequences import IMAGE_EXTENSIONS, VIDEO_EXTENSIONS, natural_key
    if isinstance(source, (int, np.integer)) or (isinstance(source, str) and source.isdigit()
                                                 and not Path(source).exists()):
        index = int(source)
        cap = cv2.VideoCapture(index)
        if not cap.isOpened():
            raise InputError(f"camera {index}: cannot open (no such device or it is busy)")
        try:
            t_end = time.monotonic() + duration_s
            k = 0
            while time.monotonic() < t_end:
                ok, img = cap.read()
                if not ok or img is None:
                    break
                k += 1
                yield f"camera {index} frame {k - 1}", _to_grey(img), k, None
        finally:
            cap.release()
        return
    p = Path(source).expanduser()
    if not p.exists():
        raise InputError(f"{p}: no such file or directory")
    if p.is_dir():
        files = sorted((c for c in p.iterdir() if c.is_file() and c.suffix.lower() in IMAGE_EXTENSIONS),
                       key=lambda c: natural_key(c.name))
        if not files:
            raise InputError(f"{p}: no image files")
        pick = np.unique(np.linspace(0, len(files) - 1, min(max_candidates, len(files))).round().astype(int))
        for n, i in enumerate(pick):
            img = cv2.imread(str(files[i]), cv2.IMREAD_UNCHANGED)
            if img is None:
                warn(f"{files[i]}: cannot read image, skipped")
                continue
            yield files[i].name, _to_grey(img), n + 1, len(pick)
        return
    if p.suffix.lower() not in VIDEO_EXTENSIONS:
        raise InputError(f"{p}: expected a video file ({'/'.join(VIDEO_EXTENSIONS)}), an image folder or a camera index")
    cap = cv2.VideoCapture(str(p))
    if not cap.isOpened():
        raise InputError(f"{p}: cannot open video (unsupported codec or not a video)")
    try:
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        step = max(1, int(np.ceil(n / max_candidates))) if n > 0 else 1
        i = 0
        read = 0
        while True:
            ok = cap.grab()
            if not ok:
                break
            if i % step == 0:
                ok, img = cap.retrieve()
                if ok and img is not None:
                    read += 1
                    yield f"frame {i}", _to_grey(img), read, (n + step - 1) // step if n > 0 else None
            i += 1
    finally:
        cap.release()
    if i == 0:
        raise InputError(f"{p}: video contains no readable frame")


# ------------------------------------------------------------------------------------------------
# selection, calibration, coverage
# ------------------------------------------------------------------------------------------------

def select_views(views: list, width: int, height: int, max_views: int = 40) -> list:
    """At most ``max_views`` views spread over board centre, size and tilt: greedy farthest-point
    sampling in feature space, starting from the largest board (deterministic)."""
    if len(views) <= max_views:
        return list(views)
    f = np.array([v.features(width, height) for v in views])
    chosen = [int(np.argmax(f[:, 2]))]
    dist = np.linalg.norm(f - f[chosen[0]], axis=1)
    while len(chosen) < max_views:
        j = int(np.argmax(dist))
        chosen.append(j)
        dist = np.minimum(dist, np.linalg.norm(f - f[j], axis=1))
    return [views[j] for j in sorted(chosen)]


def coverage(views: list, width: int, height: int, grid: tuple[int, int] = COVERAGE_GRID) -> tuple[float, str]:
    """Share of the ``grid`` cells of the image that hold at least one detected corner, and a
    small text map of them (``#`` covered, ``.`` not)."""
    gx, gy = grid
    hit = np.zeros((gy, gx), bool)
    for v in views:
        p = v.image_points
        cx = np.clip((p[:, 0] + 0.5) * gx / width, 0, gx - 1).astype(int)
        cy = np.clip((p[:, 1] + 0.5) * gy / height, 0, gy - 1).astype(int)
        hit[cy, cx] = True
    rows = ["".join("#" if h else "." for h in row) for row in hit]
    return float(hit.mean()), "\n".join(rows)


def _calibrate_once(views: list, width: int, height: int, k3: bool):
    import cv2
    obj = [v.object_points.reshape(-1, 1, 3) for v in views]
    img = [v.image_points.reshape(-1, 1, 2) for v in views]
    flags = 0 if k3 else cv2.CALIB_FIX_K3
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, D, _, _, _, _, per_view = cv2.calibrateCameraExtended(obj, img, (width, height), None, None,
                                                                  flags=flags, criteria=crit)
    return float(rms), K, np.asarray(D, dtype=np.float64).ravel(), np.asarray(per_view, dtype=np.float64).ravel()


def calibrate_views(views: list, width: int, height: int, *, k3: bool = False, min_views: int = MIN_VIEWS) -> Result:
    """Calibrate from ``views`` (radial-tangential; k3 only when asked: a few views cannot pin it
    down); views with an error above ``OUTLIER_FACTOR`` x the median (and 1 px) are dropped and the
    calibration is run again."""
    if len(views) < min_views:
        raise InputError(f"only {len(views)} views with the whole board (need at least {min_views}): move the board "
                         "through the whole image, nearer and farther, tilted left/right and up/down")
    rms, K, D, per_view = _calibrate_once(views, width, height, k3)
    limit = max(OUTLIER_FACTOR * float(np.median(per_view)), 1.0)
    keep = [v for v, e in zip(views, per_view) if e <= limit]
    dropped = [(v.name, float(e)) for v, e in zip(views, per_view) if e > limit]
    if dropped:
        if len(keep) < min_views:
            raise InputError(f"only {len(keep)} good views after dropping {len(dropped)} with large errors "
                             f"(need at least {min_views}): record more views of the board, sharp and still")
        views = keep
        rms, K, D, per_view = _calibrate_once(views, width, height, k3)
    d = D[:5] if len(D) >= 5 else np.concatenate([D, np.zeros(5 - len(D))])
    pin = PinholeIntrinsics(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), width, height)
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(d)) and pin.fx > 0 and pin.fy > 0):
        raise InputError("the calibration did not converge (non-finite or negative focal length): "
                         "record more, better spread views of the board")
    camera = Camera(pin, "radtan", tuple(float(x) for x in d)) if np.any(d != 0) else Camera(pin)
    cov, cmap = coverage(views, width, height)
    return Result(camera, rms, [(v.name, float(e)) for v, e in zip(views, per_view)], dropped, cov, cmap)


def calibrate_source(source, board: Board, *, max_views: int = 40, min_views: int = MIN_VIEWS,
                     max_candidates: int = 200, duration_s: float = 60.0, k3: bool = False,
                     progress: Optional[Callable[[str], None]] = None,
                     warn: Callable[[str], None] = lambda m: print(m, file=sys.stderr)) -> Result:
    """Detect ``board`` in ``source`` (video, image folder, camera index), select views, calibrate.

    ``progress`` receives a line every ~2 s during detection and before calibrating."""
    detector = BoardDetector(board)
    views: list[View] = []
    size: Optional[tuple[int, int]] = None
    frames = 0
    t_last = time.monotonic()
    for name, grey, k, total in iter_images(source, max_candidates, duration_s, warn):
        frames += 1
        h, w = grey.shape[:2]
        if size is None:
            size = (w, h)
        elif (w, h) != size:
            warn(f"{name}: image is {w}x{h}, the first was {size[0]}x{size[1]}; skipped")
            continue
        found = detector(grey)
        if found is not None:
            views.append(View(name, *found))
        if progress is not None and time.monotonic() - t_last > 2.0:
            progress(f"looking for the board: image {k}{'/' + str(total) if total else ''}, found in {len(views)}")
            t_last = time.monotonic()
    if size is None:
        raise InputError(f"{source}: no image could be read")
    if len(views) < min_views:
        raise InputError(f"{source}: the board ({board.describe()}) was found in only {len(views)} of {frames} images "
                         f"(need at least {min_views}); check COLSxROWS (inner corners for a chessboard), and show "
                         "the whole board, sharp, in many positions")
    chosen = select_views(views, size[0], size[1], max_views)
    if progress is not None:
        progress(f"calibrating with {len(chosen)} of {len(views)} views")
    res = calibrate_views(chosen, size[0], size[1], k3=k3, min_views=min_views)
    res.frames_read, res.boards_found = frames, len(views)
    return res
